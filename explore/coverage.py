"""Ground-truth evaluation for tests, the demo and the bench (no ROS): how much of a known world the robots have
explored, and how well a map merge placed their maps.

The *reachable area* is the free space of the ground-truth world 4-connected to the robots' start cells. A
reachable world cell counts as *explored* when its centre falls on a known cell (not −1) of at least one robot map,
placed in the world by that map's true pose.
"""
from __future__ import annotations

import math
from typing import Dict, Iterable, List, Mapping, Optional, Sequence, Tuple

import cv2
import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.admission import OCCUPIED_THRESHOLD
from multirobot_map_merge.grid import Grid

Pose = Tuple[float, float, float]   # x, y, yaw of a map frame in the world frame


def _world_cell(world: Grid, x: float, y: float) -> Optional[Tuple[int, int]]:
    inv = np.linalg.inv(world.cell_to_map())
    c, r, _ = inv @ np.array([x, y, 1.0])
    c, r = int(np.floor(c)), int(np.floor(r))
    if 0 <= c < world.width and 0 <= r < world.height:
        return c, r
    return None


def reachable_mask(world: Grid, starts: Iterable[Tuple[float, float]]) -> np.ndarray:
    """Free cells (0 ≤ value < 50) 4-connected to the cell of any start point (world metres)."""
    free = ((world.data >= 0) & (world.data < 50)).astype(np.uint8)
    _, labels = cv2.connectedComponents(free, connectivity=4, ltype=cv2.CV_32S)
    keep = set()
    for x, y in starts:
        cell = _world_cell(world, x, y)
        if cell is not None and free[cell[1], cell[0]]:
            keep.add(int(labels[cell[1], cell[0]]))
    if not keep:
        return np.zeros(world.data.shape, bool)
    return np.isin(labels, sorted(keep))


class KnownRaster:
    """A world raster on which robot maps are drawn at their world poses: a raster cell is known when its centre
    falls on a known cell (not -1) of the map. Drawing is one OpenCV warp per map (nearest cell), cheap enough for
    a dozen large maps every few seconds."""

    def __init__(self, world_from_pixel: np.ndarray, shape: Tuple[int, int]) -> None:
        # world_from_pixel: 3x3, raster pixel (column, row) -> world metres of the pixel's centre
        self.world_from_pixel = np.asarray(world_from_pixel, float)
        self.shape = (int(shape[0]), int(shape[1]))
        self.cell_m = float(np.hypot(*self.world_from_pixel[:2, 0]))

    @classmethod
    def box(cls, bounds: Sequence[float], cell_m: float = 0.1) -> 'KnownRaster':
        """Axis-aligned cells of ``cell_m`` over ``bounds`` = x0, y0, x1, y1 (world metres)."""
        x0, y0, x1, y1 = (float(v) for v in bounds)
        if not (cell_m > 0 and x1 > x0 and y1 > y0):
            raise ValueError(f'KnownRaster: empty bounds {bounds} or bad cell {cell_m}')
        shape = (max(1, int(math.ceil((y1 - y0) / cell_m))), max(1, int(math.ceil((x1 - x0) / cell_m))))
        return cls(np.array([[cell_m, 0.0, x0 + 0.5 * cell_m], [0.0, cell_m, y0 + 0.5 * cell_m], [0.0, 0.0, 1.0]]),
                   shape)

    @classmethod
    def on_grid(cls, world: Grid) -> 'KnownRaster':
        """The cells of a world grid itself (its frame is the world frame)."""
        return cls(world.cell_to_map() @ tf.translation(0.5, 0.5), world.data.shape)

    @classmethod
    def around(cls, world: Grid, cell_m: float = 0.1) -> 'KnownRaster':
        """Axis-aligned cells of ``cell_m`` covering a world grid."""
        corners = tf.apply(world.cell_to_map(), np.array([[0, 0], [world.width, 0], [0, world.height],
                                                           [world.width, world.height]], float))
        return cls.box((*corners.min(axis=0), *corners.max(axis=0)), cell_m)

    def known(self, grid: Optional[Grid], pose: Pose) -> np.ndarray:
        """Boolean raster of the cells known in ``grid`` placed at ``pose`` (its frame's pose in the world)."""
        if grid is None or grid.is_empty():
            return np.zeros(self.shape, bool)
        return self._warp(grid.known_mask().astype(np.uint8), grid, pose, 0).astype(bool)

    def values(self, grid: Optional[Grid], pose: Pose) -> np.ndarray:
        """Raster (int8) of the occupancy of ``grid`` placed at ``pose``; -1 where it has no cell."""
        if grid is None or grid.is_empty():
            return np.full(self.shape, -1, np.int8)
        return self._warp(grid.data.astype(np.int16), grid, pose, -1).astype(np.int8)

    def _warp(self, src: np.ndarray, grid: Grid, pose: Pose, border: int) -> np.ndarray:
        # raster pixel -> source pixel (OpenCV: a pixel's centre has integer coordinates, nearest = round)
        to_src = tf.translation(-0.5, -0.5) @ tf.inverse(tf.rigid(*pose) @ grid.cell_to_map()) @ self.world_from_pixel
        return cv2.warpAffine(src, to_src[:2], (self.shape[1], self.shape[0]),
                              flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=border)


def explored_mask(world: Grid, reachable: np.ndarray, maps: Sequence[Tuple[Grid, Pose]]) -> np.ndarray:
    """Reachable world cells that are known in at least one of ``maps`` (each a grid with its frame's world pose)."""
    raster = KnownRaster.on_grid(world)
    seen = np.zeros(reachable.shape, bool)
    for grid, pose in maps:
        seen |= raster.known(grid, pose)
    return seen & reachable


def explored_share(world: Grid, reachable: np.ndarray, maps: Sequence[Tuple[Grid, Pose]]) -> float:
    """Fraction (0..1) of the reachable area explored by ``maps``; 0 when nothing is reachable."""
    total = int(reachable.sum())
    if total == 0:
        return 0.0
    return float(explored_mask(world, reachable, maps).sum()) / total


def known_corners(grid: Grid) -> np.ndarray:
    """(4, 2) corners, in the grid's frame, of the bounding box of its known cells ((1, 2) zeros if none)."""
    rows, cols = np.nonzero(grid.known_mask())
    if rows.size == 0:
        return np.zeros((1, 2))
    c = np.array([[cols.min(), rows.min()], [cols.max() + 1, rows.min()], [cols.min(), rows.max() + 1],
                  [cols.max() + 1, rows.max() + 1]], float)
    return tf.apply(grid.cell_to_map(), c)


def placement_errors(estimated: Mapping[str, Pose], truth: Mapping[str, Pose],
                     maps: Mapping[str, Grid]) -> List[Dict[str, object]]:
    """Errors of estimated map-frame poses (name -> pose in the merge's world) against the true ones (name -> pose
    in the ground-truth world), relative to the first estimated robot (the merge's world is arbitrary): rotation in
    degrees and the largest displacement, in metres, of the corners of the robot map's known area. One row per
    robot of ``estimated`` that has a true pose, in that order."""
    names = [n for n in estimated if n in truth]
    if not names:
        return []
    ref = names[0]
    ref_est, ref_true = tf.rigid(*estimated[ref]), tf.rigid(*truth[ref])
    rows = []
    for n in names:
        rel_est = tf.inverse(ref_est) @ tf.rigid(*estimated[n])
        rel_true = tf.inverse(ref_true) @ tf.rigid(*truth[n])
        grid = maps.get(n)
        corners = known_corners(grid) if grid is not None else np.zeros((1, 2))
        rot, disp = tf.difference(rel_est, rel_true, corners)
        rows.append({'robot': n, 'reference': ref, 'rotation_error_deg': math.degrees(rot), 'corner_error_m': disp})
    return rows


def wall_fit(maps: Mapping[str, Grid], poses: Mapping[str, Pose], name: str,
             near_m: float = 0.5, close_m: float = 0.075) -> Tuple[int, int]:
    """(near, close): of robot ``name``'s wall cells placed by ``poses``, those with a wall of another placed robot
    map within ``near_m``, and of those, within ``close_m``: how well its walls fit the others' at these poses."""
    def walls(n: str) -> np.ndarray:
        rows, cols = np.nonzero(maps[n].data >= OCCUPIED_THRESHOLD)
        return tf.apply(tf.rigid(*poses[n]) @ maps[n].cell_to_map(), np.column_stack([cols, rows]).astype(float))
    others = [walls(n) for n in poses if n != name and n in maps]
    if name not in maps or name not in poses or not others:
        return 0, 0
    theirs, mine = np.vstack(others), walls(name)
    if not len(theirs) or not len(mine):
        return 0, 0
    cell = min(maps[name].resolution, close_m)
    lo = np.minimum(theirs.min(axis=0), mine.min(axis=0)) - 2 * near_m
    size = np.ceil((np.maximum(theirs.max(axis=0), mine.max(axis=0)) + 2 * near_m - lo) / cell).astype(int) + 1
    raster = np.full((size[1], size[0]), 255, np.uint8)
    ij = np.floor((theirs - lo) / cell).astype(int)
    raster[ij[:, 1], ij[:, 0]] = 0
    distance = cv2.distanceTransform(raster, cv2.DIST_L2, 3) * cell
    ij = np.floor((mine - lo) / cell).astype(int)
    d = distance[ij[:, 1], ij[:, 0]]
    near = d <= near_m
    return int(near.sum()), int((d[near] <= close_m).sum())


def right_by_the_data(row: Mapping[str, object], estimated: Mapping[str, Pose], truth: Mapping[str, Pose],
                      maps: Mapping[str, Grid], degrees: float = 1.0, metres: float = 0.5,
                      share: float = 0.95) -> Tuple[bool, Tuple[int, int], Tuple[int, int]]:
    """Whether a placement the strict errors call off is right by the maps themselves, as ../shared/eval's
    score_real judges real maps: a robot's own map drifts (SLAM), so its start pose is not where its walls fit
    best. Within ``degrees`` and ``metres`` of the truth (tighter than score_real's 2 degrees and 1.5 m: next to a
    start pose that fits poorly, a placement a degree and a half off can fit as well), and its walls fit the other
    placed maps at least ``share`` as well as at the true poses. Returns (verdict, fit at the placements, fit at
    the true poses)."""
    name = str(row['robot'])
    placed = wall_fit(maps, estimated, name)
    true = wall_fit(maps, {n: truth[n] for n in estimated if n in truth}, name)
    close = float(row['rotation_error_deg']) <= degrees and float(row['corner_error_m']) <= metres
    return close and placed[1] >= share * true[1], placed, true


def truth_from_estimate(estimated: Mapping[str, Pose], truth: Mapping[str, Pose]) -> Optional[Pose]:
    """Pose of the merge's world frame in the ground-truth world, through the first robot of ``estimated``."""
    names = [n for n in estimated if n in truth]
    if not names:
        return None
    m = tf.rigid(*truth[names[0]]) @ tf.inverse(tf.rigid(*estimated[names[0]]))
    x, y, yaw, _ = tf.params(m)
    return x, y, yaw


class PlacementTimeline:
    """How long a live merge was off while it ran: ``add`` each published set of placements (its stamp, and its
    placement_errors rows), ``summary`` at the end. A merge counts as off from a status whose worst robot is off by
    more than ``degrees`` or ``metres`` until the next status; the span runs from the first status with two robots
    placed to ``end``."""

    def __init__(self, degrees: float = 0.75, metres: float = 0.15) -> None:
        self.degrees, self.metres = degrees, metres
        self.first: Optional[float] = None
        self.off_s = 0.0
        self._off_since: Optional[float] = None   # stamp of the last status, if it was off
        self.worst_m: Tuple[float, str] = (0.0, '')
        self.worst_deg: Tuple[float, str] = (0.0, '')
        self.offs: List[Tuple[float, Dict[str, object]]] = []   # (stamp, worst row) of each status that was off

    def add(self, stamp: float, rows: Sequence[Mapping[str, object]]) -> None:
        if self._off_since is not None:
            self.off_s += max(stamp - self._off_since, 0.0)
            self._off_since = None
        if len(rows) < 2:
            return
        if self.first is None:
            self.first = stamp
        worst = max(rows, key=lambda r: r['corner_error_m'])
        self.worst_m = max(self.worst_m, (worst['corner_error_m'], worst['robot']))
        turned = max(rows, key=lambda r: r['rotation_error_deg'])
        self.worst_deg = max(self.worst_deg, (turned['rotation_error_deg'], turned['robot']))
        if worst['corner_error_m'] > self.metres or turned['rotation_error_deg'] > self.degrees:
            self._off_since = stamp
            self.offs.append((stamp, worst if worst['corner_error_m'] > self.metres else turned))

    def summary(self, end: float) -> Dict[str, object]:
        off = self.off_s + (max(end - self._off_since, 0.0) if self._off_since is not None else 0.0)
        return {'span_s': max(end - self.first, 0.0) if self.first is not None else 0.0, 'off_s': off,
                'degrees': self.degrees, 'cm': 100.0 * self.metres, 'worst_cm': 100.0 * self.worst_m[0],
                'worst_cm_robot': self.worst_m[1], 'worst_deg': self.worst_deg[0],
                'worst_deg_robot': self.worst_deg[1]}
