#!/usr/bin/env python3
"""rostest node for smoke.test: checks the ROS + venv + generated-message chain."""
import sys
import unittest

import rospy
import rostest
from nav_msgs.msg import OccupancyGrid

PKG = "multirobot_map_merge"


class SmokeTest(unittest.TestCase):
    def test_latched_map_received(self):
        grid = rospy.wait_for_message("map", OccupancyGrid, timeout=30.0)
        self.assertEqual(grid.header.frame_id, "smoke_map")
        self.assertEqual((grid.info.width, grid.info.height), (4, 3))
        self.assertEqual(list(grid.data), [-1, 0, 100, 0] * 3)

    def test_runs_in_project_venv(self):
        import cv2
        import numpy
        self.assertIn("/.venv/", sys.executable + "/", sys.executable)
        self.assertTrue(cv2.__version__.startswith("4.12"), cv2.__version__)
        self.assertEqual(numpy.__version__, "2.2.6")
        self.assertTrue(hasattr(cv2, "AKAZE_create"))

    def test_generated_messages_import(self):
        from multirobot_map_merge.msg import MergeStatus, PairMatchStatus, RobotMergeStatus
        status = MergeStatus(robots=[RobotMergeStatus(robot_namespace="/robot1", included=True)],
                             pairs=[PairMatchStatus(robot_a="/robot1", robot_b="/robot2")],
                             estimation_time=0.5)
        self.assertEqual(status.robots[0].transform.rotation.w, 0.0)
        self.assertEqual(MergeStatus._type, "multirobot_map_merge/MergeStatus")


if __name__ == "__main__":
    rospy.init_node("smoke_test")
    rostest.rosrun(PKG, "smoke", SmokeTest, sys.argv)
