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

import math
import sys
import threading
import time
from typing import List, Optional, Tuple

import rospy
import tf2_ros
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid
from std_msgs.msg import Bool
from visualization_msgs.msg import MarkerArray

from multirobot_map_merge.throttle import Throttle

from .costmap import Costmap
from .frontier_search import Frontier, FrontierSearch
from .goal_logic import GoalLogic, PlanAction, apply_team_penalty
from .markers import frontier_markers
from .nav_client import NavClient, pose_goal, status_name
from .params import ExploreParams, ParamError, describe
from .team import drop_explored_by_team
from .team_link import TeamLink

WARN_PERIOD = 5.0        # s (wall) between two identical warnings
Pose2 = Tuple[float, float, Tuple[float, float, float, float]]   # x, y, quaternion (x, y, z, w)


def _params_doc() -> str:
    rows = []
    for d in describe():
        unit = f' [{d.unit}]' if d.unit else ''
        rows.append(f'  ~{d.name} ({d.type}, default {d.default!r}){unit}: {d.doc}')
    return '\n'.join(rows)


__doc__ = __doc__.format(params=_params_doc())


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
    def __init__(self, params: ExploreParams) -> None:
        self.p = params
        self._throttle = Throttle(WARN_PERIOD)
        self.costmap = Costmap(params.probability_map, params.free_threshold, params.occupied_threshold,
                               by_threshold=True)
        self.search = FrontierSearch(self.costmap, params.potential_scale, params.gain_scale,
                                     params.min_frontier_size)
        self.logic = GoalLogic(params.progress_timeout, params.return_to_init)
        self.base_frame = resolve_tf_prefix(params.robot_base_frame)
        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(10.0))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self._first_map = threading.Event()
        self._wake = threading.Event()
        self._shutdown = threading.Event()
        # Planner state, owned by the planner thread; _state_lock guards what callbacks hand over to it.
        self._state_lock = threading.Lock()
        self._resume_request: Optional[bool] = None   # set by ~resume, consumed by the planner
        self._exploring = False
        self._timer: Optional[rospy.Timer] = None
        self._goal: Optional[Tuple[float, float]] = None   # current exploration goal (global frame)
        self._goal_chosen_at = math.inf                    # ROS time it was chosen
        self._initial_pose: Optional[Pose2] = None
        self._marker_count = 0
        self.client: Optional[NavClient] = None
        self._marker_pub = rospy.Publisher('~frontiers', MarkerArray, queue_size=10) if params.visualize else None
        self.team: Optional[TeamLink] = None
        self._map_sub = rospy.Subscriber(params.costmap_topic, OccupancyGrid, self._on_map, queue_size=1000,
                                         buff_size=1 << 24)
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

    def _on_goal_done(self, target: Tuple[float, float], state: int, _result) -> None:
        # actionlib's thread: record the result and wake the planner, never send a goal from here
        self.logic.on_goal_done(state, target)
        rospy.logdebug('explore: goal (%.2f, %.2f) done with status %d', target[0], target[1], state)
        self._wake.set()

    def _on_return_done(self, state: int, _result) -> None:
        rospy.loginfo('explore: return to the initial pose finished with status %s', status_name(state))

    def _on_resume(self, msg: Bool) -> None:
        with self._state_lock:
            self._resume_request = bool(msg.data)
        self._wake.set()

    def _on_tick(self, _event) -> None:
        self._wake.set()

    # ------------------------------------------------------------------ start-up (blocking, as the original)
    def start(self) -> bool:
        """Wait for the map, tf and move_base, then start planning. False if ROS shut down meanwhile."""
        rospy.loginfo('Waiting for costmap to become available, topic: %s', self._map_sub.resolved_name)
        while not self._first_map.wait(0.1):
            if rospy.is_shutdown():
                return False
        self._updates_sub = rospy.Subscriber(self.p.costmap_updates_topic, OccupancyGridUpdate, self._on_update,
                                             queue_size=1000, buff_size=1 << 24)
        if not self._wait_for_tf():
            return False
        self.client = NavClient('move_base')
        if self.p.return_to_init:
            self._initial_pose = self.robot_pose()
            if self._initial_pose is None:
                rospy.logwarn('explore: could not look up the initial pose; return_to_init is disabled')
            else:
                rospy.loginfo('explore: initial pose (%.2f, %.2f) in %s stored for return_to_init',
                              self._initial_pose[0], self._initial_pose[1], self.costmap.frame_id)
                self.logic.set_initial_pose(self._initial_pose)
        self.team = TeamLink(self.p, self.tf_buffer, self._throttle)   # its topics, if configured
        rospy.loginfo('Waiting to connect to move_base server')
        while not self.client.wait_for_server(1.0):
            if rospy.is_shutdown():
                return False
        rospy.loginfo('Connected to move_base server')
        self._resume_sub = rospy.Subscriber('~resume', Bool, self._on_resume, queue_size=10)
        with self._state_lock:
            self._exploring = True
            self._start_timer()
        threading.Thread(target=self._planner_loop, name='planner', daemon=True).start()
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
        self._shutdown.set()
        self._wake.set()

    # ------------------------------------------------------------------ planner thread
    def _start_timer(self) -> None:
        if self._timer is None:
            self._timer = rospy.Timer(rospy.Duration(1.0 / self.p.planner_frequency), self._on_tick)

    def _stop_timer(self) -> None:
        if self._timer is not None:
            self._timer.shutdown()
            self._timer = None

    def _planner_loop(self) -> None:
        while not self._shutdown.is_set() and not rospy.is_shutdown():
            if not self._wake.wait(0.2):   # short slices so shutdown is seen promptly
                continue
            self._wake.clear()
            try:
                with self._state_lock:
                    request, self._resume_request = self._resume_request, None
                if request is not None:
                    self._apply_resume(request)
                if self._exploring:
                    self.make_plan()
            except Exception as e:   # a bug or bad input in one cycle must not end exploration
                if self._throttle('cycle'):
                    rospy.logerr('explore: planning cycle failed: %s: %s', type(e).__name__, e)

    def _apply_resume(self, resume: bool) -> None:
        if resume:
            rospy.loginfo('explore: exploration resumed')
            self.logic.resume()
            with self._state_lock:
                self._exploring = True
                self._stop_timer()     # restart the period from now, as the ROS 2 port
                self._start_timer()
        elif self._exploring:
            rospy.loginfo('explore: exploration paused')
            self._stop(publish_note='Exploration paused.')

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

    def make_plan(self) -> None:
        """One planning cycle (explore.md §6), with the corrections listed in the module doc."""
        pose = self.robot_pose()
        if pose is None:
            return
        cm = self.costmap
        team_known = self.team.known_at(cm.frame_id)
        with cm.lock:
            if cm.world_to_map(pose[0], pose[1]) is None:
                if self._throttle('bounds'):
                    rospy.logerr('Robot out of costmap bounds, cannot search for frontiers; skipping this '
                                 'planning cycle')
                return
            frontiers = self.search.search_from(pose[0], pose[1])
            resolution, frame = cm.resolution, cm.frame_id
            if team_known is not None and frontiers:
                found = len(frontiers)
                frontiers = drop_explored_by_team(frontiers, cm.data, resolution, (cm.origin_x, cm.origin_y),
                                                  team_known)
                rospy.logdebug('explore: %d of %d frontiers already mapped by the team', found - len(frontiers),
                               found)
        now = rospy.get_time()
        if self._marker_pub is not None and frontiers:
            self._publish_markers(frontiers, frame, resolution)
        if self.team.goals is not None:
            team_goals = self.team.active_goals(frame, now, self._goal, self._goal_chosen_at)
            frontiers = apply_team_penalty(frontiers, team_goals, self.p.team_radius)
        result = self.logic.plan(frontiers, resolution, now)
        if result.action is PlanAction.STOP:
            if result.reason == 'all_blacklisted':
                rospy.loginfo('explore: all frontiers traversed/tried out, stopping.')
            else:
                rospy.loginfo('explore: no frontiers found, stopping.')
            self._stop(return_target=result.return_target)
        elif result.action is PlanAction.SEND_GOAL:
            self._send_goal(result.target, frame, now)
        else:
            self._publish_team_goal(frame)   # refresh for teammates

    def _publish_markers(self, frontiers: List[Frontier], frame: str, resolution: float) -> None:
        array = frontier_markers(frontiers, frame, rospy.Time.now(),
                                 lambda f: self.logic.is_blacklisted(f.centroid, resolution), self._marker_count)
        self._marker_count = 2 * len(frontiers)
        self._marker_pub.publish(array)

    def _send_goal(self, target: Tuple[float, float], frame: str, now: float) -> None:
        goal = pose_goal(frame, *target)
        rospy.logdebug('explore: sending goal (%.2f, %.2f) in %s', target[0], target[1], frame)
        self._goal, self._goal_chosen_at = target, now
        self.client.send_goal(goal, lambda s, r, t=target: self._on_goal_done(t, s, r))
        self._publish_team_goal(frame)

    def _publish_team_goal(self, frame: str) -> None:
        self.team.publish_goal(frame, self._goal, self._goal_chosen_at)

    def _stop(self, return_target: Optional[Pose2] = None, publish_note: str = 'Exploration stopped.') -> None:
        with self._state_lock:
            self._exploring = False
            self._stop_timer()
        self._goal, self._goal_chosen_at = None, math.inf
        self.logic.forget_goal()   # the goal is cancelled: after ~resume the same frontier must be sent again
        self._publish_team_goal(self.costmap.frame_id)   # withdraws our goal
        if return_target is not None:
            # The new goal replaces the running one on the server; cancelling first could race with it.
            x, y, q = return_target
            goal = pose_goal(self.costmap.frame_id, x, y, q)
            rospy.loginfo('explore: returning to the initial pose (%.2f, %.2f)', x, y)
            self.client.send_goal(goal, self._on_return_done)
        else:
            self.client.cancel_all_goals()
        rospy.loginfo(publish_note)


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
