#!/usr/bin/env python3
"""rostest checker for one explorer driving one robot (the fleet simulator or ex_stub_world.py).

Runs in order (unittest sorts the names):
  test_1_pause_and_resume: after the first goal, `<explore>/resume` false cancels the goal and no goal is sent for
      ~pause_for s (sim time); true makes the explorer send a goal again.
  test_2_explores_and_stops: the explorer logs "Exploration stopped." and, with ~world_topic, the robot's map covers
      at least ~min_explored of the free space reachable from its start (ground truth from the simulator).
  test_3_returns_home (~check_return): the last goal is the start pose ~home [x, y] (map frame), it SUCCEEDS and tf
      shows the robot within ~home_tolerance m of it.
Params: ~ns (robot namespace, '' for the root), ~explore (node name of the explorer), ~map_frame, ~base_frame,
~timeout (s, sim time, for the whole exploration).
"""
import math
import sys
import threading
import unittest

import rospy
import rostest
import tf2_ros
from actionlib_msgs.msg import GoalID, GoalStatus
from geometry_msgs.msg import PoseStamped
from move_base_msgs.msg import MoveBaseActionGoal, MoveBaseActionResult
from nav_msgs.msg import OccupancyGrid
from rosgraph_msgs.msg import Log
from std_msgs.msg import Bool

from explore.coverage import explored_share, reachable_mask
from multirobot_map_merge.ros.conversions import grid_from_msg, yaw_from_quaternion

PKG = 'multirobot_map_merge'


def ns_name(ns: str, name: str) -> str:
    return f"{ns.rstrip('/')}/{name}" if ns else name


class Watch:
    """Everything the tests observe, recorded from the start."""

    def __init__(self) -> None:
        self.ns = rospy.get_param('~ns', '')
        self.explore = rospy.get_param('~explore', '/explore')
        self.lock = threading.Lock()
        self.goals = []       # (time, goal_id, x, y)
        self.results = {}     # goal_id -> status
        self.cancels = []     # times of cancel requests
        self.stopped_at = None
        rospy.Subscriber(ns_name(self.ns, 'move_base/goal'), MoveBaseActionGoal, self.on_goal)
        rospy.Subscriber(ns_name(self.ns, 'move_base/result'), MoveBaseActionResult, self.on_result)
        rospy.Subscriber(ns_name(self.ns, 'move_base/cancel'), GoalID, self.on_cancel)
        rospy.Subscriber('/rosout', Log, self.on_log, queue_size=200)
        self.resume = rospy.Publisher(self.explore + '/resume', Bool, queue_size=1)

    def on_goal(self, msg):
        p = msg.goal.target_pose.pose.position
        with self.lock:
            self.goals.append((rospy.get_time(), msg.goal_id.id, p.x, p.y))

    def on_result(self, msg):
        with self.lock:
            self.results[msg.status.goal_id.id] = msg.status.status

    def on_cancel(self, _msg):
        with self.lock:
            self.cancels.append(rospy.get_time())

    def on_log(self, msg):
        if msg.name == self.explore and msg.msg.startswith('Exploration stopped.'):
            with self.lock:
                if self.stopped_at is None:
                    self.stopped_at = rospy.get_time()

    def wait(self, predicate, timeout: float) -> bool:
        end = rospy.get_time() + timeout
        while not rospy.is_shutdown():
            with self.lock:
                if predicate():
                    return True
            if rospy.get_time() > end:
                return False
            rospy.sleep(0.1)
        return False


WATCH = None


class ExploreCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        global WATCH
        if WATCH is None:
            WATCH = Watch()
        cls.w = WATCH
        cls.timeout = float(rospy.get_param('~timeout', 300.0))

    def test_1_pause_and_resume(self):
        w = self.w
        self.assertTrue(w.wait(lambda: len(w.goals) >= 1, 60.0), 'no first goal')
        self.assertTrue(w.wait(lambda: w.resume.get_num_connections() > 0, 30.0), 'explorer has no ~resume')
        w.resume.publish(Bool(False))
        paused_at = rospy.get_time()
        self.assertTrue(w.wait(lambda: any(t >= paused_at - 0.01 for t in w.cancels), 20.0),
                        'pause did not cancel the goal')
        with w.lock:
            cancelled_at = min(t for t in w.cancels if t >= paused_at - 0.01)
        rospy.sleep(float(rospy.get_param('~pause_for', 5.0)))
        # a goal planned just before the pause took effect may arrive shortly after the cancel (other topic)
        with w.lock:
            during = [g for g in w.goals if g[0] > cancelled_at + 1.0]
        self.assertEqual(during, [], f'goals sent while paused: {during}')
        resumed_at = rospy.get_time()
        w.resume.publish(Bool(True))
        self.assertTrue(w.wait(lambda: any(g[0] >= resumed_at for g in w.goals), 30.0), 'no goal after resume')
        with w.lock:
            first = next(g for g in w.goals if g[0] >= resumed_at)
            stopped_at = w.stopped_at
        self.assertTrue(stopped_at is None or first[0] < stopped_at,
                        'the first goal after resume is the return goal: exploration did not resume')

    def test_2_explores_and_stops(self):
        w = self.w
        self.assertTrue(w.wait(lambda: w.stopped_at is not None, self.timeout), 'exploration did not stop')
        world_topic = rospy.get_param('~world_topic', '')
        if not world_topic:
            return
        world = grid_from_msg(rospy.wait_for_message(world_topic, OccupancyGrid, timeout=10.0))
        start = rospy.wait_for_message(ns_name(w.ns, 'ground_truth/start_pose'), PoseStamped, timeout=10.0)
        q = start.pose.orientation
        pose = (start.pose.position.x, start.pose.position.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))
        robot_map = grid_from_msg(rospy.wait_for_message(ns_name(w.ns, 'map'), OccupancyGrid, timeout=10.0))
        reach = reachable_mask(world, [pose[:2]])
        share = explored_share(world, reach, [(robot_map, pose)])
        rospy.loginfo('ex_explore_checker: explored %.1f %% of %d reachable cells', 100 * share, int(reach.sum()))
        self.assertGreaterEqual(share, float(rospy.get_param('~min_explored', 0.95)))

    def test_3_returns_home(self):
        if not rospy.get_param('~check_return', False):
            return
        w = self.w
        self.assertTrue(w.wait(lambda: w.stopped_at is not None, self.timeout), 'exploration did not stop')
        home = [float(v) for v in rospy.get_param('~home', [0.0, 0.0])]
        tol = float(rospy.get_param('~home_tolerance', 0.35))
        with w.lock:
            last = w.goals[-1]
        self.assertLess(math.hypot(last[2] - home[0], last[3] - home[1]), 1e-3,
                        f'last goal ({last[2]:.2f}, {last[3]:.2f}) is not the start pose {home}')
        self.assertTrue(w.wait(lambda: w.results.get(last[1]) is not None, 120.0), 'the return goal did not end')
        self.assertEqual(w.results[last[1]], GoalStatus.SUCCEEDED)
        buf = tf2_ros.Buffer()
        tf2_ros.TransformListener(buf)
        t = buf.lookup_transform(rospy.get_param('~map_frame', 'map'), rospy.get_param('~base_frame', 'base_link'),
                                 rospy.Time(0), rospy.Duration(10.0))
        d = math.hypot(t.transform.translation.x - home[0], t.transform.translation.y - home[1])
        self.assertLess(d, tol, f'robot is {d:.2f} m from its start pose')
        with w.lock:
            after = [g for g in w.goals if g[0] > last[0]]
        self.assertEqual(after, [], 'goals sent after the return goal')


if __name__ == '__main__':
    rospy.init_node('ex_explore_checker')
    rostest.rosrun(PKG, 'explore_check', ExploreCheck, sys.argv)
