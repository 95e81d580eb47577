"""Per-robot map storage (map_merge.md §4), pure and thread safe.

Each `RobotMap` holds the newest Grid of one robot behind one lock. Grids are copy-on-write: a stored Grid and its
array are never modified after they are stored (a partial update builds a new array), so a snapshot handed to the
merger stays consistent without holding the lock (fixes the original's data race, §13.9).

Differences from the original, on purpose:
  * §13.5: the original drops a full map whose stamp is older than the stored map, and the stored map's stamp is that
    of the last *partial update*, so a full map (even one that changes the map size) can be lost for good. Here a full
    map is dropped only when it is older than the last *full* map (out-of-order delivery) and has the same size; a
    full map of a new size always replaces the stored one.
  * §13.4: clipped updates are read with the update's own row stride (cell (cx, cy) gets data[cy - y, cx - x]).
  * Updates are checked: negative position, data shape != height x width, an empty rectangle, or a rectangle that
    does not intersect the grid are rejected with a reason, and the stored map is left unchanged. Cell values are
    stored as sent: admission.admit normalises them where grids enter the merge.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np

from ..grid import Grid
from .conversions import GridUpdate


@dataclass(frozen=True)
class UpdateResult:
    applied: bool
    reason: str = ''        # why it was rejected, or what was clipped ('' when applied whole)


class RobotMap:
    """The map of one robot: full maps replace, partial updates patch a copy."""

    def __init__(self) -> None:
        self._lock = threading.Lock()   # owns _grid and _last_full_stamp
        self._grid: Optional[Grid] = None
        self._last_full_stamp: Optional[float] = None

    def snapshot(self) -> Optional[Grid]:
        """The current grid (never mutated afterwards), or None before the first full map."""
        with self._lock:
            return self._grid

    def set_full(self, grid: Grid) -> bool:
        """Store a full map; False if it is an out-of-order older copy of the same-sized map."""
        with self._lock:
            old = self._grid
            if (old is not None and self._last_full_stamp is not None and grid.stamp < self._last_full_stamp
                    and old.data.shape == grid.data.shape):
                return False
            self._grid = grid
            self._last_full_stamp = grid.stamp
            return True

    def apply_update(self, update: GridUpdate) -> UpdateResult:
        """Patch the stored map with a partial update (clipped at the grid edge). Never raises for any rectangle
        (empty, negative, huge) or data length: a bad one is rejected with the reason."""
        x, y, w, h = int(update.x), int(update.y), int(update.width), int(update.height)
        data = np.asarray(update.data)
        if x < 0 or y < 0:
            return UpdateResult(False, f'negative coordinates x {x}, y {y}')
        if w < 0 or h < 0 or data.size != w * h:
            return UpdateResult(False, f'data has {data.size} cells, expected {w} x {h}')
        if w == 0 or h == 0:
            return UpdateResult(False, f'empty rectangle {w} x {h} at x {x}, y {y}: nothing to apply')
        data = data.reshape(h, w)
        with self._lock:
            old = self._grid
            if old is None:
                return UpdateResult(False, "no full map received yet to apply it to")
            if update.stamp < old.stamp:
                # as the original (§4.2 step 7): an update older than the stored map is stale
                return UpdateResult(False, f'stamp {update.stamp:.3f} older than the stored map ({old.stamp:.3f})')
            gh, gw = old.data.shape
            if x >= gw or y >= gh:
                return UpdateResult(False, f'rectangle at x {x}, y {y} lies outside the {gw} x {gh} map')
            cw, ch = min(w, gw - x), min(h, gh - y)   # both >= 1 here
            new_data = old.data.copy()
            new_data[y:y + ch, x:x + cw] = data[:ch, :cw]
            self._grid = Grid(new_data, old.resolution, old.origin, old.frame_id, update.stamp, dict(old.extra))
        if (cw, ch) != (w, h):
            return UpdateResult(True, f'update {w} x {h} at x {x}, y {y} does not fully fit into the {gw} x {gh} '
                                      f'map; only {cw} x {ch} cells copied')
        return UpdateResult(True)


def same_inputs(a: Tuple[List[str], List[Optional[Grid]]], b: Tuple[List[str], List[Optional[Grid]]]) -> bool:
    """True if two (robot names, grids) snapshots hold the same robots with identical maps (content, geometry)."""
    if a[0] != b[0]:
        return False
    for ga, gb in zip(a[1], b[1]):
        if ga is gb:
            continue
        if ga is None or gb is None or ga.resolution != gb.resolution or ga.origin != gb.origin \
                or not np.array_equal(ga.data, gb.data):
            return False
    return True


class EstimationGate:
    """Whether the estimation loop estimates again: not on maps the last estimations were made on (static maps cost
    no CPU), but twice more on maps that have stopped changing. In the first of those, tracking checks every kept
    placement on the final maps; in the second, estimator.estimate compares the kept placements with an estimate
    afresh from those maps (skipped at once, it would never run in the node; tracking can leave a robot a few tenths
    of a degree off that its final maps, estimated afresh, place within centimetres; and both in one estimation would
    make the longest estimation of 30 robots too long). Nor does it stop while the last estimation left searches to
    a later one (its search budget ran out: a loaded machine): the next one on the same maps makes them
    (estimator.estimate), so that a robot is placed late, not never. Estimation thread only."""

    REPEATS = 2   # estimations on the same maps after the first

    def __init__(self) -> None:
        self._inputs: Optional[Tuple[List[str], List[Optional[Grid]]]] = None
        self._repeats = 0   # estimations in a row on the same maps, after the first
        self._asked: Optional[tuple] = None   # (inputs, same as self._inputs): the last wanted() call
        self._complete = True   # the last estimation made every search it wanted (none postponed)

    def wanted(self, inputs: Tuple[List[str], List[Optional[Grid]]]) -> bool:
        same = self._inputs is not None and same_inputs(self._inputs, inputs)
        self._asked = (inputs, same)
        return not (same and self._repeats >= self.REPEATS and self._complete)

    def estimated(self, inputs: Tuple[List[str], List[Optional[Grid]]], complete: bool = True) -> None:
        """Record the maps an estimation was made on (compared once, in wanted(), when it asked about them), and
        whether it made every search it wanted (`complete`: none postponed by the search budget)."""
        self._complete = complete
        asked = self._asked
        same = asked[1] if asked is not None and asked[0] is inputs else \
            self._inputs is not None and same_inputs(self._inputs, inputs)
        self._repeats = self._repeats + 1 if same else 0
        self._inputs, self._asked = inputs, None


def same_merge_inputs(a: tuple, b: tuple) -> bool:
    """Two merge inputs (names, grids, transforms, reference) that compose to the same merged grid."""
    if a[3] != b[3] or len(a[2]) != len(b[2]):
        return False
    for ta, tb in zip(a[2], b[2]):
        if (ta is None) != (tb is None) or (ta is not None and not np.array_equal(ta, tb)):
            return False
    return same_inputs((a[0], a[1]), (b[0], b[1]))
