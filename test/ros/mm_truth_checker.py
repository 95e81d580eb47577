#!/usr/bin/env python3
"""rostest node: map_merge without known poses places every robot's map where the ground truth says.

Params: ~status_topic (MergeStatus), ~merged_topic (the merged map), ~robots (list of "ns=file.yaml", as
mm_common), ~truth (truth.json of those maps, relative to data/samples), ~timeout (s), ~tolerance_m (0.3),
~tolerance_deg (2.0); optional ~reference (a robot namespace whose transform must be the identity: with origin_mode
world, world_frame is the reference robot's map frame: e.g. the robot whose map came first must stay the reference).

Waits for a status in which every listed robot is included, then compares each robot's transform into world_frame,
relative to the first listed robot, with the ground truth (the pose of each map frame in the true world), and checks
that the merged map holds each robot's walls where that transform puts them.
"""
import sys
import unittest

import numpy as np
import rospy
import rostest
from nav_msgs.msg import OccupancyGrid

import mm_common as mm
from multirobot_map_merge.msg import MergeStatus


class TruthCheck(unittest.TestCase):
    def check_status(self, status, names, truth, tol_m, tol_deg):
        placed = mm.status_transforms(status)
        ref = names[0]
        for ns in names:
            self.assertIsNotNone(placed.get(ns), f'{ns} is not in the merge')
        for ns in names[1:]:
            estimated = np.linalg.inv(placed[ref]) @ placed[ns]
            expected = np.linalg.inv(truth[ref]) @ truth[ns]
            dist, angle = mm.pose_error(estimated, expected)
            self.assertLess(dist, tol_m, f'{ns} relative to {ref}: placed {dist:.3f} m from the truth')
            self.assertLess(angle, tol_deg, f'{ns} relative to {ref}: rotated {angle:.2f} deg from the truth')
        reference = rospy.get_param('~reference', '')
        if reference:
            dist, angle = mm.pose_error(placed[reference], np.eye(3))
            self.assertLess(dist + angle, 1e-6, f'{reference} is not the reference (world_frame) any more')

    def test_placement_matches_ground_truth(self):
        specs = rospy.get_param('~robots')
        names = [s.split('=', 1)[0] for s in specs]
        truth = mm.truth_poses(rospy.get_param('~truth'), specs)
        timeout = float(rospy.get_param('~timeout', 40.0))
        tol_m, tol_deg = float(rospy.get_param('~tolerance_m', 0.3)), float(rospy.get_param('~tolerance_deg', 2.0))

        def all_included(status):
            included = {r.robot_namespace for r in status.robots if r.included}
            return set(names) <= included
        status = mm.wait_for(rospy.get_param('~status_topic'), MergeStatus, all_included, timeout,
                             f'status with {", ".join(names)} all included')
        self.check_status(status, names, truth, tol_m, tol_deg)
        placed = mm.status_transforms(status)

        # the merged map published after that status holds every map where the status places it
        merged = rospy.wait_for_message(rospy.get_param('~merged_topic'), OccupancyGrid, timeout=10.0)
        self.assertGreaterEqual(merged.header.stamp, status.header.stamp)
        grids = mm.robot_maps(specs)
        for ns in names:
            agreement = mm.wall_agreement(grids[ns], placed[ns], merged)
            self.assertGreater(agreement, 0.9, f'{ns}: only {agreement:.0%} of its walls are walls of the merged map')


if __name__ == '__main__':
    rospy.init_node('mm_truth_checker')
    rostest.rosrun('multirobot_map_merge', 'map_merge_truth', TruthCheck, sys.argv)
