"""Robot maps from a rosbag, as the map_merge node would have held them at a given moment (merge_maps --bag).

Every nav_msgs/OccupancyGrid topic whose last name component is the suffix (`map`) is one robot, named by its
namespace as the node's discovery names it (`/robot_1/map` -> `/robot_1`); its map_msgs/OccupancyGridUpdate topic
`<ns>/<suffix>_updates` is applied in bag order, with the node's own map storage (RobotMap), so full maps and
updates count exactly as they do live. Messages after `at` seconds from the bag's start are not read.
Imported lazily: merge_maps without --bag needs no rosbag.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from typing import Dict, List, Optional

from .discovery import OCCUPANCY_GRID_TYPE, append, is_robot_map_topic, parent_namespace
from .grid import Grid, GridError
from .robot_maps import RobotMap

UPDATE_TYPE = 'map_msgs/OccupancyGridUpdate'

log = logging.getLogger('rosout.multirobot_map_merge.bag_input')


class BagError(Exception):
    """The bag cannot be read or holds no robot map; the message is one line naming the file."""


@dataclass
class BagRobot:
    name: str                  # robot namespace, e.g. /robot_1
    map_topic: str
    updates_topic: Optional[str]   # None when the bag has no update topic for it
    grid: Optional[Grid] = None    # None when no full map arrived before the cut-off
    maps: int = 0              # full maps read (accepted or not)
    updates: int = 0           # updates read
    refused: int = 0           # malformed or refused messages
    first_refusal: str = ''


def _one_line(text: str) -> str:
    lines = str(text).strip().splitlines()
    return lines[0] if lines else ''


def _open(path: str):
    import rosbag   # lazily: only --bag needs it
    if not os.path.isfile(path):
        raise BagError(f'{path}: bag file not found')
    try:
        return rosbag.Bag(path, 'r')
    except Exception as e:   # rosbag raises several kinds (format, unindexed, OS, struct) for a bad file
        raise BagError(f'{path}: not a readable bag: {_one_line(e) or type(e).__name__}') from None


def find_robots(topics: Dict[str, str], suffix: str = 'map') -> List[BagRobot]:
    """Robots of a bag's {topic: type}, in topic name order."""
    robots = []
    for name in sorted(topics):
        if is_robot_map_topic(name, topics[name], suffix, '', own_topic=''):
            ns = parent_namespace(name)
            updates = append(ns, suffix + '_updates')
            robots.append(BagRobot(ns, name, updates if topics.get(updates) == UPDATE_TYPE else None))
    return robots


def read_bag_maps(path: str, at: Optional[float] = None, suffix: str = 'map') -> List[BagRobot]:
    """The robots of the bag with their maps at the end of the bag, or `at` seconds after its start."""
    from .ros_conversions import grid_from_msg, update_from_msg
    if at is not None and not at >= 0.0:
        raise BagError(f'--at must be a non-negative number of seconds, not {at}')
    bag = _open(path)
    try:
        try:
            info = bag.get_type_and_topic_info().topics
            topics = {name: t.msg_type for name, t in info.items()}
            robots = find_robots(topics, suffix)
            if not robots:
                grids = sorted(n for n, t in topics.items() if t == OCCUPANCY_GRID_TYPE)
                raise BagError(f'{path}: no {OCCUPANCY_GRID_TYPE} topic named <ns>/{suffix} '
                               f'(occupancy grid topics: {", ".join(grids) or "none"})')
            start = bag.get_start_time()
            end_time = None
            if at is not None:
                import genpy
                end_time = genpy.Time.from_sec(start + at)
            by_topic = {r.map_topic: r for r in robots}
            by_topic.update({r.updates_topic: r for r in robots if r.updates_topic})
            stores = {r.name: RobotMap() for r in robots}
            for topic, msg, _ in bag.read_messages(topics=list(by_topic), end_time=end_time):
                robot = by_topic[topic]
                _apply(robot, stores[robot.name], topic == robot.map_topic, msg, grid_from_msg, update_from_msg)
        except BagError:
            raise
        except Exception as e:   # a corrupt chunk surfaces as format, struct, decompression or genpy errors
            raise BagError(f'{path}: corrupt bag: {_one_line(e) or type(e).__name__}') from None
    finally:
        bag.close()
    for r in robots:
        r.grid = stores[r.name].snapshot()
        if r.refused:   # one line per robot, not one per message
            log.warning('%s: %d of %d messages refused, the first: %s', r.name, r.refused, r.maps + r.updates,
                        r.first_refusal)
    return robots


def _apply(robot: BagRobot, store: RobotMap, is_full: bool, msg, grid_from_msg, update_from_msg) -> None:
    try:
        if is_full:
            robot.maps += 1
            store.set_full(grid_from_msg(msg))
            return
        robot.updates += 1
        result = store.apply_update(update_from_msg(msg))
    except GridError as e:
        _refuse(robot, f'malformed {"map" if is_full else "map update"}: {e}')
        return
    if not result.applied:
        _refuse(robot, f'map update: {result.reason}')


def _refuse(robot: BagRobot, reason: str) -> None:
    robot.refused += 1
    robot.first_refusal = robot.first_refusal or reason
