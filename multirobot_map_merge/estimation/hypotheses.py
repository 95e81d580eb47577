"""Candidate screen: rigid placements proposed by descriptor matches, and a cheap screen before refinement.

Putative descriptor matches (ratio test, both directions, their union as the original) give several rigid RANSAC
hypotheses (the metadata fixes the scale, so the model is rigid), each found after removing the inliers of the
previous ones. A hypothesis is refined only if enough sampled walls of one map land near walls of the other.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, List, Optional, Tuple

import cv2
import numpy as np

from .. import transforms as tf
from .features import PreparedGrid
from .neighbours import NeighbourCache, parts_of, two_nearest
from .validation import must_be_positive

if TYPE_CHECKING:
    from .settings import EstimationSettings


RANSAC_BLOCK = 65536   # hypotheses x matches computed at once by ransac_rigid


@dataclass
class HypothesisSettings:
    ratio: float = 0.8                # descriptor ratio test
    ransac_threshold: float = 3.0     # pixels
    ransac_iterations: int = 2000
    max_hypotheses: int = 5           # rigid models tried per pair
    min_inliers: int = 4              # RANSAC inliers a model needs
    screen_points: int = 600          # wall pixels sampled to screen a hypothesis before refining it
    screen_tolerance: float = 4.0     # pixels
    screen_min_agreement: float = 0.5

    def validate(self) -> None:
        must_be_positive(self, 'ratio', 'ransac_threshold', 'ransac_iterations', 'max_hypotheses')


def putative_matches(pi: PreparedGrid, pj: PreparedGrid, ratio: float, both_ways: bool = True,
                     neighbours: Optional[NeighbourCache] = None) -> np.ndarray:
    """(K, 2) index pairs (keypoint of i, keypoint of j) passing the ratio test in either direction (or only from
    i to j: j is a union, most of whose keypoints are nowhere in i), sorted. With `neighbours`, binary descriptors'
    nearest are found from those kept there (neighbours.py: the same pairs)."""
    pi.describe(), pj.describe()
    if pi.descriptors is None or pj.descriptors is None or len(pi.descriptors) < 2 or len(pj.descriptors) < 2:
        return np.zeros((0, 2), np.int64)
    def nearest(a: PreparedGrid, b: PreparedGrid):
        if neighbours is None or a.descriptors.dtype != np.uint8:
            return _two_nearest(a.descriptors, b.descriptors)
        return two_nearest(a.descriptors, parts_of(a.descriptors, a.descriptor_parts),
                           b.descriptors, parts_of(b.descriptors, b.descriptor_parts), neighbours)

    found = [_ratio_tested(*nearest(pi, pj), ratio)]
    if both_ways:
        found.append(_ratio_tested(*nearest(pj, pi), ratio)[:, ::-1])
    # each pair once, in the order of (i, j)
    keys = np.unique(np.concatenate([f[:, 0] * len(pj.descriptors) + f[:, 1] for f in found]))
    return np.stack(np.divmod(keys, len(pj.descriptors)), axis=1)


def _two_nearest(query: np.ndarray, train: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """(distances (N, 2), nearest index (N,)): cv2.batchDistance is what a BFMatcher's knnMatch runs, with arrays
    out instead of a Python object per match."""
    norm = cv2.NORM_HAMMING if query.dtype == np.uint8 else cv2.NORM_L2
    distance, nearest = cv2.batchDistance(query, train, cv2.CV_32S if norm == cv2.NORM_HAMMING else cv2.CV_32F,
                                          normType=norm, K=2)
    return distance.astype(np.float32), nearest[:, 0]   # distances as a DMatch holds them


def _ratio_tested(distance: np.ndarray, nearest: np.ndarray, ratio: float) -> np.ndarray:
    """(K, 2) pairs (query index, its nearest train index) whose nearest is clearly nearer than the second nearest."""
    keep = np.flatnonzero(distance[:, 0] < ratio * distance[:, 1].astype(np.float64))
    return np.stack([keep, nearest[keep].astype(np.int64)], axis=1)


def ransac_rigid(p: np.ndarray, q: np.ndarray, threshold: float, iterations: int,
                 rng: np.random.Generator) -> Tuple[Optional[np.ndarray], np.ndarray]:
    """Best rigid transform p -> q by 2-point RANSAC (vectorised over all hypotheses), refit on its inliers."""
    n = len(p)
    if n < 3:
        return None, np.zeros(n, bool)
    idx = rng.integers(0, n, (iterations, 2))
    idx = idx[idx[:, 0] != idx[:, 1]]
    dp = p[idx[:, 1]] - p[idx[:, 0]]
    dq = q[idx[:, 1]] - q[idx[:, 0]]
    lp, lq = np.hypot(*dp.T), np.hypot(*dq.T)
    # a rigid motion keeps distances: drop samples that cannot be one (and too short ones: bad angle)
    keep = (lp > 5.0) & (np.abs(lp - lq) < 1.5 * threshold)
    idx, dp, dq = idx[keep], dp[keep], dq[keep]
    if len(idx) == 0:
        return None, np.zeros(n, bool)
    ang = np.arctan2(dq[:, 1], dq[:, 0]) - np.arctan2(dp[:, 1], dp[:, 0])
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    p0, q0 = p[idx[:, 0]], q[idx[:, 0]]
    tx = (q0[:, 0] - (c[:, 0] * p0[:, 0] - s[:, 0] * p0[:, 1]))[:, None]
    ty = (q0[:, 1] - (s[:, 0] * p0[:, 0] + c[:, 0] * p0[:, 1]))[:, None]
    # each hypothesis's inliers counted a block of hypotheses at a time, in place: the (hypotheses x matches)
    # arrays stay in the cache (2.4-3.4 times as fast from 300 matches up, the same counts)
    px, py, qx, qy = p[:, 0], p[:, 1], q[:, 0], q[:, 1]
    limit = threshold * threshold

    def squared_errors(a: int, b: int) -> np.ndarray:
        # hypotheses a..b x matches: how far each hypothesis puts each match's p from its q, squared
        ex = c[a:b] * px
        ex -= s[a:b] * py
        ex += tx[a:b]
        ex -= qx
        ey = s[a:b] * px
        ey += c[a:b] * py
        ey += ty[a:b]
        ey -= qy
        ex *= ex
        ey *= ey
        ex += ey
        return ex

    counts = np.empty(len(idx), np.int64)
    block = max(1, RANSAC_BLOCK // n)
    for a in range(0, len(idx), block):
        counts[a:a + block] = np.count_nonzero(squared_errors(a, a + block) < limit, axis=1)
    k = int(np.argmax(counts))
    return refit(p, q, squared_errors(k, k + 1)[0] < limit, threshold)


def refit(p: np.ndarray, q: np.ndarray, mask: np.ndarray, threshold: float) -> Tuple[Optional[np.ndarray], np.ndarray]:
    """The rigid transform p -> q fitted on the matches of `mask`, and its inliers, three times over (None while
    fewer than 3)."""
    model = None
    for _ in range(3):
        if mask.sum() < 3:
            break
        model = tf.kabsch(p[mask], q[mask])
        mask = np.hypot(*(tf.apply(model, p) - q).T) < threshold
    return model, mask


def hypotheses(p: np.ndarray, q: np.ndarray, s: EstimationSettings, rng: np.random.Generator) -> List[np.ndarray]:
    """Up to s.max_hypotheses rigid models, each found after removing the inliers of the previous ones."""
    found = []
    remaining = np.arange(len(p))
    while len(found) < s.max_hypotheses and len(remaining) >= s.min_inliers:
        model, mask = ransac_rigid(p[remaining], q[remaining], s.ransac_threshold, s.ransac_iterations, rng)
        if model is None or mask.sum() < s.min_inliers:
            break
        found.append(model)
        remaining = remaining[~mask]
    return found


def quick_agreement(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray, s: EstimationSettings,
                    rng: np.random.Generator) -> float:
    """Share of sampled walls of i that land near a wall of j, among those landing on j's known area.

    A cheap screen before ICP: hypotheses from unrelated maps score near zero, rough but right ones well above. When
    too few of the sampled walls land on j's known area to tell, the walls are sampled again among those that do: a
    union's walls on a small common area are few (one union onto another with 14 m2 in common: the screen dropped
    the one candidate near the truth, and two clusters of a generated building never merged)."""
    src = pi.walls
    if len(src) > s.screen_points:
        src = src[rng.choice(len(src), s.screen_points, replace=False)]
    x, y = _landing_on_known(src, pj, model)
    if len(x) < 20 and len(pi.walls) > s.screen_points:
        x, y = _landing_on_known(pi.walls, pj, model)
        if len(x) > s.screen_points:
            pick = rng.choice(len(x), s.screen_points, replace=False)
            x, y = x[pick], y[pick]
    if len(x) < 20:
        return 0.0
    return float((pj.wall_distance[y, x] <= s.screen_tolerance).mean())


def _landing_on_known(walls: np.ndarray, pj: PreparedGrid, model: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Pixels (x, y) of j where those of `walls` (pixels of i) that `model` places on j's known area land."""
    moved = np.rint(tf.apply(model, walls)).astype(np.int64)
    h, w = pj.work.shape
    inside = (moved[:, 0] >= 0) & (moved[:, 1] >= 0) & (moved[:, 0] < w) & (moved[:, 1] < h)
    x, y = moved[inside, 0], moved[inside, 1]
    on_known = pj.work[y, x] >= 0
    return x[on_known], y[on_known]
