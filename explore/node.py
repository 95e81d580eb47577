"""explore ROS node: greedy frontier exploration driving move_base (drop-in for explore_lite's `explore`).

Node name `explore`. Subscribes `<costmap_topic>` (nav_msgs/OccupancyGrid) and, after the first map,
`<costmap_updates_topic>` (map_msgs/OccupancyGridUpdate), both in the node namespace; looks the robot up through tf2
(`global frame` = frame_id of the latest map or update -> `robot_base_frame`); sends goals to the `move_base`
action (move_base_msgs/MoveBaseAction, relative name: remap it); publishes `~frontiers`
(visualization_msgs/MarkerArray) when `visualize`. Extras: `~resume` (std_msgs/Bool), `return_to_init`, and fleet
coordination: goals shared on `team_topic` (geometry_msgs/PoseStamped in `team_frame`) and frontiers already mapped
in the team's merged map (`team_map_topic`) skipped.

Parameters (private, read once at start; a wrong type logs a warning and uses the default; an impossible value
stops the node with one message):
{params}

Threads: subscriber callbacks only store (the map translation happens under the grid lock) or wake the planner;
one planner thread runs every planning cycle (woken by a rospy.Timer at planner_frequency in ROS time, by a
finished goal, or by ~resume), so goals are never sent from inside an actionlib callback.

Layout: this module is the ROS adapter (parameters, map input, tf, start-up, main); planning_loop.py runs the
planner thread and carries out its decisions, team_link.py holds the team topics, nav_client.py talks to
move_base; the decisions themselves are in the ROS-free modules (costmap, frontier_search, goal_logic, team).

Differences from the original, on purpose: a failed or stale robot-pose lookup skips that cycle with a throttled
warning (the original searches from (0,0) and may end exploration); a robot outside the map skips the cycle with a
throttled error (the original stops for good); occupancies up to `free_threshold` count as free, so probabilistic
maps have frontiers; the progress timeout is kept per goal area (±5 cells) so that map noise moving a frontier's
centroid cannot keep an unreachable goal alive; after "Exploration stopped." the cancelled goal's callback does not
start a new plan (the original may continue goal to goal without its timer); the node stays stopped until `~resume`
is true.
`orientation_scale` is read and unused, as in the original.
"""
from __future__ import annotations

import sys
import threading
import time
from typing import Optional, Tuple

import rospy
import tf2_ros
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid
from rospy.numpy_msg import numpy_msg
from std_msgs.msg import Bool
from visualization_msgs.msg import MarkerArray

from multirobot_map_merge.paramdoc import docstring
from multirobot_map_merge.throttle import Throttle

from .costmap import Costmap
from .nav_client import NavClient
from .params import ExploreParams, ParamError, describe
from .planning_loop import PlanningLoop, Pose2
from .team_link import TeamLink

WARN_PERIOD = 5.0        # s (wall) between two identical warnings


__doc__ = __doc__.format(params=docstring(describe()))


def resolve_tf_prefix(frame: str) -> str:
    """tf1's resolve of ``robot_base_frame`` with a ``tf_prefix`` found up the parameter tree (explore.md §3.4)."""
    if frame.startswith('/'):
        return frame[1:]
    key = rospy.search_param('tf_prefix')
    prefix = rospy.get_param(key, '') if key else ''
    prefix = prefix.lstrip('/') if isinstance(prefix, str) else ''
    return f'{prefix}/{frame}' if prefix else frame


def _yaw_quaternion(q) -> Tuple[float, float, float, float]:
    return (q.x, q.y, q.z, q.w)


class ExploreNode:
    """The ROS adapter: map input, tf, start-up; planning runs in ``self.loop`` (planning_loop.py)."""

    def __init__(self, params: ExploreParams) -> None:
        self.p = params
        self._throttle = Throttle(WARN_PERIOD)
        self.costmap = Costmap(params.probability_map, params.free_threshold, params.occupied_threshold,
                               by_threshold=True)
        self.base_frame = resolve_tf_prefix(params.robot_base_frame)
        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(10.0))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self._first_map = threading.Event()
        marker_pub = rospy.Publisher('~frontiers', MarkerArray, queue_size=10) if params.visualize else None
        self.loop = PlanningLoop(params, self.costmap, self.robot_pose, self._throttle, marker_pub)
        # numpy_msg: int8[] cells arrive as an ndarray, not a tuple of Python ints (hundreds of times as long to
        # build: six explorers would spend most of a core on their maps alone); same type and md5 on the wire
        self._map_sub = rospy.Subscriber(params.costmap_topic, numpy_msg(OccupancyGrid), self._on_map,
                                         queue_size=1000, buff_size=1 << 24)
        self._updates_sub = None
        self._resume_sub = None

    # ------------------------------------------------------------------ callbacks: store or wake only
    def _on_map(self, msg: OccupancyGrid) -> None:
        o = msg.info.origin.position
        try:
            invalid = self.costmap.update_full(msg.info.width, msg.info.height, msg.info.resolution, o.x, o.y,
                                               msg.data, msg.header.frame_id)
        except Exception as e:   # CostmapError, or anything else: no exception leaves a callback
            if self._throttle('map'):
                rospy.logwarn('explore: map on %s refused: %s', self._map_sub.resolved_name, e)
            return
        self._warn_invalid(invalid, self._map_sub.resolved_name)
        self._first_map.set()

    def _on_update(self, msg: OccupancyGridUpdate) -> None:
        try:
            invalid = self.costmap.update_partial(msg.x, msg.y, msg.width, msg.height, msg.data, msg.header.frame_id)
        except Exception as e:   # CostmapError, or anything else: no exception leaves a callback
            if self._throttle('update'):
                rospy.logwarn('explore: map update refused: %s', e)
            return
        self._warn_invalid(invalid, self._updates_sub.resolved_name if self._updates_sub else 'map updates')

    def _warn_invalid(self, count: int, topic: str) -> None:
        if count and self._throttle('invalid_cells'):
            rospy.logwarn('explore: %d cell(s) on %s with values outside -1 and 0..100 read as unknown', count, topic)

    def _on_resume(self, msg: Bool) -> None:
        self.loop.request_resume(bool(msg.data))

    # ------------------------------------------------------------------ start-up (blocking, as the original)
    def start(self) -> bool:
        """Wait for the map, tf and move_base, then start planning. False if ROS shut down meanwhile."""
        rospy.loginfo('Waiting for costmap to become available, topic: %s', self._map_sub.resolved_name)
        while not self._first_map.wait(0.1):
            if rospy.is_shutdown():
                return False
        self._updates_sub = rospy.Subscriber(self.p.costmap_updates_topic, numpy_msg(OccupancyGridUpdate),
                                             self._on_update, queue_size=1000, buff_size=1 << 24)
        if not self._wait_for_tf():
            return False
        client = NavClient('move_base')
        if self.p.return_to_init:
            initial_pose = self.robot_pose()
            if initial_pose is None:
                rospy.logwarn('explore: could not look up the initial pose; return_to_init is disabled')
            else:
                rospy.loginfo('explore: initial pose (%.2f, %.2f) in %s stored for return_to_init',
                              initial_pose[0], initial_pose[1], self.costmap.frame_id)
                self.loop.logic.set_initial_pose(initial_pose)
        team = TeamLink(self.p, self.tf_buffer, self._throttle)   # its topics, if configured
        rospy.loginfo('Waiting to connect to move_base server')
        while not client.wait_for_server(1.0):
            if rospy.is_shutdown():
                return False
        rospy.loginfo('Connected to move_base server')
        self._resume_sub = rospy.Subscriber('~resume', Bool, self._on_resume, queue_size=10)
        self.loop.start(client, team)
        return True

    def _wait_for_tf(self) -> bool:
        last_warn = time.monotonic()
        while not rospy.is_shutdown():
            frame = self.costmap.frame_id
            try:
                self.tf_buffer.lookup_transform(frame, self.base_frame, rospy.Time(0))
                return True
            except tf2_ros.TransformException as e:
                err = e
            if time.monotonic() - last_warn > 5.0:
                last_warn = time.monotonic()
                rospy.logwarn('Timed out waiting for transform from %s to %s to become available before '
                              'subscribing to costmap, tf error: %s', self.base_frame, frame, err)
            time.sleep(0.1)   # wall clock: a stalled /clock must not block shutdown
        return False

    def stop_node(self) -> None:
        self.loop.shutdown()

    def robot_pose(self) -> Optional[Pose2]:
        """Robot pose in the map frame, or None (throttled warning) if tf fails or the transform is stale."""
        frame = self.costmap.frame_id
        try:
            t = self.tf_buffer.lookup_transform(frame, self.base_frame, rospy.Time(0))
        except tf2_ros.TransformException as e:
            if self._throttle('tf'):
                rospy.logwarn('explore: no robot pose (%s -> %s): %s; skipping this planning cycle',
                              frame, self.base_frame, e)
            return None
        stamp = t.header.stamp.to_sec()
        now = rospy.get_time()
        # stamp 0: a static transform, always current
        if stamp > 0.0 and now - stamp > self.p.transform_tolerance:
            if self._throttle('tf_stale'):
                rospy.logwarn('Costmap2DClient transform timeout. Current time: %.4f, global_pose stamp: %.4f, '
                              'tolerance: %.4f; skipping this planning cycle', now, stamp,
                              self.p.transform_tolerance)
            return None
        tr = t.transform
        return tr.translation.x, tr.translation.y, _yaw_quaternion(tr.rotation)


def main() -> None:
    rospy.init_node('explore')
    try:
        params = ExploreParams.from_mapping(rospy.get_param('~', {}))
    except ParamError as e:
        rospy.logfatal('explore: %s', e)
        sys.exit(1)
    rospy.loginfo('explore: %s', params)
    node = ExploreNode(params)
    rospy.on_shutdown(node.stop_node)
    if node.start():
        rospy.spin()
    node.stop_node()
