"""2-D homogeneous transforms (3x3 numpy matrices) used across the merging core.

A transform maps column vectors: p_out = M @ [x, y, 1]. ``rigid(x, y, yaw)`` is p -> R(yaw) p + (x, y).
"""
from __future__ import annotations

import math
from typing import List, Optional, Sequence, Tuple

import numpy as np


def rigid(x: float, y: float, yaw: float, scale: float = 1.0) -> np.ndarray:
    c, s = math.cos(yaw) * scale, math.sin(yaw) * scale
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def params(m: np.ndarray) -> Tuple[float, float, float, float]:
    """(x, y, yaw, scale) of a similarity matrix."""
    return float(m[0, 2]), float(m[1, 2]), math.atan2(m[1, 0], m[0, 0]), math.hypot(m[0, 0], m[1, 0])


def scaling(s: float) -> np.ndarray:
    return np.diag([s, s, 1.0])


def translation(x: float, y: float) -> np.ndarray:
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


def inverse(m: np.ndarray) -> np.ndarray:
    return np.linalg.inv(m)


def relative_to(transforms: Sequence[Optional[np.ndarray]], k: int) -> List[Optional[np.ndarray]]:
    """The transforms (each into one frame; None: none) restated into the frame of transforms[k], which becomes
    exactly the identity."""
    to_k = inverse(transforms[k])
    out = [to_k @ t if t is not None else None for t in transforms]
    out[k] = np.eye(3)
    return out


def apply(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 3x3 transform to an (N, 2) array of points."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    return pts @ m[:2, :2].T + m[:2, 2]


def wrap_angle(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares rigid transform (3x3) taking src points onto dst points (no reflection, no scale)."""
    return kabsch_xy(src[:, 0], src[:, 1], dst[:, 0], dst[:, 1])


def kabsch_xy(sx: np.ndarray, sy: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """kabsch() of points given as coordinate arrays (source x, y, destination x, y).

    In 2-D the best rotation has a closed form, the angle of the cross-covariance (what Kabsch's SVD gives, for a
    fraction of its cost: ICP calls this thousands of times per estimation); the covariance from the raw sums."""
    n = len(sx)
    msx, msy, mdx, mdy = sx.sum() / n, sy.sum() / n, dx.sum() / n, dy.sum() / n
    c00, c01 = sx @ dx - n * msx * mdx, sx @ dy - n * msx * mdy
    c10, c11 = sy @ dx - n * msy * mdx, sy @ dy - n * msy * mdy
    angle = math.atan2(c01 - c10, c00 + c11)
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, mdx - c * msx + s * msy], [s, c, mdy - s * msx - c * msy], [0.0, 0.0, 1.0]])


def difference(a: np.ndarray, b: np.ndarray, at: np.ndarray) -> Tuple[float, float]:
    """How far apart two similarity transforms are: (|rotation difference| in radians, largest displacement of
    points `at`). Without inverting b (the estimation compares placements thousands of times)."""
    rot = abs(math.atan2(a[1, 0] * b[0, 0] - a[0, 0] * b[1, 0], a[0, 0] * b[0, 0] + a[1, 0] * b[1, 0]))
    if not len(at):
        return rot, 0.0
    return rot, float(np.hypot(*apply(a - b, at).T).max())   # a's points less b's: (a - b) applied to them
