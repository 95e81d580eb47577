"""hypotheses.py: 2-point RANSAC counts each hypothesis's inliers a block of hypotheses at a time; the blocks must
give the model and inliers that counting all hypotheses at once gives."""
import numpy as np
import pytest

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation import hypotheses
from multirobot_map_merge.estimation.hypotheses import ransac_rigid, refit


def _all_at_once(p, q, threshold, iterations, rng):
    """RANSAC as one (hypotheses x matches) array: the reference the blocks must reproduce."""
    idx = rng.integers(0, len(p), (iterations, 2))
    idx = idx[idx[:, 0] != idx[:, 1]]
    dp, dq = p[idx[:, 1]] - p[idx[:, 0]], q[idx[:, 1]] - q[idx[:, 0]]
    lp, lq = np.hypot(*dp.T), np.hypot(*dq.T)
    keep = (lp > 5.0) & (np.abs(lp - lq) < 1.5 * threshold)
    idx, dp, dq = idx[keep], dp[keep], dq[keep]
    ang = np.arctan2(dq[:, 1], dq[:, 0]) - np.arctan2(dp[:, 1], dp[:, 0])
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    p0, q0 = p[idx[:, 0]], q[idx[:, 0]]
    tx = (q0[:, 0] - (c[:, 0] * p0[:, 0] - s[:, 0] * p0[:, 1]))[:, None]
    ty = (q0[:, 1] - (s[:, 0] * p0[:, 0] + c[:, 0] * p0[:, 1]))[:, None]
    ex = c * p[:, 0] - s * p[:, 1] + tx - q[:, 0]
    ey = s * p[:, 0] + c * p[:, 1] + ty - q[:, 1]
    inliers = ex * ex + ey * ey < threshold * threshold
    return refit(p, q, inliers[np.argmax(inliers.sum(axis=1))], threshold)


@pytest.mark.parametrize('block', [hypotheses.RANSAC_BLOCK, 997])
def test_ransac_in_blocks_finds_what_all_hypotheses_at_once_find(monkeypatch, block):
    """Seeded random matches, half of them consistent with a rigid motion; with a small block (many blocks, the last
    one short) and the default one, the same model and inliers as the reference, bit for bit."""
    monkeypatch.setattr(hypotheses, 'RANSAC_BLOCK', block)
    seed = 20261127
    rng = np.random.default_rng(seed)
    print('seed', seed)
    for n in (12, 80, 301, 1000):
        p = rng.random((n, 2)) * 300
        turn = rng.random() * 3
        q = tf.apply(tf.rigid(7.0, -4.0, turn), p) + rng.normal(0, 0.5, (n, 2))
        q[n // 2:] = rng.random((n - n // 2, 2)) * 300
        for draw in range(3):
            model, mask = ransac_rigid(p, q, 3.0, 2000, np.random.default_rng(draw))
            expected_model, expected_mask = _all_at_once(p, q, 3.0, 2000, np.random.default_rng(draw))
            assert np.array_equal(mask, expected_mask), (n, draw)
            assert np.array_equal(model, expected_model), (n, draw)
            assert mask.sum() >= n // 3   # the consistent half is found
