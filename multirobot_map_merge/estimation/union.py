"""The union of a group of placed grids, prepared so that other grids can be matched against it.

A newcomer often overlaps every single placed map by too little for a pair, but their union well: matched against
the union, its acceptance is judged on everything the group knows. The union is composed at the working resolution
in the group's frame (its seed grid's map frame) and prepared like any grid, except for its keypoints: those are
the members' own, pooled (features.pooled_keypoints), so they grow with the group and no detector runs on it.
"""
from __future__ import annotations

from typing import Callable, Dict, Optional, Sequence, Tuple

import numpy as np

from .. import transforms as tf
from ..compose import compose
from ..grid import Grid, crop_to_known
from .features import PreparedGrid, map_keypoints, pooled_keypoints, prepare
from .verify import landing_box, warp_into

Box = Tuple[float, float, float, float]   # x0, y0, x1, y1 (metres, merged frame)
HISTORY = 4   # prepared versions of a union kept to tell where it changed


def footprint(grid: Grid, transform: np.ndarray) -> Optional[Box]:
    """Bounding box, in the merged frame, of the known part of `grid` placed by `transform`."""
    box = crop_to_known(grid.data, margin=0)
    if box is None:
        return None
    r0, r1, c0, c1 = box
    corners = tf.apply(transform @ grid.cell_to_map(), np.array([[c0, r0], [c1, r0], [c0, r1], [c1, r1]], float))
    (x0, y0), (x1, y1) = corners.min(axis=0), corners.max(axis=0)
    return float(x0), float(y0), float(x1), float(y1)


def known_corners(grid: Grid) -> np.ndarray:
    """The corners of the box around a grid's known part, metres of its map frame (none for an empty grid)."""
    box = footprint(grid, np.eye(3))
    if box is None:
        return np.zeros((0, 2))
    x0, y0, x1, y1 = box
    return np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]])


def overlap_area(a: Optional[Box], b: Optional[Box]) -> float:
    if a is None or b is None:
        return 0.0
    return max(min(a[2], b[2]) - max(a[0], b[0]), 0.0) * max(min(a[3], b[3]) - max(a[1], b[1]), 0.0)


def most_overlapping(box: Optional[Box], footprints: Dict[int, Box], candidates) -> int:
    """The candidate whose footprint overlaps `box` the most (-1 if none overlaps it)."""
    best, best_area = -1, 0.0
    for m in candidates:
        area = overlap_area(box, footprints.get(m))
        if area > best_area:
            best, best_area = m, area
    return best


def compose_near(grids: Sequence[Optional[Grid]], transforms: Dict[int, np.ndarray], near: Sequence[int],
                 box: Box, resolution: float) -> Optional[Grid]:
    """The union of the placed grids `near` (those whose footprint meets `box`), cropped to the box (composed only
    there: the grids near a robot's map reach beyond it, and tracking composes one such union per placed map in every
    estimation)."""
    if not near:
        return None
    return compose([grids[k] for k in near], [transforms[k] for k in near], resolution, within=box)


class UnionMap:
    """The composed map of a group's members (grid index -> metric transform into the group's frame)."""

    def __init__(self, resolution: float, keypoints_of: Callable[[int, PreparedGrid], tuple] = None):
        self.resolution = resolution
        # member's keypoints in its map frame and descriptors: detected now, or kept from an earlier estimation
        self.keypoints_of = keypoints_of or (lambda k, part: map_keypoints(part))
        self.members: Dict[int, np.ndarray] = {}
        self.grids: Dict[int, Grid] = {}
        self.parts: Dict[int, PreparedGrid] = {}
        self.footprints: Dict[int, Box] = {}
        self.version = 0                  # grows with every change of the members
        self._history: Dict[int, PreparedGrid] = {}   # the last few prepared versions (see changed_within)
        self._prepared: Optional[PreparedGrid] = None
        self._prepared_version = -1

    def add(self, k: int, grid: Grid, part: PreparedGrid, transform: np.ndarray) -> None:
        self.members[k] = np.asarray(transform, float)
        self.grids[k], self.parts[k] = grid, part
        box = footprint(grid, self.members[k])
        if box is not None:
            self.footprints[k] = box
        self.version += 1

    def remove(self, k: int) -> None:
        """Member k leaves the union (the others keep their placements)."""
        for members in (self.members, self.grids, self.parts, self.footprints):
            members.pop(k, None)
        self.version += 1

    def changed_under(self, part: PreparedGrid, model: np.ndarray, since: int) -> bool:
        """Whether the union differs, where grid `part` lies when placed by `model` (its pixels -> pixels of the
        union prepared at version `since`), from that union (True when unknown)."""
        old, new = self._history.get(since), self.prepared()
        if old is None or new is None:
            return True
        shift = np.linalg.inv(new.px_to_map) @ old.px_to_map
        if not np.allclose(shift[:2, :2], np.eye(2)) or not np.allclose(shift[:2, 2], np.round(shift[:2, 2])):
            return True
        dx, dy = (int(round(v)) for v in shift[:2, 2])
        h, w = old.work.shape
        if dx < 0 or dy < 0 or dy + h > new.work.shape[0] or dx + w > new.work.shape[1]:
            return True
        box = landing_box(part, old, model, 1)   # only where the grid lands (a union is mostly elsewhere)
        if box is None:
            return False
        x0, y0, x1, y1 = box
        under = warp_into((part.work >= 0).view(np.uint8), model, box) > 0
        return not np.array_equal(old.work[y0:y1, x0:x1][under],
                                  new.work[dy + y0:dy + y1, dx + x0:dx + x1][under])

    def absorb(self, other: 'UnionMap', other_to_self: np.ndarray) -> None:
        """Take every member of another union, placed by `other_to_self` (its frame -> this frame)."""
        for k, t in other.members.items():
            self.add(k, other.grids[k], other.parts[k], other_to_self @ t)

    def prepared(self) -> Optional[PreparedGrid]:
        """The union prepared for matching (work image, fields, pooled keypoints), rebuilt only after a change;
        a single member at the identity is its own union."""
        if self._prepared_version == self.version:
            return self._prepared
        only = next(iter(self.members)) if len(self.members) == 1 else None
        if only is not None and np.allclose(self.members[only], np.eye(3)):
            self._prepared = self.parts[only]
        else:
            # by content, not index: where members differ on a cell, and in the keypoints' order (RANSAC's draws
            # pick among the matches by their places), a union holds the same whatever the grids' order
            order = sorted(self.members, key=lambda k: self.parts[k].draw_key)
            union = compose([self.grids[k] for k in order], [self.members[k] for k in order], self.resolution)
            # the wall fields when a match first reads them: a union is also prepared for its size alone (a live
            # node's growth asks it of every estimation, whether or not a grid is matched onto it then)
            self._prepared = prepare(union, self.resolution, None, lazy=True) if union is not None else None
            if self._prepared is not None:
                # what it is made of, for a match kept to be known again (match_memo.py)
                self._prepared.derived['signature'] = ('union', self.resolution, tuple(
                    (k, id(self.parts[k]), self.members[k].tobytes()) for k in order))
                (self._prepared.keypoints, self._prepared.descriptors,
                 self._prepared.descriptor_parts) = pooled_keypoints(
                    [(*self.keypoints_of(k, self.parts[k]), self.members[k]) for k in order],
                    self._prepared.px_to_map, self._prepared.work.shape)
        self._prepared_version = self.version
        self._history[self.version] = self._prepared
        for old in sorted(self._history)[:-HISTORY]:
            del self._history[old]
        return self._prepared

    @property
    def known_pixels(self) -> int:
        p = self.prepared()
        return p.known_pixels if p is not None else 0

    def anchor(self, k: int) -> int:
        """The member whose footprint overlaps member k's the most: whom k is reported as paired with."""
        found = most_overlapping(self.footprints.get(k), self.footprints, (m for m in self.members if m != k))
        return found if found >= 0 else min(m for m in self.members if m != k)
