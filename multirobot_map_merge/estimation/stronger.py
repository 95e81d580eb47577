"""A weak match of a single grid waits while that grid matches another grid clearly better, as a pair.

A building of identical parts (a hall of pillars, shops around an atrium, a maze of equal cells) lets a map fit a
map it shares nothing with, a quarter or half turn away, well enough to pass the rules; the same map also fits the
map it really overlaps, as a pair, with more support and without contradictions. On the generated 36-map buildings
(seeds 0-2 of `bench_merge.py --generated`) such matches agreed 0.935-0.987 and put 1-11 maps of a building off
(every right pair there agreed 0.99 or better); which one came first depended on the random draw.

So a grid accepted onto a few grids (FEW_MEMBERS) with an agreement below WEAK_AGREEMENT is matched as a
pair against every grid outside them (descriptors only; each pair once per estimation); accepted onto a larger
union so, against the grids it was matched with as a pair already (a union is judged on all its members' walls,
and weak matches onto large unions are common where walls are irregular). When one of those pairs agrees by
AGREEMENT_MARGIN better with more support, the weak match waits (it counts as refused, not as a contradiction): the
grid joins through the stronger pair, and that group meets the other one later as a union. A real map that agrees
weakly with every map (furniture moved between two passes) has no stronger pair and joins as before.
"""
from __future__ import annotations

from typing import Callable, Dict, Iterable, Optional, Sequence, Tuple

from .features import PreparedGrid
from .pair import PairMatch
from .settings import EstimationSettings
from .workers import MatchCall, ParallelMatcher

WEAK_AGREEMENT = 0.99     # below this an accepted match is checked against the grid's pairs
AGREEMENT_MARGIN = 0.01   # a pair agreeing this much better (with more support) is the stronger evidence
FEW_MEMBERS = 3           # a weak match onto this many grids or fewer is checked against all of the grid's pairs


class PairEvidence:
    """Descriptor matches of pairs of grids, each computed once per estimation (in parallel, by `matcher`)."""

    def __init__(self, prepared: Sequence[Optional[PreparedGrid]], matcher: ParallelMatcher):
        self.prepared, self.s, self.matcher = prepared, matcher.s, matcher
        self._matches: Dict[Tuple[int, int], PairMatch] = {}

    def put(self, m: PairMatch) -> None:
        """A match of two single grids made elsewhere (the growth's, onto a group of one) with the same call."""
        self._matches.setdefault((m.i, m.j), m)

    def of(self, k: int, others: Iterable[int], compute: bool = True) -> Dict[int, PairMatch]:
        """grid -> the match of grid k onto it (k's metric frame -> its), for each of `others` (without `compute`,
        for those matched already)."""
        others = list(others)
        todo = [x for x in others if (k, x) not in self._matches] if compute else []
        for m in self.matcher.match_all([MatchCall(k, x, self.prepared[k], self.prepared[x], dict(search=False))
                                         for x in todo]):
            self._matches[(k, m.j)] = m
        return {x: self._matches[(k, x)] for x in others if (k, x) in self._matches}


def stronger_elsewhere(link: PairMatch, evidence: PairEvidence, candidates: Iterable[int], s: EstimationSettings,
                       skip: Callable[[int], bool] = lambda x: False, compute: bool = True) -> Optional[str]:
    """Why the accepted match `link` of grid link.i (onto a grid or a union) waits, or None: grid link.i matches
    another of `candidates` (but those `skip` names) as a pair clearly better (without `compute`, among the pairs
    matched already)."""
    best = link.best
    if best is None or best.agreement >= WEAK_AGREEMENT:
        return None
    k = link.i
    others = [x for x in candidates if x not in (k, link.j) and evidence.prepared[x] is not None and not skip(x)]
    for x, m in evidence.of(k, others, compute).items():
        if m.accepted and m.best.agreement >= best.agreement + AGREEMENT_MARGIN and m.best.support > best.support:
            return (f'waits: as a pair with grid {x} it agrees {m.best.agreement:.3f} (support {m.best.support}), '
                    f'here {best.agreement:.3f} ({best.support})')
    return None
