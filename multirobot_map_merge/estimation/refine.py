"""Refinement: ICP of one map's walls onto the other's nearest walls, from a candidate placement.

Point-to-point, with a shrinking correspondence radius (coarse capture first, then precise). Walls seen from
opposite sides are a wall's two faces, not the same wall, and do not pair (`facing`). ICP can settle in a nearby
minimum, so plausible placements are polished afterwards (polish.py).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from .. import transforms as tf
from .features import PreparedGrid, opposed
from .validation import must_be_positive
from .verify import same_place

if TYPE_CHECKING:
    from .settings import EstimationSettings


@dataclass
class RefineSettings:
    icp_radii: tuple = (6.0, 4.0, 3.0, 2.0)  # pixels: correspondence radius of each ICP level
    icp_iterations: int = 6           # at most, per level
    icp_max_points: int = 2000
    facing: bool = True               # walls seen from opposite sides neither support a placement nor pair in ICP
    polish: bool = True               # polish every plausible placement after ICP (polish.py); False: ICP's stands

    def validate(self) -> None:
        must_be_positive(self, 'icp_iterations', 'icp_max_points')


def icp(pi: PreparedGrid, pj: PreparedGrid, start: np.ndarray, s: EstimationSettings,
        rng: np.random.Generator, reached: Sequence[np.ndarray] = ()) -> np.ndarray:
    """Refine a pixel transform i -> j by point-to-point ICP of i's walls onto j's nearest walls; stop after a
    level that ends at the same place as one of the placements `reached` (ICP from there ends where they did)."""
    src, src_side = pi.walls, pi.wall_normals
    if len(src) > s.icp_max_points:
        pick = rng.choice(len(src), s.icp_max_points, replace=False)
        src, src_side = src[pick], src_side[pick]
    model = start.copy()
    if len(src) < 10 or len(pj.walls) < 10:
        return model
    h, w = pj.work.shape
    nearest, walls, normals = pj.nearest_wall.reshape(-1), pj.walls, pj.wall_normals
    # shrinking correspondence radius: coarse capture first, then precise; each level runs until it settles
    # (flat `take`s instead of fancy indexing, and a negative coordinate fails the bound as a huge unsigned one:
    # ICP is the estimation's inner loop, and this halves it)
    for radius in s.icp_radii:
        for _ in range(s.icp_iterations):
            moved = tf.apply(model, src)
            xy = np.rint(moved).astype(np.int64)
            x, y = xy[:, 0], xy[:, 1]
            pick = np.flatnonzero((x.view(np.uint64) < w) & (y.view(np.uint64) < h))
            # the nearest wall of j (pj.nearest, inlined)
            wall = nearest.take(y.take(pick) * w + x.take(pick))
            nn = walls.take(wall, axis=0)
            gap = nn - moved.take(pick, axis=0)
            dx, dy = gap[:, 0], gap[:, 1]
            close = np.flatnonzero(dx * dx + dy * dy < radius * radius)
            if s.facing and len(close):
                # a wall's two faces are not the same wall: pair only walls seen from the same side
                turned = src_side.take(pick.take(close), axis=0) @ model[:2, :2].T
                close = close[~opposed(turned, normals.take(wall.take(close), axis=0))]
            if len(close) < 10:
                return model
            step = tf.kabsch(moved.take(pick.take(close), axis=0), nn.take(close, axis=0))
            model = step @ model
            if abs(step[1, 0]) < 5e-4 and np.abs(step[:2, 2]).max() < 0.1:
                break
        if any(same_place(model, t, pi) for t in reached):
            break
    return model
