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
from .features import PreparedGrid, opposed_xy
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
    # ICP is the estimation's inner loop: coordinates as separate arrays and the placement written out (a 2x2
    # product of (N, 2) arrays costs several times these few products), flat `take`s instead of fancy indexing, and
    # a negative coordinate fails the bound as a huge unsigned one
    sx, sy = np.ascontiguousarray(src[:, 0]), np.ascontiguousarray(src[:, 1])
    ax, ay = np.ascontiguousarray(src_side[:, 0]), np.ascontiguousarray(src_side[:, 1])
    # shrinking correspondence radius: coarse capture first, then precise; each level runs until it settles
    for radius in s.icp_radii:
        for _ in range(s.icp_iterations):
            (a, b, tx), (c, d, ty) = model[0], model[1]
            mx, my = sx * a + sy * b + tx, sx * c + sy * d + ty
            x, y = np.rint(mx).astype(np.int64), np.rint(my).astype(np.int64)
            pick = np.flatnonzero((x.view(np.uint64) < w) & (y.view(np.uint64) < h))
            # the nearest wall of j (pj.nearest, inlined)
            wall = nearest.take(y.take(pick) * w + x.take(pick))
            nn = walls.take(wall, axis=0)
            gx, gy = nn[:, 0], nn[:, 1]
            px, py = mx.take(pick), my.take(pick)
            dx, dy = gx - px, gy - py
            close = np.flatnonzero(dx * dx + dy * dy < radius * radius)
            if s.facing and len(close):
                # a wall's two faces are not the same wall: pair only walls seen from the same side (i's side
                # turned by the placement)
                k, near = pick.take(close), normals.take(wall.take(close), axis=0)
                kx, ky = ax.take(k), ay.take(k)
                close = close[~opposed_xy(kx * a + ky * b, kx * c + ky * d, near[:, 0], near[:, 1])]
            if len(close) < 10:
                return model
            step = tf.kabsch_xy(px.take(close), py.take(close), gx.take(close), gy.take(close))
            model = step @ model
            if abs(step[1, 0]) < 5e-4 and max(abs(step[0, 2]), abs(step[1, 2])) < 0.1:
                break
        if any(same_place(model, t, pi) for t in reached):
            break
    return model
