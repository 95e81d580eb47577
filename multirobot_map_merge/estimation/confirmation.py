"""Confirmation: a live fleet's grid placed for the first time is published once a later estimation confirms it.

Early maps are small and alike: one room with a door at each end, placed next to another robot's room through a
door, agreed 0.99 with 133 supporting walls and was 179 degrees and 42 m off (a live 12-robot run, 10 sim s); a
map of one room corner fitted a corner of another robot's room, 90 degrees and 51 m off. No rule on the maps of
that moment tells them from right placements; the same maps a little later do: the placement checked on them
(tracking.py) no longer holds. So a new placement is held back: the next estimations check it on the maps of then,
as they check every placement they keep, and it is published once it still holds, at the same place, on a common
area with a map that stands (the reference, one published before, one confirmed now) grown by CONFIRM_GROWTH_M2
since it was first held, or once no map has changed for STATIC_AFTER_S (static maps: no estimation will see
more). A check on maps that changed elsewhere sees nothing new: a live run published a robot's room a quarter turn
off because the other robot's map had grown away from the room (the same 19 m2 in common); on the maps of a second
later it agreed 0.85. New maps that grow together confirm only each other, not their place in the merge. Where the
building repeats itself, maps that grow keep fitting an alias too: a placement is also judged on the merge that
stands before it is confirmed (uniqueness.py). A
placement in the last published merge is not held again where it is placed as shown relative to the reference (a
change of the merged frame re-places robots already confirmed: still_shown); one that left the merge before is, and
is confirmed with a map that stands where a merge in some frame showed the two (memory.shown; a failed check forgets
it). A merge in the frame of a new map holding published ones moves to the frame of one of those, and the new map
waits (anchor_on_published). Only with a memory (the node): merge_maps and the offline
benchmarks estimate once.

The merged frame moves only to show more robots (keep_standing): when a group without the published reference
outgrows the published group, its new placements are held in its own frame while the published group stays, and the
merge moves to it once they are confirmed, gathered over estimations. A live 12-robot run had shown five robots for
100 sim s, then one for 15 s: a group of seven had outgrown them, and all its members but its seed were held.
"""
from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Callable, Dict, Hashable, List, NamedTuple, Optional, Sequence, Set, Tuple

import numpy as np

from .. import transforms as tf
from ..compose import warp_into
from ..grid import Grid
from .memory import EstimationMemory
from .pair import PairMatch
from .uniqueness import CONTRADICTS
from .union import Box, footprint, known_corners, overlap_area

if TYPE_CHECKING:
    from .estimator import Estimate

log = logging.getLogger('rosout.multirobot_map_merge.estimation.confirmation')

HELD = 'placed for the first time: published once a later estimation confirms it'
SAME_PLACE_M = 0.5   # metres at the grid's corners: a confirmation refines a placement, it does not move it
# maps unchanged for this long have stopped: longer than the map update interval of common SLAM nodes (gmapping's and
# slam_toolbox's default: 5 s), so that a few robots whose maps happen not to change between two estimations (2 s
# apart) do not count as a fleet that has stopped, and have their first placements confirmed on the same maps
STATIC_AFTER_S = 6.0
# new common area a confirmation needs: as much as a pair needs at least (VerifySettings.min_overlap_m2)
CONFIRM_GROWTH_M2 = 4.0
# the known area that grids confirmed together add to that of the grids that stand (summed over grids) from which
# each is judged again on the merge they make (second_look): less adds little that its first judgement did not see
LOOK_AGAIN_SHARE = 0.25
# the search's best places among which the second look searches a rival as good as the place: such a rival ranks
# high (second_look's office36 case: 1st of 32; 7th for another), and a look costs 0.6 of a search of all
# pair.RIVAL_PLACES (the first look's): the 30-map replay (bench/replay_node.py) judges 13 grids again in one
# estimation
LOOK_AGAIN_KEEP = 12


class Held(NamedTuple):
    """A new placement waiting for confirmation (memory.held, by name)."""
    transform: np.ndarray        # metric: its map frame -> the frame of memory.held_reference
    common: Dict[Hashable, float]   # name -> known area (m2) it shared with that placed map when first held here


def static_for(memory: EstimationMemory, settled: bool, now: Optional[float]) -> bool:
    """Whether the maps count as static for confirmation: `settled` (the same as in the last estimation) and, when
    the caller tells the time (`now`), unchanged for STATIC_AFTER_S since the first estimation that saw them (kept
    in memory.unchanged_since, set here when the maps have changed)."""
    if now is None:
        return settled
    if not settled or memory.unchanged_since is None or now < memory.unchanged_since:
        memory.unchanged_since = now
    return settled and now - memory.unchanged_since >= STATIC_AFTER_S


def tracks_held(memory: Optional[EstimationMemory], names: Optional[Sequence],
                preferred_reference: Optional[int]) -> bool:
    """Whether this estimation tracks the placements the last one held: it had the same reference."""
    return memory is not None and bool(memory.held) and bool(names) and preferred_reference is not None \
        and names[preferred_reference] == memory.held_reference


def with_held(previous: Optional[Sequence[Optional[np.ndarray]]], memory: Optional[EstimationMemory],
              names: Optional[Sequence], preferred_reference: Optional[int],
              count: int) -> Optional[List[Optional[np.ndarray]]]:
    """The placements to track: the published ones (`previous`) and those held by the last estimation, when that
    one had the same reference; `previous` as it is otherwise."""
    if not tracks_held(memory, names, preferred_reference):
        return previous
    out = list(previous) if previous is not None and len(previous) == count else [None] * count
    if out[preferred_reference] is None:
        out[preferred_reference] = np.eye(3)
    for k, name in enumerate(names):
        if out[k] is None and name in memory.held:
            out[k] = memory.held[name].transform
    return out


def held_tracked(memory: Optional[EstimationMemory], names: Optional[Sequence], preferred_reference: Optional[int],
                 previous: Optional[Sequence[Optional[np.ndarray]]]) -> Set[int]:
    """The grids whose placement in `previous` is one the last estimation held (with_held added it): tracked
    with the published ones, but not confirmed yet."""
    if previous is None or not tracks_held(memory, names, preferred_reference):
        return set()
    return {k for k, name in enumerate(names) if k != preferred_reference and name in memory.held
            and k < len(previous) and previous[k] is not None
            and np.array_equal(previous[k], memory.held[name].transform)}


def held_in_frame(memory: EstimationMemory, reference_name) -> dict:
    """The placements the last estimation held, in the frame of grid `reference_name`: as held when it was the
    reference then; restated through its own held placement when it was held itself (a group's seed is its largest
    map, and two maps of a group that outgrew the published one can take turns as they grow: keep_standing); none
    otherwise."""
    if reference_name == memory.held_reference:
        return memory.held
    own = memory.held.get(reference_name)
    if own is None:
        return {}
    to_new = tf.inverse(own.transform)
    return {n: h._replace(transform=to_new @ h.transform) for n, h in memory.held.items() if n != reference_name}


def common_areas(k: int, transforms: Sequence[Optional[np.ndarray]], grids: Sequence[Optional[Grid]],
                 boxes: Dict[int, Optional[Box]]) -> Dict[int, float]:
    """The known area (m2) grid k, placed by transforms[k], shares with each other placed grid whose footprint
    (`boxes`, union.footprint of every placed grid) meets its own, counted at its resolution where the two meet."""
    grid, placed, box = grids[k], transforms[k], boxes.get(k)
    if box is None:
        return {}
    res = grid.resolution

    def known(g: Grid, t: np.ndarray, x0: float, y0: float, shape: Tuple[int, int]) -> np.ndarray:
        cells = np.full(shape, -1, np.int8)
        warp_into(cells, g.data, tf.scaling(1.0 / res) @ tf.translation(-x0, -y0) @ t @ g.cell_to_map())
        return cells >= 0

    out = {}
    for m, other in boxes.items():
        if m == k or other is None or overlap_area(other, box) <= 0.0:
            continue
        x0, y0 = max(box[0], other[0]), max(box[1], other[1])
        shape = (max(int(math.ceil((min(box[3], other[3]) - y0) / res)), 1),
                 max(int(math.ceil((min(box[2], other[2]) - x0) / res)), 1))
        both = known(grid, placed, x0, y0, shape) & known(grids[m], transforms[m], x0, y0, shape)
        out[m] = float(np.count_nonzero(both)) * res ** 2
    return out


def confirmed_now(new: Sequence[int], standing: Set[int], transforms: Sequence[Optional[np.ndarray]],
                  corners: Dict[int, np.ndarray], common: Dict[int, Dict[int, float]],
                  first: Dict[int, Dict[Hashable, float]], memory: EstimationMemory, names: Sequence,
                  verdict: Callable[[int], Optional[str]] = lambda k: '') -> Set[int]:
    """The new grids held before at the same place (`first`: their common areas then, by name) that a grid m that
    stands, or one confirmed before them, confirms: their common area has grown by CONFIRM_GROWTH_M2 since, or a
    merge in some frame showed both as they are placed now, relative to each other (memory.shown: the merge moved
    to a larger group and left them out, and the groups have joined since). `corners`: union.known_corners of the
    new grids."""
    def shown_so(k: int, m: int) -> bool:
        was_k, was_m = memory.shown.get(names[k]) or {}, memory.shown.get(names[m]) or {}
        now = tf.inverse(transforms[m]) @ transforms[k]
        return any(tf.difference(now, tf.inverse(was_m[frame]) @ t, corners[k])[1] <= SAME_PLACE_M
                   for frame, t in was_k.items() if frame in was_m)

    confirmed: Set[int] = set()
    grown = True
    while grown:
        grown = False
        for k in new:
            if k in confirmed or k not in first:
                continue
            by = [m for m in standing | confirmed
                  if common[k].get(m, 0.0) >= first[k].get(names[m], 0.0) + CONFIRM_GROWTH_M2 or shown_so(k, m)]
            if not by:
                continue
            why = verdict(k)
            # one that shares too little with the merge that stands to be judged there (None) is confirmed only
            # by a grid confirmed now
            if why == '' or (why is None and any(m in confirmed for m in by)):
                confirmed.add(k)
                grown = True
    return confirmed


def together(k: int, new: Sequence[int], common: Dict[int, Dict[int, float]]) -> Set[int]:
    """The new grids linked to new grid k by known area they share, one with the next (k among them)."""
    out, todo = {k}, [k]
    while todo:
        for m, area in common.get(todo.pop(), {}).items():
            if m in common and m not in out and area > 0.0:
                out.add(m)
                todo.append(m)
    return out


def remember_shown(transforms: Sequence[Optional[np.ndarray]], reference: Optional[int], memory: EstimationMemory,
                   names: Sequence) -> None:
    """What the merge about to be published shows (memory.shown)."""
    if reference is None:
        return
    for k, t in enumerate(transforms):
        if t is not None:
            memory.shown.put(names[k], {**(memory.shown.get(names[k]) or {}), names[reference]: t})


def still_shown(transforms: Sequence[Optional[np.ndarray]], reference: Optional[int],
                published: Optional[Sequence[Optional[np.ndarray]]], grids: Sequence[Optional[Grid]],
                corners: Optional[Dict[int, np.ndarray]] = None) -> Set[int]:
    """The placed grids published before (`published`, in the frame of then) that are placed now as they were
    relative to the reference (within SAME_PLACE_M at their corners), the reference among them; none when the
    reference was not published. The merged frame may have moved since; a grid placed elsewhere relative to the
    others is a new placement, and waits like one. `corners`: union.known_corners of the grids, when known."""
    if reference is None or published is None or reference >= len(published) or published[reference] is None \
            or transforms[reference] is None:
        return set()
    corners = corners if corners is not None else {}
    to_now = transforms[reference] @ tf.inverse(published[reference])
    out = set()
    for k, t in enumerate(transforms):
        if t is None or k >= len(published) or published[k] is None or grids[k] is None:
            continue
        if k not in corners:
            corners[k] = known_corners(grids[k])
        if tf.difference(t, to_now @ published[k], corners[k])[1] <= SAME_PLACE_M:
            out.add(k)
    return out


def anchor_on_published(result: 'Estimate', published: Optional[Sequence[Optional[np.ndarray]]],
                        grids: Sequence[Optional[Grid]]) -> None:
    """Keep the merge in the frame of a published grid placed as most of the others stay as they were shown
    (still_shown): when the merge's reference was not published before (its group's seed) and grids that were are
    placed, or when it was but fewer of them stay as shown relative to it than to another one (its map frame
    moved: a SLAM failure turned it), the merge moves (in place: `result`'s transforms and reference) to the frame
    of the largest published grid with the most. The reference left is a new placement like any other: a seed
    joined the published grids through a link made now (a generated warehouse replayed as a growing fleet: its new
    seed, 4 m off along a row of racks, was published as the merge's frame with five published grids around it)."""
    reference = result.reference
    if published is None or reference is None:
        return
    candidates = [k for k, t in enumerate(result.transforms) if t is not None and k < len(published)
                  and published[k] is not None and grids[k] is not None]
    if not candidates:
        return
    corners: Dict[int, np.ndarray] = {}
    if reference in candidates \
            and len(still_shown(result.transforms, reference, published, grids, corners)) == len(candidates):
        return   # the usual case: every published grid stays as shown relative to the reference
    shown = {a: len(still_shown(result.transforms, a, published, grids, corners)) for a in candidates}
    most = max(shown.values())
    if shown.get(reference) == most:
        return
    anchor = max((a for a in candidates if shown[a] == most), key=lambda a: np.count_nonzero(grids[a].data >= 0))
    log.debug('the merge in the frame of grid %d, not of grid %d: %d published grids placed as shown', anchor,
              reference, most)
    result.transforms = tf.relative_to(result.transforms, anchor)
    result.reference = anchor


def hold_new(transforms: List[Optional[np.ndarray]], reference: Optional[int], pairs: List[PairMatch],
             published: Optional[Sequence[Optional[np.ndarray]]], memory: EstimationMemory, names: Sequence,
             grids: Sequence[Optional[Grid]], settled: bool,
             check: Optional[Callable[..., Optional[str]]] = None) -> int:
    """Hold back (in place: transforms set to None, a reason added to `pairs`) the grids placed now that were not
    published before, unless the last estimation held them at the same place (held_in_frame) and their common area
    with a grid that stands (the reference, those published before) or one confirmed now has grown by
    CONFIRM_GROWTH_M2 since they were first held there (or a merge showed the two so: confirmed_now), or every map
    is the same as in the last estimation (`settled`); how many. Held grids that grow together do not confirm each
    other: in a live run, two new robots right relative to each other were a quarter turn off the merge. With a
    `check` (uniqueness.StandingCheck: why a grid, placed so, is not confirmed on the grids that stand; None when
    it shares too little with them to be judged), a grid is confirmed only when it finds nothing against it, and
    one it does not judge only by a grid confirmed now; grids confirmed together are judged again on the merge they
    make (second_look)."""
    held_before = held_in_frame(memory, names[reference]) if reference is not None else {}
    memory.held, memory.confirmed = {}, {}
    memory.held_reference = names[reference] if reference is not None else None
    placed = [k for k, t in enumerate(transforms) if t is not None]
    standing = still_shown(transforms, reference, published, grids) | ({reference} if reference is not None else set())
    new = [k for k in placed if k not in standing]
    boxes = {k: footprint(grids[k], transforms[k]) for k in placed if grids[k] is not None} if new else {}
    common = {k: common_areas(k, transforms, grids, boxes) for k in new}
    corners = {k: known_corners(grids[k]) for k in new}
    first = {}   # the common areas of those held before at the same place, when first held there
    for k in new:
        before = held_before.get(names[k])
        if before is not None and tf.difference(transforms[k], before.transform, corners[k])[1] <= SAME_PLACE_M:
            first[k] = before.common
    verdicts: Dict[int, Optional[str]] = {}
    base = {m: transforms[m] for m in standing}

    def refuse(k: int, why: str) -> None:
        verdicts[k] = why
        log.debug('grid %d: placement not confirmed: %s', k, why)
        if why.startswith(CONTRADICTS):
            for n in together(k, new, common):
                verdicts.setdefault(n, f'placed with grid {k}, whose place {why}')

    def verdict(k: int) -> Optional[str]:
        if check is None:
            return ''
        if k not in verdicts:
            verdicts[k] = check(k, transforms[k], base, settled)
            if verdicts[k]:
                refuse(k, verdicts[k])
        return verdicts[k]

    looked: Set[int] = set()
    while True:
        confirmed = {k for k in first if not verdict(k)} if settled else \
            confirmed_now(new, standing, transforms, corners, common, first, memory, names, verdict)
        if check is not None:
            second_look(confirmed - looked, confirmed, base, transforms, grids, common, check, refuse)
            looked |= confirmed
        # a grid found contradicting the merge also refuses the new grids placed with it: again without those
        # confirmed before it was judged (each grid is judged once: this ends)
        if not any(verdicts.get(k) for k in confirmed):
            break
    for k in new:
        held = Held(transforms[k], first.get(k, {names[m]: area for m, area in common[k].items()}))
        if k in confirmed:
            log.debug('grid %d: placement confirmed', k)
            memory.confirmed[names[k]] = held
            continue
        memory.held[names[k]] = held
        transforms[k] = None
        pairs[:] = [p for p in pairs if p.i != k]
        pairs.append(PairMatch(k, reference, reason=HELD))
    return len(memory.held)


def second_look(judged: Set[int], confirmed: Set[int], base: Dict[int, np.ndarray],
                transforms: Sequence[Optional[np.ndarray]], grids: Sequence[Optional[Grid]],
                common: Dict[int, Dict[int, float]],
                check: Callable[..., Optional[str]], refuse: Callable[[int, str], None]) -> None:
    """Each grid of `judged` (confirmed now) that shares known area with another grid confirmed now, judged again on
    the union of the grids that stand and the others confirmed now, where a rival counts when it is as good as its
    place (check's `settled` rule; searched among LOOK_AGAIN_KEEP places), when those others know LOOK_AGAIN_SHARE
    of what the grids that stand know or more; `refuse` is told why for each it refuses. Each was judged on the
    grids that stand alone, where its true place may be unknown yet: new grids confirmed together can show it (a
    generated office36 replayed as a growing fleet: eight maps confirmed together on the one map that stood, one of
    them 180 degrees and 34 m off; on the merge they made it fitted its true place as well, 1406 agreeing walls
    against 1840, and the nine took the merge over from the nine published before)."""
    if not judged or len(confirmed) < 2:
        return   # the usual estimation: nothing, or one grid, confirmed
    known = {m: np.count_nonzero(grids[m].data >= 0) for m in set(base) | confirmed if grids[m] is not None}
    standing = sum(known.get(m, 0) for m in base)
    for k in sorted(judged):
        others = [m for m in confirmed if m != k]
        if not any(common[k].get(m, 0.0) > 0.0 for m in others) \
                or sum(known.get(m, 0) for m in others) < LOOK_AGAIN_SHARE * standing:
            continue
        union = {**base, **{m: transforms[m] for m in confirmed if m != k}}
        why = check(k, transforms[k], union, True, keep=LOOK_AGAIN_KEEP)
        if why:
            refuse(k, f'with the grids confirmed now: {why}')


def keep_standing(result: 'Estimate', published: Optional[Sequence[Optional[np.ndarray]]],
                  preferred_reference: Optional[int], memory: EstimationMemory) -> bool:
    """After hold_new: when the estimation chose a group without the preferred (published) reference and that group
    now shows fewer grids than the group holding the reference had published, the latter is published instead (in
    place: `result`'s transforms, reference and pairs); the chosen group's placements stay held in its frame, to be
    confirmed when a later estimation chooses it again, those confirmed now with the common area they were first
    held on (else each would start anew, and the group could never show its members confirmed together). Whether
    it did."""
    if result.standing is None or published is None or preferred_reference is None:
        return False
    members, links = result.standing
    kept = {k for k in members if k < len(published) and published[k] is not None}
    shown = sum(t is not None for t in result.transforms)
    if len(kept) <= shown:
        return False
    log.debug('a group of %d grids around grid %d outgrew the published one, its new placements held: %d grids '
              'published around grid %d', shown + result.held, result.reference, len(kept), preferred_reference)
    chosen_seed = result.reference
    memory.held.update(memory.confirmed)
    result.transforms = [members[k] if k in kept else None for k in range(len(result.transforms))]
    result.reference = preferred_reference
    result.pairs = [link for link in links if link.i in kept] + [p for p in result.pairs if p.i not in kept]
    # the chosen group's seed, and the standing group's new members, wait like the placements held
    for k in [chosen_seed, *members]:
        if k is not None and k not in kept and not any(p.i == k for p in result.pairs):
            result.pairs.append(PairMatch(k, preferred_reference, reason=HELD))
    return True
