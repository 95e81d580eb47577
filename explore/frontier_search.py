"""Frontier search of explore_lite (explore.md §5), vectorised with numpy/OpenCV.

The original runs three queue-based searches cell by cell. Their results depend on visiting order (which unknown
cell seeds each frontier: the seed is counted in ``size`` but left out of ``points``, the centroid sum and
``min_distance``), so this port replays the same breadth-first orders level by level: each BFS level is one numpy
step whose order is (order of the parent in the previous level, neighbour slot), exactly a FIFO queue's order.
Results, including the seed, point order, ``middle`` and floating-point sums, equal the original's.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable, List, Optional, Tuple

import cv2
import numpy as np

from .costmap import FREE_SPACE, LETHAL_OBSTACLE, NO_INFORMATION, Costmap

_log = logging.getLogger('rosout.' + __name__)

Point2 = Tuple[float, float]


@dataclass(eq=False)
class Frontier:
    """One frontier, with the original's fields (z components, always 0, are dropped)."""
    size: int                       # cells, including the seed cell
    min_distance: float             # m, from the robot cell's centre to the nearest non-seed cell (inf if none)
    cost: float                     # potential_scale·min_distance·res − gain_scale·size·res
    initial: Point2                 # world centre of the seed cell
    centroid: Point2                # sum of non-seed cell centres / size (the original's quirk: pulled to 0,0)
    middle: Point2                  # first non-seed cell (BFS order) at min_distance; (0, 0) if none
    points: np.ndarray = field(repr=False)  # (size-1, 2) world centres of the non-seed cells, BFS order


def frontier_cost(min_distance: float, size: int, resolution: float, potential_scale: float,
                  gain_scale: float) -> float:
    """The original's cost; mixed units (m·m/cell) kept on purpose. NaN for inf distance with potential_scale 0."""
    return (potential_scale * min_distance * resolution) - (gain_scale * size * resolution)


def _near4(mask: np.ndarray) -> np.ndarray:
    """Cells with at least one 4-neighbour in ``mask`` (2-D, no wrap-around)."""
    near = np.zeros_like(mask)
    near[:, 1:] |= mask[:, :-1]
    near[:, :-1] |= mask[:, 1:]
    near[1:, :] |= mask[:-1, :]
    near[:-1, :] |= mask[1:, :]
    return near


def frontier_cell_mask(data: np.ndarray) -> np.ndarray:
    """Cells that satisfy the frontier predicate: exactly NO_INFORMATION with a 4-neighbour exactly FREE_SPACE."""
    return (data == NO_INFORMATION) & _near4(data == FREE_SPACE)


# Below this many cells a BFS level is expanded in plain Python: numpy's per-call overhead would dominate
# (long one-cell-wide corridors give hundreds of thousands of tiny levels).
_SMALL_LEVEL = 24


def _bfs_order(sources: np.ndarray, open_: np.ndarray, offsets: np.ndarray,
               stop: Optional[np.ndarray] = None, level_sizes: Optional[List[int]] = None) -> np.ndarray:
    """Cells reached by a FIFO-queue BFS from ``sources`` (excluded), in the order the queue would pop them.

    Works on a padded flat grid. ``open_`` (contiguous bool, consumed: cells are closed as they are reached) says
    which cells may be entered; sources must be closed already. Each level is the previous level's cells' neighbours
    in (parent order, offset order), first occurrence kept — exactly the queue's visited-on-push order. With
    ``stop``, ends after the first level that reaches a ``stop`` cell. With ``level_sizes``, the number of cells
    of each level is appended to it (level 1 = the sources' neighbours).
    """
    chunks: List[object] = []
    open_mv = memoryview(open_.view(np.uint8))
    stop_mv = memoryview(stop.view(np.uint8)) if stop is not None else None
    offs = [int(o) for o in offsets]
    claim = np.empty(open_.size, dtype=np.int32)
    cur: object = sources
    while len(cur):
        if len(cur) < _SMALL_LEVEL:
            nxt: List[int] = []
            for c in (cur.tolist() if isinstance(cur, np.ndarray) else cur):
                for o in offs:
                    n = c + o
                    if open_mv[n]:
                        open_mv[n] = 0
                        nxt.append(n)
            if not nxt:
                break
            if level_sizes is not None:
                level_sizes.append(len(nxt))
            if chunks and isinstance(chunks[-1], list):
                chunks[-1].extend(nxt)
            else:
                chunks.append(list(nxt))
            found = stop_mv is not None and any(stop_mv[n] for n in nxt)
            cur = nxt
        else:
            if not isinstance(cur, np.ndarray):
                cur = np.array(cur, dtype=np.int64)
            cand = (cur[:, None] + offsets[None, :]).ravel()
            cand = cand[open_[cand]]
            if cand.size == 0:
                break
            # Keep each cell's first occurrence: ufunc.at has defined semantics for repeated indices.
            pos = np.arange(cand.size, dtype=np.int32)
            claim[cand] = cand.size
            np.minimum.at(claim, cand, pos)
            cand = cand[claim[cand] == pos]
            open_[cand] = False
            chunks.append(cand)
            if level_sizes is not None:
                level_sizes.append(int(cand.size))
            found = stop is not None and bool(stop[cand].any())
            cur = cand
        if found:
            break
    if not chunks:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([np.asarray(ch, dtype=np.int64) for ch in chunks])


def search_frontiers(data: np.ndarray, resolution: float, origin: Point2, robot_cell: Tuple[int, int],
                     potential_scale: float = 1e-3, gain_scale: float = 1.0,
                     min_frontier_size: float = 0.5, path_distance: bool = False) -> List[Frontier]:
    """Frontiers reachable from ``robot_cell`` (mx, my) in the cost grid ``data`` (uint8, shape (size_y, size_x)).

    Sorted by ascending cost with a stable sort (NaN costs last); the original's unstable sort may order ties
    differently. Frontiers with ``size·resolution < min_frontier_size`` are dropped. ``path_distance``: a
    frontier's ``min_distance`` (and ``middle``) is measured along free space (4-connected steps from the search's
    start cell) instead of in a straight line, see ``path_steps``.
    """
    if data.dtype != np.uint8 or data.ndim != 2:
        raise TypeError(f"cost grid must be a 2-D uint8 array, got {data.dtype} {data.shape}")
    sy, sx = data.shape
    mx, my = int(robot_cell[0]), int(robot_cell[1])
    if not (0 <= mx < sx and 0 <= my < sy):
        _log.error("Robot out of costmap bounds, cannot search for frontiers")
        return []
    # One-cell LETHAL border: neighbour offsets need no bounds checks and the border is never free/unknown/entered.
    w = sx + 2
    padded = np.full((sy + 2, w), LETHAL_OBSTACLE, dtype=np.uint8)
    padded[1:-1, 1:-1] = data
    off4 = np.array([-1, 1, -w, w], dtype=np.int64)  # nhood4 order
    off8 = np.array([-1, 1, -w, w, -1 - w, -1 + w, 1 - w, 1 + w], dtype=np.int64)  # nhood8 order
    free2 = padded == FREE_SPACE
    free = free2.ravel()
    pos = (my + 1) * w + (mx + 1)

    start = _nearest_clear_cell(pos, free, sx, sy, off8)
    if start is None:
        # No free cell anywhere: the original floods from the robot cell but no cell can be a frontier.
        _log.warning("Could not find nearby clear cell to start search")
        return []
    # Main BFS: from a free start only value-0 cells are entered (value <= 0), i.e. the 4-connected free region.
    open_free = free.copy()
    open_free[start] = False
    first_level = np.array([start], dtype=np.int64)
    level_sizes: List[int] = [1]
    order = np.concatenate([first_level, _bfs_order(first_level, open_free, off4, level_sizes=level_sizes)])

    unknown2 = padded == NO_INFORMATION
    fmask2 = unknown2 & _near4(free2)
    seeds, label_of = _frontier_seeds(order, unknown2, fmask2, off4)
    if seeds.size == 0:
        return []
    open_f = fmask2.ravel().copy()
    open_f[seeds] = False
    # Groups are disjoint, so one joint BFS from all seeds gives every group the order its own BFS would have.
    rest = _bfs_order(seeds, open_f, off8)
    seed_labels = label_of(seeds)
    lut = np.full(int(seed_labels.max()) + 1, -1, dtype=np.int64)
    lut[seed_labels] = np.arange(seeds.size)
    steps = path_steps(order, level_sizes, padded.shape, off4, rest) if path_distance else None
    frontiers = _assemble(seeds, rest, lut[label_of(rest)], w, resolution, origin, (mx, my),
                          potential_scale, gain_scale, min_frontier_size, steps)
    frontiers.sort(key=lambda f: (math.isnan(f.cost), f.cost))
    return frontiers


def path_steps(order: np.ndarray, level_sizes: List[int], shape: Tuple[int, int], off4: np.ndarray,
               cells: np.ndarray) -> np.ndarray:
    """Steps along free space from the search's start to each frontier cell of ``cells`` (flat padded indices):
    one more than its nearest free 4-neighbour's BFS level.

    Why: explore_lite ranks frontiers by straight-line distance. In a building the way to a frontier often starts
    away from it (round a wall), so driving towards the chosen frontier makes another one look nearer; the robot
    then switches goals back and forth between two frontiers for ever without reaching either (each switch also
    restarts the progress timeout). Distances along free space shrink as the robot drives along its path, so the
    choice stays. 4-connected steps measure Manhattan length in the open, which is still a metric with that
    property (a monotone path to a frontier shortens its distance by every step taken).
    """
    level = np.full(shape[0] * shape[1], np.inf)
    level[order] = np.repeat(np.arange(len(level_sizes), dtype=np.float64), level_sizes)
    near = np.min(level[cells[:, None] + off4[None, :]], axis=1)
    return near + 1.0


def _frontier_seeds(order: np.ndarray, unknown2: np.ndarray, fmask2: np.ndarray,
                    off4: np.ndarray) -> Tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """Seed cell of each frontier in the order the main BFS meets them, and a flat-index → group-label function.

    The original meets unknown cells as 4-neighbours of popped free cells; the first cell met of each
    8-connected group of frontier cells becomes that group's seed (the rest of the group is flagged by building it).
    """
    w = fmask2.shape[1]
    near_unknown = order[_near4(unknown2).ravel()[order]]
    met = (near_unknown[:, None] + off4[None, :]).ravel()
    met = met[unknown2.ravel()[met]]
    if met.size == 0:
        return met, lambda cells: cells
    # Label only the bounding box of the frontier cells: labelling the whole grid costs far more on large maps.
    rows = np.flatnonzero(fmask2.any(axis=1))
    cols = np.flatnonzero(fmask2.any(axis=0))
    r0, c0 = int(rows[0]), int(cols[0])
    box = np.ascontiguousarray(fmask2[r0:rows[-1] + 1, c0:cols[-1] + 1]).view(np.uint8)
    _, box_labels = cv2.connectedComponents(box, connectivity=8, ltype=cv2.CV_32S)

    def label_of(cells: np.ndarray) -> np.ndarray:
        return box_labels[cells // w - r0, cells % w - c0]

    _, first = np.unique(label_of(met), return_index=True)
    first.sort()
    return met[first], label_of


def _assemble(seeds: np.ndarray, rest: np.ndarray, k: np.ndarray, w: int, resolution: float, origin: Point2,
              robot_cell: Tuple[int, int], potential_scale: float, gain_scale: float,
              min_frontier_size: float, steps: Optional[np.ndarray] = None) -> List[Frontier]:
    """Frontier records from the seeds and the non-seed cells ``rest`` (BFS order) with their frontier index ``k``;
    ``steps`` (per cell of ``rest``): distances along free space in cells instead of straight lines."""
    n = seeds.size
    sizes = 1 + np.bincount(k, minlength=n)

    def world(cells: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        cx = (cells % w - 1).astype(np.float64)
        cy = (cells // w - 1).astype(np.float64)
        return origin[0] + (cx + 0.5) * resolution, origin[1] + (cy + 0.5) * resolution

    # Distances are to the robot cell's centre, not the start cell's (as the original).
    rx = origin[0] + (robot_cell[0] + 0.5) * resolution
    ry = origin[1] + (robot_cell[1] + 0.5) * resolution
    wx, wy = world(rest)
    ix, iy = world(seeds)
    # bincount adds weights in input order, i.e. the original's summation order per frontier; the seed is left
    # out of the sum but counted in the size (the original's centroid quirk).
    cxs = np.bincount(k, weights=wx, minlength=n) / sizes
    cys = np.bincount(k, weights=wy, minlength=n) / sizes
    dx, dy = rx - wx, ry - wy
    dist = np.sqrt(dx * dx + dy * dy)  # the original's pow(d, 2.0), which compilers turn into d*d
    if steps is not None:
        dist = steps * resolution
    # Strict '<' update in the original: the first cell (BFS order) at the minimum distance is 'middle'.
    by_dist = np.lexsort((np.arange(rest.size), dist, k))
    is_first = np.ones(by_dist.size, dtype=bool)
    is_first[1:] = k[by_dist][1:] != k[by_dist][:-1]
    nearest = np.full(n, -1, dtype=np.int64)
    nearest[k[by_dist[is_first]]] = by_dist[is_first]
    by_group = np.argsort(k, kind='stable')
    bounds = np.concatenate([[0], np.cumsum(sizes - 1)])

    frontiers: List[Frontier] = []
    for i in range(n):
        size = int(sizes[i])
        if size * resolution < min_frontier_size:
            continue
        j = int(nearest[i])
        min_distance = float(dist[j]) if j >= 0 else math.inf
        sel = by_group[bounds[i]:bounds[i + 1]]
        frontiers.append(Frontier(
            size=size, min_distance=min_distance,
            cost=frontier_cost(min_distance, size, resolution, potential_scale, gain_scale),
            initial=(float(ix[i]), float(iy[i])), centroid=(float(cxs[i]), float(cys[i])),
            middle=(float(wx[j]), float(wy[j])) if j >= 0 else (0.0, 0.0),
            points=np.column_stack((wx[sel], wy[sel]))))
    return frontiers


def _nearest_clear_cell(pos: int, free: np.ndarray, sx: int, sy: int, off8: np.ndarray) -> Optional[int]:
    """The original's nearestCell: BFS over the 8-neighbourhood ignoring values; first FREE cell popped, or None."""
    if free[pos]:
        return int(pos)
    if not free.any():
        return None
    w = sx + 2
    inside = np.zeros((sy + 2, w), dtype=bool)
    inside[1:-1, 1:-1] = True
    inside = inside.ravel()
    inside[pos] = False
    # Popped in BFS order, so the first free cell of the order is the one the original returns.
    order = _bfs_order(np.array([pos], dtype=np.int64), inside, off8, stop=free)
    return int(order[np.argmax(free[order])])


class FrontierSearch:
    """The original's FrontierSearch: searches a Costmap (under its lock) from a world position."""

    def __init__(self, costmap: Costmap, potential_scale: float, gain_scale: float,
                 min_frontier_size: float, path_distance: bool = False) -> None:
        self.costmap = costmap
        self.path_distance = path_distance
        self.potential_scale = potential_scale
        self.gain_scale = gain_scale
        self.min_frontier_size = min_frontier_size

    def search_from(self, x: float, y: float) -> List[Frontier]:
        """Frontiers sorted by cost, searched from world position (x, y); [] if (x, y) is outside the grid."""
        with self.costmap.lock:
            cell = self.costmap.world_to_map(x, y)
            if cell is None:
                _log.error("Robot out of costmap bounds, cannot search for frontiers")
                return []
            return search_frontiers(self.costmap.data, self.costmap.resolution,
                                    (self.costmap.origin_x, self.costmap.origin_y), cell,
                                    self.potential_scale, self.gain_scale, self.min_frontier_size,
                                    self.path_distance)
