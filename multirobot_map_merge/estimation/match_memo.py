"""The matches of an estimation afresh, kept for the estimation made again (estimator._consistent_of).

The audit makes an estimation again with each join of a round judged on the union grown by the joins before it
(Grower.strict); until that judgement first makes a map wait, the estimation made again asks the same matches of the
same grids and unions as the first, and match_pair is deterministic (its draws are seeded by the grids' indices).
A match is known by the grids' indices, its options, and what it matched: a single grid (the prepared grid of the
estimation's feature cache, the same object in both) or a union (its members and their placements,
UnionMap.prepared's `signature`). The held-out courtyard36_v, made again for a broken map that joined in the 21st
round of its growth: 147 matches kept, 11.4 and 12.7 s where made anew 12.5 and 13.2 s (one after the other);
hospital36 in its fifth drawn order: 235 kept, 21.9 s against 25.4 s. No match repeats within one estimation.
"""
from __future__ import annotations

import copy
import dataclasses
import threading
from typing import Dict, Hashable, Optional

from .features import PreparedGrid
from .pair import PairMatch


def signature(p: PreparedGrid) -> Hashable:
    """What a prepared grid is, for a match: a union's members and placements, or the grid object itself."""
    return p.derived.get('signature', ('grid', id(p)))


def copied(m: PairMatch) -> PairMatch:
    """m and its placements copied (their arrays shared: nothing writes into them): callers judge and restate the
    placements they get (verify.refusal notes the expected error in a placement). A deep copy took 8 times as long."""
    return dataclasses.replace(m, best=copy.copy(m.best), alternatives=[copy.copy(c) for c in m.alternatives],
                               other_places_m=list(m.other_places_m))


class MatchMemo:
    """Matches by what they matched; thread safe. Each is kept and handed out as a copy (`copied`)."""

    def __init__(self) -> None:
        self._kept: Dict[tuple, PairMatch] = {}
        self._grids: Dict[int, PreparedGrid] = {}   # the single grids keyed by id, kept alive with their matches
        self._lock = threading.Lock()
        self.hits = 0

    def _key(self, i: int, j: int, pi: PreparedGrid, pj: PreparedGrid, options: Dict[str, object]) -> tuple:
        return i, j, signature(pi), signature(pj), tuple(sorted(options.items()))

    def get(self, i: int, j: int, pi: PreparedGrid, pj: PreparedGrid,
            options: Dict[str, object]) -> Optional[PairMatch]:
        with self._lock:
            found = self._kept.get(self._key(i, j, pi, pj, options))
            if found is not None:
                self.hits += 1
        return copied(found) if found is not None else None

    def put(self, i: int, j: int, pi: PreparedGrid, pj: PreparedGrid, options: Dict[str, object],
            m: PairMatch) -> None:
        kept = copied(m)
        with self._lock:
            for p in (pi, pj):
                if 'signature' not in p.derived:
                    self._grids[id(p)] = p
            self._kept[self._key(i, j, pi, pj, options)] = kept
