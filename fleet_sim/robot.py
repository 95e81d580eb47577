"""One simulated robot: true pose in the world, laser + log-odds map in its own map frame, and a move_base stand-in
(plan on the own map, drive, re-plan, succeed / abort). Pure Python, driven by fleet_sim.sim in fixed sim steps.

The map frame's origin is the robot's start pose (as a SLAM package's map frame). Without drift the map-frame pose
is the true pose seen from the start pose, so maps are exact up to the laser noise; with drift (fleet_sim.drift)
the map-frame pose, on TF and where scans are fused, is the SLAM's belief, and the robot drives by it.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np

from .drift import SlamDrift
from .laser import add_noise, beam_angles, cast, glass_no_return
from .mapping import LogOddsMap, compose, relative_pose
from .motion import Clearance, FollowerConfig, PathFollower, path_blocked_index, step_with_collision
from .planner import PlannerConfig, PlanResult, plan_path

_log = logging.getLogger('rosout.fleet_sim.robot')

Pose = Tuple[float, float, float]

ACTIVE, SUCCEEDED, ABORTED, IDLE = 'active', 'succeeded', 'aborted', 'idle'
MAX_STUCK_REPLANS = 3
PROGRESS_DISTANCE = 0.1        # m the robot must move within stuck_timeout to count as making progress


@dataclass
class RobotConfig:
    n_beams: int = 360
    max_range: float = 5.0
    range_noise: float = 0.01
    resolution: float = 0.05
    robot_radius: float = 0.2
    goal_tolerance: float = 0.25
    stuck_timeout: float = 5.0
    linear_speed: float = 0.5
    angular_speed: float = 1.5
    fov_deg: float = 360.0
    range_noise_per_m: float = 0.0
    clear_no_return: bool = True


@dataclass
class Outcome:
    """A goal ended: status SUCCEEDED or ABORTED, with the reason of an abort."""
    status: str
    text: str = ''


class SimRobot:
    def __init__(self, ns: str, start: Sequence[float], world_occ: np.ndarray, world_res: float,
                 world_origin: Sequence[float], clearance: Clearance, cfg: RobotConfig,
                 rng: np.random.Generator, drift: Optional[SlamDrift] = None,
                 glass: Optional[np.ndarray] = None) -> None:
        """drift: the SLAM's pose error (None: exact poses); glass: world cells of glass (None: no glass)."""
        self.ns = ns
        self.start: Pose = (float(start[0]), float(start[1]), float(start[2]))
        self.pose: Pose = self.start                     # true pose in the world frame
        self.cfg = cfg
        self._occ, self._world_res = world_occ, world_res
        self._world_origin = (float(world_origin[0]), float(world_origin[1]))
        self._clear = clearance
        self._rng = rng
        self.mapper = LogOddsMap(cfg.resolution, line_sampling=True)
        self.drift, self._glass = drift, glass
        self.angles = beam_angles(cfg.n_beams)
        if cfg.fov_deg < 360.0:
            self.angles = self.angles[np.abs(self.angles) <= math.radians(cfg.fov_deg) / 2.0 + 1e-9]
        self.ranges: Optional[np.ndarray] = None        # last scan
        self._scan_pose: Optional[Pose] = None
        self.planner_cfg = PlannerConfig(robot_radius=cfg.robot_radius, goal_tolerance=cfg.goal_tolerance)
        self.follower_cfg = FollowerConfig(linear_speed=cfg.linear_speed, angular_speed=cfg.angular_speed)
        # navigation state (owned by the simulation thread)
        self.state = IDLE
        self.goal: Optional[Tuple[float, float]] = None   # map frame
        self.follower: Optional[PathFollower] = None
        self.n_plans = 0
        self._progress_pos = (0.0, 0.0)
        self._progress_t = 0.0
        self._stuck_replans = 0
        self._replan_reason = ''

    # ------------------------------------------------------------------ frames
    @property
    def true_pose_map(self) -> Pose:
        """True pose in the robot's own map frame."""
        return relative_pose(self.start, self.pose)

    @property
    def pose_map(self) -> Pose:
        """Believed pose in the robot's own map frame (what TF map -> base_link carries; without drift the true
        one)."""
        if self.drift is None:
            return relative_pose(self.start, self.pose)
        return self.drift.believed(relative_pose(self.start, self.pose))

    def to_world(self, p: Sequence[float]) -> Pose:
        """World pose of a point of the map frame (where the robot believes it is)."""
        p = (p[0], p[1], p[2] if len(p) > 2 else 0.0)
        return compose(self.start, p if self.drift is None else self.drift.to_true(p))

    def set_world(self, world_occ: np.ndarray, clearance: Clearance) -> None:
        """What blocks beams and robots now (doors shut, people walking)."""
        self._occ, self._clear = world_occ, clearance

    # ------------------------------------------------------------------ sensing
    def scan(self, force: bool = False) -> bool:
        """Cast the laser and fuse it into the map; skipped while the robot stands still (as a SLAM package only
        updates after motion) unless ``force``. Returns True if a new scan was taken."""
        if not force and self._scan_pose is not None and _same_pose(self._scan_pose, self.pose):
            return False
        cfg = self.cfg
        origin = self._world_origin
        ranges = cast(self._occ, self._world_res, self.pose, cfg.n_beams, cfg.max_range, angles=self.angles,
                      origin=origin)
        if self._glass is not None:
            glass_no_return(ranges, self.angles, self.pose, self._glass, self._world_res, origin)
        self.ranges = add_noise(ranges, self._rng, cfg.range_noise, sigma_per_m=cfg.range_noise_per_m)
        if self.drift is not None:     # scan matching first: a loop may close here
            self.drift.scanned(self.true_pose_map)
        self.mapper.integrate(self.pose_map, self.ranges, self.angles, cfg.max_range,
                              clear_no_return=cfg.clear_no_return)
        self._scan_pose = self.pose
        if self.state == ACTIVE and self.follower is not None:
            self._check_path()
        return True

    def _check_path(self) -> None:
        """Re-plan at the next step when the remaining path now meets a wall the robot has discovered."""
        m = self.mapper
        i = path_blocked_index(m.occupied_cells, m.resolution, m.origin, self.follower.remaining(),
                               self.cfg.robot_radius)
        if i is not None:
            self._replan_reason = 'path blocked by a discovered wall'

    # ------------------------------------------------------------------ navigation
    def _plan(self) -> PlanResult:
        self.n_plans += 1
        x, y, _ = self.pose_map
        return plan_path(self.mapper.values(), self.mapper.resolution, self.mapper.origin, (x, y), self.goal,
                         self.planner_cfg)

    def set_goal(self, x: float, y: float, t: float) -> Optional[Outcome]:
        """Start driving to map-frame (x, y). Returns an Outcome at once when the goal ends immediately."""
        self.cancel()
        if not (math.isfinite(x) and math.isfinite(y)):
            return Outcome(ABORTED, 'the goal is not finite')
        self.goal = (float(x), float(y))
        self._stuck_replans = 0
        self._replan_reason = ''
        self._mark_progress(t)
        if self._at_goal():
            self.state = IDLE
            return Outcome(SUCCEEDED, 'already at the goal')
        result = self._plan()
        if result.path is None:
            self.state = IDLE
            return Outcome(ABORTED, f'no plan: {result.reason}')
        self.follower = PathFollower(result.path, self.follower_cfg)
        self.state = ACTIVE
        return None

    def cancel(self) -> None:
        self.state = IDLE
        self.follower = None

    def _at_goal(self) -> bool:
        x, y, _ = self.pose_map
        return math.hypot(x - self.goal[0], y - self.goal[1]) <= self.cfg.goal_tolerance

    def _mark_progress(self, t: float) -> None:
        self._progress_pos = self.pose[:2]
        self._progress_t = t

    def step(self, dt: float, t: float) -> Optional[Outcome]:
        """Advance by dt (t: sim time after the step). Returns an Outcome when the active goal ends."""
        if self.state != ACTIVE:
            return None
        if self._at_goal():
            return self._finish(SUCCEEDED, '')
        if math.hypot(self.pose[0] - self._progress_pos[0], self.pose[1] - self._progress_pos[1]) \
                >= PROGRESS_DISTANCE:
            self._mark_progress(t)
            self._stuck_replans = 0
        elif t - self._progress_t > self.cfg.stuck_timeout:
            self._stuck_replans += 1
            if self._stuck_replans > MAX_STUCK_REPLANS:
                return self._finish(ABORTED, 'the robot is stuck')
            self._mark_progress(t)
            self._replan_reason = 'no progress'
        if self._replan_reason:
            _log.debug('%s: re-planning (%s)', self.ns, self._replan_reason)
            self._replan_reason = ''
            result = self._plan()
            if result.path is None:
                return self._finish(ABORTED, f'no plan: {result.reason}')
            self.follower = PathFollower(result.path, self.follower_cfg)
        f = self.follower
        pm = self.pose_map
        if math.hypot(f.end[0] - pm[0], f.end[1] - pm[1]) < 0.02:
            # at the end of a path that stops short of the goal (a goal next to a wall)
            if math.hypot(pm[0] - self.goal[0], pm[1] - self.goal[1]) <= self.cfg.goal_tolerance + 0.05:
                return self._finish(SUCCEEDED, '')
            self._replan_reason = 'end of path short of the goal'
            return None
        v, w = f.command(pm, dt, self._line_free)
        new, _blocked = step_with_collision(self.pose, v, w, dt, self._clear, self.cfg.robot_radius)
        if self.drift is not None:
            self.drift.moved(relative_pose(self.start, self.pose), relative_pose(self.start, new))
        self.pose = new
        return None

    def _line_free(self, a: Sequence[float], b: Sequence[float]) -> bool:
        wa, wb = self.to_world(a), self.to_world(b)
        return self._clear.segment_free(wa, wb, self.cfg.robot_radius)

    def _finish(self, status: str, text: str) -> Outcome:
        self.state = IDLE
        self.follower = None
        return Outcome(status, text)


def _same_pose(a: Sequence[float], b: Sequence[float]) -> bool:
    return abs(a[0] - b[0]) < 1e-4 and abs(a[1] - b[1]) < 1e-4 and abs(math.remainder(a[2] - b[2], 2 * math.pi)) < 1e-4
