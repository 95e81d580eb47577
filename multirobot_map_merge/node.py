"""map_merge ROS node: a thin rospy adapter over the pure core (drop-in for hrnr/m-explore's C++ map_merge).

Node name `map_merge`. Publishes the merged nav_msgs/OccupancyGrid latched on `<merged_map_topic>` (relative to the
node namespace), `~status` (multirobot_map_merge/MergeStatus, latched, after every estimation) and, with
`~publish_tf`, tf world_frame -> each included robot's map frame. Subscribes `<robot_ns>/<robot_map_topic>` and
`<robot_ns>/<robot_map_updates_topic>` of every discovered robot (map_merge.md §2-§3).

Parameters (private, read once at start; a wrong type logs a warning and uses the default):
{params}

Threads (rospy runs every subscriber on its own thread; callbacks only convert + store, or wake a worker):
  * discovery: at start, then every 1/discovery_rate s;
  * estimation (only when known_init_poses is false): every 1/estimation_rate s, or at once when a robot's first map
    arrives; it keeps the reference robot while that robot stays in the merge;
  * merging: every 1/merging_rate s: the newest maps, the last estimated transforms (kept per robot name, so they
    follow the robot when the list grows), compose, publish.
Loops sleep on one stop Event (wall clock), so SIGINT ends the node within a fraction of a second.

Differences from the original, on purpose (see also robot_maps.py): init poses are metres/radians of the robot map
frame in the world unless `~legacy_cell_poses`; a malformed map or update is refused with a throttled warning naming
the robot instead of being merged; the reference robot does not jump between estimations; a robot whose init pose is
missing is retried at every discovery pass (as the original) with a throttled warning; the tf child frame is the
robot map's header.frame_id (or `<robot_ns>/map` when empty) without a leading '/', as tf2 requires.
`~status` transforms are robot map frame -> world_frame as placed by the latest merge cycle.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np
import rospy
from geometry_msgs.msg import Transform, TransformStamped
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid

from . import transforms as tf
from .discovery import append, init_pose_param_names, robot_map_topics, robot_topics
from .grid import Grid, GridError
from .known_poses import InitPose
from .msg import MergeStatus, PairMatchStatus, RobotMergeStatus
from .node_params import MapMergeParams
from .pipeline import MergingPipeline
from .robot_maps import RobotMap
from .ros_conversions import grid_from_msg, grid_to_msg, update_from_msg

WARN_PERIOD = 10.0   # s between two identical warnings (same robot, same kind)


def _params_doc() -> str:
    return '\n'.join(f'  ~{name} ({kind}, default {default!r})' for name, kind, default in MapMergeParams.fields_doc())


__doc__ = __doc__.format(params=_params_doc())


class _Throttle:
    """Per-key throttling: rospy's *_throttle helpers key on the call site, which would hide other robots."""

    def __init__(self, period: float = WARN_PERIOD) -> None:
        self._period = period
        self._last: Dict[Tuple[str, ...], float] = {}
        self._lock = threading.Lock()

    def __call__(self, key: Tuple[str, ...]) -> bool:
        now = time.monotonic()
        with self._lock:
            if now - self._last.get(key, -math.inf) < self._period:
                return False
            self._last[key] = now
            return True


@dataclass
class Robot:
    name: str                              # absolute namespace, e.g. /robot1 (or / for a root /map)
    pose: Optional[InitPose]               # known_init_poses only
    maps: RobotMap = field(default_factory=RobotMap)
    subscribers: list = field(default_factory=list)


def _transform_msg(m: np.ndarray) -> Transform:
    x, y, yaw, _ = tf.params(m)
    t = Transform()
    t.translation.x, t.translation.y = x, y
    t.rotation.z, t.rotation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
    return t


def center_origin(merged: Grid) -> Tuple[float, float, float]:
    """The original's origin (§7.3 step 7): canvas centred on world_frame, resolution as float32 widened."""
    res = float(np.float32(merged.resolution))
    return (-(merged.width / 2.0) * res, -(merged.height / 2.0) * res, 0.0)


def frame_of(robot: str, grid: Optional[Grid]) -> str:
    frame = grid.frame_id if grid is not None and grid.frame_id else append(robot, 'map')
    return frame.lstrip('/')


class MapMergeNode:
    def __init__(self, params: MapMergeParams) -> None:
        self.params = params
        self._stop = threading.Event()
        self._wake_estimation = threading.Event()
        self._throttle = _Throttle()
        self._robots_lock = threading.Lock()          # owns _robots (newest first, as the original) and _by_name
        self._robots: List[Robot] = []
        self._by_name: Dict[str, Robot] = {}
        self._estimate_lock = threading.Lock()        # owns _transforms, _reference, _world_from_merged
        self._transforms: Dict[str, np.ndarray] = {}  # robot name -> metric transform map frame -> merged frame
        self._reference: Optional[str] = None
        self._world_from_merged = np.eye(3)           # last shift applied by the merge cycle (center mode)
        self._merge_pipeline = MergingPipeline(params.estimation_settings())   # merging thread only
        self._estimate_pipeline = MergingPipeline(params.estimation_settings())  # estimation thread only
        self.own_topic = rospy.resolve_name(params.merged_map_topic)
        self._map_pub = rospy.Publisher(params.merged_map_topic, OccupancyGrid, queue_size=50, latch=True)
        self._status_pub = rospy.Publisher('~status', MergeStatus, queue_size=1, latch=True)
        self._tf = None
        if params.publish_tf:
            import tf2_ros   # only needed with publish_tf
            self._tf = tf2_ros.TransformBroadcaster()

    # ------------------------------------------------------------------ logging
    def _warn(self, robot: str, kind: str, text: str) -> None:
        if self._throttle((robot, kind)):
            rospy.logwarn('map_merge: robot [%s]: %s', robot, text)

    # ------------------------------------------------------------------ threads
    def start(self) -> List[threading.Thread]:
        rospy.on_shutdown(self._stop.set)
        loops = [('discovery', self.discover, self.params.discovery_rate, None),
                 ('merging', self.merge_once, self.params.merging_rate, None)]
        if not self.params.known_init_poses:
            loops.append(('estimation', self.estimate_once, self.params.estimation_rate, self._wake_estimation))
        threads = [threading.Thread(target=self._loop, args=loop, name=loop[0], daemon=True) for loop in loops]
        for t in threads:
            t.start()
        return threads

    def stop(self) -> None:
        self._stop.set()
        self._wake_estimation.set()

    def _loop(self, name: str, body, rate: float, wake: Optional[threading.Event]) -> None:
        period = 1.0 / rate
        while not self._stop.is_set() and not rospy.is_shutdown():
            started = time.monotonic()
            try:
                body()
            except Exception as e:   # a bug or bad input in one cycle must not end the loop
                if self._throttle(('', name)):
                    rospy.logerr('map_merge: %s cycle failed: %s: %s', name, type(e).__name__, e)
            remaining = period - (time.monotonic() - started)
            if wake is None:
                self._stop.wait(max(remaining, 0.0))
            else:
                # short slices so a stop request is seen promptly while waiting on the wake event
                deadline = time.monotonic() + max(remaining, 0.0)
                while not self._stop.is_set() and time.monotonic() < deadline:
                    if wake.wait(min(0.2, max(deadline - time.monotonic(), 0.0))):
                        break
                wake.clear()

    # ------------------------------------------------------------------ discovery (§3.2)
    def discover(self) -> None:
        rospy.logdebug('Robot discovery started.')
        try:
            topics = rospy.get_published_topics()
        except Exception as e:   # master unreachable: try again next pass
            self._warn('', 'master', f'cannot list published topics: {e}')
            return
        for name in robot_map_topics(topics, self.params, self.own_topic):
            with self._robots_lock:
                if name in self._by_name:
                    continue
            pose = None
            if self.params.known_init_poses:
                pose = self._read_init_pose(name)
                if pose is None:
                    continue   # not recorded: retried at the next pass, as the original
            self._add_robot(name, pose)

    def _read_init_pose(self, robot: str) -> Optional[InitPose]:
        values = []
        for pname in init_pose_param_names(robot):
            try:
                v = rospy.get_param(pname)
            except KeyError:
                v = None
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                self._warn(robot, 'init_pose',
                           f"Couldn't get initial position for robot [{robot}]: parameter {pname} is "
                           f"{'missing' if v is None else repr(v)}; did you define parameters "
                           f"map_merge/init_pose_[xyz] and init_pose_yaw? Retrying at the next discovery.")
                return None
            values.append(float(v))
        x, y, _z, yaw = values   # z is required (as the original) but unused
        return InitPose(x, y, yaw)

    def _add_robot(self, name: str, pose: Optional[InitPose]) -> None:
        rospy.loginfo('adding robot [%s] to system', name)
        robot = Robot(name, pose)
        map_topic, updates_topic = robot_topics(name, self.params)
        rospy.loginfo('Subscribing to MAP topic: %s.', map_topic)
        robot.subscribers.append(rospy.Subscriber(map_topic, OccupancyGrid, self._on_map, callback_args=robot,
                                                  queue_size=50, buff_size=1 << 24))
        rospy.loginfo('Subscribing to MAP updates topic: %s.', updates_topic)
        robot.subscribers.append(rospy.Subscriber(updates_topic, OccupancyGridUpdate, self._on_update,
                                                  callback_args=robot, queue_size=50, buff_size=1 << 24))
        with self._robots_lock:
            self._robots.insert(0, robot)   # newest first, as the original
            self._by_name[name] = robot

    # ------------------------------------------------------------------ callbacks: convert + store only
    def _on_map(self, msg: OccupancyGrid, robot: Robot) -> None:
        rospy.logdebug('received full map update')
        try:
            grid = grid_from_msg(msg)
        except GridError as e:
            self._warn(robot.name, 'map', f'malformed map refused: {e}')
            return
        first = robot.maps.snapshot() is None
        if not robot.maps.set_full(grid):
            rospy.logdebug('map_merge: robot [%s]: out-of-order older map dropped', robot.name)
        elif first:
            self._wake_estimation.set()

    def _on_update(self, msg: OccupancyGridUpdate, robot: Robot) -> None:
        rospy.logdebug('received partial map update')
        try:
            update = update_from_msg(msg)
        except GridError as e:
            self._warn(robot.name, 'update', f'malformed map update refused: {e}')
            return
        result = robot.maps.apply_update(update)
        if result.reason:
            self._warn(robot.name, 'update', ('' if result.applied else 'map update refused: ') + result.reason)

    # ------------------------------------------------------------------ estimation (§9)
    def _snapshot(self) -> Tuple[List[Robot], List[Optional[Grid]]]:
        with self._robots_lock:
            robots = list(self._robots)
        return robots, [r.maps.snapshot() for r in robots]

    def estimate_once(self) -> None:
        rospy.logdebug('Grid pose estimation started.')
        robots, grids = self._snapshot()
        names = [r.name for r in robots]
        pipeline = self._estimate_pipeline
        pipeline.feed(grids)
        with self._estimate_lock:
            reference = self._reference
        preferred = names.index(reference) if reference in names and grids[names.index(reference)] is not None \
            else None
        result = pipeline.estimate(preferred_reference=preferred)
        for p in result.pairs:
            rospy.logdebug('map_merge: pair %s - %s: %d matches, %d inliers, confidence %.3f, %s%s',
                           names[p.i], names[p.j], p.matches, p.inliers, p.confidence,
                           'accepted' if p.accepted else 'rejected', f' ({p.reason})' if p.reason else '')
        transforms = {n: t for n, t in zip(names, result.transforms) if t is not None}
        with self._estimate_lock:
            self._transforms = transforms
            self._reference = names[result.reference] if result.reference is not None else None
            world_from_merged = self._world_from_merged.copy()
        self._publish_status(robots, grids, result, world_from_merged)

    def _publish_status(self, robots: List[Robot], grids, result, world_from_merged: np.ndarray) -> None:
        status = MergeStatus()   # fresh message each time (latched)
        status.header.stamp = rospy.Time.now()
        status.header.frame_id = self.params.world_frame
        status.estimation_time = float(result.seconds)
        for robot, grid, t in zip(robots, grids, result.transforms):
            entry = RobotMergeStatus(robot_namespace=robot.name, map_frame=frame_of(robot.name, grid),
                                     included=t is not None)
            entry.transform = _transform_msg(world_from_merged @ t) if t is not None else Transform()
            if t is None:
                entry.transform.rotation.w = 1.0
            status.robots.append(entry)
        for p in result.pairs:
            status.pairs.append(PairMatchStatus(robot_a=robots[p.i].name, robot_b=robots[p.j].name,
                                                matches=int(p.matches), inliers=int(p.inliers),
                                                confidence=float(p.confidence), used=bool(p.accepted)))
        self._status_pub.publish(status)

    # ------------------------------------------------------------------ merging (§6)
    def merge_once(self) -> None:
        rospy.logdebug('Map merging started.')
        robots, grids = self._snapshot()
        pipeline = self._merge_pipeline
        pipeline.feed(grids)
        if self.params.known_init_poses:
            pipeline.set_known_poses([r.pose for r in robots], legacy=self.params.legacy_cell_poses)
        else:
            with self._estimate_lock:
                by_name, reference = dict(self._transforms), self._reference
            # transforms follow the robot by name; a grid that became empty since estimation is skipped by compose
            pipeline.set_transforms([by_name.get(r.name) for r in robots])
            names = [r.name for r in robots]
            pipeline.reference = names.index(reference) if reference in names else None
        merged = pipeline.compose(self.params.world_frame)
        if merged is None:
            return   # nothing to publish this cycle, as the original
        world_from_merged = np.eye(3)
        if self.params.origin_mode == 'center':
            old_origin = merged.cell_to_map()
            merged.origin = center_origin(merged)
            world_from_merged = merged.cell_to_map() @ tf.inverse(old_origin)
        with self._estimate_lock:
            self._world_from_merged = world_from_merged
        now = rospy.Time.now()
        rospy.logdebug('all maps merged, publishing')
        self._map_pub.publish(grid_to_msg(merged, stamp=now, frame_id=self.params.world_frame))
        if self._tf is not None:
            self._broadcast_tf(robots, grids, pipeline.transforms, world_from_merged, now)

    def _broadcast_tf(self, robots, grids, transforms, world_from_merged: np.ndarray, now) -> None:
        out = []
        for robot, grid, t in zip(robots, grids, transforms):
            if grid is None or t is None:
                continue
            msg = TransformStamped()
            msg.header.stamp = now
            msg.header.frame_id = self.params.world_frame
            msg.child_frame_id = frame_of(robot.name, grid)
            msg.transform = _transform_msg(world_from_merged @ t)
            out.append(msg)
        if out:
            self._tf.sendTransform(out)


def main() -> None:
    rospy.init_node('map_merge')
    params = MapMergeParams.read(rospy.get_param, '~', warn=rospy.logwarn)
    rospy.loginfo('map_merge: %s', params)
    node = MapMergeNode(params)
    threads = node.start()
    rospy.spin()
    node.stop()
    for t in threads:
        t.join(timeout=1.0)
