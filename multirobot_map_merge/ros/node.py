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
    not placed against the union of the placed ones (estimation/); a robot placed for the first time is published
    once a later estimation confirms it on more area shared with the published ones (estimation/confirmation.py),
    the next one coming at most CONFIRM_S later;
  * merging: every 1/merging_rate s: the newest maps, the last estimated transforms (kept per robot name, so they
    follow the robot when the list grows), compose, publish (and ~status after a new estimation, so that its
    transforms match the merged map published with it).
Locks: robots.Robots owns the robot list (its lock; each RobotMap has its own); `_estimate_lock` owns the estimated
transforms, the reference robot and the pending status. No lock is held while estimating or composing. Each
pipeline has one owner thread.
Timing (pacing.py, process.py): the loops are paced on ROS time, as the original's ros::Rate, so they follow /clock
under use_sim_time. Until /clock has started (ROS time 0) they are paced on the wall clock; a jump back in ROS time
starts a new period instead of raising. They wait in slices of at most 0.1 s (wall) and wake on a stop request, so
SIGINT ends the node within a fraction of a second: main() waits at most 0.5 s for a cycle still running (an
estimation of many maps can take seconds) and exits without it, and a watchdog ends the process 1.6 s after the
shutdown request whatever still runs. Rates are checked positive at start (no zero-period loop). An estimation that
takes longer than half its period (many robots) is followed by a rest of half the (wall) time it took, so that
estimation uses at most about two thirds of the node's time and merging keeps its rate; the correlation searches of
one estimation stop after params.SEARCH_BUDGET s (the rest are searched in the next ones; on the same maps each
has twice the budget of the last, the third no limit), so that robots that match by descriptors join quickly; a cut
only delays a robot, what is placed passes the same rules (estimation/growth.py). An unchanged merge (same maps,
same transforms) is re-sent, not recomposed.

Differences from the original, on purpose (see also robot_maps.py): init poses are metres/radians of the robot map
frame in the world unless `~legacy_cell_poses`; a malformed map or update is refused with a throttled warning naming
the robot instead of being merged; the reference robot does not jump between estimations; a robot whose init pose is
missing is retried at every discovery pass (as the original) with a throttled warning; the tf child frame is the
robot map's header.frame_id (or `<robot_ns>/map` when empty) without a leading '/', as tf2 requires. Cell values
outside -1 and 0..100 are read as unknown, and a robot whose map or placement would make the merged grid unusable
(non-finite, over ~max_merged_cells) is left out of that cycle, each with a throttled warning naming the robot
(admission.py, compose.select_parts); the other robots are merged as usual. Maps are matched as trinary through
~free_threshold and ~occupied_threshold (probabilistic maps, e.g. Cartographer's, are placed too); the merged map
keeps the values as published, combined as the original (maximum).
`~status` transforms are robot map frame -> world_frame as placed by the latest merge cycle.
Diagnostic: with the environment variable MAP_MERGE_RECORD_ESTIMATIONS=DIR the node records every estimation's
inputs and result into DIR (recording.py; scripts/replay_estimations.py estimates them again offline).
"""
from __future__ import annotations

import threading
import time
from typing import Dict, List, Optional

import numpy as np
import rospy
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import OccupancyGrid
from rospy.numpy_msg import numpy_msg

from .. import transforms as tf
from ..admission import describe_invalid
from ..estimation.features import FeatureCache
from ..msg import MergeStatus
from ..paramdoc import docstring
from ..pipeline import MergingPipeline
from ..recording import EstimationRecorder
from ..throttle import Throttle
from .conversions import center_origin, grid_to_msg, restamped, transform_msg
from .pacing import LoopPacer
from .params import MapMergeParams
from .process import exit_now, limit_malloc_arenas, start_exit_watchdog
from .robot_maps import EstimationGate, same_merge_inputs
from .robots import Robot, Robots
from .status import fill_transforms, frame_of, status_of

WARN_PERIOD = 10.0      # s between two identical warnings (same robot, same kind)
CACHE_SPARE = 4         # feature cache capacity: one entry per robot and these
ESTIMATION_REST = 0.5   # an estimation that took b s (wall) is followed by a rest of b * this at least
CONFIRM_S = 2.0         # s (ROS time) at most from an estimation that placed a robot for the first time to the next
EXIT_GRACE = 0.5        # s (wall) main() waits for running cycles after shutdown before exiting without them


__doc__ = __doc__.format(params=docstring(MapMergeParams.describe()))


class MapMergeNode:
    def __init__(self, params: MapMergeParams) -> None:
        self.params = params
        self._stop = threading.Event()
        self._kicks: Dict[str, threading.Event] = {n: threading.Event() for n in ('discovery', 'merging', 'estimation')}
        self._estimation_pacer: Optional[LoopPacer] = None
        self._throttle = Throttle(WARN_PERIOD)
        self.own_topic = rospy.resolve_name(params.merged_map_topic)
        self._robots = Robots(params, self.own_topic, self._warn,
                              on_first_map=lambda: LoopPacer.wake(self._kicks['estimation']))
        self._estimate_lock = threading.Lock()        # owns _transforms, _reference, _pending_status
        self._transforms: Dict[str, np.ndarray] = {}  # robot name -> metric transform map frame -> merged frame
        self._reference: Optional[str] = None
        self._pending_status = None   # (MergeStatus, transforms): built by estimation, completed + sent by merging
        self._merge_pipeline = MergingPipeline(params.estimation_settings())   # merging thread only
        self._estimate_pipeline = MergingPipeline(params.estimation_settings())  # estimation thread only
        self._estimation_gate = EstimationGate()   # estimation thread only
        self._cache_capacity = 0                      # estimation thread only
        self._recorder = EstimationRecorder.from_environment()   # estimation thread only (a diagnostic)
        self._last_merge = None                       # merging thread only: (inputs, message, world_from_merged)
        self._map_pub = rospy.Publisher(params.merged_map_topic, OccupancyGrid, queue_size=50, latch=True)
        # merged maps go out as numpy_msg messages: the same bytes, serialized ~100 times faster (conversions.py)
        self._packed_map = numpy_msg(OccupancyGrid)
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
        loops = [('discovery', self._robots.discover, LoopPacer(self.params.discovery_rate, self._kicks['discovery'])),
                 ('merging', self.merge_once, LoopPacer(self.params.merging_rate, self._kicks['merging']))]
        if not self.params.known_init_poses:
            # an estimation of many maps can take longer than its period: rest half as long as it took, so that
            # it uses at most about two thirds of the node's time (the original would run it back to back)
            self._estimation_pacer = LoopPacer(self.params.estimation_rate, self._kicks['estimation'], ESTIMATION_REST)
            loops.append(('estimation', self.estimate_once, self._estimation_pacer))
        threads = [threading.Thread(target=self._loop, args=loop, name=loop[0], daemon=True) for loop in loops]
        for t in threads:
            t.start()
        return threads

    def stop(self) -> None:
        self._stop.set()
        if self._recorder is not None:
            self._recorder.close()
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

    # ------------------------------------------------------------------ estimation (§9)
    def estimate_once(self) -> None:
        rospy.logdebug('Grid pose estimation started.')
        robots, grids = self._robots.snapshot()
        names = [r.name for r in robots]
        inputs = (names, grids)
        if not self._estimation_gate.wanted(inputs):
            # the same maps give the same placement: keep it (static maps, e.g. map_server, cost no CPU)
            rospy.logdebug('map_merge: maps unchanged over the last estimations; transforms kept')
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
        now, started = rospy.get_time(), time.perf_counter()
        result = pipeline.estimate(preferred_reference=preferred, previous=previous, names=names, now=now)
        if self._recorder is not None:
            self._recorder.record(now, names, grids, reference if preferred is not None else None, previous, result,
                                  time.perf_counter() - started)
        for p in result.pairs:
            rospy.logdebug('map_merge: pair %s - %s: %d matches, %d inliers, confidence %.3f, %s%s',
                           names[p.i], names[p.j], p.matches, p.inliers, p.confidence,
                           'accepted' if p.accepted else 'rejected', f' ({p.reason})' if p.reason else '')
        self._estimation_gate.estimated(inputs, complete=not result.postponed and not result.held)
        if result.held and self._estimation_pacer is not None:
            # a new placement is published once a later estimation confirms it (estimation/confirmation.py): with
            # a slow estimation_rate (the original's launch file: 0.1 Hz) that one comes after CONFIRM_S
            self._estimation_pacer.sooner = CONFIRM_S
        transforms = {n: t for n, t in zip(names, result.transforms) if t is not None}
        status = status_of([r.name for r in robots], grids, result, self.params.world_frame)
        with self._estimate_lock:
            self._transforms = transforms
            self._reference = names[result.reference] if result.reference is not None else None
            self._pending_status = status   # sent by the next merge cycle, with that cycle's placement

    def _publish_status(self, pending, world_from_merged: np.ndarray, stamp) -> None:
        """Send the status an estimation left (taken with the transforms this cycle composed with, or None)."""
        if pending is None:
            return
        status, transforms = pending
        fill_transforms(status, transforms, world_from_merged, stamp)
        self._status_pub.publish(status)

    # ------------------------------------------------------------------ merging (§6)
    def merge_once(self) -> None:
        rospy.logdebug('Map merging started.')
        robots, grids = self._robots.snapshot()
        pipeline = self._merge_pipeline
        pipeline.feed(grids, matching=False)   # transforms come from the estimation or known poses
        self._warn_admission(robots, pipeline)
        pending = None
        if self.params.known_init_poses:
            pipeline.set_known_poses([r.pose for r in robots], legacy=self.params.legacy_cell_poses)
        else:
            with self._estimate_lock:
                # the status is taken with the transforms it describes: one taken later could come from an
                # estimation that ended while this cycle composed (a loaded machine: a status placing three robots
                # went out with a merged map composed of one)
                by_name, reference = dict(self._transforms), self._reference
                pending, self._pending_status = self._pending_status, None
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
                msg = grid_to_msg(merged, stamp=now, frame_id=self.params.world_frame,
                                  packed_class=self._packed_map)
            self._last_merge = (inputs, msg, world_from_merged)
        if msg is not None:
            rospy.logdebug('all maps merged, publishing')
            self._map_pub.publish(msg)
            if self._tf is not None:
                placed = [None if k in pipeline.left_out else t for k, t in enumerate(pipeline.transforms)]
                self._broadcast_tf(robots, grids, placed, world_from_merged, now)
        # else: nothing to publish this cycle, as the original
        self._publish_status(pending, world_from_merged, now)

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
            msg.transform = transform_msg(world_from_merged @ t)
            out.append(msg)
        if out:
            self._tf.sendTransform(out)


def main() -> None:
    limit_malloc_arenas()   # first: arenas are created by the threads started from here on
    rospy.init_node('map_merge')
    rospy.on_shutdown(start_exit_watchdog)   # the first shutdown hook: runs before rospy's own clean-up
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
        exit_now()
