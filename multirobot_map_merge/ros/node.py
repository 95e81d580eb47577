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
    arrives; it keeps the reference robot while that robot stays in the merge, and it is skipped while the robots
    and their maps are unchanged since the last estimation (same input, same placement). Each estimation first
    re-checks the robots placed by the last one against the union of the others (tracking: a placement is kept,
    refined, while it passes the acceptance rules, and dropped at once when it does not), then matches the robots
    not placed against the union of the placed ones (estimation.py);
  * merging: every 1/merging_rate s: the newest maps, the last estimated transforms (kept per robot name, so they
    follow the robot when the list grows), compose, publish (and ~status after a new estimation, so that its
    transforms match the merged map published with it).
Locks: `_robots_lock` owns the robot list; each RobotMap has its own lock (copy-on-write grids); `_estimate_lock`
owns the estimated transforms, the reference robot and the pending status. No lock is held while estimating or
composing. Each pipeline has one owner thread.
Timing: the loops are paced on ROS time, as the original's ros::Rate, so they follow /clock under use_sim_time.
Until /clock has started (ROS time 0) they are paced on the wall clock; a jump back in ROS time starts a new period
instead of raising. They wait in slices of at most 0.1 s (wall) and wake on a stop request, so SIGINT ends the node
within a fraction of a second: main() waits at most 0.5 s for a cycle still running (an estimation of many maps can
take seconds) and exits without it, and a watchdog ends the process 1.6 s after the shutdown request whatever still
runs. Rates are checked positive at start (no zero-period loop). An estimation that takes longer than half its
period (many robots) is followed by a rest of half the (wall) time it took, so that estimation uses at most about
two thirds of the node's time and merging keeps its rate; the correlation searches of one estimation stop after
node_params.SEARCH_BUDGET s (the rest are searched in the next ones), so that robots that match by descriptors join
quickly. An unchanged merge (same maps, same transforms) is re-sent, not recomposed.

Differences from the original, on purpose (see also robot_maps.py): init poses are metres/radians of the robot map
frame in the world unless `~legacy_cell_poses`; a malformed map or update is refused with a throttled warning naming
the robot instead of being merged; the reference robot does not jump between estimations; a robot whose init pose is
missing is retried at every discovery pass (as the original) with a throttled warning; the tf child frame is the
robot map's header.frame_id (or `<robot_ns>/map` when empty) without a leading '/', as tf2 requires. Cell values
outside -1 and 0..100 are read as unknown, and a robot whose map or placement would make the merged grid unusable
(non-finite, over ~max_merged_cells) is left out of that cycle, each with a throttled warning naming the robot
(admission.py, compose.select_parts); the other robots are merged as usual.
`~status` transforms are robot map frame -> world_frame as placed by the latest merge cycle.
"""
from __future__ import annotations

import copy
import ctypes
import ctypes.util
import logging
import math
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np
import rospy
from geometry_msgs.msg import Transform, TransformStamped
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid
from rospy.numpy_msg import numpy_msg

from .. import transforms as tf
from ..admission import describe_invalid
from .discovery import append, init_pose_param_names, robot_map_topics, robot_topics
from ..estimation.features import FeatureCache
from ..grid import Grid, GridError
from ..known_poses import InitPose
from ..msg import MergeStatus, PairMatchStatus, RobotMergeStatus
from .params import MapMergeParams
from ..pipeline import MergingPipeline
from .robot_maps import RobotMap
from .conversions import grid_from_msg, grid_to_msg, update_from_msg
from ..throttle import Throttle

WARN_PERIOD = 10.0      # s between two identical warnings (same robot, same kind)
CACHE_SPARE = 4         # feature cache capacity: one entry per robot and these
ESTIMATION_REST = 0.5   # an estimation that took b s (wall) is followed by a rest of b * this at least
SLICE = 0.1             # s (wall) between two checks of the stop flag while a loop waits on simulated time
EXIT_GRACE = 0.5        # s (wall) main() waits for running cycles after shutdown before exiting without them
HARD_EXIT = 1.6         # s (wall) after a shutdown request the process ends even if rospy's shutdown still runs


def _params_doc() -> str:
    return '\n'.join(f'  ~{name} ({kind}, default {default!r}): {doc}'
                     for name, kind, default, doc in MapMergeParams.fields_doc())


__doc__ = __doc__.format(params=_params_doc())


class LoopPacer:
    """Paces one loop at a rate in ROS time, as ros::Rate does (so it follows /clock under use_sim_time).

    `wait()` returns when the period since `start_cycle()` has passed (and, with `rest_share`, at least that share
    of the wall time the cycle's work took), or at once when the loop's `kick` event is set (a stop request, or the
    estimation's wake-up). Under simulated time it waits on rospy's clock condition, which every /clock message
    notifies, in slices of at most SLICE wall seconds; until /clock has started it paces on the wall clock; when
    ROS time jumps back (bag loop, simulator reset) the period restarts instead of raising as rospy.Rate would.
    """

    def __init__(self, rate: float, kick: threading.Event, rest_share: float = 0.0) -> None:
        if not (math.isfinite(rate) and rate > 0.0):
            raise ValueError(f'loop rate {rate} is not a positive finite number')   # no zero-period loop
        self.period = 1.0 / rate
        self.kick = kick
        self.rest_share = rest_share   # after a cycle that took b seconds, rest at least rest_share * b
        self._ros0 = 0.0
        self._wall0 = 0.0

    def start_cycle(self) -> None:
        self._ros0, self._wall0 = rospy.get_time(), time.monotonic()

    def _elapsed(self) -> float:
        """Seconds since start_cycle(): ROS time, or wall time while there is none; -1 if ROS time went back."""
        now = rospy.get_time()
        if self._ros0 > 0.0 and now > 0.0:
            return now - self._ros0 if now >= self._ros0 else -1.0
        return time.monotonic() - self._wall0   # no ROS time yet (sim time, /clock not started)

    def wait(self) -> None:
        cond = rospy.rostime.get_rostime_cond()
        # the rest is in wall time: it keeps the CPU share down, whatever the simulated time's speed-up
        rest_until = time.monotonic() + (time.monotonic() - self._wall0) * self.rest_share
        while not self.kick.is_set():
            elapsed = self._elapsed()
            if elapsed < 0.0:
                break   # ROS time moved backwards (bag loop, simulator reset): start a new period now
            remaining = max(self.period - elapsed, rest_until - time.monotonic())
            if remaining <= 0.0:
                break
            if rospy.rostime.is_wallclock():
                self.kick.wait(min(remaining, 1.0))
            else:
                with cond:   # kick() notifies under the same lock: no wake-up is lost
                    if not self.kick.is_set():
                        cond.wait(SLICE)
        self.kick.clear()

    @staticmethod
    def wake(event: threading.Event) -> None:
        """Set a loop's kick event and wake it if it waits on simulated time."""
        event.set()
        cond = rospy.rostime.get_rostime_cond()
        with cond:
            cond.notify_all()


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


def same_inputs(a: Tuple[List[str], List[Optional[Grid]]], b: Tuple[List[str], List[Optional[Grid]]]) -> bool:
    """True if two (robot names, grids) snapshots hold the same robots with identical maps (content, geometry)."""
    if a[0] != b[0]:
        return False
    for ga, gb in zip(a[1], b[1]):
        if ga is gb:
            continue
        if ga is None or gb is None or ga.resolution != gb.resolution or ga.origin != gb.origin \
                or not np.array_equal(ga.data, gb.data):
            return False
    return True


def same_merge_inputs(a: tuple, b: tuple) -> bool:
    """Two merge inputs (names, grids, transforms, reference) that compose to the same merged grid."""
    if a[3] != b[3] or len(a[2]) != len(b[2]):
        return False
    for ta, tb in zip(a[2], b[2]):
        if (ta is None) != (tb is None) or (ta is not None and not np.array_equal(ta, tb)):
            return False
    return same_inputs((a[0], a[1]), (b[0], b[1]))


def restamped(msg: OccupancyGrid, stamp) -> OccupancyGrid:
    """A fresh copy of a merged map message with a new stamp; the (never modified) data list is shared."""
    out = OccupancyGrid()
    out.header.frame_id = msg.header.frame_id
    out.header.stamp = stamp
    out.info = copy.deepcopy(msg.info)
    out.info.map_load_time = stamp
    out.data = msg.data
    return out


def frame_of(robot: str, grid: Optional[Grid]) -> str:
    frame = grid.frame_id if grid is not None and grid.frame_id else append(robot, 'map')
    return frame.lstrip('/')


class MapMergeNode:
    def __init__(self, params: MapMergeParams) -> None:
        self.params = params
        self._stop = threading.Event()
        self._kicks: Dict[str, threading.Event] = {n: threading.Event() for n in ('discovery', 'merging', 'estimation')}
        self._throttle = Throttle(WARN_PERIOD)
        self._robots_lock = threading.Lock()          # owns _robots (newest first, as the original) and _by_name
        self._robots: List[Robot] = []
        self._by_name: Dict[str, Robot] = {}
        self._estimate_lock = threading.Lock()        # owns _transforms, _reference, _pending_status
        self._transforms: Dict[str, np.ndarray] = {}  # robot name -> metric transform map frame -> merged frame
        self._reference: Optional[str] = None
        self._pending_status = None   # (MergeStatus, transforms): built by estimation, completed + sent by merging
        self._merge_pipeline = MergingPipeline(params.estimation_settings())   # merging thread only
        self._estimate_pipeline = MergingPipeline(params.estimation_settings())  # estimation thread only
        self._estimated_inputs: Optional[Tuple[List[str], List[Optional[Grid]]]] = None   # estimation thread only
        self._cache_capacity = 0                      # estimation thread only
        self._last_merge = None                       # merging thread only: (inputs, message, world_from_merged)
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
        rospy.on_shutdown(self.stop)
        loops = [('discovery', self.discover, LoopPacer(self.params.discovery_rate, self._kicks['discovery'])),
                 ('merging', self.merge_once, LoopPacer(self.params.merging_rate, self._kicks['merging']))]
        if not self.params.known_init_poses:
            # an estimation of many maps can take longer than its period: rest half as long as it took, so that
            # it uses at most about two thirds of the node's time (the original would run it back to back)
            loops.append(('estimation', self.estimate_once,
                          LoopPacer(self.params.estimation_rate, self._kicks['estimation'], ESTIMATION_REST)))
        threads = [threading.Thread(target=self._loop, args=loop, name=loop[0], daemon=True) for loop in loops]
        for t in threads:
            t.start()
        return threads

    def stop(self) -> None:
        self._stop.set()
        for kick in self._kicks.values():
            LoopPacer.wake(kick)

    def stopped(self) -> bool:
        return self._stop.is_set() or rospy.is_shutdown()

    def wait_for_shutdown(self) -> None:
        """Block until stop() or a ROS shutdown (rospy.spin() would notice the latter only every 0.5 s)."""
        while not self.stopped():
            self._stop.wait(0.5)

    def _loop(self, name: str, body, pacer: LoopPacer) -> None:
        while not self.stopped():
            pacer.start_cycle()
            try:
                body()
            except Exception as e:   # a bug or bad input in one cycle must not end the loop
                if self._throttle(('', name)):
                    rospy.logerr('map_merge: %s cycle failed: %s: %s', name, type(e).__name__, e)
            if self.stopped():
                break
            pacer.wait()

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
        # numpy_msg: the int8[] data arrives as an ndarray (no per-cell Python ints); same type and md5 on the wire
        robot.subscribers.append(rospy.Subscriber(map_topic, numpy_msg(OccupancyGrid), self._on_map,
                                                  callback_args=robot, queue_size=50, buff_size=1 << 24))
        rospy.loginfo('Subscribing to MAP updates topic: %s.', updates_topic)
        robot.subscribers.append(rospy.Subscriber(updates_topic, numpy_msg(OccupancyGridUpdate), self._on_update,
                                                  callback_args=robot, queue_size=50, buff_size=1 << 24))
        with self._robots_lock:
            self._robots.insert(0, robot)   # newest first, as the original
            self._by_name[name] = robot

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
            LoopPacer.wake(self._kicks['estimation'])   # estimate at once instead of up to 1/estimation_rate later

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

    # ------------------------------------------------------------------ estimation (§9)
    def _snapshot(self) -> Tuple[List[Robot], List[Optional[Grid]]]:
        with self._robots_lock:
            robots = list(self._robots)
        return robots, [r.maps.snapshot() for r in robots]

    def estimate_once(self) -> None:
        rospy.logdebug('Grid pose estimation started.')
        robots, grids = self._snapshot()
        names = [r.name for r in robots]
        if self._estimated_inputs is not None and same_inputs(self._estimated_inputs, (names, grids)):
            # the same maps give the same placement: keep it (static maps, e.g. map_server, cost no CPU)
            rospy.logdebug('map_merge: maps unchanged since the last estimation; transforms kept')
            return
        pipeline = self._estimate_pipeline
        # Features are cached per map content. Live maps change between estimations, so only the current ones are
        # worth keeping: a capacity just above the robot count keeps memory flat (a prepared map of 200k cells
        # takes ~4 MB; the core's default capacity, 256, could hold 1 GB of stale ones). Robots only join, and
        # mostly together: the cache is rebuilt (features recomputed once) when their number changes.
        capacity = len(names) + CACHE_SPARE
        if capacity != self._cache_capacity:
            pipeline.cache, self._cache_capacity = FeatureCache(capacity=capacity), capacity
        pipeline.feed(grids)
        self._warn_admission(robots, pipeline)   # names the robots whose maps cannot be matched (admission.py)
        with self._estimate_lock:
            reference = self._reference
            previous = [self._transforms.get(n) for n in names]
        preferred = names.index(reference) if reference in names and grids[names.index(reference)] is not None \
            else None
        # a robot placed before stays placed while its map still agrees with the others (tracking.py)
        result = pipeline.estimate(preferred_reference=preferred, previous=previous, names=names)
        for p in result.pairs:
            rospy.logdebug('map_merge: pair %s - %s: %d matches, %d inliers, confidence %.3f, %s%s',
                           names[p.i], names[p.j], p.matches, p.inliers, p.confidence,
                           'accepted' if p.accepted else 'rejected', f' ({p.reason})' if p.reason else '')
        self._estimated_inputs = (names, grids)
        transforms = {n: t for n, t in zip(names, result.transforms) if t is not None}
        status = self._status_of(robots, grids, result)
        with self._estimate_lock:
            self._transforms = transforms
            self._reference = names[result.reference] if result.reference is not None else None
            self._pending_status = status   # sent by the next merge cycle, with that cycle's placement

    def _status_of(self, robots: List[Robot], grids, result) -> Tuple[MergeStatus, List[Optional[np.ndarray]]]:
        """A fresh MergeStatus (robot transforms still to fill in) and the estimated transform of each entry."""
        status = MergeStatus()   # fresh message each time (latched)
        status.header.frame_id = self.params.world_frame
        status.estimation_time = float(result.seconds)
        for robot, grid, t in zip(robots, grids, result.transforms):
            status.robots.append(RobotMergeStatus(robot_namespace=robot.name, map_frame=frame_of(robot.name, grid),
                                                  included=t is not None))
        for p in result.pairs:
            used = bool(p.accepted) and result.transforms[p.i] is not None and result.transforms[p.j] is not None
            status.pairs.append(PairMatchStatus(robot_a=robots[p.i].name, robot_b=robots[p.j].name,
                                                matches=int(p.matches), inliers=int(p.inliers),
                                                confidence=float(p.confidence), used=used))
        return status, list(result.transforms)

    def _publish_status(self, world_from_merged: np.ndarray, stamp) -> None:
        with self._estimate_lock:
            pending, self._pending_status = self._pending_status, None
        if pending is None:
            return
        status, transforms = pending
        status.header.stamp = stamp
        for entry, t in zip(status.robots, transforms):
            if t is not None:
                entry.transform = _transform_msg(world_from_merged @ t)
            else:
                entry.transform.rotation.w = 1.0   # identity, not an all-zero quaternion
        self._status_pub.publish(status)

    # ------------------------------------------------------------------ merging (§6)
    def merge_once(self) -> None:
        rospy.logdebug('Map merging started.')
        robots, grids = self._snapshot()
        pipeline = self._merge_pipeline
        pipeline.feed(grids, matching=False)   # transforms come from the estimation or known poses
        self._warn_admission(robots, pipeline)
        if self.params.known_init_poses:
            pipeline.set_known_poses([r.pose for r in robots], legacy=self.params.legacy_cell_poses)
        else:
            with self._estimate_lock:
                by_name, reference = dict(self._transforms), self._reference
            # transforms follow the robot by name; a grid that became empty since estimation is skipped by compose
            pipeline.set_transforms([by_name.get(r.name) for r in robots])
            names = [r.name for r in robots]
            pipeline.reference = names.index(reference) if reference in names else None
        inputs = ([r.name for r in robots], grids, pipeline.transforms, pipeline.reference)
        now = rospy.Time.now()
        last = self._last_merge
        if last is not None and same_merge_inputs(last[0], inputs):
            # nothing changed (static maps, or maps republished unchanged): re-send the last merge, freshly stamped
            _, msg, world_from_merged = last
            msg = restamped(msg, now) if msg is not None else None
        else:
            merged = pipeline.compose(self.params.world_frame, self.params.max_merged_cells)
            for k, reason in pipeline.left_out.items():
                self._warn(robots[k].name, 'left_out', f'left out of this merge: {reason}')
            world_from_merged = np.eye(3)
            msg = None
            if merged is not None:
                if self.params.origin_mode == 'center':
                    old_origin = merged.cell_to_map()
                    merged.origin = center_origin(merged)
                    world_from_merged = merged.cell_to_map() @ tf.inverse(old_origin)
                msg = grid_to_msg(merged, stamp=now, frame_id=self.params.world_frame)
            self._last_merge = (inputs, msg, world_from_merged)
        if msg is not None:
            rospy.logdebug('all maps merged, publishing')
            self._map_pub.publish(msg)
            if self._tf is not None:
                placed = [None if k in pipeline.left_out else t for k, t in enumerate(pipeline.transforms)]
                self._broadcast_tf(robots, grids, placed, world_from_merged, now)
        # else: nothing to publish this cycle, as the original
        self._publish_status(world_from_merged, now)

    def _warn_admission(self, robots: List[Robot], pipeline: MergingPipeline) -> None:
        """Name the robots whose maps the pipeline's admission normalised or refused (admission.py)."""
        for k, count in pipeline.invalid_cells.items():
            self._warn(robots[k].name, 'cells', describe_invalid(count))
        for k, reason in pipeline.refused.items():
            self._warn(robots[k].name, 'refused', f'map left out of the estimation: {reason}')

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


def limit_malloc_arenas() -> None:
    """glibc gives each thread (rospy runs one per connection) its own malloc arena, and after a large block is
    freed it serves blocks up to that size from the arenas instead of mmap: freed numpy arrays of a long run then
    stay resident. Two arenas and a fixed 128 KiB mmap threshold keep RSS flat (measured: 640 -> 260 MiB after
    4 minutes with 30 live robots). No-op where libc has no mallopt."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library('c') or 'libc.so.6')
        m_trim_threshold, m_mmap_threshold, m_arena_max = -1, -3, -8   # glibc's malloc.h
        libc.mallopt(m_arena_max, 2)
        libc.mallopt(m_mmap_threshold, 128 * 1024)
        libc.mallopt(m_trim_threshold, 128 * 1024)
    except (OSError, AttributeError):
        pass


def _exit_now() -> None:
    logging.shutdown()   # flush the log files
    os._exit(0)


def _start_exit_watchdog() -> None:
    """rospy's shutdown unregisters every topic from the master and joins its threads (up to 5 s each): with many
    robots on a loaded machine that alone can approach 2 s. The issue wants the node gone within 2 s of SIGINT."""
    timer = threading.Timer(HARD_EXIT, _exit_now)
    timer.daemon = True
    timer.start()


def main() -> None:
    limit_malloc_arenas()   # first: arenas are created by the threads started from here on
    rospy.init_node('map_merge')
    rospy.on_shutdown(_start_exit_watchdog)   # the first shutdown hook: runs before rospy's own clean-up
    params = MapMergeParams.read(rospy.get_param, '~', warn=rospy.logwarn)
    rospy.loginfo('map_merge: %s', params)
    node = MapMergeNode(params)
    threads = node.start()
    node.wait_for_shutdown()
    node.stop()
    deadline = time.monotonic() + EXIT_GRACE
    for t in threads:
        t.join(timeout=max(deadline - time.monotonic(), 0.0))
    busy = [t.name for t in threads if t.is_alive()]
    if busy:
        # a long estimation cannot be interrupted, and its worker pool would be joined at interpreter exit
        rospy.loginfo('map_merge: exiting without waiting for the running %s cycle', ', '.join(busy))
        _exit_now()
