"""Known initial poses -> transforms into the merged (world) frame.

Metric (default, as the package documentation says): init_pose_x/y in metres and init_pose_yaw in radians give
the pose of the robot's map frame in the world; each grid is then placed through its own origin and resolution.

Legacy (opt-in, the C++ 2.x behaviour, map_merge.md §8.3): x/y are cell counts, the pose is inverted and the grid
turns about its cell (0, 0) corner; origins are ignored and grids are overlaid cell for cell.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from . import transforms as tf
from .grid import Grid


@dataclass(frozen=True)
class InitPose:
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0


def metric_transform(pose: InitPose) -> np.ndarray:
    """Map frame of the robot -> world."""
    return tf.rigid(pose.x, pose.y, pose.yaw)


def legacy_transform(pose: InitPose, grid: Grid, output_resolution: float) -> np.ndarray:
    """The original's placement expressed as a metric transform map frame -> merged frame.

    The original maps grid cell indices to canvas cell indices by the inverse of [[c, -s, x], [s, c, y]]; the
    merged frame here is canvas cells times the output resolution.
    """
    cells_to_canvas = tf.inverse(tf.rigid(pose.x, pose.y, pose.yaw))
    # corner coordinates = index coordinates + 0.5
    corner = tf.translation(0.5, 0.5) @ cells_to_canvas @ tf.translation(-0.5, -0.5)
    return tf.scaling(output_resolution) @ corner @ tf.inverse(grid.cell_to_map())


def transforms_from_poses(grids: Sequence[Optional[Grid]], poses: Sequence[Optional[InitPose]],
                          legacy: bool = False) -> list:
    """One transform per grid (None where the grid or its pose is missing)."""
    out: list = []
    if legacy:
        # the original takes the resolution of the first grid placed at exactly the identity
        ref = next((g for g, p in zip(grids, poses) if g is not None and p == InitPose()), None)
        ref = ref or next((g for g in grids if g is not None), None)
        res = ref.resolution if ref is not None else 1.0
    for g, p in zip(grids, poses):
        if g is None or p is None:
            out.append(None)
        elif legacy:
            out.append(legacy_transform(p, g, res))
        else:
            out.append(metric_transform(p))
    return out
