"""Parameters of the explore node (explore.md §2.1) plus this port's extensions.

Each field's ``metadata['doc']`` is the one description of the parameter (the doc/explore.md table is generated from
``describe()``). Parameters are read once at start-up from the node's private namespace (``~name``).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields
from typing import Any, List, Mapping

from multirobot_map_merge.paramdoc import ParamDoc, param
from multirobot_map_merge.paramdoc import describe as describe_params

_log = logging.getLogger('rosout.' + __name__)


class ParamError(ValueError):
    """A parameter value the node cannot run with."""


_p = param


@dataclass
class ExploreParams:
    # --- explore_lite's parameters: same names, types and defaults as the original code ---
    robot_base_frame: str = _p('base_link', "Robot frame for the pose lookup; a `tf_prefix` found up the parameter "
                               "tree is applied as tf1 does.")
    costmap_topic: str = _p('costmap', "Source `nav_msgs/OccupancyGrid` topic, resolved in the node namespace.")
    costmap_updates_topic: str = _p('costmap_updates', "Source `map_msgs/OccupancyGridUpdate` topic, node "
                                    "namespace; subscribed after the first full map. Optional.")
    transform_tolerance: float = _p(0.3, "Maximum age of the robot pose transform; an older pose counts as "
                                    "unavailable.", 's')
    visualize: bool = _p(False, "Publish frontiers as `visualization_msgs/MarkerArray` on `~frontiers`.")
    planner_frequency: float = _p(1.0, "Replanning rate (the timer period is 1/planner_frequency). Lower it to "
                                  "let the robot reach a goal before the goal is re-evaluated.", 'Hz')
    progress_timeout: float = _p(30.0, "When the robot has not got closer to its current goal for this long, the "
                                 "goal is blacklisted.", 's')
    potential_scale: float = _p(1e-3, "Weight of the distance to the frontier in its cost "
                                "(cost = potential_scale·min_distance·resolution − gain_scale·size·resolution).")
    orientation_scale: float = _p(0.0, "Read but unused, as in the original (kept for compatibility).")
    gain_scale: float = _p(1.0, "Weight of the frontier size in its cost (larger frontiers are preferred).")
    min_frontier_size: float = _p(0.5, "Frontiers shorter than this (size in cells × resolution) are ignored.", 'm')
    # --- extensions of this port (the ROS 2 port's return_to_init, team coordination, probabilistic maps) ---
    return_to_init: bool = _p(False, "When exploration ends (no frontiers left or all blacklisted), drive back to "
                              "the pose the robot had at start-up.", extension=True)
    path_distance: bool = _p(False, "Rank frontiers by their distance along the free space of the map instead of "
                             "the original's straight line. A straight line makes a robot whose way to its goal "
                             "starts round a wall switch goals back and forth between two frontiers without "
                             "reaching either; in larger buildings it never finishes.", extension=True)
    team_topic: str = _p('', "Topic on which the explorers of a team share their current goals; robots avoid "
                         "frontiers within `team_radius` of another robot's goal. Empty disables coordination.",
                         extension=True)
    team_frame: str = _p('world', "Frame in which goals are exchanged on `team_topic`.", extension=True)
    team_radius: float = _p(4.0, "Frontiers whose centroid is closer than this to another robot's goal are "
                            "chosen only when no other frontier is left.", 'm', extension=True)
    team_map_topic: str = _p('', "Merged map of the team (`nav_msgs/OccupancyGrid` in `team_frame`, e.g. "
                             "map_merge's map with its `publish_tf`): frontiers whose far side this map already "
                             "shows as known (a teammate has mapped it) are skipped. Empty: off.", extension=True)
    probability_map: bool = _p(False, "Treat occupancies strictly between `free_threshold` and "
                               "`occupied_threshold` as unknown (uncertain cells count as unexplored, e.g. "
                               "Cartographer maps). Off: they are neither free nor unknown, as the original's "
                               "values 1..98. Do not use with a costmap source: its inflation band would become "
                               "frontiers.", extension=True)
    free_threshold: int = _p(25, "Highest occupancy (0..100) counted as free. The original counts only exactly 0 "
                             "as free, so probabilistic maps had no frontiers; 0 restores that. A ternary map "
                             "(−1/0/100) gives the same result for any value.", extension=True)
    occupied_threshold: int = _p(65, "Lowest occupancy (0..100) counted as occupied (lethal).", extension=True)

    def validate(self) -> None:
        """Raise ParamError for values the node cannot run with."""
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and math.isnan(v):
                raise ParamError(f"~{f.name} is NaN")
        if not (math.isfinite(self.planner_frequency) and self.planner_frequency > 0.0):
            raise ParamError(f"~planner_frequency must be a positive number, got {self.planner_frequency}")
        if self.team_radius < 0.0:
            raise ParamError(f"~team_radius must not be negative, got {self.team_radius}")
        if not 0 <= self.free_threshold < self.occupied_threshold <= 100:
            raise ParamError(f"need 0 <= ~free_threshold ({self.free_threshold}) < ~occupied_threshold "
                             f"({self.occupied_threshold}) <= 100")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> 'ExploreParams':
        """Parameters from a name → value mapping (e.g. ``rospy.get_param('~')``), validated.

        Type rules follow roscpp's ``param()``: a float parameter also accepts an int; a value of the wrong type is
        ignored with a WARN and the default is used. Unknown names are ignored.
        """
        kwargs = {}
        for f in fields(cls):
            if f.name not in values:
                continue
            v = values[f.name]
            expected = {'str': str, 'float': float, 'bool': bool, 'int': int}[f.type]
            if expected is float and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            if isinstance(v, expected) and (expected is bool or not isinstance(v, bool)):
                kwargs[f.name] = v
            else:
                _log.warning("parameter ~%s = %r is not of type %s; using the default %r",
                             f.name, v, f.type, f.default)
        params = cls(**kwargs)
        params.validate()
        return params


def describe() -> List[ParamDoc]:
    """One row per parameter, in declaration order (source of the doc/explore.md table and the node docstring)."""
    return describe_params(ExploreParams)
