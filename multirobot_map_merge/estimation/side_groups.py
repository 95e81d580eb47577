"""The groups that never joined the merge, placed onto it as a whole at the end of an estimation.

The growth takes apart a group whose union the merge refuses (estimator.search_grow): its members are then matched
and searched one by one. In a repetitive building a map at the end of a chain shares a few rooms with the merge, and
a few rooms fit an alias as well as the truth (the generated hospital36: maps 24-26, placed alone onto the final
merge, fit an alias at agreement 1.00 with more support than the truth has), so each stays out, by the share it
must have with the merge (growth.LEFT_OUT_SHARE). The union of their group, placed where the end's search put one
of them right, agrees with the merge by several of them: what the chain shares with it together tells where it
is. The join of that union that the growth refused was refused beside the alias of the whole wing (the unions
overlap elsewhere, far more, and contradict: pair.match_pair's between_groups), a rule for two groups that may each
hold a broken map; the search of the union onto the final merge found that alias or the truth by its random draws.

So the members of such a group that are still left out at the end are placed together, as the union they made (their
placements in it as the group had them), where the end's search of one of them placed that member
(growth.search_left_out: it passed the rules of a pair, short of the share, or every rule but precision: the held-out
school36_v's group of 11 joined with its member's place 0.24 m uncertain at the far corners and stayed out at 0.28 m, as
the maps' order and the draws had it; the union, with all its walls, is judged there with the precision rule too), or
else where a match of the union onto the merge by the growth's rules places it (Grower.match_groups_now: the growth took
the group apart while the merge was another, a broken member still in it; the held-out courtyard36_v in the given order,
maps 01 and 12, whose end searches placed neither). They join there when the union passes the rules of a pair onto the
merge, at least MEETING of them each agree with MIN_AGREEING members of the merge (or with one, where the union's
placement is precise: eviction.vouched_for) and contradict none (eviction.judge_members), more than the members the
merge contradicts, and a search of the union finds no place as good elsewhere (pair.find_rival, pair.as_good; it counts
against the search budget, and with the budget spent the group waits for a later estimation). A broken map placed by one
fitting part meets the merge by that part alone; a group meets it by several maps that agree. In hospital36 the seven
members of the chain meet the merge where the end's search put one of them (seeds 0-2 of the random sampling); without
the ICP refinement of the union there, one of them (map_25) contradicted a member by their thin common walls (19 m2)."""
from __future__ import annotations

import logging
from typing import Dict, Iterator, List, Optional, Tuple

import numpy as np

from .. import transforms as tf
from .eviction import judge_members, vouched_for
from .pair import PairMatch, accepted_at, as_good
from .refine import icp
from .union import footprint
from .verify import Placement, pair_confidence, same_place

log = logging.getLogger('rosout.' + __name__)

MEETING = 2   # members of a side group that members of the merge must each vouch for where it joins


def remember(side_groups: List[Dict[int, np.ndarray]], members: Dict[int, np.ndarray]) -> None:
    """Keep a group's placements (grid -> transform into its frame) before it is taken apart."""
    if len(members) > 1:
        side_groups.append({k: np.array(t, float) for k, t in members.items()})


def search_side_groups(grower, group) -> int:
    """Place the side groups the growth took apart (grower.side_groups) onto the merge `group`, their members still
    left out (not evicted) together: see the module. Returns how many grids joined."""
    joined = 0
    tried: set = set()
    for side in sorted(grower.side_groups, key=len, reverse=True):
        # by content, not index: the first seeds the union (its frame), and the places are tried in this order
        left = sorted((k for k in side if k not in group.members and k not in grower.evicted
                       and grower.prepared[k] is not None), key=lambda k: grower.prepared[k].draw_key)
        if len(left) < 2 or frozenset(left) in tried:
            continue
        tried.add(frozenset(left))
        them = grower.group_of(left[0], {k: side[k] for k in left})
        m = _placed(grower, group, them)
        if m is None:
            continue
        group.absorb(them, m.transform_m, m)
        for k in left:
            grower.refused.pop(k, None)
        grower.settle(len(left))
        joined += len(left)
    return joined


def _placed(grower, group, them) -> Optional[PairMatch]:
    """The match that places the union of `them` onto the merge `group`, if one does by the rules of the module: at
    the places of its members' searches, then at the place of a match of the two unions."""
    part, union, s = them.union.prepared(), group.union.prepared(), grower.s
    for px, where in _places(grower, group, them):
        place = union.px_to_map @ px @ tf.inverse(part.px_to_map)
        c = grower.passes_onto(part, union, place)
        if c is None or pair_confidence(c.support, c.support + c.conflicts) < s.confidence:
            continue
        meeting, contradicted = _meeting(grower, group, them, place, c)
        if len(meeting) < MEETING or len(meeting) <= len(contradicted):
            continue
        searched, rival = grower.rival_of(part, union, c, enough=lambda r: as_good(r, c, s))
        if not searched:
            log.debug('side group %s waits for a later estimation: the search budget is spent before the search '
                      'for a place as good elsewhere', sorted(them.members))
            return None
        log.debug('side group %s %s: the union placed where %s put it (agreement %.2f, support %d), members %s each '
                  'agreeing with members of the merge%s', sorted(them.members),
                  'stays out' if rival is not None else 'joins the merge', where, c.agreement, c.support, meeting,
                  f'; a place as good elsewhere (agreement {rival.agreement:.2f}, support {rival.support})'
                  if rival is not None else '')
        if rival is not None:
            return None
        return accepted_at(them.seed, group.seed, c, place)
    return None


def _places(grower, group, them) -> Iterator[Tuple[np.ndarray, str]]:
    """The distinct places (pixels of the union of `them` -> pixels of the merge `group`) to judge the union at, and
    where each comes from: its members' searches, then, made only when those are judged in vain, a match of the two
    unions by the growth's rules (merge_groups: the growth took the group apart while the merge was another, a broken
    member still in it)."""
    part, union, s = them.union.prepared(), group.union.prepared(), grower.s
    rng = np.random.default_rng((s.seed, part.draw_key))
    places: List[np.ndarray] = []
    for k, t in them.members.items():
        for m in (grower.left_out_matches.get(k), grower.left_out_imprecise.get(k)):
            if m is None or m.transform_m is None or m.j != group.seed:
                continue
            # where the member's own search puts the union, refined on the union's walls (a member's small common
            # area can leave it a little turned)
            px = icp(part, union, tf.inverse(union.px_to_map) @ m.transform_m @ tf.inverse(t) @ part.px_to_map, s,
                     rng)
            if not any(same_place(px, p, part) for p in places):
                places.append(px)
    for px in places:
        yield px, 'member searches'
    matched = grower.match_groups_now(them, group)
    if matched.accepted:
        px = tf.inverse(union.px_to_map) @ matched.transform_m @ part.px_to_map
        if not any(same_place(px, p, part) for p in places):
            yield px, 'a match of the two unions'


def _meeting(grower, group, them, to_merge: np.ndarray, c: Placement) -> Tuple[List[int], List[int]]:
    """(meeting, contradicted): the members of `them` that members of the merge vouch for (MIN_AGREEING of them, or
    one where c, the union's placement `to_merge`, is precise: eviction.vouched_for) and that contradict none there,
    and those that contradict one."""
    meeting, contradicted = [], []
    for k, t in them.members.items():
        placed = to_merge @ t
        agreeing, contradicting = judge_members(k, placed, group.members, group.union.footprints,
                                                footprint(grower.grids[k], placed), grower.prepared, grower.s,
                                                verified=grower.judged)
        if contradicting:
            contradicted.append(k)
        elif vouched_for(agreeing, c, grower.s):
            meeting.append(k)
    return meeting, contradicted
