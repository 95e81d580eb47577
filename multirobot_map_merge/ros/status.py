"""The node's ~status message (multirobot_map_merge/MergeStatus): built after an estimation, completed and sent by
the merge cycle that publishes its placement, so that the transforms match the merged map sent with it."""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..grid import Grid
from ..msg import MergeStatus, PairMatchStatus, RobotMergeStatus
from .conversions import transform_msg, yaw_from_quaternion
from .discovery import append


def frame_of(robot: str, grid: Optional[Grid]) -> str:
    """A robot map's tf frame: its header.frame_id, or <robot_ns>/map when empty; no leading '/' (tf2)."""
    frame = grid.frame_id if grid is not None and grid.frame_id else append(robot, 'map')
    return frame.lstrip('/')


def status_of(names: Sequence[str], grids: Sequence[Optional[Grid]], result,
              world_frame: str) -> Tuple[MergeStatus, List[Optional[np.ndarray]]]:
    """A fresh MergeStatus of an estimation result (robot transforms still to fill in) and the estimated transform
    of each entry."""
    status = MergeStatus()   # fresh message each time (latched)
    status.header.frame_id = world_frame
    status.estimation_time = float(result.seconds)
    for name, grid, t in zip(names, grids, result.transforms):
        status.robots.append(RobotMergeStatus(robot_namespace=name, map_frame=frame_of(name, grid),
                                              included=t is not None))
    for p in result.pairs:
        used = bool(p.accepted) and result.transforms[p.i] is not None and result.transforms[p.j] is not None
        status.pairs.append(PairMatchStatus(robot_a=names[p.i], robot_b=names[p.j], matches=int(p.matches),
                                            inliers=int(p.inliers), confidence=float(p.confidence), used=used))
    return status, list(result.transforms)


def fill_transforms(status: MergeStatus, transforms: Sequence[Optional[np.ndarray]], world_from_merged: np.ndarray,
                    stamp) -> None:
    """Each included robot's transform map frame -> world_frame as placed by this merge cycle."""
    status.header.stamp = stamp
    for entry, t in zip(status.robots, transforms):
        if t is not None:
            entry.transform = transform_msg(world_from_merged @ t)
        else:
            entry.transform.rotation.w = 1.0   # identity, not an all-zero quaternion


def included_poses(status: Optional[MergeStatus]) -> Dict[str, Tuple[float, float, float]]:
    """Robot namespace (without slashes) -> (x, y, yaw) of its map frame in world_frame, for the robots a ~status
    includes (read back by the demo's supervisor and scripts/status_errors.py)."""
    out = {}
    for r in (status.robots if status is not None else []):
        if r.included:
            q = r.transform.rotation
            out[r.robot_namespace.strip('/')] = (r.transform.translation.x, r.transform.translation.y,
                                                 yaw_from_quaternion(q.x, q.y, q.z, q.w))
    return out
