"""A 2D laser scanner on an occupancy grid: all beams traced in parallel with a grid DDA (Amanatides & Woo).

The DDA visits every cell a beam passes through, moving to a 4-neighbour at each step, so a beam can never slip
between two diagonally touching wall cells (the leak that fixed-step ray marching has through 1-cell walls).
"""
from __future__ import annotations

import math
from typing import Optional, Sequence, Tuple

import numpy as np


def beam_angles(n_beams: int, angle_min: float = -math.pi, angle_max: Optional[float] = None) -> np.ndarray:
    """Beam angles relative to the robot heading: a full turn from angle_min by default (like sensor_msgs/LaserScan
    with angle_increment = (angle_max - angle_min) / n_beams)."""
    if n_beams <= 0:
        raise ValueError("n_beams must be positive")
    if angle_max is None:
        angle_max = angle_min + 2.0 * math.pi
    return angle_min + (angle_max - angle_min) / n_beams * np.arange(n_beams)


def cast(world_occ: np.ndarray, resolution: float, pose: Sequence[float], n_beams: int, max_range: float,
         rng: Optional[np.random.Generator] = None, sigma: float = 0.0, dropout: float = 0.0,
         angles: Optional[np.ndarray] = None, origin: Tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Ranges (metres) of a scan from ``pose`` = (x, y, yaw) in the grid's frame.

    world_occ: bool (H, W), row 0 = lowest y, cell (c, r) covers origin + [c, c+1) x [r, r+1) * resolution; cells
    outside the array block beams. A beam that hits nothing within max_range gives +inf, a dropped beam NaN
    (REP 117). A hit range is the distance to the surface of the first blocking cell, plus N(0, sigma) noise.
    ``angles`` (relative to yaw) overrides the default full turn of n_beams beams.
    """
    occ = np.asarray(world_occ, dtype=bool)
    if occ.ndim != 2:
        raise ValueError("world_occ must be a 2-D array")
    rel = beam_angles(n_beams) if angles is None else np.asarray(angles, dtype=float)
    n = rel.size
    H, W = occ.shape
    # work in cell units: position px, py; directions unit vectors
    px = (float(pose[0]) - origin[0]) / resolution
    py = (float(pose[1]) - origin[1]) / resolution
    a = float(pose[2]) + rel
    dx, dy = np.cos(a), np.sin(a)
    limit = max_range / resolution

    with np.errstate(divide='ignore', invalid='ignore'):
        step_x = np.where(dx > 0, 1, -1).astype(np.int64)
        step_y = np.where(dy > 0, 1, -1).astype(np.int64)
        ix0, iy0 = math.floor(px), math.floor(py)
        # t (cell units along the beam) at which the beam crosses the next vertical / horizontal cell boundary
        t_max_x = np.where(dx != 0, ((ix0 + (dx > 0)) - px) / dx, np.inf)
        t_max_y = np.where(dy != 0, ((iy0 + (dy > 0)) - py) / dy, np.inf)
        t_dx = np.where(dx != 0, 1.0 / np.abs(dx), np.inf)
        t_dy = np.where(dy != 0, 1.0 / np.abs(dy), np.inf)

    ranges = np.full(n, np.inf)
    ix = np.full(n, ix0, np.int64)
    iy = np.full(n, iy0, np.int64)
    t_entry = np.zeros(n)
    active = np.arange(n)
    # each step crosses one cell boundary; a beam of length L crosses at most |dx|L + |dy|L + 2 of them
    for _ in range(int(2.0 * limit) + 4):
        if active.size == 0:
            break
        cx, cy = ix[active], iy[active]
        inside = (cx >= 0) & (cx < W) & (cy >= 0) & (cy < H)
        blocked = ~inside
        blocked[inside] = occ[cy[inside], cx[inside]]
        hit = blocked & (t_entry[active] <= limit)
        ranges[active[hit]] = t_entry[active[hit]] * resolution
        keep = ~blocked & (t_entry[active] <= limit)
        active = active[keep]
        if active.size == 0:
            break
        tx, ty = t_max_x[active], t_max_y[active]
        go_x = tx <= ty              # on a tie (exact corner) step in x, then y: still 4-connected
        ax, ay = active[go_x], active[~go_x]
        t_entry[ax] = tx[go_x]
        ix[ax] += step_x[ax]
        t_max_x[ax] += t_dx[ax]
        t_entry[ay] = ty[~go_x]
        iy[ay] += step_y[ay]
        t_max_y[ay] += t_dy[ay]

    if sigma > 0.0 or dropout > 0.0:
        rng = rng if rng is not None else np.random.default_rng()
        finite = np.isfinite(ranges)
        if sigma > 0.0:
            ranges[finite] = np.maximum(0.0, ranges[finite] + rng.normal(0.0, sigma, int(finite.sum())))
        if dropout > 0.0:
            ranges[rng.random(n) < dropout] = np.nan
    return ranges
