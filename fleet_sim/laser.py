"""A 2D laser scanner on an occupancy grid: all beams traced in parallel on the cells of a grid DDA (Amanatides & Woo).

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

    Same cells as the DDA of cast_stepwise, but without a loop over cells: see _cast_major.
    """
    occ = np.asarray(world_occ, dtype=bool)
    if occ.ndim != 2:
        raise ValueError("world_occ must be a 2-D array")
    rel = beam_angles(n_beams) if angles is None else np.asarray(angles, dtype=float)
    n = rel.size
    H, W = occ.shape
    px = (float(pose[0]) - origin[0]) / resolution
    py = (float(pose[1]) - origin[1]) / resolution
    ix0, iy0 = math.floor(px), math.floor(py)
    limit = max_range / resolution
    ranges = np.full(n, np.inf)
    if not (0 <= ix0 < W and 0 <= iy0 < H) or occ[iy0, ix0]:
        ranges[:] = 0.0
    else:
        a = float(pose[2]) + rel
        dx, dy = np.cos(a), np.sin(a)
        # pad with a blocked border: every cell index past the grid is clipped onto it (outside blocks beams)
        occ_p = np.pad(occ, 1, constant_values=True).ravel()
        x_major = np.abs(dx) >= np.abs(dy)
        for major, beams in ((0, np.flatnonzero(x_major)), (1, np.flatnonzero(~x_major))):
            if beams.size == 0:
                continue
            if major == 0:   # columns are cell columns; the minor coordinate is y
                args = (px, py, ix0, iy0, dx[beams], dy[beams], W, H, 1, W + 2)
            else:            # rows play the part of columns
                args = (py, px, iy0, ix0, dy[beams], dx[beams], H, W, W + 2, 1)
            ranges[beams] = _cast_major(occ_p, *args, limit)
        ranges *= resolution
    return add_noise(ranges, rng, sigma, dropout)


def add_noise(ranges: np.ndarray, rng: Optional[np.random.Generator], sigma: float, dropout: float = 0.0,
              sigma_per_m: float = 0.0) -> np.ndarray:
    """Gaussian noise on the finite ranges (standard deviation sigma + sigma_per_m * range, never below 0) and a
    ``dropout`` share of beams dropped (NaN), in place; returns ``ranges``."""
    if sigma > 0.0 or dropout > 0.0 or sigma_per_m > 0.0:
        rng = rng if rng is not None else np.random.default_rng()
        finite = np.isfinite(ranges)
        if sigma_per_m > 0.0:
            sd = sigma + sigma_per_m * ranges[finite]
            ranges[finite] = np.maximum(0.0, ranges[finite] + sd * rng.standard_normal(int(finite.sum())))
        elif sigma > 0.0:
            ranges[finite] = np.maximum(0.0, ranges[finite] + rng.normal(0.0, sigma, int(finite.sum())))
        if dropout > 0.0:
            ranges[rng.random(ranges.size) < dropout] = np.nan
    return ranges


def glass_no_return(ranges: np.ndarray, angles: np.ndarray, pose: Sequence[float], glass: np.ndarray,
                    resolution: float, origin: Tuple[float, float] = (0.0, 0.0),
                    max_incidence_deg: float = 10.0) -> np.ndarray:
    """No return (+inf), in place, for the beams of a noiseless scan whose hit cell is glass, unless they meet the
    glass within ``max_incidence_deg`` of its normal (a pane reflects a laser back only head-on). ``glass`` is a
    bool grid like cast()'s world_occ; ``angles`` are relative to the pose's yaw. Returns ``ranges``."""
    hit = np.flatnonzero(np.isfinite(ranges) & (ranges > 0.0))
    if hit.size == 0:
        return ranges
    a = float(pose[2]) + angles[hit]
    dx, dy = np.cos(a), np.sin(a)
    # the hit point lies on the face of the hit cell: a little further along the beam is inside it
    t = ranges[hit] / resolution
    px = (float(pose[0]) - origin[0]) / resolution + t * dx
    py = (float(pose[1]) - origin[1]) / resolution + t * dy
    c = np.floor(px + 1e-6 * np.sign(dx)).astype(np.int64)
    r = np.floor(py + 1e-6 * np.sign(dy)).astype(np.int64)
    h, w = glass.shape
    inside = (c >= 0) & (c < w) & (r >= 0) & (r < h)
    on_glass = np.zeros(hit.size, bool)
    on_glass[inside] = glass[r[inside], c[inside]]
    # the face the beam entered by: a vertical one (normal along x) where x is on a cell boundary
    on_x_face = np.abs(px - np.round(px)) <= np.abs(py - np.round(py))
    cos_incidence = np.where(on_x_face, np.abs(dx), np.abs(dy))
    head_on = cos_incidence >= np.cos(np.radians(max_incidence_deg))
    ranges[hit[on_glass & ~head_on]] = np.inf
    return ranges


def _cast_major(occ_p: np.ndarray, pm: float, pn: float, im0: int, in0: int, dm: np.ndarray, dn: np.ndarray,
                nm: int, nn: int, stride_m: int, stride_n: int, limit: float) -> np.ndarray:
    """Hit t (cell units, inf: none within limit) of beams that move at least as fast along their major axis as along
    the minor one (|dm| >= |dn|, so dm != 0). Cell (m, n) of the padded grid is occ_p[(m + 1) * stride_m +
    (n + 1) * stride_n]; the grid has nm cells along the major axis, nn along the minor one.

    The beam crosses major-axis cell boundaries at t = T(j) (j = 0, 1, ..); between two crossings it stays in one
    major-axis slice and changes minor cell at most once, so each slice holds 1 or 2 of its DDA cells: the cell it
    enters the slice in and the one it leaves in. Ties (a corner crossing) go major first, as cast_stepwise does: the
    minor cell at a slice boundary is the one before any minor crossing at that instant. Every slice is evaluated at
    once, in rounds of growing length so that short beams stop early."""
    b = dm.size
    pos = dm > 0
    up = dn > 0
    # T(j) = t0 + j * tstep: time of the j-th major crossing (tstep = 1 / |dm|)
    tstep = 1.0 / np.abs(dm)
    t0 = ((im0 + pos) - pm) / dm
    with np.errstate(divide='ignore'):
        inv_dn = np.where(dn != 0, 1.0 / np.where(dn != 0, dn, 1.0), 0.0)
    sign_row = pos.astype(np.int64)                      # row of the major-cell table below

    out = np.full(b, np.inf)
    todo = np.arange(b)
    j0, count = -1, 16
    while todo.size:
        up_t = up[todo, None]
        j = np.arange(j0, j0 + count + 1)                # slice indices, plus one for the exit of the last
        T = t0[todo, None] + tstep[todo, None] * j       # T(j): entry time of slice j
        if j0 == -1:
            T[:, 0] = 0.0                                # slice -1: the start cell's slice, from t = 0
        # minor cell at each slice boundary, just before any minor crossing at that instant
        y = pn + T * dn[todo, None]
        n_all = np.where(up_t, np.ceil(y) - 1.0, np.floor(y)).astype(np.int64)
        if j0 == -1:
            n_all[:, 0] = in0
        changes = n_all[:, 1:] != n_all[:, :-1]
        np.maximum(n_all, -1, out=n_all)                 # off the grid: onto the blocked border
        np.minimum(n_all, nn, out=n_all)
        n_all += 1
        n_all *= stride_n
        # major cell of each slice (index offset in occ_p): one table row per direction, picked per beam
        table = np.clip(im0 + np.outer([-1, 1], j[:-1] + 1), -1, nm)
        m = ((table + 1) * stride_m)[sign_row[todo]]
        t_in = T[:, :-1]
        hit_a = occ_p[m + n_all[:, :-1]]
        hit_a &= t_in <= limit
        hit_b = occ_p[m + n_all[:, 1:]]
        hit_b &= changes
        t_hit = np.where(hit_a, t_in, np.inf)
        if hit_b.any():
            # the minor crossing inside the slice; kept inside the slice: for a beam almost parallel to the major
            # axis the rounded minor coordinate may show the crossing some slices later than the exact formula, and
            # the cells follow the rounded one
            rows, cols = np.nonzero(hit_b)
            n_prev = n_all[rows, cols] // stride_n - 1
            t_y = ((n_prev + up[todo[rows]]) - pn) * inv_dn[todo[rows]]
            t_y = np.minimum(np.maximum(t_y, T[rows, cols]), T[rows, cols + 1])
            t_y[t_y > limit] = np.inf
            np.minimum.at(t_hit, (rows, cols), t_y)
        t_hit = t_hit.min(axis=1)
        out[todo] = t_hit
        done = np.isfinite(t_hit) | (T[:, -1] > limit)
        todo = todo[~done]
        j0 += count
        count *= 2
    return out


def cast_stepwise(world_occ: np.ndarray, resolution: float, pose: Sequence[float], n_beams: int, max_range: float,
         rng: Optional[np.random.Generator] = None, sigma: float = 0.0, dropout: float = 0.0,
         angles: Optional[np.ndarray] = None, origin: Tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """cast() by stepping every beam from cell to cell (one numpy iteration per cell boundary): the reference
    implementation, slower (its Python loop runs once per cell of the longest beam). Same arguments and result.

    Ranges (metres) of a scan from ``pose`` = (x, y, yaw) in the grid's frame.

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

    return add_noise(ranges, rng, sigma, dropout)
