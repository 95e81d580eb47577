#!/usr/bin/env python3
"""rostest node for the map_merge tests: waits for the merged map and checks it.

Params: ~topic (merged map, default /map_merge/map), ~timeout (s), ~frame (expected frame_id, default world),
~min_known_cells (int), ~min_larger_than (list of "w,h": the merged map must be larger in area than each),
~occupied_points (list of "x,y": world points, metres, that must be occupied in the merged map within ~tolerance
metres), ~status_topic (optional: a MergeStatus that must list exactly ~status_included robots as included and use a
pair), ~metadata_topic + ~metadata_size [w, h] (a latched MapMetaData to check), ~tf_child + ~tf_expected [x, y, yaw]
(a tf world_frame -> tf_child to look up), ~stable_for (s: after the first merged map that passes, keep checking
that later maps still satisfy the checks for this long),
~warn_node + ~warn_robots (list): every listed robot must be named in a WARN of that node on /rosout, and warnings
about one robot must stay throttled (at most 2 kinds x one per ~warn_period s).
"""
import sys
import unittest

import numpy as np
import rospy
import rostest
from nav_msgs.msg import OccupancyGrid

PKG = 'multirobot_map_merge'


def _param_list(name):
    return [tuple(float(v) for v in s.split(',')) for s in rospy.get_param(name, [])]


class MergeCheck(unittest.TestCase):
    def check(self, grid):
        self.assertEqual(grid.header.frame_id, rospy.get_param('~frame', 'world'))
        w, h = grid.info.width, grid.info.height
        self.assertEqual(len(grid.data), w * h)
        for mw, mh in _param_list('~min_larger_than'):
            self.assertGreater(w * h, mw * mh, f'merged {w} x {h} not larger than input {mw:.0f} x {mh:.0f}')
        data = np.asarray(grid.data, np.int8).reshape(h, w)
        min_known = int(rospy.get_param('~min_known_cells', 0))
        self.assertGreaterEqual(int((data >= 0).sum()), min_known, 'too few known cells')
        res, ox, oy = grid.info.resolution, grid.info.origin.position.x, grid.info.origin.position.y
        tol = int(np.ceil(float(rospy.get_param('~tolerance', 0.15)) / res))
        for x, y in _param_list('~occupied_points'):
            c, r = int(np.floor((x - ox) / res)), int(np.floor((y - oy) / res))
            window = data[max(r - tol, 0):r + tol + 1, max(c - tol, 0):c + tol + 1]
            self.assertTrue(window.size and (window >= 65).any(), f'no wall near ({x}, {y}) (cell {c}, {r})')

    def test_merged_map(self):
        from rosgraph_msgs.msg import Log
        warnings = []
        warn_node = rospy.get_param('~warn_node', '')
        rosout = rospy.Subscriber('/rosout', Log, lambda m: warnings.append(m.msg)
                                  if m.name == warn_node and m.level == Log.WARN else None, queue_size=100)
        watch_start = rospy.get_time()
        topic = rospy.get_param('~topic', '/map_merge/map')
        deadline = rospy.get_time() + float(rospy.get_param('~timeout', 40.0))
        # early merged maps may hold one robot only (before the first estimation): wait for one that passes
        while True:
            grid = rospy.wait_for_message(topic, OccupancyGrid, timeout=max(deadline - rospy.get_time(), 1.0))
            try:
                self.check(grid)
                break
            except AssertionError:
                if rospy.get_time() > deadline:
                    raise
                rospy.sleep(0.5)
        stable_for = float(rospy.get_param('~stable_for', 0.0))
        end = rospy.get_time() + stable_for
        while rospy.get_time() < end:
            rospy.sleep(1.0)
            # a new subscription gets the latched newest map; a newer stamp shows the node is still merging
            newer = rospy.wait_for_message(topic, OccupancyGrid, timeout=10.0)
            self.assertGreater(newer.header.stamp, grid.header.stamp, 'the merged map is no longer published')
            self.check(newer)
            grid = newer
        rosout.unregister()
        window = rospy.get_time() - watch_start
        period = float(rospy.get_param('~warn_period', 10.0))
        for robot in rospy.get_param('~warn_robots', []):
            about = [w for w in warnings if f'robot [{robot}]' in w]
            self.assertTrue(about, f'no warning names {robot} in {window:.0f} s')
            self.assertLessEqual(len(about), 2 * (window // period + 1), f'warnings about {robot} not throttled: '
                                 f'{len(about)} in {window:.0f} s')
        meta_topic = rospy.get_param('~metadata_topic', '')
        if meta_topic:
            from nav_msgs.msg import MapMetaData
            meta = rospy.wait_for_message(meta_topic, MapMetaData, timeout=10.0)
            self.assertEqual((meta.width, meta.height), tuple(rospy.get_param('~metadata_size')))
        status_topic = rospy.get_param('~status_topic', '')
        if status_topic:
            from multirobot_map_merge.msg import MergeStatus
            status = rospy.wait_for_message(status_topic, MergeStatus, timeout=10.0)
            included = sorted(r.robot_namespace for r in status.robots if r.included)
            self.assertEqual(included, sorted(rospy.get_param('~status_included')))
            self.assertTrue(any(p.used for p in status.pairs), 'no pair used')
        child = rospy.get_param('~tf_child', '')
        if child:
            import tf2_ros
            buf = tf2_ros.Buffer()
            tf2_ros.TransformListener(buf)
            t = buf.lookup_transform(rospy.get_param('~frame', 'world'), child, rospy.Time(0), rospy.Duration(10.0))
            x, y, yaw = rospy.get_param('~tf_expected')
            q = t.transform.rotation
            self.assertAlmostEqual(t.transform.translation.x, x, places=3)
            self.assertAlmostEqual(t.transform.translation.y, y, places=3)
            self.assertAlmostEqual(2.0 * np.arctan2(q.z, q.w), yaw, places=3)


if __name__ == '__main__':
    rospy.init_node('mm_merge_checker')
    rostest.rosrun(PKG, 'map_merge_check', MergeCheck, sys.argv)
