"""Robot discovery (map_merge.md §3), pure: roscpp's name helpers, the robot-map-topic filter, init poses read
from parameters.

roscpp's names::clean/append/parentNamespace are reproduced exactly; rospy's own helpers differ (e.g.
rospy.names.namespace('/robot1/map') == '/robot1/', with a trailing slash), so they must not be used here.
"""
from __future__ import annotations

import math
from typing import Callable, Iterable, List, Optional, Sequence, Tuple

from ..known_poses import InitPose

OCCUPANCY_GRID_TYPE = 'nav_msgs/OccupancyGrid'


def clean(name: str) -> str:
    """Collapse every '//' to '/' and drop one trailing '/' (so clean('/') == '')."""
    while '//' in name:
        name = name.replace('//', '/')
    if name.endswith('/'):
        name = name[:-1]
    return name


def append(left: str, right: str) -> str:
    return clean(left + '/' + right)


def parent_namespace(name: str) -> str:
    """roscpp names::parentNamespace: '/robot1/map' -> '/robot1', '/map' -> '/', 'map' -> ''."""
    if name == '' or name == '/':
        return name
    stripped = name
    if stripped.endswith('/'):
        # roscpp quirk: drops the last *two* characters of a name ending with '/'
        stripped = stripped[:-2]
    last = stripped.rfind('/')
    if last == -1:
        return ''
    if last == 0:
        return '/'
    return stripped[:last]


def is_robot_map_topic(name: str, msg_type: str, robot_map_topic: str, robot_namespace: str,
                       own_topic: str) -> bool:
    """§3.2 step 2: every condition must hold."""
    return (msg_type == OCCUPANCY_GRID_TYPE
            and name != own_topic
            and robot_namespace in name
            and append(parent_namespace(name), robot_map_topic) == name)


def robot_map_topics(published_topics: Iterable[Sequence[str]], params, own_topic: str) -> List[str]:
    """Robot namespaces (§3.2 steps 2-3) in the order of `published_topics` ([name, type] pairs, as
    rospy.get_published_topics() returns them); duplicates removed, first occurrence kept.

    `params` needs robot_map_topic and robot_namespace (a MapMergeParams); own_topic is the node's fully
    resolved merged-map topic.
    """
    robots: List[str] = []
    for entry in published_topics:
        name, msg_type = entry[0], entry[1]
        if is_robot_map_topic(name, msg_type, params.robot_map_topic, params.robot_namespace, own_topic):
            robot = parent_namespace(name)
            if robot not in robots:
                robots.append(robot)
    return robots


def robot_topics(robot: str, params) -> Tuple[str, str]:
    """§3.2 step 7: (map topic, map updates topic) of a robot namespace (absolute names)."""
    return append(robot, params.robot_map_topic), append(robot, params.robot_map_updates_topic)


def init_pose_param_names(robot: str) -> List[str]:
    """§2.4: absolute names of the four init-pose parameters, in the order the original reads them."""
    return [append(append(robot, 'map_merge'), 'init_pose_' + k) for k in ('x', 'y', 'z', 'yaw')]


def read_init_pose(robot: str, get_param: Callable[[str], object], warn: Callable[[str], None]) -> Optional[InitPose]:
    """The robot's init pose from its map_merge/init_pose_* parameters (`get_param` raises KeyError when one is
    missing), or None after one warning (`warn`) naming the first missing or non-numeric one."""
    values = []
    for pname in init_pose_param_names(robot):
        try:
            v = get_param(pname)
        except KeyError:
            v = None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            warn(f"Couldn't get initial position for robot [{robot}]: parameter {pname} is "
                 f"{'missing' if v is None else repr(v)}; did you define parameters "
                 f"map_merge/init_pose_[xyz] and init_pose_yaw? Retrying at the next discovery.")
            return None
        values.append(float(v))
    x, y, _z, yaw = values   # z is required (as the original) but unused
    return InitPose(x, y, yaw)
