#!/usr/bin/env python3
"""rostest node for fleet_sim_world_file.test: a world from a map_server YAML, random start poses, wall-clock
time (no /use_sim_time), the laser scan, and bad parameters that must stop the node at start.

Params: ~world (the YAML the simulator loads), ~num_robots, ~n_beams (expected beams per scan).
"""
import math
import os
import subprocess
import sys
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import OccupancyGrid
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import LaserScan

from multirobot_map_merge.mapio import load_map

PKG = 'multirobot_map_merge'


class WorldFileCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.n = int(rospy.get_param('~num_robots'))
        cls.ns = [f'robot_{i + 1}' for i in range(cls.n)]
        cls.world_file = load_map(rospy.get_param('~world'))

    def test_world_map_is_the_file(self):
        msg = rospy.wait_for_message('/fleet_sim/world_map', OccupancyGrid, timeout=30.0)
        self.assertEqual(msg.header.frame_id, 'world')
        self.assertEqual((msg.info.width, msg.info.height), (self.world_file.width, self.world_file.height))
        self.assertAlmostEqual(msg.info.resolution, self.world_file.resolution, places=6)
        np.testing.assert_array_equal(np.asarray(msg.data, np.int8).reshape(msg.info.height, msg.info.width),
                                      self.world_file.data)

    def test_random_starts_are_free_apart_and_on_wall_time(self):
        starts = []
        for ns in self.ns:
            msg = rospy.wait_for_message(f'{ns}/ground_truth/start_pose', PoseStamped, timeout=30.0)
            self.assertEqual(msg.header.frame_id, 'world')
            x, y = msg.pose.position.x, msg.pose.position.y
            c, r = int(x / self.world_file.resolution), int(y / self.world_file.resolution)
            self.assertEqual(self.world_file.data[r, c], 0, f'{ns} starts on a non-free cell')
            starts.append((x, y))
            pose = rospy.wait_for_message(f'{ns}/ground_truth/pose', PoseStamped, timeout=30.0)
            # no /use_sim_time: stamps are wall-clock time
            self.assertLess(abs(pose.header.stamp.to_sec() - time.time()), 10.0)
        for i in range(self.n):
            for j in range(i + 1, self.n):
                self.assertGreaterEqual(math.dist(starts[i], starts[j]), 1.0)
        # and on the wall clock the simulator publishes no /clock for other nodes to follow
        with self.assertRaises(rospy.ROSException):
            rospy.wait_for_message('/clock', Clock, timeout=2.0)

    def test_maps_tf_and_scans(self):
        buf = tf2_ros.Buffer()
        tf2_ros.TransformListener(buf)
        for ns in self.ns:
            m = rospy.wait_for_message(f'{ns}/map', OccupancyGrid, timeout=30.0)
            self.assertEqual(m.header.frame_id, f'{ns}/map')
            self.assertGreater(sum(1 for v in m.data if v == 0), 500)
            t = buf.lookup_transform(f'{ns}/map', f'{ns}/base_link', rospy.Time(0), rospy.Duration(10.0))
            # robots stand still at their start: the map frame is the start pose
            self.assertAlmostEqual(t.transform.translation.x, 0.0, places=6)
            self.assertAlmostEqual(t.transform.translation.y, 0.0, places=6)
        scan = rospy.wait_for_message('robot_1/scan', LaserScan, timeout=30.0)
        self.assertEqual(scan.header.frame_id, 'robot_1/base_link')
        self.assertEqual(len(scan.ranges), int(rospy.get_param('~n_beams')))
        ranges = np.asarray(scan.ranges)
        self.assertGreater(np.isfinite(ranges).sum(), 10)
        self.assertTrue(np.all(ranges[np.isfinite(ranges)] <= scan.range_max + 0.1))

    def run_bad(self, name, *args):
        """Start another simulator with bad parameters: it must exit non-zero with one clear message."""
        # the node's own executable (rosrun may find several copies through the workspace symlink)
        exe = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', 'nodes', 'fleet_sim')
        cmd = [sys.executable, exe, f'__name:={name}', *args]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=os.environ.copy())
        self.assertNotEqual(proc.returncode, 0, proc.stdout + proc.stderr)
        return proc.stdout + proc.stderr

    def test_bad_parameters_stop_the_node(self):
        out = self.run_bad('fs_bad_world', '_world:=/nonexistent/world.yaml')
        self.assertIn('cannot load', out)
        out = self.run_bad('fs_bad_start', '_robots:=[{x: -100.0, y: 0.0}]')
        self.assertIn('inside a wall or outside', out)
        out = self.run_bad('fs_bad_rate', '_map_rate:=0.0')
        self.assertIn('map_rate', out)


if __name__ == '__main__':
    rospy.init_node('fs_world_checker')
    rostest.rosrun(PKG, 'fleet_sim_world_check', WorldFileCheck, sys.argv)
