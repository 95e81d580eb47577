"""Log-odds occupancy mapping from laser scans, in the robot's own map frame (as a SLAM package builds it).

The map frame is the frame whose origin is the robot's start pose: a robot starting at world pose P sees the world
through P^-1 (see relative_pose). The grid grows in chunks when scans reach past it; its origin always stays on a
multiple of the resolution, so the map-frame origin is a cell corner.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np

from multirobot_map_merge.grid import Grid

_log = logging.getLogger('rosout.fleet_sim.mapping')

Pose = Tuple[float, float, float]


def compose(a: Sequence[float], b: Sequence[float]) -> Pose:
    """a ∘ b: pose b (given in frame a) expressed in a's parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.remainder(a[2] + b[2], 2 * math.pi))


def relative_pose(ref: Sequence[float], pose: Sequence[float]) -> Pose:
    """ref^-1 ∘ pose: a pose given in the parent frame, expressed in frame ``ref``."""
    c, s = math.cos(ref[2]), math.sin(ref[2])
    dx, dy = pose[0] - ref[0], pose[1] - ref[1]
    return (c * dx + s * dy, -s * dx + c * dy, math.remainder(pose[2] - ref[2], 2 * math.pi))


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


@dataclass
class ChangedRect:
    """Cells [x, x+width) x [y, y+height) of the current grid that may differ since the last changed_rect();
    ``full`` means the grid was resized or moved (or this is the first call): publish a full map."""
    x: int
    y: int
    width: int
    height: int
    full: bool = False


class LogOddsMap:
    """Occupancy grid fused from scans in log-odds; to_grid() gives -1/0/100 by map_server-like thresholds."""

    def __init__(self, resolution: float = 0.05, l_hit: float = 2.0, l_miss: float = -1.5,
                 l_min: float = -5.0, l_max: float = 5.0, occupied_thresh: float = 0.65,
                 free_thresh: float = 0.196, chunk_m: float = 4.0, line_sampling: bool = False) -> None:
        """line_sampling: mark the free cells of a beam as a Bresenham line does (one cell per step along the
        beam's major axis, ~2.5x fewer samples) instead of sampling every half cell (which also catches cells the
        beam only clips)."""
        if resolution <= 0:
            raise ValueError("resolution must be positive")
        self.line_sampling = bool(line_sampling)
        self.resolution = float(resolution)
        self.l_hit, self.l_miss, self.l_min, self.l_max = l_hit, l_miss, l_min, l_max
        self._occ_l, self._free_l = _logit(occupied_thresh), _logit(free_thresh)
        self._chunk = max(1, int(round(chunk_m / resolution)))
        # grid cell (c, r) covers map-frame cell (c + c0, r + r0); start with one chunk around the origin
        self._c0 = self._r0 = -self._chunk
        self._L = np.zeros((2 * self._chunk, 2 * self._chunk), np.float32)
        self._dirty: Optional[list] = None     # [c_min, r_min, c_max, r_max] in map-frame cell indices
        self._full = True                      # nothing published yet
        self.n_scans = 0

    # ------------------------------------------------------------------------------------------- geometry
    @property
    def origin(self) -> Pose:
        return (self._c0 * self.resolution, self._r0 * self.resolution, 0.0)

    @property
    def shape(self) -> Tuple[int, int]:
        return self._L.shape

    def _ensure(self, cmin: int, rmin: int, cmax: int, rmax: int) -> None:
        """Grow so map-frame cells [cmin..cmax] x [rmin..rmax] are inside, by whole chunks."""
        h, w = self._L.shape
        c0, r0, c1, r1 = self._c0, self._r0, self._c0 + w, self._r0 + h
        if cmin >= c0 and rmin >= r0 and cmax < c1 and rmax < r1:
            return
        k = self._chunk
        nc0 = c0 if cmin >= c0 else c0 - k * math.ceil((c0 - cmin) / k)
        nr0 = r0 if rmin >= r0 else r0 - k * math.ceil((r0 - rmin) / k)
        nc1 = c1 if cmax < c1 else c1 + k * math.ceil((cmax + 1 - c1) / k)
        nr1 = r1 if rmax < r1 else r1 + k * math.ceil((rmax + 1 - r1) / k)
        L = np.zeros((nr1 - nr0, nc1 - nc0), np.float32)
        L[r0 - nr0:r0 - nr0 + h, c0 - nc0:c0 - nc0 + w] = self._L
        self._L, self._c0, self._r0 = L, nc0, nr0
        self._full = True

    # ------------------------------------------------------------------------------------------- fusion
    def integrate(self, pose: Sequence[float], ranges: np.ndarray, angles: np.ndarray, max_range: float,
                  clear_no_return: bool = True) -> None:
        """Fuse one scan taken at ``pose`` (map frame). Finite ranges: free along the beam, occupied at the end;
        +inf (no return): free up to max_range if clear_no_return; NaN (dropout): nothing."""
        ranges = np.asarray(ranges, dtype=float)
        angles = np.asarray(angles, dtype=float)
        if ranges.shape != angles.shape or ranges.ndim != 1:
            raise ValueError(f"{ranges.shape} ranges for {angles.shape} angles")
        x, y, yaw = (float(v) for v in pose)
        res = self.resolution
        hit = np.isfinite(ranges) & (ranges <= max_range) & (ranges >= 0)
        free_len = np.where(hit, ranges, np.nan)
        if clear_no_return:
            free_len = np.where(np.isposinf(ranges) | (np.isfinite(ranges) & (ranges > max_range)),
                                max_range, free_len)
        beams = np.flatnonzero(np.isfinite(free_len))
        a = yaw + angles[beams]
        ca, sa = np.cos(a), np.sin(a)
        lengths = free_len[beams]

        # free samples along each beam, all beams at once (ragged -> flat with repeat/cumsum): every half cell, or
        # with line_sampling one per cell of the beam's major axis; in cell units
        step = 1.0 / np.maximum(np.abs(ca), np.abs(sa)) if self.line_sampling else np.full(beams.size, 0.5)
        counts = np.ceil(lengths / res / step).astype(np.int64)
        total = int(counts.sum())
        k = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)     # sample index within its beam
        px, py = x / res, y / res
        fx = np.floor(px + k * np.repeat(step * ca, counts)).astype(np.int64)
        fy = np.floor(py + k * np.repeat(step * sa, counts)).astype(np.int64)
        is_hit = hit[beams]
        hx = np.floor(px + lengths[is_hit] / res * ca[is_hit]).astype(np.int64)
        hy = np.floor(py + lengths[is_hit] / res * sa[is_hit]).astype(np.int64)
        # the robot's own cell too, so growth always covers the pose
        rc, rr = math.floor(px), math.floor(py)
        bounds = [rc, rr, rc, rr]
        for cx, cy in ((fx, fy), (hx, hy)):
            if cx.size:
                bounds = [min(bounds[0], int(cx.min())), min(bounds[1], int(cy.min())),
                          max(bounds[2], int(cx.max())), max(bounds[3], int(cy.max()))]
        self._ensure(*bounds)

        if fx.size + hx.size:
            # one dense log-odds change over the scan's bounding box (cheaper than sorting cells for unique)
            c_lo, r_lo, c_hi, r_hi = bounds
            h, w = r_hi - r_lo + 1, c_hi - c_lo + 1
            delta = np.zeros(h * w, np.float32)
            delta[(fy - r_lo) * w + (fx - c_lo)] = self.l_miss
            delta[(hy - r_lo) * w + (hx - c_lo)] = self.l_hit    # after the free cells: a hit cell is not cleared
            win = self._L[r_lo - self._r0:r_hi - self._r0 + 1, c_lo - self._c0:c_hi - self._c0 + 1]
            win += delta.reshape(h, w)
            np.maximum(win, self.l_min, out=win)                  # untouched cells are within the bounds already
            np.minimum(win, self.l_max, out=win)
            # the changed cells' box (the robot's own cell may be untouched, e.g. all beams dropped)
            tx, ty = np.concatenate([fx, hx]), np.concatenate([fy, hy])
            box = [int(tx.min()), int(ty.min()), int(tx.max()), int(ty.max())]
            d = self._dirty
            self._dirty = box if d is None else [min(d[0], box[0]), min(d[1], box[1]),
                                                 max(d[2], box[2]), max(d[3], box[3])]
        self.n_scans += 1

    # ------------------------------------------------------------------------------------------- output
    def values(self, rect: Optional[ChangedRect] = None) -> np.ndarray:
        """int8 (H, W): 100 where P(occupied) > occupied_thresh, 0 where < free_thresh, else -1; only the cells of
        ``rect`` if given."""
        L = self._L if rect is None else self._L[rect.y:rect.y + rect.height, rect.x:rect.x + rect.width]
        out = np.full(L.shape, -1, np.int8)
        out[L > self._occ_l] = 100
        out[L < self._free_l] = 0
        return out

    def occupied_cells(self, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Per grid cell (cols, rows; outside the grid: False) whether it is occupied (100 in values())."""
        h, w = self._L.shape
        inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        out = np.zeros(np.shape(cols), bool)
        out[inside] = self._L[rows[inside], cols[inside]] > self._occ_l
        return out

    def to_grid(self, frame_id: str = 'map', stamp: float = 0.0) -> Grid:
        return Grid(self.values(), self.resolution, self.origin, frame_id=frame_id, stamp=stamp)

    def changed_rect(self) -> Optional[ChangedRect]:
        """The part of to_grid() that may have changed since the previous call (None: nothing changed)."""
        h, w = self._L.shape
        if self._full:
            self._full, self._dirty = False, None
            return ChangedRect(0, 0, w, h, full=True)
        if self._dirty is None:
            return None
        c_min, r_min, c_max, r_max = self._dirty
        self._dirty = None
        x, y = c_min - self._c0, r_min - self._r0
        return ChangedRect(x, y, c_max - c_min + 1, r_max - r_min + 1)
