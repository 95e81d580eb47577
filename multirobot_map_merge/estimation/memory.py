"""What one estimation leaves to the next in a live fleet (by robot name): work that need not be done again.

Robot maps grow a little between two estimations and their frames do not move. A verdict on a map (its placement
holds; it matched nothing against a union; its keypoints) therefore stands until the map has grown by a share or
been revised (cells it knew changed: a SLAM failure turns or shifts them). `changed` measures both. The merging
pipeline owns one EstimationMemory; the offline tool, estimating once, uses none.
"""
from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import Any, Dict, Hashable, Optional, Tuple

import numpy as np

from ..grid import Grid

GROWTH = 0.2      # share of a map's known cells that may be added before a verdict on it is made again
REVISION = 0.02   # share of its known cells that may change before a verdict on it is made again


def changed(before: Grid, after: Grid) -> Tuple[float, float]:
    """(grown, revised): the share of `before`'s known cells that `after` knows in addition, and the share of them
    whose value changed class (unknown, free, occupied). inf when the two cannot be compared cell by cell."""
    if before is after:
        return 0.0, 0.0
    if before.resolution != after.resolution or before.origin[2] != after.origin[2]:
        return math.inf, math.inf
    dx = (before.origin[0] - after.origin[0]) / after.resolution
    dy = (before.origin[1] - after.origin[1]) / after.resolution
    if abs(dx - round(dx)) > 1e-3 or abs(dy - round(dy)) > 1e-3:
        return math.inf, math.inf
    dx, dy = int(round(dx)), int(round(dy))
    old_known = int((before.data >= 0).sum())
    if old_known == 0:
        return math.inf, math.inf
    new_known = int((after.data >= 0).sum())
    h, w = before.data.shape
    r0, c0 = max(0, -dy), max(0, -dx)
    r1, c1 = min(h, after.height - dy), min(w, after.width - dx)
    revised = old_known   # cells of before outside after count as revised
    if r1 > r0 and c1 > c0:
        old = before.data[r0:r1, c0:c1]
        new = after.data[r0 + dy:r1 + dy, c0 + dx:c1 + dx]
        known = old >= 0
        # classes: unknown (< 0), free (0-49), occupied (>= 50); boolean masks, not class images (building
        # them is a noticeable share of a live node's time)
        moved = known & ((new < 0) | ((new >= 50) != (old >= 50)))
        revised = old_known - int(np.count_nonzero(known)) + int(np.count_nonzero(moved))
    return max(new_known - old_known, 0) / old_known, revised / old_known


def unchanged(before: Optional[Grid], after: Grid) -> bool:
    if before is None:
        return False
    grown, revised = changed(before, after)
    return grown <= GROWTH and revised <= REVISION


class Store:
    """A bounded dictionary, oldest entries dropped first."""

    def __init__(self, capacity: int = 4096):
        self._items: "OrderedDict[Hashable, Any]" = OrderedDict()
        self._capacity = capacity

    def get(self, key: Hashable) -> Optional[Any]:
        return self._items.get(key)

    def put(self, key: Hashable, value: Any) -> None:
        self._items[key] = value
        self._items.move_to_end(key)
        while len(self._items) > self._capacity:
            self._items.popitem(last=False)

    def drop(self, key: Hashable) -> None:
        self._items.pop(key, None)


class EstimationMemory:
    """checks: name -> the verdict of its last placement check that held (tracking.Verdict); keypoints: name ->
    (grid, points in its map frame, descriptors); tries: (name, union member names) -> (grid, union known pixels,
    whether it contradicted the union, whether it found where they overlap) of a failed match; searches: (name, seed
    name) -> (grid, union known pixels, union member names) of a correlation search; latest: name -> the content key
    of its map in the last estimation that tracked placements; settled_inputs: the (name, content key) pairs of the last
    estimation if its maps were those of the one before, else None; fresh_inputs: the pairs last estimated afresh
    (estimator.py); postponed_inputs: the pairs of the last estimation if its search budget left searches to a later
    one, else None (postponed_rounds: how many in a row); relaxed: name -> map of the placements tracking last
    relaxed (relax.py); held, held_reference: new placements waiting for confirmation (confirmation.py);
    unchanged_since: the time (the caller's clock) of the first estimation on the current maps."""

    def __init__(self) -> None:
        self.checks, self.keypoints, self.tries, self.searches = Store(), Store(), Store(), Store()
        self.latest = Store()
        self.settled_inputs: Optional[tuple] = None
        self.fresh_inputs: Optional[tuple] = None
        self.postponed_inputs: Optional[tuple] = None
        self.postponed_rounds = 0   # estimations in a row on those maps, each with twice the budget of the last
        self.relaxed: Optional[Dict[str, Grid]] = None
        # name -> a new placement waiting for confirmation (confirmation.Held)
        self.held: Dict[str, tuple] = {}
        self.confirmed: Dict[str, tuple] = {}   # the held placements the last estimation confirmed (the same kind)
        # name -> {a reference's name: its placement in the last merge in that frame that showed it} (forgotten
        # when a check of its placement fails: tracking.py)
        self.shown = Store()
        self.held_reference: Optional[str] = None   # the reference grid's name in the estimation that held them
        self.unchanged_since: Optional[float] = None
        self._compared: Dict[Tuple[int, int], tuple] = {}   # this estimation's comparisons (see unchanged)
        self._compared_lock = threading.Lock()

    def new_estimation(self) -> None:
        """Forget the last estimation's comparisons (they hold its maps)."""
        with self._compared_lock:
            self._compared = {}

    def unchanged(self, before: Optional[Grid], after: Grid) -> bool:
        """unchanged(), kept for the same two map objects until the next estimation: one estimation asks about
        the same two maps several times, and maps are not changed in place (a robot's update makes a new one)."""
        if before is None:
            return False
        key = (id(before), id(after))
        with self._compared_lock:
            kept = self._compared.get(key)
        if kept is not None and kept[0] is before and kept[1] is after:
            return kept[2]
        result = unchanged(before, after)
        with self._compared_lock:
            self._compared[key] = (before, after, result)   # holding both: their ids are not reused meanwhile
        return result
