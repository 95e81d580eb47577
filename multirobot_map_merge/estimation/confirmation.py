"""Confirmation: a live fleet's grid placed for the first time is published once a later estimation confirms it.

Early maps are small and alike: one room with a door at each end, placed next to another robot's room through a
door, agreed 0.99 with 133 supporting walls and was 179 degrees and 42 m off (a live 12-robot run, 10 sim s); a
map of one room corner fitted a corner of another robot's room, 90 degrees and 51 m off. No rule on the maps of
that moment tells them from right placements; the same maps a little later do: the placement checked on them
(tracking.py) no longer holds. So a new placement is held back: the next estimations check it on the maps of then,
as they check every placement they keep, and it is published once it still holds, at the same place, on a map of
its own that has changed since (the corner's robot had sent no new map 2 s later, and the check on the same map
still held), or once no map has changed for STATIC_AFTER_S (static maps: no estimation will see more). A
placement in the last published merge is not held again (a change of the merged frame re-places robots already
confirmed); one that left the merge before is. Only with a memory (the node): merge_maps and the offline
benchmarks estimate once.

The merged frame moves only to show more robots (keep_standing): when a group without the published reference
outgrows the published group, its new placements are held in its own frame while the published group stays, and the
merge moves to it once they are confirmed. A live 12-robot run had shown five robots for 100 sim s, then one for
15 s: a group of seven had outgrown them, and all its members but its seed were held.
"""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING, List, Optional, Sequence

import numpy as np

from .. import transforms as tf
from ..grid import Grid
from .features import content_key
from .memory import EstimationMemory
from .pair import PairMatch
from .union import known_corners

if TYPE_CHECKING:
    from .estimator import Estimate

log = logging.getLogger('rosout.multirobot_map_merge.estimation.confirmation')

HELD = 'placed for the first time: published once a later estimation confirms it'
SAME_PLACE_M = 0.5   # metres at the grid's corners: a confirmation refines a placement, it does not move it
# maps unchanged for this long have stopped: longer than the map update interval of common SLAM nodes (gmapping's and
# slam_toolbox's default: 5 s), so that a few robots whose maps happen not to change between two estimations (2 s
# apart) do not count as a fleet that has stopped, and have their first placements confirmed on the same maps
STATIC_AFTER_S = 6.0


def static_for(memory: EstimationMemory, settled: bool, now: Optional[float]) -> bool:
    """Whether the maps count as static for confirmation: `settled` (the same as in the last estimation) and, when
    the caller tells the time (`now`), unchanged for STATIC_AFTER_S since the first estimation that saw them (kept
    in memory.unchanged_since, set here when the maps have changed)."""
    if now is None:
        return settled
    if not settled or memory.unchanged_since is None or now < memory.unchanged_since:
        memory.unchanged_since = now
    return settled and now - memory.unchanged_since >= STATIC_AFTER_S


def with_held(previous: Optional[Sequence[Optional[np.ndarray]]], memory: Optional[EstimationMemory],
              names: Optional[Sequence], preferred_reference: Optional[int],
              count: int) -> Optional[List[Optional[np.ndarray]]]:
    """The placements to track: the published ones (`previous`) and those held by the last estimation, when that
    one had the same reference; `previous` as it is otherwise."""
    if memory is None or not memory.held or not names or preferred_reference is None \
            or names[preferred_reference] != memory.held_reference:
        return previous
    out = list(previous) if previous is not None and len(previous) == count else [None] * count
    if out[preferred_reference] is None:
        out[preferred_reference] = np.eye(3)
    for k, name in enumerate(names):
        if out[k] is None and name in memory.held:
            out[k] = memory.held[name][0]
    return out


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
    to_new = tf.inverse(own[0])
    return {n: (to_new @ t, first) for n, (t, first) in memory.held.items() if n != reference_name}


def hold_new(transforms: List[Optional[np.ndarray]], reference: Optional[int], pairs: List[PairMatch],
             published: Optional[Sequence[Optional[np.ndarray]]], memory: EstimationMemory, names: Sequence,
             grids: Sequence[Optional[Grid]], contents: Optional[Sequence[Optional[str]]], settled: bool) -> int:
    """Hold back (in place: transforms set to None, a reason added to `pairs`) the grids placed now that were not
    published before, unless the last estimation held them at the same place (held_in_frame) and the map has
    changed since it was first held, or every map is the same as in the last estimation (`settled`); how many.
    `contents`: the grids' content keys when the estimation has them (features.content_key)."""
    held_before = held_in_frame(memory, names[reference]) if reference is not None else {}
    memory.held = {}
    memory.held_reference = names[reference] if reference is not None else None
    for k, t in enumerate(transforms):
        if t is None or k == reference or (published is not None and k < len(published)
                                           and published[k] is not None):
            continue
        before = held_before.get(names[k])
        now = contents[k] if contents is not None else content_key(grids[k])
        first = now   # the content of the map it was first held on, while it is held at the same place
        if before is not None and tf.difference(t, before[0], known_corners(grids[k]))[1] <= SAME_PLACE_M:
            first = before[1]
            if settled or first != now:
                log.debug('grid %d: placement confirmed', k)
                continue
        memory.held[names[k]] = (t, first)
        transforms[k] = None
        pairs[:] = [p for p in pairs if p.i != k]
        pairs.append(PairMatch(k, reference, reason=HELD))
    return len(memory.held)


def keep_standing(result: 'Estimate', published: Optional[Sequence[Optional[np.ndarray]]],
                  preferred_reference: Optional[int]) -> bool:
    """After hold_new: when the estimation chose a group without the preferred (published) reference and that group
    now shows fewer grids than the group holding the reference had published, the latter is published instead (in
    place: `result`'s transforms, reference and pairs); the chosen group's placements stay held in its frame, to be
    confirmed when a later estimation chooses it again. Whether it did."""
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
    result.transforms = [members[k] if k in kept else None for k in range(len(result.transforms))]
    result.reference = preferred_reference
    result.pairs = [link for link in links if link.i in kept] + [p for p in result.pairs if p.i not in kept]
    # the chosen group's seed, and the standing group's new members, wait like the placements held
    for k in [chosen_seed, *members]:
        if k is not None and k not in kept and not any(p.i == k for p in result.pairs):
            result.pairs.append(PairMatch(k, preferred_reference, reason=HELD))
    return True
