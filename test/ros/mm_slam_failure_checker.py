#!/usr/bin/env python3
"""rostest node: a robot whose map turns (a SLAM failure) loses its old placement within two estimations and is
never merged wrong.

Params: ~status_topic, ~robots (specs "ns=file.yaml", as mm_common; the last robot's map is published by this node),
~truth (truth.json), ~failing (the namespace whose map turns: the one this node publishes), ~turn_deg, ~timeout (s,
for the merge before the failure), ~watch (s of statuses checked after the failure, default 15), ~tolerance_m
(0.15), ~tolerance_deg (1.0).

1. Publishes the failing robot's map (latched) and waits for a status in which every robot is placed right.
2. Publishes the same map turned by turn_deg about its frame origin (the true pose of that frame turns by -turn_deg).
3. Checks every following status: the other robots stay included and right; the failing robot, from the second
   status on (and in the last), is either left out or placed right for the turned map.
"""
import math
import sys
import unittest

import numpy as np
import rospy
import rostest
from nav_msgs.msg import OccupancyGrid

import mm_common as mm
from multirobot_map_merge.grid import Grid
from multirobot_map_merge.msg import MergeStatus
from multirobot_map_merge.ros.conversions import grid_to_msg


def turned(grid: Grid, degrees: float) -> Grid:
    x, y, yaw = grid.origin
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return Grid(grid.data, grid.resolution, (c * x - s * y, s * x + c * y, yaw + math.radians(degrees)),
                grid.frame_id)


class SlamFailureCheck(unittest.TestCase):
    def placed_right(self, placed, names, truth, tol_m, tol_deg):
        """{ns: (error m, error deg)} of each included robot relative to the first listed one."""
        ref = names[0]
        out = {}
        for ns in names[1:]:
            if placed.get(ns) is None or placed.get(ref) is None:
                continue
            estimated = np.linalg.inv(placed[ref]) @ placed[ns]
            expected = np.linalg.inv(truth[ref]) @ truth[ns]
            out[ns] = mm.pose_error(estimated, expected)
        return out

    def test_turned_map_is_dropped_and_never_merged_wrong(self):
        specs = rospy.get_param('~robots')
        names = [s.split('=', 1)[0] for s in specs]
        truth = mm.truth_poses(rospy.get_param('~truth'), specs)
        failing = rospy.get_param('~failing')
        turn = float(rospy.get_param('~turn_deg', 20.0))
        tol_m, tol_deg = float(rospy.get_param('~tolerance_m', 0.15)), float(rospy.get_param('~tolerance_deg', 1.0))
        grid = mm.load_spec(specs[names.index(failing)], failing.strip('/') + '/map')[1]
        pub = rospy.Publisher(failing + '/map', OccupancyGrid, queue_size=1, latch=True)
        pub.publish(grid_to_msg(grid, stamp=rospy.Time.now()))

        def all_right(status):
            placed = mm.status_transforms(status)
            errors = self.placed_right(placed, names, truth, tol_m, tol_deg)
            return len(errors) == len(names) - 1 and all(m < tol_m and d < tol_deg for m, d in errors.values())
        mm.wait_for(rospy.get_param('~status_topic'), MergeStatus, all_right,
                    float(rospy.get_param('~timeout', 40.0)), 'status with every robot placed right')

        statuses = []
        sub = rospy.Subscriber(rospy.get_param('~status_topic'), MergeStatus, statuses.append, queue_size=20)
        rospy.sleep(0.5)
        del statuses[:]   # the latched one from before the failure
        failed_at = rospy.Time.now()
        pub.publish(grid_to_msg(turned(grid, turn), stamp=failed_at))
        # a status follows every estimation that ran; with the maps static again, the last one stands
        rospy.sleep(float(rospy.get_param('~watch', 15.0)))
        sub.unregister()
        after = [s for s in statuses if s.header.stamp > failed_at]
        self.assertGreaterEqual(len(after), 1, 'no estimation after the failure')
        new_truth = dict(truth)
        new_truth[failing] = truth[failing] @ mm.rigid(0.0, 0.0, -math.radians(turn))
        for n, status in enumerate(after):
            placed = mm.status_transforms(status)
            others = self.placed_right(placed, [names[0]] + [ns for ns in names[1:] if ns != failing], truth,
                                       tol_m, tol_deg)
            for ns, (m, d) in others.items():
                self.assertTrue(m < tol_m and d < tol_deg, f'status {n}: {ns} moved to {m:.2f} m, {d:.1f} deg')
            self.assertEqual(len(others), len(names) - 2, f'status {n}: another robot was dropped')
            if placed.get(failing) is None:
                continue
            old_m, old_d = self.placed_right(placed, [names[0], failing], truth, tol_m, tol_deg)[failing]
            new_m, new_d = self.placed_right(placed, [names[0], failing], new_truth, tol_m, tol_deg)[failing]
            if n >= 1 or n == len(after) - 1:
                self.assertTrue(new_m < tol_m and new_d < tol_deg,
                                f'status {n}: {failing} still merged {new_m:.2f} m, {new_d:.1f} deg off its turned '
                                f'map (old placement: {old_m:.2f} m, {old_d:.1f} deg off)')
            else:
                self.assertTrue((new_m < tol_m and new_d < tol_deg) or (old_m < tol_m and old_d < tol_deg),
                                f'status {n}: {failing} merged where neither its old nor its turned map belongs')


if __name__ == '__main__':
    rospy.init_node('mm_slam_failure_checker')
    rostest.rosrun('multirobot_map_merge', 'map_merge_slam_failure', SlamFailureCheck, sys.argv)
