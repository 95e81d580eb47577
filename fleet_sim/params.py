"""Parameters of the fleet_sim node: one dataclass holding the defaults and the one description of each parameter.

Pure (no rospy). ``FleetSimParams.from_mapping(rospy.get_param('~'))`` reads the node's private parameters once at
start; the doc/fleet_sim.md table and the node docstring come from ``describe()``. Unlike map_merge (which must keep the
original's forgiving behaviour), a simulator with a wrong parameter would silently simulate something else, so any
wrong type or value is a ParamError: the node stops at start with that one message.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, fields
from typing import Any, Dict, List, Mapping, Optional

from multirobot_map_merge.paramdoc import ParamDoc, param
from multirobot_map_merge.paramdoc import describe as describe_params


class ParamError(ValueError):
    """A parameter value the simulator cannot run with."""


# the values of the `realistic` profile, one per parameter it changes, filled by _p below
REALISTIC: Dict[str, Any] = {}


def _p(default: Any, doc: str, unit: str = '', realistic: Any = None) -> Any:
    """A parameter field (paramdoc.param); ``realistic``: its value under ``~profile: realistic``, which its
    documentation then states, so the profile, the docstring and the doc table come from this one place."""
    field = param(default, doc + (f" *realistic*: `{_shown(realistic)}`." if realistic is not None else ''), unit)
    field.metadata = {**field.metadata, 'realistic': realistic}
    return field


def _shown(value: Any) -> str:
    return ('true' if value else 'false') if isinstance(value, bool) else str(value)


@dataclass(frozen=True)
class RobotSpec:
    """A robot to simulate: namespace (no leading slash) and start pose in the world frame (metres, radians)."""
    ns: str
    x: float
    y: float
    yaw: float = 0.0


_NS_RE = re.compile(r'^[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$')


@dataclass(frozen=True)
class FleetSimParams:
    # --- the world ---
    world: str = _p('', "map_server YAML of the world (occupied cells and unknown cells are walls). Empty: a "
                    "generated floor plan, `fleet_sim.world.make_floor_plan(~world_seed)`.")
    world_seed: int = _p(0, "Seed of the generated floor plan.")
    world_width: float = _p(24.0, "Width of the generated floor plan (walls included).", 'm')
    world_height: float = _p(16.0, "Height of the generated floor plan (walls included).", 'm')
    # --- the robots ---
    robots: list = _p(None, "List of `{ns: robot_1, x: .., y: .., yaw: ..}` (world metres, radians; `ns` "
                      "optional, default `robot_<i>`). Empty: `~num_robots` robots at random free poses.")
    num_robots: int = _p(1, "Number of robots when `~robots` is not given.")
    seed: int = _p(0, "Seed of the random start poses, the laser noise and the realistic profile's glass, people, "
                   "doors and drift.")
    map_frame: str = _p('map', "Last component of each robot's map frame: `<ns>/<map_frame>`.")
    base_frame: str = _p('base_link', "Last component of each robot's base frame: `<ns>/<base_frame>`.")
    robot_radius: float = _p(0.2, "Robot radius: the robot centre keeps this far from world walls; the planner "
                             "keeps 0.05 m more.", 'm')
    linear_speed: float = _p(0.5, "Driving speed.", 'm/s')
    angular_speed: float = _p(1.5, "Turning speed.", 'rad/s')
    goal_tolerance: float = _p(0.25, "move_base SUCCEEDS when the robot is this close to the goal; a goal cell too "
                               "close to a wall is replaced by the nearest reachable cell within this distance.",
                               'm')
    stuck_timeout: float = _p(5.0, "move_base re-plans when the robot has not moved 0.1 m for this long (sim "
                              "time) and ABORTS after 3 such re-plans in a row.", 's')
    # --- the sensor and the SLAM stand-in ---
    resolution: float = _p(0.05, "Resolution of the robots' maps.", 'm')
    profile: str = _p('', "Empty: the parameters below at their defaults (an ideal robot: 360-degree laser, short "
                      "beams, exact poses, a static world). `realistic`: every parameter not set explicitly takes "
                      "its *realistic* value (a 270-degree 30 m scanner with range noise growing with distance, "
                      "glass, people, doors that open and shut, the pose error of a SLAM).")
    n_beams: int = _p(360, "Laser beams over a full turn (the ones within `~fov` are cast).")
    fov: float = _p(360.0, "Laser field of view, centred on the heading (common scanners: 180 or 270).", 'deg',
                    realistic=270.0)
    max_range: float = _p(5.0, "Laser range: beams reaching no wall within it give no return.", 'm',
                          realistic=30.0)
    range_noise: float = _p(0.01, "Standard deviation of the Gaussian range noise (at range 0).", 'm')
    range_noise_per_m: float = _p(0.0, "Growth of the range noise's standard deviation per metre of range.", 'm/m',
                                  realistic=0.0015)
    clear_no_return: bool = _p(True, "Beams with no return (nothing within `~max_range`, glass) mark free space "
                               "up to `~max_range` in the map; false: they mark nothing, as gmapping.",
                               realistic=False)
    glass_panes: int = _p(0, "Panes of glass (0.8-2 m) in interior walls of the world: they stop robots, but "
                          "return a beam only within 10 degrees of their normal.", realistic=4)
    people: int = _p(0, "People walking (discs of 0.25 m at 0.8 m/s between random places): the laser sees them, "
                     "so they show in the maps until later scans clear them; robots pass through them.",
                     realistic=3)
    door_changes: float = _p(0.0, "Share of the generated floor plan's doors that open and shut while the robots "
                             "explore (a shut door stops robots and beams; it never shuts on a robot).",
                             realistic=0.5)
    door_period: float = _p(120.0, "Mean time a changing door stays open, or shut.", 's')
    drift_yaw: float = _p(0.0, "Heading error the SLAM's scan matching leaves per metre driven (a random walk: "
                          "after d metres its standard deviation is drift_yaw * sqrt(d)); the pose on TF and the "
                          "map are the robot's belief, its error grows from 0 at the start pose.", 'deg/√m',
                          realistic=0.05)
    drift_xy: float = _p(0.0, "Position error left per metre driven, per axis (random walk, as `~drift_yaw`).",
                         'm/√m', realistic=0.005)
    loop_closure_path: float = _p(10.0, "With drift: a robot back within 1 m of a place it passed this much path "
                                  "ago closes a loop: its belief jumps back to the error it had there (a visible "
                                  "jump on TF), and its later scans fit the map it drew there.", 'm')
    scan_rate: float = _p(5.0, "Laser scans fused into the maps per second (sim time).", 'Hz')
    map_rate: float = _p(1.0, "Full `<ns>/map` publications per second (sim time), skipped while the map has not "
                         "changed (it is latched); a grown map is published at the next update instead.", 'Hz')
    update_rate: float = _p(5.0, "`<ns>/map_updates` and `<ns>/ground_truth/pose` publications per second (sim "
                            "time).", 'Hz')
    tf_rate: float = _p(10.0, "TF `<ns>/map` -> `<ns>/base_link` publications per second (sim time).", 'Hz')
    publish_scan: bool = _p(False, "Publish each scan as sensor_msgs/LaserScan on `<ns>/scan`.")
    # --- time ---
    speedup: float = _p(1.0, "Sim time runs this many times faster than real time (needs `/use_sim_time` true: "
                        "the node then publishes `/clock`).")
    sim_step: float = _p(0.05, "Fixed motion step (sim time).", 's')

    def __post_init__(self) -> None:
        if self.robots is None:
            object.__setattr__(self, 'robots', [])

    @property
    def drift(self) -> bool:
        """The robots' believed poses differ from the true ones."""
        return self.drift_yaw > 0.0 or self.drift_xy > 0.0

    # ------------------------------------------------------------------ validation
    def validate(self) -> None:
        """Raise ParamError for values the simulator cannot run with."""
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ParamError(f"~{f.name} must be finite, got {v}")
        positive = ('world_width', 'world_height', 'linear_speed', 'angular_speed', 'resolution', 'max_range',
                    'scan_rate', 'map_rate', 'update_rate', 'tf_rate', 'speedup', 'sim_step', 'stuck_timeout')
        for name in positive:
            if getattr(self, name) <= 0.0:   # rates: no zero-period timers
                raise ParamError(f"~{name} must be positive, got {getattr(self, name)}")
        if self.profile not in PROFILES:
            raise ParamError(f"~profile must be one of {sorted(PROFILES)}, got {self.profile!r}")
        if not 0.0 < self.fov <= 360.0:
            raise ParamError(f"~fov must be in (0, 360] degrees, got {self.fov}")
        if not 0.0 <= self.door_changes <= 1.0:
            raise ParamError(f"~door_changes must be in 0..1, got {self.door_changes}")
        for name in ('glass_panes', 'people'):
            if not 0 <= getattr(self, name) <= 1000:
                raise ParamError(f"~{name} must be in 0..1000, got {getattr(self, name)}")
        for name in ('door_period', 'loop_closure_path'):
            if getattr(self, name) <= 0.0:
                raise ParamError(f"~{name} must be positive, got {getattr(self, name)}")
        for name in ('robot_radius', 'range_noise', 'goal_tolerance', 'range_noise_per_m', 'drift_yaw', 'drift_xy'):
            if getattr(self, name) < 0.0:
                raise ParamError(f"~{name} must not be negative, got {getattr(self, name)}")
        if self.n_beams < 1 or self.n_beams > 100000:
            raise ParamError(f"~n_beams must be in 1..100000, got {self.n_beams}")
        if self.num_robots < 1 or self.num_robots > 100:
            raise ParamError(f"~num_robots must be in 1..100, got {self.num_robots}")
        if self.sim_step > 1.0:
            raise ParamError(f"~sim_step must be at most 1 s, got {self.sim_step}")
        for name in ('map_frame', 'base_frame'):
            if not _NS_RE.match(getattr(self, name)):
                raise ParamError(f"~{name} {getattr(self, name)!r} is not a valid frame name")
        self.robot_specs(None)   # raises on a malformed ~robots

    def robot_specs(self, random_poses: Optional[List[tuple]]) -> List[RobotSpec]:
        """The robots to simulate: ``~robots`` if given, else ``~num_robots`` at ``random_poses`` (x, y, yaw)."""
        if not self.robots:
            poses = random_poses or []
            return [RobotSpec(f'robot_{i + 1}', *p) for i, p in enumerate(poses)]
        if not isinstance(self.robots, list):
            raise ParamError(f"~robots must be a list of dicts, got {type(self.robots).__name__}")
        specs = []
        for i, r in enumerate(self.robots):
            if not isinstance(r, dict):
                raise ParamError(f"~robots[{i}] must be a dict {{ns, x, y, yaw}}, got {r!r}")
            unknown = set(r) - {'ns', 'x', 'y', 'yaw'}
            if unknown:
                raise ParamError(f"~robots[{i}] has unknown keys {sorted(unknown)}")
            ns = r.get('ns', f'robot_{i + 1}')
            if not isinstance(ns, str) or not _NS_RE.match(ns.strip('/')):
                raise ParamError(f"~robots[{i}].ns {ns!r} is not a valid namespace")
            vals = []
            for key in ('x', 'y', 'yaw'):
                v = r.get(key, 0.0 if key == 'yaw' else None)
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ParamError(f"~robots[{i}].{key} must be a finite number, got {v!r}")
                vals.append(float(v))
            specs.append(RobotSpec(ns.strip('/'), *vals))
        names = [s.ns for s in specs]
        if len(set(names)) != len(names):
            raise ParamError(f"~robots: namespaces must be unique, got {names}")
        return specs

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> 'FleetSimParams':
        """Parameters from a name -> value mapping (e.g. ``rospy.get_param('~')``), validated; unknown names are
        ignored (other tools may keep parameters there). A float parameter also accepts an int."""
        if not isinstance(values, Mapping):
            values = {}
        profile = values.get('profile', '')
        if profile not in PROFILES:
            raise ParamError(f"~profile must be one of {sorted(PROFILES)}, got {profile!r}")
        values = {**PROFILES[profile], **values}    # explicit values win over the profile's
        kwargs = {}
        for f in fields(cls):
            if f.name not in values:
                continue
            v = values[f.name]
            expected = {'str': str, 'float': float, 'bool': bool, 'int': int, 'list': list}[f.type]
            if expected is float and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            if expected is list and v in ('', None):
                v = []
            if not isinstance(v, expected) or (expected is not bool and isinstance(v, bool)):
                raise ParamError(f"~{f.name} = {v!r} is not of type {f.type}")
            kwargs[f.name] = v
        params = cls(**kwargs)
        params.validate()
        return params


REALISTIC.update({f.name: f.metadata['realistic'] for f in fields(FleetSimParams)
                  if f.metadata.get('realistic') is not None})
PROFILES: Dict[str, Dict[str, Any]] = {'': {}, 'realistic': REALISTIC}


def describe() -> List[ParamDoc]:
    """One row per parameter, in declaration order (source of the doc/fleet_sim.md table and the node docstring)."""
    return describe_params(FleetSimParams, shown_default=lambda name, default: [] if name == 'robots' else default)
