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
import struct
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

from ..grid import Grid, GridError
from .discovery import OCCUPANCY_GRID_TYPE, append, is_robot_map_topic, parent_namespace
from .robot_maps import RobotMap

UPDATE_TYPE = 'map_msgs/OccupancyGridUpdate'

log = logging.getLogger('rosout.multirobot_map_merge.ros.bag_input')


class BagError(Exception):
    """The bag cannot be read or holds no robot map; the message is one line naming the file."""


@dataclass
class BagRobot:
    name: str                  # robot namespace, e.g. /robot_1
    map_topic: str
    updates_topic: Optional[str]   # None when the bag has no update topic for it
    grid: Optional[Grid] = None    # None when no full map arrived before the cut-off
    maps: int = 0              # full maps up to the cut-off (kept or not)
    updates: int = 0           # updates up to the cut-off
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
            end_time = None
            if at is not None:
                import genpy
                end_time = genpy.Time.from_sec(bag.get_start_time() + at)
            _replay(bag, robots, end_time)
        except BagError:
            raise
        except Exception as e:   # a corrupt chunk surfaces as format, struct, decompression or genpy errors
            raise BagError(f'{path}: corrupt bag: {_one_line(e) or type(e).__name__}') from None
    finally:
        bag.close()
    for r in robots:
        if r.refused:   # one line per robot, not one per message
            log.warning('%s: %d of %d messages refused, the first: %s', r.name, r.refused, r.maps + r.updates,
                        r.first_refusal)
    return robots


def _replay(bag, robots: List[BagRobot], end_time) -> None:
    """Feed each robot's messages up to end_time to a RobotMap, as the node would have received them.

    Deserialising every full map of a long bag costs minutes, and only the last one the node would have kept
    matters (with the updates after it): a first pass over the raw messages reads the stamps and sizes from the
    headers to find it, the second deserialises from there. A robot whose map there turns out malformed is
    replayed from the start.
    """
    by_topic = {r.map_topic: r for r in robots}
    by_topic.update({r.updates_topic: r for r in robots if r.updates_topic})
    since = _last_kept_full_maps(bag, by_topic, end_time)
    stores = {r.name: RobotMap() for r in robots}
    malformed = set()
    if since:
        for topic, raw, t in bag.read_messages(topics=list(by_topic), start_time=min(since.values()),
                                               end_time=end_time, raw=True):
            robot = by_topic[topic]
            if robot.name in since and t >= since[robot.name]:
                if not _apply(robot, stores[robot.name], topic == robot.map_topic, _message(raw)):
                    malformed.add(robot.name)
    for robot in robots:
        if robot.name in malformed or (robot.name in since and stores[robot.name].snapshot() is None):
            robot.refused, robot.first_refusal = 0, ''
            stores[robot.name] = RobotMap()
            own = [t for t in (robot.map_topic, robot.updates_topic) if t]
            for topic, raw, _ in bag.read_messages(topics=own, end_time=end_time, raw=True):
                _apply(robot, stores[robot.name], topic == robot.map_topic, _message(raw))
        robot.grid = stores[robot.name].snapshot()


def _message(raw):
    """A message from rosbag's raw tuple (datatype, data, md5sum, position, class)."""
    msg = raw[4]()
    msg.deserialize(raw[1])
    return msg


def _last_kept_full_maps(bag, by_topic: Dict[str, BagRobot], end_time) -> Dict[str, object]:
    """Bag time of the last full map each robot's RobotMap would keep (its set_full rule: an older stamp of the
    same size is dropped), from the raw headers; counts every robot's maps and updates on the way."""
    kept: Dict[str, Tuple[float, Tuple[int, int], object]] = {}
    for topic, raw, t in bag.read_messages(topics=list(by_topic), end_time=end_time, raw=True):
        robot = by_topic[topic]
        if topic != robot.map_topic:
            robot.updates += 1
            continue
        robot.maps += 1
        stamp, shape = _header_stamp_and_shape(raw[1])
        last = kept.get(robot.name)
        if last is None or stamp is None or not (stamp < last[0] and shape == last[1]):
            kept[robot.name] = (stamp if stamp is not None else float('inf'), shape, t)
    return {name: k[2] for name, k in kept.items()}


def _header_stamp_and_shape(data: bytes) -> Tuple[Optional[float], Optional[Tuple[int, int]]]:
    """(header stamp, (height, width)) of a serialised nav_msgs/OccupancyGrid; (None, None) if too short."""
    try:
        _seq, secs, nsecs, frame_len = struct.unpack_from('<4I', data, 0)
        # MapMetaData after the frame id: map_load_time (8 bytes), resolution (4), width, height
        width, height = struct.unpack_from('<2I', data, 16 + frame_len + 12)
    except struct.error:
        return None, None
    return secs + 1e-9 * nsecs, (height, width)


def _apply(robot: BagRobot, store: RobotMap, is_full: bool, msg) -> bool:
    """Feed one message to the robot's map; False if it is a malformed full map."""
    from .conversions import grid_from_msg, update_from_msg   # message types: imported with rosbag
    try:
        if is_full:
            store.set_full(grid_from_msg(msg))
            return True
        result = store.apply_update(update_from_msg(msg))
    except GridError as e:
        _refuse(robot, f'malformed {"map" if is_full else "map update"}: {e}')
        return not is_full
    if not result.applied:
        _refuse(robot, f'map update: {result.reason}')
    return True


def _refuse(robot: BagRobot, reason: str) -> None:
    robot.refused += 1
    robot.first_refusal = robot.first_refusal or reason
