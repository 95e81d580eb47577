"""The members a correlation search placed, and those placed onto a few maps that the members near them contradict,
searched again onto the final merge without them.

A search takes the best place on the union as it was then. A small map of a building of alike shops can fit a
place half a turn away over its whole area (a generated mall not among the benchmarks: map_00, 69 m2, agreement
0.97, 703 agreeing walls), while at the truth the union of that moment shares its open floor but almost no walls
(7): the search places it at the alias, by the rules of a pair. The maps that join later see the truth: on the
final merge the same search places it right (agreement 1.00, 790 walls) and the alias ranks below. Tracking's check
of the searched placements (Grower.confirm_searches) does not see it: the members near the alias agree with it.

So at the end of an estimation afresh each member a search placed is searched again, by the search of the maps
left out (growth.search_left_out: distinct places), onto the union of the other members. Where that search accepts
a place distinct from the member's, the member moves there when that place passes search_left_out's rules (the
share of its area, members agreeing, none contradicting), and leaves the merge otherwise. Where it finds two places
as good (pair.AMBIGUOUS), the merge cannot tell where the member is, and it leaves: in the held-out mall36_v,
map_01, placed by a search 12.9 m off at agreement 1.00 with 1068 walls, has the truth as good there (992 walls).

A member that joined a group of a few maps (stronger.FEW_MEMBERS) by its own match was judged against those alone,
and the maps that joined later judged it only as part of their union, where its contradictions count among all the
union's walls. Once the merge is relaxed, such a member is checked against the members near it as it is placed
(tracking's check, as Grower.confirm_searches judges the searched ones), and searched again when they contradict it
(search_doubted_again): the held-out mall36_v's map_08 joined map_06 alone by descriptors, 6.4 m along alike shops
(agreement 0.995); the members near it agree 0.97 with it there before the relaxation and 0.82 after, and the
search onto them finds the truth as good (1140 walls against 1219). The check alone does not take a member out:
taking out every member that failed it lost three right maps of the real maps (`real_dev`). Nor does such a member
move where the search places it elsewhere: it leaves. Its placement was found wrong, and the merge may lack the maps
at its truth: with its maps in reverse order, mall36_v's merge placed map_08 so, and its search moved it to another
shop 12.8 m off the truth.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from typing import List

from .. import transforms as tf
from .eviction import judge_members, vouched_for
from .pair import AMBIGUOUS
from .union import footprint
from .verify import distinct
from .workers import MatchCall

log = logging.getLogger('rosout.' + __name__)

ELSEWHERE = 'a search onto the final merge without it places it elsewhere, where it does not join'
AS_GOOD = 'a search onto the final merge without it finds another place as good'


def search_placed_again(grower, group) -> List[int]:
    """Search each member of `group` that a search placed (grower.searched) onto the union of the others; move or
    take out those it places elsewhere or finds as good elsewhere (see the module). Returns the members moved or
    taken out."""
    todo = sorted(k for k in group.members if k in grower.searched and k not in (group.seed, grower.reference))
    return _search_again(grower, group, todo, 'members a search placed')


def search_doubted_again(grower, group) -> List[int]:
    """Search the members of the final merge `group` that joined a few maps and that the members near them
    contradict (in_doubt) onto the union of the others, as search_placed_again does, but those it places elsewhere
    leave instead of moving there. Returns the members taken out; they count as evicted (grower.evicted): not
    searched again as maps left out, and the maps left out that they saw are (Grower.search_left_out). Held-out
    mall36_v, maps in reverse order: map_08 sat 6.4 m off at an alias of alike shops until this check, and its walls
    there made the true place of map_01 look ambiguous to the end's search; searched again without it, map_01 joins
    (agreement 1.00 with 1040 walls)."""
    started = time.perf_counter()
    todo = in_doubt(grower, group)
    log.debug('members placed onto a few maps checked on the final merge: %s in doubt, %.2f s', todo,
              time.perf_counter() - started)
    left = _search_again(grower, group, todo, 'members placed onto a few maps the members near them contradict',
                         may_move=False)
    grower.evicted.update(left)
    return left


def in_doubt(grower, group) -> List[int]:
    """The members of `group` that joined a group of a few maps by their own match (grower.placed_onto_few; not the
    seed, the reference, nor one a search placed) that the members near them contradict as they are placed
    (Grower.contradicted)."""
    todo = sorted(k for k in group.members if k in grower.placed_onto_few and k not in grower.searched
                  and k not in (group.seed, grower.reference))
    return [c.k for c in grower.contradicted(group, todo)]


def _search_again(grower, group, todo: List[int], what: str, may_move: bool = True) -> List[int]:
    """Search the members `todo` of `group` onto the union of the others (see the module); unless `may_move`, a
    member placed elsewhere leaves."""
    changed = []
    started = time.perf_counter()
    for start in range(0, len(todo), grower.s.threads):
        chunk = todo[start:start + grower.s.threads]
        calls = [MatchCall(k, group.seed, grower.prepared[k],
                           grower.union_of(group, {j: t for j, t in group.members.items() if j != k}),
                           dict(onto_union=True, descriptors=False, distinct_places=True)) for k in chunk]
        for k, m in zip(chunk, grower.matcher.match_all(calls)):
            if not m.accepted and m.reason.startswith(AMBIGUOUS):
                _leave(grower, group, k, m, f'{AS_GOOD} ({m.reason})')
            elif not m.accepted or not _elsewhere(grower, group, k, m):
                continue
            elif may_move and _joins_there(grower, group, k, m):
                log.debug('grid %d moves: a search onto the final merge without it places it elsewhere', k)
                group.leave(k)
                group.join(k, grower.grids[k], grower.prepared[k], m)
            else:
                _leave(grower, group, k, m, ELSEWHERE)
            changed.append(k)
    if todo:
        log.debug('%d %s searched again onto the final merge: %d moved or left, %.2f s', len(todo), what,
                  len(changed), time.perf_counter() - started)
    return changed


def _leave(grower, group, k: int, m, why: str) -> None:
    """Member k leaves the merge `group`, refused by its search m onto the others for `why`."""
    log.debug('grid %d leaves group %d: %s', k, group.seed, why)
    group.leave(k)
    grower.refused[k] = dataclasses.replace(m, accepted=False, reason=why)


def _elsewhere(grower, group, k: int, m) -> bool:
    """Whether the match m of member k places it at another place than the group has it."""
    part = grower.prepared[k]
    to_px = tf.scaling(1.0 / part.resolution)   # distinct compares pixel transforms: pixels of k's size will do
    return distinct(to_px @ m.transform_m @ part.px_to_map, to_px @ group.members[k] @ part.px_to_map, part,
                    grower.s)


def _joins_there(grower, group, k: int, m) -> bool:
    """Whether member k, placed by m, passes search_left_out's rules there against the other members."""
    if not grower.shares_enough(k, m.best.overlap_m2):
        return False
    others = {j: t for j, t in group.members.items() if j != k}
    agreeing, contradicting = judge_members(k, m.transform_m, others, group.union.footprints,
                                            footprint(grower.grids[k], m.transform_m), grower.prepared, grower.s,
                                            verified=grower.judged)
    return vouched_for(agreeing, m.best, grower.s) and not contradicting
