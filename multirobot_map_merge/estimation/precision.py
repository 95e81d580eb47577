"""How precisely the shared walls determine a placement.

A small common area can agree everywhere and still leave the angle loose: a few walls close together fix the
translation but hardly the rotation, and a degree off moves the far end of a large map by decimetres. Each agreeing
wall constrains the placement only along its normal; the information matrix of these point-to-line constraints
(as for the covariance of ICP, Censi 2007) gives the covariance of (x, y, angle), and through it the spread of the
corners of both maps. Neighbouring wall pixels are not independent measurements (rasterised walls err together,
and a map's walls bend a little where its SLAM drifted), so the formal spread is scaled by INFLATION, chosen with
bench/calibrate_precision.py: over the pairs of maps the matcher places near the truth (dev and the generated
buildings), the actual corner error is a median 4 times the formal one, 8-9 times at the 90th percentile; with 15,
one of those that pass (1105 of 1169) is more than 0.15 m off, against 11 with 10. A join of two groups on the
small maps of a live fleet's first seconds (a replay of the 30-map reveal) passed at 10 (0.22 m expected) and was
1.6 degrees off: its turned walls fitted better than the true ones.
"""
from __future__ import annotations

import math
from typing import Optional, Tuple

import numpy as np

from .. import transforms as tf
from .features import PreparedGrid, opposed

INFLATION = 15.0
MIN_SIGMA = 0.5   # pixels: residuals below half a pixel are rasterisation, not evidence of precision
MIN_PAIRS = 10


def _matched_walls(src: PreparedGrid, dst: PreparedGrid, model: np.ndarray,
                   tolerance: float) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Walls of src (placed by model) within `tolerance` of a wall of dst seen from the same side: their points and
    dst's unit wall normals there (dst pixels), and the residuals along those normals."""
    moved = tf.apply(model, src.walls)
    nearest, dist = dst.nearest(moved)
    close = np.flatnonzero(dist <= tolerance)
    at = np.rint(nearest[close]).astype(np.int64)
    normals = dst.free_side[at[:, 1], at[:, 0]]
    length = np.hypot(normals[:, 0], normals[:, 1])
    # walls seen from opposite sides are a wall's two faces, not one wall
    keep = (length > 1e-3) & ~opposed(src.wall_normals[close] @ model[:2, :2].T, normals)
    points, normals = moved[close][keep], normals[keep] / length[keep, None]
    residuals = ((points - nearest[close][keep]) * normals).sum(axis=1)
    return points, normals, residuals


def covariance(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray,
               tolerance: float) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """Formal covariance of (x, y, angle) of the placement `model` (pixels i -> pixels j) about the centre of the
    walls that constrain it, and that centre (pixels of j); None when too few walls agree to tell."""
    p1, n1, r1 = _matched_walls(pi, pj, model, tolerance)
    p2, n2, r2 = _matched_walls(pj, pi, tf.inverse(model), tolerance)
    # j's walls matched in i's frame: bring them into j's frame
    p2, n2 = tf.apply(model, p2), n2 @ model[:2, :2].T
    points, normals, residuals = np.vstack([p1, p2]), np.vstack([n1, n2]), np.concatenate([r1, r2])
    if len(points) < MIN_PAIRS:
        return None
    centre = points.mean(axis=0)
    rel = points - centre
    rows = np.column_stack([normals, rel[:, 0] * normals[:, 1] - rel[:, 1] * normals[:, 0]])
    info = rows.T @ rows
    if np.linalg.cond(info) > 1e12:
        return None
    sigma2 = max(float((residuals ** 2).mean()), MIN_SIGMA ** 2)
    return sigma2 * np.linalg.inv(info), centre


def corner_error(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray, tolerance: float,
                 moving_only: bool = False, angle_bound: Optional[float] = None) -> float:
    """Expected error (pixels of j) at the farthest corner of either grid for the placement `model` (pixels i ->
    pixels j): INFLATION times the formal standard deviation. inf when too few walls agree to tell. With
    `moving_only` (j is the union of a placed group, which does not move), at the corners of grid i only. With
    `angle_bound` (radians: what another measure, orientation.py, bounds the angle to), the angle is that measure's
    and the shared walls' translation is the one they give at that angle."""
    found = covariance(pi, pj, model, tolerance)
    if found is None:
        return math.inf
    cov, centre = found
    cov = cov * INFLATION ** 2
    if angle_bound is not None:
        # the shift the walls allow once the angle is known (about their centre), and the other measure's angle
        shift = cov[:2, :2] - np.outer(cov[:2, 2], cov[2, :2]) / cov[2, 2]
        cov = np.zeros((3, 3))
        cov[:2, :2], cov[2, 2] = shift, angle_bound ** 2
    moved = tf.apply(model, corners_of(pi))
    corners = moved if moving_only else np.vstack([moved, corners_of(pj)])
    worst = 0.0
    for x, y in corners - centre:
        # displacement of a point under a small turn dtheta about the centre and a shift (dx, dy)
        g = np.array([[1.0, 0.0, -y], [0.0, 1.0, x]])
        worst = max(worst, float(np.trace(g @ cov @ g.T)))
    return math.sqrt(worst)


def corners_of(p: PreparedGrid) -> np.ndarray:
    """The four corners of a prepared grid's working image (pixels)."""
    h, w = p.work.shape
    return np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]])
