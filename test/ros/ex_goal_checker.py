#!/usr/bin/env python3
"""rostest checker for explore's goal handling against ex_stub_world.py (test-only move_base stand-in).

Watches the `move_base` action topics and `~frontiers` of the explorer. test_unreachable_is_blacklisted: the first
goal lies in ~abort_region [x0, y0, x1, y1] and is ABORTED; afterwards a goal elsewhere is sent, never again one
within the blacklist square (±5 cells) of the aborted target, and a frontiers MarkerArray shows a red (blacklisted)
frontier inside ~abort_region. Params: ~timeout (s), ~resolution (m, of the stub map), ~markers (topic).
"""
import sys
import threading
import unittest

import rospy
import rostest
from actionlib_msgs.msg import GoalStatus
from move_base_msgs.msg import MoveBaseActionGoal, MoveBaseActionResult
from visualization_msgs.msg import Marker, MarkerArray

PKG = 'multirobot_map_merge'


class GoalLog:
    def __init__(self, markers_topic: str) -> None:
        self.lock = threading.Lock()
        self.goals = []      # (goal_id, x, y)
        self.results = {}    # goal_id -> status
        self.red = []        # mean (x, y) of red POINTS markers seen
        rospy.Subscriber('move_base/goal', MoveBaseActionGoal, self.on_goal)
        rospy.Subscriber('move_base/result', MoveBaseActionResult, self.on_result)
        rospy.Subscriber(markers_topic, MarkerArray, self.on_markers)

    def on_goal(self, msg):
        p = msg.goal.target_pose.pose.position
        with self.lock:
            self.goals.append((msg.goal_id.id, p.x, p.y))

    def on_result(self, msg):
        with self.lock:
            self.results[msg.status.goal_id.id] = msg.status.status

    def on_markers(self, msg):
        with self.lock:
            for m in msg.markers:
                if m.action == Marker.ADD and m.type == Marker.POINTS and m.color.r == 1.0 and m.points:
                    self.red.append((sum(p.x for p in m.points) / len(m.points),
                                     sum(p.y for p in m.points) / len(m.points)))

    def snapshot(self):
        with self.lock:
            return list(self.goals), dict(self.results), list(self.red)


def inside(region, x, y):
    return region[0] <= x <= region[2] and region[1] <= y <= region[3]


class GoalCheck(unittest.TestCase):
    def test_unreachable_is_blacklisted(self):
        region = [float(v) for v in rospy.get_param('~abort_region')]
        tol = 5 * float(rospy.get_param('~resolution', 0.05))
        log = GoalLog(rospy.get_param('~markers', '/explore/frontiers'))
        deadline = rospy.get_time() + float(rospy.get_param('~timeout', 30.0))
        done = False
        while not rospy.is_shutdown() and rospy.get_time() < deadline and not done:
            rospy.sleep(0.2)
            goals, results, red = log.snapshot()
            done = (len(goals) >= 2 and results.get(goals[0][0]) == GoalStatus.ABORTED
                    and any(inside(region, x, y) for x, y in red))
        goals, results, red = log.snapshot()
        self.assertGreaterEqual(len(goals), 1, 'the explorer sent no goal')
        gid, ax, ay = goals[0]
        self.assertTrue(inside(region, ax, ay), f'first goal ({ax:.2f}, {ay:.2f}) is not the unreachable frontier')
        self.assertEqual(results.get(gid), GoalStatus.ABORTED, 'the unreachable goal was not aborted')
        self.assertGreaterEqual(len(goals), 2, 'no goal after the abort')
        for _, x, y in goals[1:]:
            self.assertFalse(abs(x - ax) < tol and abs(y - ay) < tol,
                             f'goal ({x:.2f}, {y:.2f}) sent again next to the blacklisted ({ax:.2f}, {ay:.2f})')
        self.assertTrue(any(inside(region, x, y) for x, y in red), f'no red frontier marker in {region}: {red}')


if __name__ == '__main__':
    rospy.init_node('ex_goal_checker')
    rostest.rosrun(PKG, 'explore_goal_check', GoalCheck, sys.argv)
