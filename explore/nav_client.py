"""A one-goal-at-a-time move_base client (what explore_lite gets from actionlib's SimpleActionClient).

Built on actionlib's plain ActionClient because SimpleActionClient logs "Got a transition callback on a goal handle
that we're not tracking" at ERROR whenever a status message for the replaced goal is in flight while a new goal is
sent, which happens at every goal switch, and because its done callback can race with ``send_goal`` returning.
Here each goal gets a token before it is sent; callbacks for any other token are ignored, as the original ignores
replaced goals. ``pose_goal`` builds the node's goals (both kinds: frontier and return), ``status_name`` names an end
state in logs.
"""
from __future__ import annotations

import itertools
import threading
from typing import Any, Callable, Optional, Tuple, Union

import actionlib
import rospy
from actionlib import CommState
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import Quaternion
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal

DoneCallback = Callable[[int, Any], None]   # (terminal GoalStatus, result)
IDENTITY = (0.0, 0.0, 0.0, 1.0)   # exploration goals have no orientation, as the original's
_STATUS = {getattr(GoalStatus, n): n for n in ('PENDING', 'ACTIVE', 'PREEMPTED', 'SUCCEEDED', 'ABORTED', 'REJECTED',
                                               'PREEMPTING', 'RECALLING', 'RECALLED', 'LOST')}


def pose_goal(frame: str, x: float, y: float,
              q: Tuple[float, float, float, float] = IDENTITY) -> MoveBaseGoal:
    """A move_base goal at (x, y) in ``frame`` with orientation ``q`` (x, y, z, w), stamped now."""
    goal = MoveBaseGoal()
    goal.target_pose.header.frame_id = frame
    goal.target_pose.header.stamp = rospy.Time.now()
    goal.target_pose.pose.position.x, goal.target_pose.pose.position.y = x, y
    goal.target_pose.pose.orientation = Quaternion(*q)
    return goal


def status_name(state: int) -> Union[str, int]:
    """GoalStatus name of ``state`` for logs (the number itself if it is none of them)."""
    return _STATUS.get(state, state)


class NavClient:
    def __init__(self, ns: str = 'move_base') -> None:
        self._client = actionlib.ActionClient(ns, MoveBaseAction)
        self._lock = threading.Lock()   # owns _token, _handle, _done_cb
        self._tokens = itertools.count(1)
        self._token = 0
        self._handle = None
        self._done_cb: Optional[DoneCallback] = None

    def wait_for_server(self, timeout: float) -> bool:
        return self._client.wait_for_server(rospy.Duration(timeout))

    def send_goal(self, goal: MoveBaseGoal, done_cb: Optional[DoneCallback] = None) -> None:
        """Send ``goal``; it replaces the previous one (the server preempts it; its callback never fires)."""
        token = next(self._tokens)
        with self._lock:
            self._token, self._handle, self._done_cb = token, None, done_cb
        handle = self._client.send_goal(goal, transition_cb=lambda gh, t=token: self._on_transition(t, gh))
        with self._lock:
            if self._token == token:
                self._handle = handle   # keeps the goal's state machine alive (actionlib holds it weakly)

    def cancel_all_goals(self) -> None:
        """Cancel every goal on the server (also other clients' goals, as the original) and forget ours."""
        with self._lock:
            self._token, self._handle, self._done_cb = 0, None, None
        self._client.cancel_all_goals()

    def _on_transition(self, token: int, gh) -> None:
        if gh.get_comm_state() != CommState.DONE:
            return
        with self._lock:
            if token != self._token:
                return
            cb, self._done_cb = self._done_cb, None
            self._token, self._handle = 0, None
        if cb is not None:
            cb(gh.get_goal_status(), gh.get_result())
