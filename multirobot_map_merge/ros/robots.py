"""The robots the node merges: discovery, their subscriptions, and the maps their callbacks store.

Callbacks only convert and store (a malformed map or update is refused with a throttled warning naming the robot);
the estimation and merging threads take consistent snapshots. `_lock` owns the robot list (newest first, as the
original) and the name index; each RobotMap has its own lock (copy-on-write grids).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Tuple

import rospy
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid
from rospy.numpy_msg import numpy_msg

from ..grid import Grid, GridError
from ..known_poses import InitPose
from .conversions import grid_from_msg, update_from_msg
from .discovery import read_init_pose, robot_map_topics, robot_topics
from .params import MapMergeParams
from .robot_maps import RobotMap


@dataclass
class Robot:
    name: str                              # absolute namespace, e.g. /robot1 (or / for a root /map)
    pose: Optional[InitPose]               # known_init_poses only
    maps: RobotMap = field(default_factory=RobotMap)
    subscribers: list = field(default_factory=list)


class Robots:
    """The discovered robots, newest first, with their subscriptions and stored maps."""

    def __init__(self, params: MapMergeParams, own_topic: str, warn: Callable[[str, str, str], None],
                 on_first_map: Callable[[], None]) -> None:
        self._params = params
        self._own_topic = own_topic          # the merged map: never a robot's map
        self._warn = warn                    # (robot, kind, text), throttled by the caller
        self._on_first_map = on_first_map
        self._lock = threading.Lock()
        self._robots: List[Robot] = []
        self._by_name: Dict[str, Robot] = {}

    def snapshot(self) -> Tuple[List[Robot], List[Optional[Grid]]]:
        with self._lock:
            robots = list(self._robots)
        return robots, [r.maps.snapshot() for r in robots]

    # ------------------------------------------------------------------ discovery (§3.2)
    def discover(self) -> None:
        rospy.logdebug('Robot discovery started.')
        try:
            topics = rospy.get_published_topics()
        except Exception as e:   # master unreachable: try again next pass
            self._warn('', 'master', f'cannot list published topics: {e}')
            return
        for name in robot_map_topics(topics, self._params, self._own_topic):
            with self._lock:
                if name in self._by_name:
                    continue
            pose = None
            if self._params.known_init_poses:
                pose = read_init_pose(name, rospy.get_param, lambda text: self._warn(name, 'init_pose', text))
                if pose is None:
                    continue   # not recorded: retried at the next pass, as the original
            self._add_robot(name, pose)

    def _add_robot(self, name: str, pose: Optional[InitPose]) -> None:
        rospy.loginfo('adding robot [%s] to system', name)
        robot = Robot(name, pose)
        # listed before it is subscribed: a latched map can arrive (and wake the estimation) before the second
        # subscription returns, and an estimation that then takes a snapshot without the robot would be the last
        # for 1/estimation_rate s (a loaded machine: the robot joined 50 s late)
        with self._lock:
            self._robots.insert(0, robot)   # newest first, as the original
            self._by_name[name] = robot
        map_topic, updates_topic = robot_topics(name, self._params)
        rospy.loginfo('Subscribing to MAP topic: %s.', map_topic)
        # numpy_msg: the int8[] data arrives as an ndarray (no per-cell Python ints); same type and md5 on the wire
        robot.subscribers.append(rospy.Subscriber(map_topic, numpy_msg(OccupancyGrid), self._on_map,
                                                  callback_args=robot, queue_size=50, buff_size=1 << 24))
        rospy.loginfo('Subscribing to MAP updates topic: %s.', updates_topic)
        robot.subscribers.append(rospy.Subscriber(updates_topic, numpy_msg(OccupancyGridUpdate), self._on_update,
                                                  callback_args=robot, queue_size=50, buff_size=1 << 24))

    # ------------------------------------------------------------------ callbacks: convert + store only
    def _on_map(self, msg: OccupancyGrid, robot: Robot) -> None:
        rospy.logdebug('received full map update')
        try:
            self._store_map(msg, robot)
        except Exception as e:   # no exception leaves a callback: a bug or bad input drops this message only
            self._warn(robot.name, 'map', f'map dropped: {type(e).__name__}: {e}')

    def _store_map(self, msg: OccupancyGrid, robot: Robot) -> None:
        try:
            grid = grid_from_msg(msg)
        except GridError as e:
            self._warn(robot.name, 'map', f'malformed map refused: {e}')
            return
        if 'tilted_origin' in grid.extra:
            self._warn(robot.name, 'tilt', 'map origin orientation (%g, %g, %g, %g) is not a pure yaw; roll/pitch '
                                           'ignored' % grid.extra['tilted_origin'])
        first = robot.maps.snapshot() is None
        if not robot.maps.set_full(grid):
            rospy.logdebug('map_merge: robot [%s]: out-of-order older map dropped', robot.name)
        elif first:
            self._on_first_map()   # the node estimates at once instead of up to 1/estimation_rate later

    def _on_update(self, msg: OccupancyGridUpdate, robot: Robot) -> None:
        rospy.logdebug('received partial map update')
        try:
            update = update_from_msg(msg)
            result = robot.maps.apply_update(update)
        except GridError as e:
            self._warn(robot.name, 'update', f'malformed map update refused: {e}')
            return
        except Exception as e:   # no exception leaves a callback
            self._warn(robot.name, 'update', f'map update dropped: {type(e).__name__}: {e}')
            return
        if result.reason:
            self._warn(robot.name, 'update', ('' if result.applied else 'map update refused: ') + result.reason)
