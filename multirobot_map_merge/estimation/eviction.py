"""Members that keep the others out: a map placed in a group that the maps left out contradict, one by one.

A map broken by a SLAM failure (part of it turned) joins a group placed by one of its parts while its other part
overlaps nothing yet. Maps that later overlap that part agree with every other member but contradict it, and are
refused by the union: in a generated 36-robot warehouse nine maps agreed wall for wall (1.00) with every member
they overlapped but one, and 0.32-0.64 with that one, so the union refused them (0.82-0.88). Which group a
broken map falls into first then decides which robots are merged. Here each map left out is judged against the
members one by one, at the place its match onto the union found; a member that is the only one to contradict maps
the other members agree with is taken out of the group, and the maps left out are matched again. In a repetitive
building the match onto the union can find an alias (a wing of identical rooms) better than the true place, which
the broken member contradicts; the next best distinct places of that match are judged the same way. Where several
broken members hold together in the merge (each placed by its part that overlaps the others), the maps left out
contradict all of them at once: several maps that name the same few members single them out together.
"""
from __future__ import annotations

import logging
from collections import Counter
from typing import TYPE_CHECKING, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from .. import transforms as tf
from .features import PreparedGrid
from .pair import PairMatch
from .union import overlap_area
from .verify import Placement, plausible, structural_conflicts, too_contradicted, verify


if TYPE_CHECKING:
    from .settings import EstimationSettings

log = logging.getLogger('rosout.multirobot_map_merge.estimation.eviction')

MIN_AGREEING = 2   # members that must agree with a map left out for its contradiction of one other to count
# one member alone vouches for a map's placement (vouched_for) where that placement is this precise: its expected error
# at the far corners at most this share of max_corner_error_m (0.1 m by default)
ONE_WITNESS_PRECISION = 0.4
# members that maps left out may single out together (contradicted_members' `together`), at most, and the maps that
# must name the same ones
TOGETHER_MOST = 4
TOGETHER_VOTERS = 2


def judge_members(k: int, placed_k: np.ndarray, members: Mapping[int, np.ndarray], footprints: Mapping,
                  box, prepared: Sequence[Optional[PreparedGrid]], s: EstimationSettings,
                  verified: Optional[Dict[tuple, Placement]] = None, union_support: Optional[int] = None,
                  most: int = 1):
    """(agreeing, contradicting): the members that grid k, placed by `placed_k` (metric: its map -> the group's
    frame), agrees with as a pair would, and those it overlaps enough to mean something and that contradict it
    (judged until more than `most` contradict it): a pair that agrees too little or contradicts inside both maps'
    views, not one whose common walls, agreeing, are too few to accept it as a pair (counted as contradicting, map_35
    of the generated courtyard36, 81 agreeing walls over 21 m2 with map_15, kept broken map_16 from being singled
    out when the maps were given in reversed order, and three maps out of the merge). `verified` keeps the
    verifications of one estimation by grids and placement: the maps left out are judged again after each
    eviction, mostly at the same places against the same members (generated hospital36: 2,230 verifications, 1,734
    of them different).

    With `union_support` (the walls of k that agreed with the union of the members at this place, where the union
    refused k for its deep contradictions), a member whose common walls with k are too few to judge it as a pair
    still contradicts when its deep contradictions alone are more than the union tolerates (max_deep_conflicts of
    that support): a broken member's turned part over a corner of k's view (the held-out courtyard36_v: broken
    map_13 over 2.6 m2 of map_02, 46 deep contradictions and 4 agreeing walls, refused map_02 on a union where six
    members agreed with it over 31-125 m2 each)."""
    agreeing, contradicting = [], []
    for j, t in members.items():
        if overlap_area(box, footprints.get(j)) < s.min_overlap_m2 or prepared[j] is None:
            continue
        c = verified_against(k, placed_k, j, t, prepared, s, verified)
        if c.overlap_m2 < s.min_overlap_m2 or c.support + c.conflicts < s.min_support:
            # too little in common to judge as a pair, unless its contradictions alone refuse k on the union
            if union_support is None or c.agreement >= s.min_agreement \
                    or structural_conflicts(c) <= s.max_deep_conflicts * union_support:
                continue
            contradicting.append(j)
        elif plausible(c, s):
            agreeing.append(j)
        elif c.agreement < s.min_agreement or too_contradicted(c, s):
            contradicting.append(j)
        if len(contradicting) > most:
            break   # it singles out no member (a broken map contradicts several): the rest need not be judged
    return agreeing, contradicting


def verified_against(k: int, placed_k: np.ndarray, j: int, placed_j: np.ndarray,
                     prepared: Sequence[Optional[PreparedGrid]], s: 'EstimationSettings',
                     verified: Optional[Dict[tuple, Placement]] = None) -> Placement:
    """Grid k placed by `placed_k` verified against member j placed by `placed_j` (metric: each map -> the group's
    frame), in j's own pixels; kept in `verified` (see judge_members)."""
    pk, pj = prepared[k], prepared[j]
    model = tf.inverse(pj.px_to_map) @ tf.inverse(placed_j) @ placed_k @ pk.px_to_map
    key = (k, j, model.tobytes())
    c = verified.get(key) if verified is not None else None
    if c is None:
        c = verify(pk, pj, model, s)
        if verified is not None:
            verified[key] = c
    return c


def members_agreement(k: int, placed_k: np.ndarray, members: Mapping[int, np.ndarray], footprints: Mapping, box,
                      prepared: Sequence[Optional[PreparedGrid]], s: 'EstimationSettings',
                      verified: Optional[Dict[tuple, Placement]] = None) -> float:
    """The agreement of grid k placed by `placed_k` with the members whose footprints its `box` overlaps, each
    verified in its own pixels, their walls pooled (support over support and conflicts, as Placement.agreement).

    A union is the members resampled into the frame of its seed, and thin walls resampled at an angle lose or move
    a pixel here and there: classic36's map_21, placed at the truth onto members 00, 24 and 28 (0.04 of its area),
    agrees 0.975-1.000 with their union as it is composed in one member's frame or another's, and 1.000 with the
    members one by one in every frame."""
    support = counted = 0
    for j, t in members.items():
        if prepared[j] is None or overlap_area(box, footprints.get(j)) <= 0.0:
            continue
        c = verified_against(k, placed_k, j, t, prepared, s, verified)
        support += c.support
        counted += c.support + c.conflicts - c.fringe_conflicts
    return support / counted if counted else 0.0


def vouched_for(agreeing: Sequence[int], c: Placement, s: 'EstimationSettings') -> bool:
    """Whether the members `agreeing` with a map placed by c (a placement that passed the rules of a pair, its
    precision computed) vouch for it: MIN_AGREEING of them, or one where c is precise (ONE_WITNESS_PRECISION).

    A right map that a single member agreed with was placed 3 cells off: one pair's common walls can leave a
    placement a little off, and nothing else checks it. Where a single member agrees, the placement must be precise
    by itself. In the 78 runs of the generated and held-out buildings (both orders), the end's searches placed 4 maps
    right that one member agreed with (expected error at the far corners 0.04-0.05 m, one 0.14 m) and one 3.5 cells
    off (0.20 m); the held-out maze36_v's maps 04 and 19 (reverse order) met the merge together by map_26
    alone, their union's placement 0.04 m uncertain, and maze36_u's group of four met it by one member each, 0.24 m
    uncertain, and would have joined 4.7 cells off."""
    return len(agreeing) >= MIN_AGREEING \
        or len(agreeing) == 1 and c.corner_error_m <= ONE_WITNESS_PRECISION * s.max_corner_error_m


def places(m: Optional[PairMatch], s: 'EstimationSettings') -> bool:
    """Whether the refused match m found a place that can vote (contradicted_members): support and a common area
    that a match needs."""
    return m is not None and m.best is not None and m.transform_m is not None \
        and m.best.support >= s.min_support and m.best.overlap_m2 >= s.min_overlap_m2


def contradicted_members(left_out: Sequence[int], refused: Mapping[int, PairMatch],
                         members: Mapping[int, np.ndarray], footprints: Mapping, footprint_of,
                         prepared: Sequence[Optional[PreparedGrid]], keep: Sequence[int],
                         s: EstimationSettings, seen: Optional[Mapping[int, frozenset]] = None,
                         voters: Optional[Dict[int, list]] = None,
                         verified: Optional[Dict[tuple, Placement]] = None, own: bool = False,
                         together: Optional[Dict[frozenset, list]] = None) -> List[int]:
    """The members (never those in `keep`) that maps left out single out: each such map, at the place its refused
    match onto the group (`refused`: grid -> that match, placing it in the group's frame) found, or at the first of
    that match's other places (PairMatch.other_places_m) where it does, agrees with at least MIN_AGREEING members
    and contradicts this one alone. Every member so singled out is returned, the most singled out first: one map's
    word is enough although that map can be the wrong one, since a member taken out is searched onto the final merge
    and joins again where it is accepted (Grower.search_left_out(readmit=True)); with two maps needed, the broken
    map_00 of generated hospital36, singled out by one, kept right maps out. With `seen` (grid -> the members its
    refused match was made against), a map votes only against a member its match saw; `voters`, if given, is filled
    with member -> [(grid, the place it voted from)]; `verified`: see judge_members. With `own`, each refused match
    is the map's own onto the union of `members`: where the union refused it for deep contradictions, a member too
    small to judge as a pair can hold them (judge_members' union_support).

    `together`, if given, is filled with the maps that single out no member but contradict two to TOGETHER_MOST
    members while they agree with more (and MIN_AGREEING or more): the set of those members -> [(grid, the place it
    judged them from)], at the first such place of each map (see singled_out_together)."""
    votes: Counter = Counter()
    if len(members) <= MIN_AGREEING:
        return []
    for k in left_out:
        m = refused.get(k)
        if not places(m, s) or prepared[k] is None:
            continue
        several = None   # (the members, the place) where the map contradicts several, if any
        for place in [m.transform_m] + list(m.other_places_m):
            # the best place first; the others where the best is an alias of a repetitive building (the true
            # place, contradicted by the broken member, ranked below it)
            union_support = m.best.support if own and place is m.transform_m and too_contradicted(m.best, s) \
                else None
            agreeing, contradicting = judge_members(k, place, members, footprints, footprint_of(k, place),
                                                    prepared, s, verified=verified, union_support=union_support,
                                                    most=1 if together is None else TOGETHER_MOST)
            if len(contradicting) == 1 and len(agreeing) >= MIN_AGREEING:
                break
            if together is not None and several is None and 1 < len(contradicting) <= TOGETHER_MOST \
                    and len(agreeing) >= max(MIN_AGREEING, len(contradicting) + 1):
                several = (frozenset(contradicting), place)
        else:
            if several is not None and several[0].isdisjoint(keep) \
                    and (seen is None or several[0] <= seen.get(k, frozenset())):
                together.setdefault(several[0], []).append((k, several[1]))
                log.debug('grid %d left out agrees with more members of the merge than it contradicts, and '
                          'contradicts members %s', k, sorted(several[0]))
            continue
        j = contradicting[0]
        if j in keep or (seen is not None and j not in seen.get(k, ())):
            continue   # a match made before j joined: its place may be an alias that j's walls would have ruled out
        votes[j] += 1
        if voters is not None:
            voters.setdefault(j, []).append((k, place))
        log.debug('grid %d left out agrees with members %s of the merge and contradicts member %d alone', k,
                  agreeing, j)
    return [j for j, _ in votes.most_common()]


def singled_out_together(together: Mapping[frozenset, list]) -> List[frozenset]:
    """The sets of members that TOGETHER_VOTERS or more maps left out contradict, each while agreeing with more
    members (contradicted_members' `together`), the most named first.

    Two broken maps or more can hold together in the merge, each placed by its part that overlaps the other members,
    and every map that overlaps their turned parts contradicts all of them: no member is singled out. The generated
    warehouse36 seeded by map_03: broken maps 20 and 29 in a merge of 15; maps 2, 5, 14 and 35, at their true places,
    agreed with 3-6 members each and contradicted both, and 13 mergeable maps stayed out. tunnels36 seeded by map_12:
    nine maps left out agreed with 9-17 members each and contradicted the same four (broken maps 2, 7, 29, 33). A
    broken map left out, placed by one part, contradicts the members its other part overlaps; another map that
    contradicts the same members, and only those, is the evidence that they are the ones that are wrong."""
    return sorted((members for members, voters in together.items()
                   if len({k for k, _ in voters}) >= TOGETHER_VOTERS), key=lambda members: -len(together[members]))


def contradicting_pairs(members: Mapping[int, np.ndarray], footprints: Mapping,
                        prepared: Sequence[Optional[PreparedGrid]], s: 'EstimationSettings',
                        verified: Optional[Dict[tuple, Placement]] = None) -> List[Tuple[int, int]]:
    """The pairs of members (grid -> metric transform into the group's frame) that contradict each other as pairs:
    enough in common to judge (a pair's common area and walls), and agreeing too little or contradicting well inside
    both maps' views (as judge_members counts a member contradicting)."""
    ks = sorted(k for k in members if prepared[k] is not None)
    out = []
    for n, a in enumerate(ks):
        for b in ks[n + 1:]:
            if overlap_area(footprints.get(a), footprints.get(b)) < s.min_overlap_m2:
                continue
            c = verified_against(a, members[a], b, members[b], prepared, s, verified)
            if c.overlap_m2 >= s.min_overlap_m2 and c.support + c.conflicts >= s.min_support \
                    and (c.agreement < s.min_agreement or too_contradicted(c, s)):
                out.append((a, b))
    return out


def cover(pairs: Sequence[Tuple[int, int]]) -> set:
    """Members that take part in every one of `pairs` (greedily: the one in most of those left first, the lowest on a
    tie): a merge less these holds no two that contradict each other."""
    left, out = list(pairs), set()
    while left:
        counts = Counter(k for pair in left for k in pair)
        k = min(counts, key=lambda k: (-counts[k], k))
        out.add(k)
        left = [pair for pair in left if k not in pair]
    return out


def waiting_in_round(pairs: Sequence[Tuple[int, int]], admitted: Mapping[int, Tuple[int, int, int]]) -> set:
    """The members of `pairs` that a member which joined before them in the same round contradicts (and which did
    not wait itself), taken in the order they joined: those a judgement of each join on the union grown by the joins
    before it in its round (Grower.strict) would make wait, by the pairs alone. `admitted`: grid -> (round, place
    in it, group) of its join (Grower.admitted)."""
    against: Dict[int, set] = {}
    for a, b in pairs:
        against.setdefault(a, set()).add(b)
        against.setdefault(b, set()).add(a)
    waiting: set = set()
    for k in sorted((k for k in against if k in admitted), key=lambda k: admitted[k]):
        if any(j in admitted and j not in waiting and admitted[j][0] == admitted[k][0]
               and admitted[j][1] < admitted[k][1] for j in against[k]):
            waiting.add(k)
    return waiting


def singled_out(k: int, pairs: Sequence[Tuple[int, int]]) -> bool:
    """Whether member k takes part in more of `pairs` than each member it contradicts in them."""
    counts = Counter(x for pair in pairs for x in pair)
    return all(counts[k] > counts[b if a == k else a] for a, b in pairs if k in (a, b))


def passed_beside(k: int, pairs: Sequence[Tuple[int, int]], admitted: Mapping[int, Tuple[int, int, int]]) -> bool:
    """Whether member k joined its group in a round after a member it contradicts in `pairs` had joined that group
    (the union k was matched onto held it: the union's check passed k beside it)."""
    return k in admitted and any(j in admitted and admitted[j][2] == admitted[k][2] and admitted[j][0] < admitted[k][0]
                                 for a, b in pairs if k in (a, b) for j in (b if a == k else a,))
