"""The pose error of a SLAM: what scan matching leaves of odometry drift, and the jump when a loop closes.

A robot's belief (its pose on TF, the pose its scans are fused at) is ``error ∘ truth``, both in the robot's map
frame (whose origin is the start pose, where the error is 0). Scan matching removes most of the odometry's drift;
what it leaves grows as a random walk with the distance driven: each step turns the belief's future path about
the believed position (a heading error, whose effect grows with the distance driven after it) and shifts it a
little. A robot back near a place it passed at least ``loop_closure_path`` metres of path ago closes a loop: its
scans match the map it drew there, so its belief jumps back to the error it had then. Maps are not redrawn after a
closure (as gmapping's), so the drift of the part drawn in between stays inside the map.
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
LOOP_RADIUS = 1.0         # m: back this close to a remembered place closes a loop


@dataclass
class LoopClosure:
    """A loop closed at path length ``path_m``: the believed pose jumped by ``jump_m`` and ``jump_deg``."""
    path_m: float
    jump_m: float
    jump_deg: float


class SlamDrift:
    def __init__(self, rng: np.random.Generator, yaw_deg_per_sqrt_m: float, xy_m_per_sqrt_m: float,
                 loop_closure_path: float) -> None:
        self.rng = rng
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
        self._next_kf = 0.0

    def believed(self, true_map: Sequence[float]) -> Pose:
        return compose(self.error, true_map)

    def to_true(self, believed_map: Sequence[float]) -> Pose:
        """The true map-frame pose of a believed one."""
        return compose(_inverse(self.error), believed_map)

    def moved(self, before: Sequence[float], after: Sequence[float]) -> None:
        """The robot moved from true map-frame pose ``before`` to ``after``: the error grows with the distance."""
        ds = math.hypot(after[0] - before[0], after[1] - before[1])
        if ds <= 0.0:
            return
        self.path_m += ds
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
        if self._kf_path.size:
            old = self._kf_path <= self.path_m - self.loop_closure_path
            if old.any():
                d = np.hypot(*(self._kf_xy[old] - xy).T)
                k = int(np.argmin(d))
                if d[k] <= LOOP_RADIUS:
                    self._close(true_map, self._kf_error[int(np.flatnonzero(old)[k])])
        if self.path_m >= self._next_kf:
            self._next_kf = self.path_m + KEYFRAME_SPACING
            self._kf_xy = np.vstack([self._kf_xy, xy])
            self._kf_path = np.append(self._kf_path, self.path_m)
            self._kf_error.append(self.error)

    def _close(self, true_map: Sequence[float], error: Pose) -> None:
        before = self.believed(true_map)
        self.error = error
        after = self.believed(true_map)
        jump_m = math.hypot(after[0] - before[0], after[1] - before[1])
        jump_deg = abs(math.degrees(math.remainder(after[2] - before[2], 2 * math.pi)))
        if jump_m >= 0.01 or jump_deg >= 0.1:   # the scans already fitting the old map close nothing new
            self.closures.append(LoopClosure(self.path_m, jump_m, jump_deg))
            _log.debug('loop closed after %.1f m: the pose jumped %.1f cm, %.2f deg', self.path_m, 100 * jump_m,
                       jump_deg)


def _inverse(p: Sequence[float]) -> Pose:
    c, s = math.cos(p[2]), math.sin(p[2])
    return (-c * p[0] - s * p[1], s * p[0] - c * p[1], -p[2])
