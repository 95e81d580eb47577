"""The ROS side of fleet coordination (an extension; see team.py for the pure part and doc/explore.md).

Subscribes ``team_topic`` (teammates' goals, geometry_msgs/PoseStamped in ``team_frame``; all-zero orientation:
the sender has no goal any more; position.z: the sender's remaining distance to its goal in m, 0 if unknown) and
``team_map_topic`` (the team's merged map), publishes this robot's goal on ``team_topic``, and moves points between
the robot's map frame and the team frame through tf. Kept apart from the planning loop because all of it is
optional and waits on tf that map_merge only provides once it placed the robot.
"""
from __future__ import annotations

import math
from typing import List, Optional, Tuple

import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import PoseStamped, Quaternion
from nav_msgs.msg import OccupancyGrid
from rospy.numpy_msg import numpy_msg

from multirobot_map_merge.grid import Grid, GridError
from multirobot_map_merge.ros.conversions import grid_from_msg, yaw_from_quaternion
from multirobot_map_merge.throttle import Throttle

from .params import ExploreParams
from .frontier_search import Frontier
from .team import KnownAt, TeamGoals, grid_known_at, team_frontiers

Point2 = Tuple[float, float]
HAS_GOAL = (0.0, 0.0, 0.0, 1.0)   # orientation of a published goal (all zeros: withdrawn)
MIN_DISTANCE = 1e-3               # m: a robot at its goal publishes this remaining distance, not 0 (unknown)


class TeamLink:
    """Team topics of one explorer. Created at start-up (as the node's other late subscriptions); each part is
    inactive when its topic parameter is empty."""

    def __init__(self, params: ExploreParams, tf_buffer: tf2_ros.Buffer, throttle: Throttle) -> None:
        self.p = params
        self._tf_buffer = tf_buffer
        self._throttle = throttle
        self.goals: Optional[TeamGoals] = None    # teammates' goals; None without team_topic
        self._pub = None
        self._map: Optional[Grid] = None   # replaced whole by its callback, read by the planner
        self._tf_reported = False
        if params.team_topic:
            self.goals = TeamGoals(rospy.get_name())
            self._pub = rospy.Publisher(params.team_topic, PoseStamped, queue_size=10)
            rospy.Subscriber(params.team_topic, PoseStamped, self._on_team_goal, queue_size=50)
        if params.team_map_topic:
            # numpy_msg: the merged map's cells as an ndarray (see node.py)
            rospy.Subscriber(params.team_map_topic, numpy_msg(OccupancyGrid), self._on_team_map, queue_size=1,
                             buff_size=1 << 25)

    # ------------------------------------------------------------------ callbacks: store only
    def _on_team_goal(self, msg: PoseStamped) -> None:
        sender = msg._connection_header.get('callerid', '') if hasattr(msg, '_connection_header') else ''
        q = msg.pose.orientation
        if not sender:
            return
        if msg.header.frame_id.lstrip('/') != self.p.team_frame.lstrip('/'):
            if self._throttle('team_frame'):
                rospy.logwarn('explore: team goal of %s in frame [%s], expected [%s]; ignored', sender,
                              msg.header.frame_id, self.p.team_frame)
            return
        withdrawn = q.x == 0.0 and q.y == 0.0 and q.z == 0.0 and q.w == 0.0   # all-zero quaternion: no goal
        point = None if withdrawn else (msg.pose.position.x, msg.pose.position.y)
        z = msg.pose.position.z   # a goal is planar: z carries the remaining distance (0: not sent, unknown)
        self.goals.update(sender, point, msg.header.stamp.to_sec(), rospy.get_time(),
                          z if z > 0.0 and math.isfinite(z) else math.inf)

    def _on_team_map(self, msg: OccupancyGrid) -> None:
        try:
            self._map = grid_from_msg(msg)
        except GridError as e:
            if self._throttle('team_map'):
                rospy.logwarn('explore: team map refused: %s', e)

    # ------------------------------------------------------------------ planner thread
    def _lookup(self, target: str, source: str):
        try:
            return self._tf_buffer.lookup_transform(target, source, rospy.Time(0))
        except tf2_ros.TransformException as e:
            # normal until map_merge has placed this robot: say so once, then only at DEBUG
            log = rospy.logdebug if self._tf_reported else rospy.loginfo
            self._tf_reported = True
            if self._throttle('team_tf'):
                log('explore: no tf %s -> %s yet (%s); team coordination waits for it', source, target, e)
            return None

    def known_at(self, frame: str) -> Optional[KnownAt]:
        """known_at() of the team map for points of ``frame``, or None (no team map yet, or not in tf yet)."""
        grid = self._map
        if grid is None:
            return None
        t = self._lookup(grid.frame_id or self.p.team_frame, frame)
        if t is None:
            return None
        x, y, c, s = _planar(t)
        return grid_known_at(grid, np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]]))

    def frontiers(self, frame: str, robot_xy: Point2, table: np.ndarray, own_known_at: KnownAt) -> List[Frontier]:
        """The team map's frontiers in ``frame`` (the robot's map frame), searched from the robot at ``robot_xy``
        there; [] without a team map or its tf (team.team_frontiers)."""
        grid = self._map
        if grid is None:
            return []
        t = self._lookup(grid.frame_id or self.p.team_frame, frame)
        if t is None:
            return []
        x, y, c, s = _planar(t)
        team_from_own = np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])
        robot = team_from_own @ np.array([robot_xy[0], robot_xy[1], 1.0])
        p = self.p
        return team_frontiers(grid, table, (robot[0], robot[1]), np.linalg.inv(team_from_own), p.potential_scale,
                              p.gain_scale, p.min_frontier_size, p.path_distance, own_known_at)

    def active_goals(self, frame: str, now: float, own_goal: Optional[Point2], own_chosen_at: float,
                     own_distance: float = math.inf) -> List[Tuple[Point2, float]]:
        """Teammates' current goals in ``frame`` (the map frame) with their remaining distances (inf: unknown); []
        while the team frame is not in tf. ``own_goal`` (in ``frame``, chosen at ROS time ``own_chosen_at``, this
        robot ``own_distance`` from it) decides who yields (team.py)."""
        t = self._lookup(frame, self.p.team_frame)
        if t is None:
            return []
        own = None
        if own_goal is not None:
            back = self._lookup(self.p.team_frame, frame)
            own = _apply(back, own_goal) if back is not None else None
        goals = self.goals.active(now, own, own_chosen_at, self.p.team_radius, own_distance)
        return [(_apply(t, g.point), g.distance) for g in goals]

    def publish_goal(self, frame: str, goal: Optional[Point2], chosen_at: float,
                     distance: float = math.inf) -> None:
        """Tell teammates this robot's goal (in ``frame``) and its remaining distance to it, or that it has none
        (``goal`` None)."""
        if self._pub is None:
            return
        msg = PoseStamped()
        msg.header.frame_id = self.p.team_frame
        if goal is None:
            msg.header.stamp = rospy.Time.now()   # all-zero orientation: withdrawn
        else:
            t = self._lookup(self.p.team_frame, frame)
            if t is None:
                return
            msg.header.stamp = rospy.Time.from_sec(chosen_at)
            msg.pose.position.x, msg.pose.position.y = _apply(t, goal)
            if math.isfinite(distance):
                msg.pose.position.z = max(distance, MIN_DISTANCE)   # 0 would read as unknown
            msg.pose.orientation = Quaternion(*HAS_GOAL)
        self._pub.publish(msg)


def _planar(t) -> Tuple[float, float, float, float]:
    """(x, y, cos yaw, sin yaw) of a TransformStamped's planar part (yaw about z)."""
    tr, q = t.transform.translation, t.transform.rotation
    yaw = yaw_from_quaternion(q.x, q.y, q.z, q.w)   # tf2 keeps no non-finite transform
    return tr.x, tr.y, math.cos(yaw), math.sin(yaw)


def _apply(t, p: Point2) -> Point2:
    """Apply a TransformStamped's planar part to point p."""
    x, y, c, s = _planar(t)
    return x + c * p[0] - s * p[1], y + s * p[0] + c * p[1]
