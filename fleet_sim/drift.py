"""The pose error of a SLAM: what scan matching leaves of odometry drift, and the jump when a loop closes.

A robot's belief (its pose on TF, the pose its scans are fused at) is ``error ∘ truth``, both in the robot's map
frame (whose origin is the start pose, where the error is 0). Scan matching removes most of the odometry's drift;
what it leaves grows as a random walk with the distance driven in new territory: each step turns the belief's
future path about the believed position (a heading error, whose effect grows with the distance driven after it)
and shifts it a little. Where the robot has been before, its scans match the map it drew there, so the error does
not grow: back within LOOP_RADIUS of a place it passed less than ``loop_closure_path`` metres of path ago (but more
than RECENT_PATH), the error stays as it is; back at a place passed longer ago, a loop closes: the belief jumps to
the error the robot had there (and keeps to the errors of that old pass while it follows it). Maps are not redrawn
after a closure (as gmapping's), so the drift of the part drawn in between stays inside the map.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import List, Sequence, Tuple

import numpy as np

from .mapping import compose

_log = logging.getLogger('rosout.fleet_sim.drift')

Pose = Tuple[float, float, float]
KEYFRAME_SPACING = 0.5    # m of path between two remembered places
LOOP_RADIUS = 1.0         # m: back this close to a remembered place, the scans match the map drawn there
RECENT_PATH = 2.0         # m of path: the places passed within it are the robot's current trail, not a return


@dataclass
class LoopClosure:
    """A loop closed at path length ``path_m``: the believed pose jumped by ``jump_m`` and ``jump_deg``."""
    path_m: float
    jump_m: float
    jump_deg: float


class SlamDrift:
    def __init__(self, rng: np.random.Generator, yaw_deg_per_sqrt_m: float, xy_m_per_sqrt_m: float,
                 loop_closure_path: float, label: str = 'robot') -> None:
        """label: the robot's name in the log."""
        self.rng, self.label = rng, label
        self.yaw_sd = math.radians(yaw_deg_per_sqrt_m)
        self.xy_sd = xy_m_per_sqrt_m
        self.loop_closure_path = loop_closure_path
        self.error: Pose = (0.0, 0.0, 0.0)
        self.path_m = 0.0
        self.closures: List[LoopClosure] = []
        # remembered places: true map-frame position, path length and error there
        self._kf_xy = np.zeros((0, 2))
        self._kf_path = np.zeros(0)
        self._kf_error: List[Pose] = []
        self._new_territory = True    # the error grows only there
        self._on_old_pass = False     # following a pass older than loop_closure_path (a loop has closed)

    def believed(self, true_map: Sequence[float]) -> Pose:
        return compose(self.error, true_map)

    def to_true(self, believed_map: Sequence[float]) -> Pose:
        """The true map-frame pose of a believed one."""
        return compose(_inverse(self.error), believed_map)

    def moved(self, before: Sequence[float], after: Sequence[float]) -> None:
        """The robot moved from true map-frame pose ``before`` to ``after``: the error grows with the distance."""
        ds = math.hypot(after[0] - before[0], after[1] - before[1])
        self.path_m += ds
        if ds <= 0.0 or not self._new_territory:
            return
        dyaw = self.yaw_sd * math.sqrt(ds) * float(self.rng.standard_normal())
        dx, dy = self.xy_sd * math.sqrt(ds) * self.rng.standard_normal(2)
        bx, by, _ = self.believed(after)
        c, s = math.cos(dyaw), math.sin(dyaw)
        # a turn by dyaw about the believed position (the belief does not jump), then the shift
        turn = (bx - (c * bx - s * by) + float(dx), by - (s * bx + c * by) + float(dy), dyaw)
        self.error = compose(turn, self.error)

    def scanned(self, true_map: Sequence[float]) -> None:
        """A scan at ``true_map``: remember the place, or close a loop at a place passed long enough ago."""
        xy = np.array(true_map[:2], float)
        d = np.hypot(*(self._kf_xy - xy).T) if self._kf_path.size else np.zeros(0)
        near = d <= LOOP_RADIUS
        old = near & (self._kf_path <= self.path_m - self.loop_closure_path)
        if old.any():
            k = int(np.flatnonzero(old)[np.argmin(d[old])])
            self._jump_to(true_map, self._kf_error[k], closing=not self._on_old_pass)
        self._on_old_pass = bool(old.any())
        self._new_territory = not (near & (self._kf_path <= self.path_m - RECENT_PATH)).any()
        if not (d < KEYFRAME_SPACING).any():
            self._kf_xy = np.vstack([self._kf_xy, xy])
            self._kf_path = np.append(self._kf_path, self.path_m)
            self._kf_error.append(self.error)

    def _jump_to(self, true_map: Sequence[float], error: Pose, closing: bool) -> None:
        before = self.believed(true_map)
        self.error = error
        if not closing:
            return          # following the old pass: its neighbouring places' errors differ little
        after = self.believed(true_map)
        jump_m = math.hypot(after[0] - before[0], after[1] - before[1])
        jump_deg = abs(math.degrees(math.remainder(after[2] - before[2], 2 * math.pi)))
        self.closures.append(LoopClosure(self.path_m, jump_m, jump_deg))
        _log.info('%s: loop closed after %.1f m of path: the pose jumped %.1f cm, %.2f deg', self.label, self.path_m,
                  100 * jump_m, jump_deg)


def _inverse(p: Sequence[float]) -> Pose:
    c, s = math.cos(p[2]), math.sin(p[2])
    return (-c * p[0] - s * p[1], s * p[0] - c * p[1], -p[2])
