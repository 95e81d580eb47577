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

from .settings import EstimationSettings

ORIGIN_MODES = ('center', 'world')


@dataclass(frozen=True)
class MapMergeParams:
    # --- the original's parameters (private namespace ~), same names, types and code defaults ---
    merging_rate: float = 4.0             # Hz, merge-and-publish loop
    discovery_rate: float = 0.05          # Hz, robot discovery (every 20 s)
    estimation_rate: float = 0.5          # Hz, transform estimation (only when known_init_poses is false)
    known_init_poses: bool = True         # true: transforms from <robot_ns>/map_merge/init_pose_*; false: estimated
    estimation_confidence: float = 1.0    # confidence a matched pair needs to be merged
    robot_map_topic: str = 'map'          # last name component of the robots' map topics
    robot_map_updates_topic: str = 'map_updates'  # last name component of the robots' map update topics
    robot_namespace: str = ''             # plain substring filter on full topic names
    merged_map_topic: str = 'map'         # output topic, relative to the node namespace
    world_frame: str = 'world'            # frame_id of the merged map
    # --- opt-in extras of this port (defaults keep the original's behaviour where it is not a bug) ---
    publish_tf: bool = False              # broadcast world_frame -> each included robot's map frame
    origin_mode: str = 'center'           # 'center': origin centred on world_frame as the original; 'world': metric
    legacy_cell_poses: bool = False       # init poses in cells, inverted, corner pivot (the original 2.x, §8.3)
    feature: str = 'akaze'                # keypoint detector of the estimator (EstimationSettings.feature)

    @classmethod
    def fields_doc(cls) -> List[Tuple[str, str, Any]]:
        """(name, type name, default) of every parameter, for the node docstring and the README table."""
        return [(f.name, _TYPE_NAMES[f.type if isinstance(f.type, type) else _ANNOT[f.type]], f.default)
                for f in dataclasses.fields(cls)]

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
        return cls(**values)

    def estimation_settings(self) -> EstimationSettings:
        return EstimationSettings(feature=self.feature, confidence=self.estimation_confidence)


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
