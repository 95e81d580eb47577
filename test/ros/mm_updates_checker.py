#!/usr/bin/env python3
"""rostest node: map_updates and full-map replacement reach the merged map (map_merge.md §4, §6).

It publishes the robot maps and updates itself, so that it controls their order, and checks the merged maps of two
map_merge nodes:
  * ~kp_*: known poses, origin_mode world, robot map frame = world: an update inside the map, an update clipped at
    the right edge (rows must not shift: the original's bug), then a full map of a new size with an older stamp
    than the last update (the original drops it);
  * ~est_*: estimation mode with a very slow estimation_rate: an update must reach the merged map before the next
    estimation (the merged content follows the newest maps at merging_rate).
"""
import sys
import unittest

import numpy as np
import rospy
import rostest
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid

import mm_common as mm
from multirobot_map_merge.grid import Grid
from multirobot_map_merge.msg import MergeStatus
from multirobot_map_merge.ros.conversions import grid_to_msg


def update_msg(x, y, data, stamp=None):
    u = OccupancyGridUpdate()
    u.header.stamp = stamp or rospy.Time.now()
    data = np.asarray(data, np.int8)
    u.x, u.y, u.height, u.width = x, y, data.shape[0], data.shape[1]
    u.data = data.reshape(-1).tolist()
    return u


def value_at(merged, x, y):
    """Merged cell value at world point (x, y), or None outside the merged grid."""
    c, r, _ = np.floor(np.linalg.inv(mm.merged_cell_to_world(merged)) @ [x, y, 1.0]).astype(int)
    data = mm.merged_array(merged)
    return int(data[r, c]) if 0 <= r < data.shape[0] and 0 <= c < data.shape[1] else None


class UpdatesCheck(unittest.TestCase):
    def wait_merged(self, topic, predicate, what, timeout=15.0):
        return mm.wait_for(topic, OccupancyGrid, predicate, timeout, what)

    def test_known_poses_updates_clipping_and_resize(self):
        topic = rospy.get_param('~kp_merged_topic')
        ns = rospy.get_param('~kp_robot')
        map_pub = rospy.Publisher(ns + '/map', OccupancyGrid, queue_size=1, latch=True)
        upd_pub = rospy.Publisher(ns + '/map_updates', OccupancyGridUpdate, queue_size=10)
        res, origin = 0.1, (1.0, 2.0, 0.0)
        first = Grid(np.zeros((30, 40), np.int8), res, origin, ns.strip('/') + '/map')
        map_pub.publish(grid_to_msg(first, stamp=rospy.Time.now()))

        def centre(c, r):   # world point of robot cell (c, r): init pose (0, 0, 0)
            return origin[0] + (c + 0.5) * res, origin[1] + (r + 0.5) * res
        self.wait_merged(topic, lambda m: value_at(m, *centre(39, 29)) == 0, 'the first map')
        while upd_pub.get_num_connections() == 0:
            rospy.sleep(0.1)

        inside = [[100, 90, 80], [70, 60, 50]]
        upd_pub.publish(update_msg(5, 4, inside))
        m = self.wait_merged(topic, lambda m: value_at(m, *centre(5, 4)) == 100, 'the inside update')
        for r in range(2):
            for c in range(3):
                self.assertEqual(value_at(m, *centre(5 + c, 4 + r)), inside[r][c], f'cell ({5 + c}, {4 + r})')

        # 4 x 3 at x 38 in a 40 wide map: 2 x 3 cells fit; row k must get data[k][0:2]
        clipped = [[11, 12, 13, 14], [21, 22, 23, 24], [31, 32, 33, 34]]
        last_update = rospy.Time.now()
        upd_pub.publish(update_msg(38, 10, clipped, last_update))
        m = self.wait_merged(topic, lambda m: value_at(m, *centre(38, 10)) == 11, 'the clipped update')
        for r in range(3):
            for c in range(2):
                self.assertEqual(value_at(m, *centre(38 + c, 10 + r)), clipped[r][c], f'cell ({38 + c}, {10 + r})')
        self.assertIn(value_at(m, *centre(40, 10)), (None, -1), 'the clipped part went past the map edge')

        # a full map of a new size, stamped before the last update: it must still replace the stored map
        bigger = Grid(np.zeros((40, 50), np.int8), res, origin, first.frame_id)
        bigger.data[35, 45] = 100
        map_pub.publish(grid_to_msg(bigger, stamp=last_update - rospy.Duration(5.0)))
        m = self.wait_merged(topic, lambda m: value_at(m, *centre(45, 35)) == 100, 'the resized map')
        self.assertEqual(value_at(m, *centre(5, 4)), 0, 'the old content survived the new full map')
        self.assertEqual(value_at(m, *centre(49, 39)), 0)

    def test_estimation_mode_content_follows_updates(self):
        topic = rospy.get_param('~est_merged_topic')
        status_topic = rospy.get_param('~est_status_topic')
        specs = rospy.get_param('~est_robots')
        grids = mm.robot_maps(specs)
        pubs = {}
        for spec in specs:
            ns = spec.split('=', 1)[0]
            pubs[ns] = (rospy.Publisher(ns + '/map', OccupancyGrid, queue_size=1, latch=True),
                        rospy.Publisher(ns + '/map_updates', OccupancyGridUpdate, queue_size=10))
            pubs[ns][0].publish(grid_to_msg(grids[ns], stamp=rospy.Time.now()))
        names = list(pubs)
        status = mm.wait_for(status_topic, MergeStatus,
                             lambda s: {r.robot_namespace for r in s.robots if r.included} >= set(names), 30.0,
                             'status with both robots included')
        placed = mm.status_transforms(status)
        statuses = []
        status_sub = rospy.Subscriber(status_topic, MergeStatus, statuses.append)

        # an occupied 12 x 12 block on a free part of the second robot's map
        ns, grid = names[1], grids[names[1]]
        free = grid.data == 0
        r0, c0 = next((r, c) for r in range(0, grid.height - 12, 4) for c in range(0, grid.width - 12, 4)
                      if free[r:r + 12, c:c + 12].all())
        points = [(placed[ns] @ grid.cell_to_map() @ [c + 0.5, r + 0.5, 1.0])[:2]
                  for r in range(r0 + 3, r0 + 9) for c in range(c0 + 3, c0 + 9)]   # inner cells only

        def occupied_share(m):
            values = [value_at(m, x, y) for x, y in points]
            return sum(v is not None and v >= 65 for v in values) / len(values)
        before = rospy.wait_for_message(topic, OccupancyGrid, timeout=10.0)
        self.assertLess(occupied_share(before), 0.2, 'the test block area is already occupied')
        while pubs[ns][1].get_num_connections() == 0:
            rospy.sleep(0.1)
        sent = rospy.Time.now()
        pubs[ns][1].publish(update_msg(c0, r0, np.full((12, 12), 100), sent))
        m = self.wait_merged(topic, lambda m: occupied_share(m) > 0.9, 'the update in the merged map', 30.0)
        status_sub.unregister()
        newer = [s.header.stamp for s in statuses if s.header.stamp > sent]
        self.assertTrue(not newer or m.header.stamp < min(newer), 'the update was merged only after an estimation')


if __name__ == '__main__':
    rospy.init_node('mm_updates_checker')
    rostest.rosrun('multirobot_map_merge', 'map_merge_updates', UpdatesCheck, sys.argv)
