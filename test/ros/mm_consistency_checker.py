#!/usr/bin/env python3
"""rostest node: ~status contents, and tf / ~status / merged grid placement agree (map_merge with ~publish_tf).

Params: ~merged_topic, ~status_topic, ~world_frame, ~robots (list of "ns=file.yaml" as mm_common: every robot that
publishes a map), ~origin_mode (center | world), ~timeout (s).

* the status lists exactly the robots, with their map frames, all included, a finite estimation time, and pairs
  whose statistics are consistent and whose used pairs connect every robot;
* tf world_frame -> each robot's map frame equals the status transform at the status's stamp;
* the merged map holds every robot's walls where tf (at the merged map's stamp) places them;
* origin_mode world: world_frame is one robot's map frame (its transform is the identity).
"""
import math
import sys
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from nav_msgs.msg import OccupancyGrid

import mm_common as mm
from multirobot_map_merge.msg import MergeStatus


class ConsistencyCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.buffer = tf2_ros.Buffer(rospy.Duration(30.0))
        cls.listener = tf2_ros.TransformListener(cls.buffer)
        cls.specs = rospy.get_param('~robots')
        cls.names = [s.split('=', 1)[0] for s in cls.specs]
        cls.world = rospy.get_param('~world_frame', 'world')

        def all_included(status):
            return {r.robot_namespace for r in status.robots if r.included} >= set(cls.names)
        cls.status = mm.wait_for(rospy.get_param('~status_topic'), MergeStatus, all_included,
                                 float(rospy.get_param('~timeout', 40.0)), 'status with every robot included')

    def lookup(self, child, stamp):
        t = self.buffer.lookup_transform(self.world, child, stamp, rospy.Duration(10.0))
        return t, mm.matrix_of(t.transform)

    def test_status_contents(self):
        s = self.status
        self.assertEqual(s.header.frame_id, self.world)
        self.assertGreater(s.header.stamp.to_sec(), 0.0)
        self.assertTrue(math.isfinite(s.estimation_time) and s.estimation_time > 0.0, s.estimation_time)
        self.assertEqual(sorted(r.robot_namespace for r in s.robots), sorted(self.names))
        for r in s.robots:
            self.assertEqual(r.map_frame, r.robot_namespace.strip('/') + '/map')
            self.assertTrue(r.included)
            q = r.transform.rotation
            self.assertAlmostEqual(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w, 1.0, places=6)
            self.assertEqual((q.x, q.y, r.transform.translation.z), (0.0, 0.0, 0.0))
        n = len(self.names)
        pairs = {frozenset((p.robot_a, p.robot_b)) for p in s.pairs}
        self.assertEqual(len(pairs), len(s.pairs), 'a pair is listed twice')
        self.assertLessEqual(len(pairs), n * (n - 1) // 2)
        groups = {ns: {ns} for ns in self.names}   # used pairs must connect every included robot
        for p in s.pairs:
            self.assertNotEqual(p.robot_a, p.robot_b)
            self.assertIn(p.robot_a, self.names)
            self.assertIn(p.robot_b, self.names)
            self.assertLessEqual(p.inliers, p.matches)
            self.assertTrue(math.isfinite(p.confidence) and p.confidence >= 0.0, p.confidence)
            if p.used:
                merged = groups[p.robot_a] | groups[p.robot_b]
                for ns in merged:
                    groups[ns] = merged
        self.assertEqual(groups[self.names[0]], set(self.names), 'the used pairs do not connect every robot')

    def test_tf_agrees_with_status_and_merged_map(self):
        placed = mm.status_transforms(self.status)
        for r in self.status.robots:
            _, m = self.lookup(r.map_frame, self.status.header.stamp)
            dist, angle = mm.pose_error(m, placed[r.robot_namespace])
            self.assertLess(dist, 1e-4, f'tf and ~status disagree on {r.robot_namespace}')
            self.assertLess(angle, 1e-3, f'tf and ~status disagree on {r.robot_namespace}')

        merged = rospy.wait_for_message(rospy.get_param('~merged_topic'), OccupancyGrid, timeout=10.0)
        self.assertEqual(merged.header.frame_id, self.world)
        grids = mm.robot_maps(self.specs)
        identities = []
        for ns in self.names:
            t, m = self.lookup(grids[ns].frame_id, merged.header.stamp)
            # tf2 keeps stamps as double seconds: equal to the nanosecond rounding
            self.assertLess(abs((t.header.stamp - merged.header.stamp).to_sec()), 1e-6, 'tf not sent with the map')
            agreement = mm.wall_agreement(grids[ns], m, merged)
            self.assertGreater(agreement, 0.9, f'{ns}: only {agreement:.0%} of its walls lie on merged walls '
                                               'where tf places them')
            if sum(mm.pose_error(m, np.eye(3))) < 1e-6:
                identities.append(ns)
        if rospy.get_param('~origin_mode', 'center') == 'world':
            self.assertEqual(len(identities), 1, f'world_frame is not one robot map frame: {identities}')


if __name__ == '__main__':
    rospy.init_node('mm_consistency_checker')
    rostest.rosrun('multirobot_map_merge', 'map_merge_consistency', ConsistencyCheck, sys.argv)
