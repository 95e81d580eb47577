"""The simulation loop without ROS: a world, N robots, fixed motion steps and the schedule of scans and
publications in sim time. fleet_sim.node wraps it; bench/bench_fleet_sim.py runs it bare.

Determinism: start poses and every robot's laser noise come from ``seed``; given the same goals at the same sim
times, two runs give the same poses and maps.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import numpy as np

from multirobot_map_merge.admission import clean_cells
from multirobot_map_merge.grid import Grid
from multirobot_map_merge.mapio import MapFileError

from .drift import SlamDrift
from .motion import Clearance
from .params import FleetSimParams, ParamError, RobotSpec
from .robot import Outcome, RobotConfig, SimRobot
from .scenery import Doors, People, glass_mask
from .world import load_world, make_floor_plan, obstacle_mask

_log = logging.getLogger('rosout.fleet_sim.sim')


def build_world(params: FleetSimParams) -> Grid:
    """The world grid (frame 'world'); ParamError with a clear message for a missing or bad file."""
    if params.world:
        try:
            world = load_world(params.world)
        except (MapFileError, OSError, ValueError) as e:
            raise ParamError(f"~world: cannot load {params.world!r}: {e}") from None
        if abs(world.origin[2]) > 1e-9:
            raise ParamError(f"~world: {params.world!r} has a rotated origin, which is not supported")
        data, invalid = clean_cells(world.data)
        if invalid:   # the package's one rule (admission.py): read as unknown, which blocks robots and beams
            _log.warning("~world: %s: %d cell(s) with values outside -1 and 0..100 read as unknown", params.world,
                         invalid)
            world = Grid(data, world.resolution, world.origin, world.frame_id, world.stamp, dict(world.extra))
        return world
    try:
        return make_floor_plan(params.world_seed, params.world_width, params.world_height)
    except ValueError as e:
        raise ParamError(f"~world_width/~world_height: {e}") from None


@dataclass
class Due:
    """What the node must publish after a step."""
    scan: bool = False                                   # a laser period: every robot has a current scan
    scanned: List[int] = field(default_factory=list)    # robots with a new scan (the others stood still)
    update: bool = False
    map: bool = False
    tf: bool = False


class _Every:
    """A sim-time schedule of period 1/rate, first due at the first step."""

    def __init__(self, rate: float) -> None:
        self.period = 1.0 / rate
        self.next = 0.0

    def due(self, t: float) -> bool:
        if t + 1e-9 < self.next:
            return False
        # skip missed periods instead of bursting (only happens when a period is shorter than the step)
        self.next += self.period * max(1, math.floor((t - self.next) / self.period) + 1)
        return True


class FleetSim:
    def __init__(self, params: FleetSimParams, world: Optional[Grid] = None) -> None:
        params.validate()
        self.params = params
        self.world = world if world is not None else build_world(params)
        self.clearance = Clearance(self.world)
        occ = obstacle_mask(self.world)
        rng = np.random.default_rng(params.seed)
        if params.robots:
            specs = params.robot_specs(None)
        else:
            try:
                poses = self.clearance.random_free_poses(rng, params.num_robots, params.robot_radius)
            except ValueError as e:
                raise ParamError(str(e)) from None
            specs = params.robot_specs(poses)
        for s in specs:
            if not self.clearance.free(s.x, s.y, params.robot_radius):
                raise ParamError(f"robot {s.ns}: start pose ({s.x:.3f}, {s.y:.3f}) is inside a wall or outside "
                                 f"the world (a robot of radius {params.robot_radius} m does not fit there)")
        cfg = RobotConfig(n_beams=params.n_beams, max_range=params.max_range, range_noise=params.range_noise,
                          resolution=params.resolution, robot_radius=params.robot_radius,
                          goal_tolerance=params.goal_tolerance, stuck_timeout=params.stuck_timeout,
                          linear_speed=params.linear_speed, angular_speed=params.angular_speed,
                          fov_deg=params.fov, range_noise_per_m=params.range_noise_per_m,
                          clear_no_return=params.clear_no_return)
        # the realistic scenery, each from a random stream of its own (the default runs draw nothing new)
        self.occ = occ
        self.glass = glass_mask(self.world, occ, np.random.default_rng([params.seed, 0, 1]), params.glass_panes) \
            if params.glass_panes else None
        self.doors = Doors(self.world, occ, np.random.default_rng([params.seed, 0, 2]), params.door_changes,
                           params.door_period) if params.door_changes > 0.0 else None
        try:
            self.people = People(self.clearance, np.random.default_rng([params.seed, 0, 3]), params.people) \
                if params.people else None
        except ValueError as e:
            raise ParamError(f"~people: {e}") from None
        self.robots: List[SimRobot] = [
            SimRobot(s.ns, (s.x, s.y, s.yaw), occ, self.world.resolution, self.world.origin, self.clearance, cfg,
                     np.random.default_rng([params.seed, i + 1]),
                     drift=SlamDrift(np.random.default_rng([params.seed, i + 1, 1]), params.drift_yaw,
                                     params.drift_xy, params.loop_closure_path, s.ns) if params.drift else None,
                     glass=self.glass)
            for i, s in enumerate(specs)]
        self.specs: List[RobotSpec] = specs
        self.t = 0.0            # sim seconds since start
        self.steps = 0
        self._scan = _Every(params.scan_rate)
        self._update = _Every(params.update_rate)
        self._map = _Every(params.map_rate)
        self._tf = _Every(params.tf_rate)
        # first scan at t = 0 so every robot has a map before anything is published
        self._update_scenery()
        for r in self.robots:
            r.scan(force=True)
        self._scan.due(0.0)

    def step(self) -> Tuple[Due, List[Tuple[int, Outcome]]]:
        """Advance one fixed step: motion of every robot, then the scans and publications that fall due."""
        dt = self.params.sim_step
        self.steps += 1
        self.t = self.steps * dt      # no accumulated rounding
        outcomes = []
        for i, r in enumerate(self.robots):
            o = r.step(dt, self.t)
            if o is not None:
                outcomes.append((i, o))
        if self.people is not None:
            self.people.step(dt)
        due = Due()
        due.scan = self._scan.due(self.t)
        if due.scan:
            self._update_scenery()
            due.scanned = [i for i, r in enumerate(self.robots) if r.scan()]
        due.update = self._update.due(self.t)
        due.map = self._map.due(self.t)
        due.tf = self._tf.due(self.t)
        return due, outcomes

    def _update_scenery(self) -> None:
        """Doors that fall due open or shut (robots then collide with the shut ones), and what the lasers see now:
        the walls, the shut doors and the people."""
        if self.doors is None and self.people is None:
            return
        robots_xy = [r.pose[:2] for r in self.robots]
        if self.doors is not None and self.doors.update(self.t, robots_xy):
            self.occ = self.doors.blocked()
            self.clearance = Clearance(self.world, self.occ)
        seen = self.occ
        if self.people is not None:
            self.people.clear = self.clearance
            seen = self.people.draw(self.occ, self.world, robots_xy, self.params.robot_radius + 0.05)
        for r in self.robots:
            r.set_world(seen, self.clearance)

    def set_goal(self, i: int, x: float, y: float) -> Optional[Outcome]:
        return self.robots[i].set_goal(x, y, self.t)
