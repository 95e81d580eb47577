"""The explore node's planning loop (ROS side): the planner thread, its state, and what one cycle does.

One planner thread runs every planning cycle, woken by a rospy.Timer at planner_frequency (ROS time), by a finished
goal or by ~resume, so goals are never sent from inside an actionlib callback. A cycle (explore.md §6): robot pose,
frontier search, the team's filters, then GoalLogic's decision carried out: send a goal, keep it, or stop (and
maybe return to the initial pose). The decisions are in the pure modules (frontier_search, goal_logic, team); this
module holds what they need from ROS: time, tf through the node's ``robot_pose``, move_base, the marker topic.
"""
from __future__ import annotations

import math
import threading
from typing import Callable, List, Optional, Tuple

import rospy

from multirobot_map_merge.throttle import Throttle

from .costmap import Costmap
from .frontier_search import Frontier, FrontierSearch
from .goal_logic import GoalLogic, PlanAction, apply_team_penalty
from .markers import frontier_markers
from .nav_client import NavClient, pose_goal, status_name
from .params import ExploreParams
from .team import costmap_known_at, drop_explored_by_team, rank_with_team
from .team_link import TeamLink

Pose2 = Tuple[float, float, Tuple[float, float, float, float]]   # x, y, quaternion (x, y, z, w)


class PlanningLoop:
    """Planner state, owned by the planner thread; ``_state_lock`` guards what callbacks hand over to it."""

    def __init__(self, params: ExploreParams, costmap: Costmap, robot_pose: Callable[[], Optional[Pose2]],
                 throttle: Throttle, marker_pub: Optional[rospy.Publisher]) -> None:
        self.p = params
        self.costmap = costmap
        self.search = FrontierSearch(costmap, params.potential_scale, params.gain_scale, params.min_frontier_size,
                                     params.path_distance)
        self.logic = GoalLogic(params.progress_timeout, params.return_to_init)
        self._robot_pose = robot_pose
        self._throttle = throttle
        self._marker_pub = marker_pub
        self._wake = threading.Event()
        self._shutdown = threading.Event()
        self._state_lock = threading.Lock()
        self._resume_request: Optional[bool] = None   # set by ~resume, consumed by the planner
        self._exploring = False
        self._timer: Optional[rospy.Timer] = None
        self._goal: Optional[Tuple[float, float]] = None   # current exploration goal (global frame)
        self._goal_chosen_at = math.inf                    # ROS time it was chosen
        self._goal_distance = math.inf                     # remaining distance to it at the latest plan, m
        self._marker_count = 0
        self.client: Optional[NavClient] = None   # both set by start(), once the node has them
        self.team: Optional[TeamLink] = None

    def start(self, client: NavClient, team: TeamLink) -> None:
        """Start exploring: the timer and the planner thread."""
        self.client, self.team = client, team
        with self._state_lock:
            self._exploring = True
            self._start_timer()
        threading.Thread(target=self._loop, name='planner', daemon=True).start()

    def shutdown(self) -> None:
        self._shutdown.set()
        self._wake.set()

    # ------------------------------------------------------------------ callbacks: store or wake only
    def request_resume(self, resume: bool) -> None:
        """~resume: handed over to the planner thread."""
        with self._state_lock:
            self._resume_request = resume
        self._wake.set()

    def _on_tick(self, _event) -> None:
        self._wake.set()

    def _on_goal_done(self, target: Tuple[float, float], state: int, _result) -> None:
        # actionlib's thread: record the result and wake the planner, never send a goal from here
        self.logic.on_goal_done(state, target)
        rospy.logdebug('explore: goal (%.2f, %.2f) done with status %d', target[0], target[1], state)
        self._wake.set()

    def _on_return_done(self, state: int, _result) -> None:
        rospy.loginfo('explore: return to the initial pose finished with status %s', status_name(state))

    # ------------------------------------------------------------------ planner thread
    def _start_timer(self) -> None:
        if self._timer is None:
            self._timer = rospy.Timer(rospy.Duration(1.0 / self.p.planner_frequency), self._on_tick)

    def _stop_timer(self) -> None:
        if self._timer is not None:
            self._timer.shutdown()
            self._timer = None

    def _loop(self) -> None:
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

    def make_plan(self) -> None:
        """One planning cycle (explore.md §6), with the corrections listed in the node's module doc."""
        pose = self._robot_pose()
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
            # the team map's frontiers are ranked together with its own (team.py says why)
            own_known = (costmap_known_at(cm.data.copy(), resolution, (cm.origin_x, cm.origin_y))
                         if team_known is not None else None)
        extra: List[Frontier] = [] if own_known is None else self.team.frontiers(frame, pose[:2], cm.table, own_known)
        now = rospy.get_time()
        if self._marker_pub is not None and frontiers:
            self._publish_markers(frontiers, frame, resolution)   # the own map's, as the original
        frontiers = rank_with_team(frontiers, extra)
        team_goals: List[Tuple[Tuple[float, float], float]] = []
        if self.team.goals is not None:
            team_goals = self.team.active_goals(frame, now, self._goal, self._goal_chosen_at, self._goal_distance)
            heading = self._goal if self._goal is not None else (pose[0], pose[1])
            points, remaining = [g for g, _ in team_goals], [d for _, d in team_goals]
            frontiers = apply_team_penalty(frontiers, points, self.p.team_radius, heading, remaining)
        result = self.logic.plan(frontiers, resolution, now, team_busy=bool(team_goals))
        self._goal_distance = result.frontier.min_distance if result.frontier is not None else math.inf
        if result.action is PlanAction.WAIT:
            if self._goal is not None:
                rospy.loginfo('explore: every frontier left is blacklisted; waiting while teammates explore')
                self._goal, self._goal_chosen_at = None, math.inf
                self.client.cancel_all_goals()
            self._publish_team_goal(frame)   # withdrawn: a waiting robot does not keep teammates waiting
        elif result.action is PlanAction.STOP:
            if result.reason == 'all_blacklisted':
                rospy.loginfo('explore: all frontiers traversed/tried out, stopping: no reachable frontier left '
                              '(%d, all blacklisted: aborted by move_base or no progress for progress_timeout).',
                              len(frontiers))
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

    def _publish_team_goal(self, frame: str) -> None:
        self.team.publish_goal(frame, self._goal, self._goal_chosen_at, self._goal_distance)
