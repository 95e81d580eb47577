"""Parameters of the map_merge node: one dataclass, the original's names and code defaults (map_merge.md §2.3).

Pure (no rospy): `MapMergeParams.read(get_param)` takes any callable with the signature of
``rospy.get_param(name, default)``, so the node passes rospy.get_param with private names and tests pass a dict.
Type rules follow roscpp: a double parameter may be given as an int; a value of the wrong type falls back to the
default (the original does so silently; we log a warning through the given `warn` callable).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Tuple

from ..admission import FREE_THRESHOLD, OCCUPIED_THRESHOLD, check_thresholds
from ..estimation.settings import EstimationSettings
from ..grid import MAX_CELLS
from ..paramdoc import ParamDoc, param
from ..paramdoc import describe as describe_params

ORIGIN_MODES = ('center', 'world')


_p = param   # a parameter: its code default and its one-line meaning (the node docstring and doc/map_merge.md)


# s of correlation search per estimation in the node: a live fleet's small maps seldom place by it, and an estimation
# that searches every pair of them leaves the robots that match by descriptors waiting (the rest is searched later)
SEARCH_BUDGET = 1.0

@dataclass(frozen=True)
class MapMergeParams:
    # --- the original's parameters (private namespace ~), same names, types and code defaults (§2.3) ---
    merging_rate: float = _p(4.0, 'Hz of the merge-and-publish loop (ROS time)')
    discovery_rate: float = _p(0.05, 'Hz of the robot discovery loop (every 20 s); the first pass runs at start-up')
    estimation_rate: float = _p(0.5, 'Hz of the transform estimation loop (only when known_init_poses is false)')
    known_init_poses: bool = _p(True, "true: place each map by its robot's map_merge/init_pose_* parameters; "
                                      'false: estimate the transforms from the maps')
    estimation_confidence: float = _p(1.0, 'confidence threshold of a matched pair: the original\'s '
                                           'inliers / (8 + 0.3 matches), counted on verified wall correspondences')
    robot_map_topic: str = _p('map', 'last name component of the robots\' map topics')
    robot_map_updates_topic: str = _p('map_updates', 'last name component of the robots\' map update topics')
    robot_namespace: str = _p('', 'plain substring that a robot map topic name must contain ("" = every robot)')
    merged_map_topic: str = _p('map', 'merged map topic, relative to the node namespace (latched)')
    world_frame: str = _p('world', 'frame_id of the merged map (and parent frame of publish_tf)')
    # --- opt-in extras of this port (defaults keep the original's behaviour where it is not a bug) ---
    publish_tf: bool = _p(False, 'extra: broadcast world_frame -> each merged robot map frame at merging_rate')
    origin_mode: str = _p('center', 'extra: "center" puts the merged grid\'s centre at world_frame\'s origin (the '
                                    'original); "world" keeps the grid at its true place in world_frame')
    legacy_cell_poses: bool = _p(False, 'extra: read init poses as the C++ 2.x node does (cells, inverted, corner '
                                        'pivot)')
    feature: str = _p('akaze', 'extra: keypoint detector of the estimator (akaze as the original, orb, sift)')
    free_threshold: int = _p(FREE_THRESHOLD, 'extra: highest occupancy (0..100) read as free when maps are matched '
                                             '(map_saver\'s); the merged map keeps the values as published')
    occupied_threshold: int = _p(OCCUPIED_THRESHOLD, 'extra: lowest occupancy (0..100) read as a wall when maps are '
                                                     'matched; the values between the two thresholds (a probabilistic '
                                                     'map\'s uncertain cells, e.g. Cartographer\'s) count as unknown')
    estimation_processes: bool = _p(False, 'extra: true: the estimation matches maps on 2 worker processes (as '
                                           'merge_maps does), which use both cores where threads take turns; it '
                                           'gained the node nothing on 30 robots and took 230-340 MiB more')
    max_merged_cells: int = _p(1 << 24, 'extra: largest merged grid (cells); a robot whose map or placement would '
                                        'make it larger is left out of that cycle with a warning (1..2^28)')

    @classmethod
    def describe(cls) -> List[ParamDoc]:
        """One row per parameter, with ROS type names: the one source of the node docstring and of the table in
        doc/map_merge.md (scripts/param_table.py)."""
        return describe_params(cls, type_name=lambda annotation: _TYPE_NAMES[_ANNOT[annotation]])

    @classmethod
    def read(cls, get_param: Callable[[str, Any], Any], prefix: str = '~',
             warn: Optional[Callable[[str], None]] = None) -> 'MapMergeParams':
        """Read every parameter once through get_param(prefix + name, default); bad values -> default + warning."""
        values: Dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            kind = f.type if isinstance(f.type, type) else _ANNOT[f.type]
            raw = get_param(prefix + f.name, f.default)
            value, problem = _coerce(raw, kind)
            if problem is None and f.name == 'origin_mode' and value not in ORIGIN_MODES:
                problem = f"must be one of {', '.join(ORIGIN_MODES)}"
            if problem is None and f.name.endswith('_rate') and not (math.isfinite(value) and value > 0.0):
                problem = 'must be a positive finite rate'   # no zero-period timers
            if problem is None and f.name == 'max_merged_cells' and \
                    (isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_CELLS):
                problem = f'must be an integer in 1..{MAX_CELLS}'
            if problem is None and f.name == 'feature':
                try:
                    EstimationSettings(feature=value).validate()
                except ValueError as e:
                    problem = str(e)
            if problem is not None:
                if warn is not None:
                    warn(f"parameter {prefix}{f.name} = {raw!r} {problem}; using the default {f.default!r}")
                value = f.default
            values[f.name] = value
        try:
            check_thresholds(values['free_threshold'], values['occupied_threshold'])
        except ValueError as e:
            if warn is not None:
                warn(f'parameters {prefix}free_threshold, {prefix}occupied_threshold: {e}; using the defaults '
                     f'{FREE_THRESHOLD}, {OCCUPIED_THRESHOLD}')
            values['free_threshold'], values['occupied_threshold'] = FREE_THRESHOLD, OCCUPIED_THRESHOLD
        return cls(**values)

    def estimation_settings(self) -> EstimationSettings:
        # no eviction while maps grow: on partial maps it took right members out and moved the reference from one
        # estimation to the next (bench_node, 30 robots revealed: robots placed 1-2 degrees off in 10 of 25
        # statuses, against 7 of 34 with 3 at most without it); tracking drops a contradicted placement instead, and
        # refines the kept placements together (so no relaxation or search of the maps left out at the end of each
        # estimation either). The one estimate afresh of the static final maps searches the maps left out and
        # evicts (EstimationSettings.for_final_maps)
        return EstimationSettings(feature=self.feature, confidence=self.estimation_confidence,
                                  search_budget_s=SEARCH_BUDGET, free_threshold=self.free_threshold,
                                  occupied_threshold=self.occupied_threshold, evict=False, relax_final=False,
                                  search_left_out=False, processes=self.estimation_processes)


_ANNOT = {'float': float, 'bool': bool, 'str': str, 'int': int}
_TYPE_NAMES = {float: 'double', bool: 'bool', str: 'string', int: 'int'}


def _coerce(raw: Any, kind: type) -> Tuple[Any, Optional[str]]:
    """(value, None) or (None, reason): roscpp's XML-RPC rules (int accepted for double, nothing else converted)."""
    if kind is float:
        if isinstance(raw, bool) or not isinstance(raw, (int, float)):
            return None, f'is not a double ({type(raw).__name__})'
        if raw != raw:
            return None, 'is NaN'
        return float(raw), None
    if kind is bool:
        return (raw, None) if isinstance(raw, bool) else (None, f'is not a bool ({type(raw).__name__})')
    if kind is str:
        return (raw, None) if isinstance(raw, str) else (None, f'is not a string ({type(raw).__name__})')
    return raw, None
