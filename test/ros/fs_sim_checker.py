#!/usr/bin/env python3
"""rostest node for fleet_sim_basic.test: the simulator's ROS interface against its own ground truth.

Params: ~robots (the simulator's robot list), ~speedup (expected sim/real rate; the test runs with /use_sim_time),
~goal_robot (robot that drives the free goal, the wall goal and the cancel), ~enclosed (list of "ns,x,y": a goal in
world metres that robot cannot reach because it is enclosed), ~timeout (s, wall clock per goal).
"""
import math
import sys
import threading
import time
import unittest

import actionlib
import cv2
import numpy as np
import rospy
import rostest
import tf2_ros
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import PoseStamped
from map_msgs.msg import OccupancyGridUpdate
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
from nav_msgs.msg import OccupancyGrid
from rosgraph_msgs.msg import Clock

from multirobot_map_merge.ros.conversions import yaw_from_quaternion

PKG = 'multirobot_map_merge'


def yaw_of(q):
    return yaw_from_quaternion(q.x, q.y, q.z, q.w)


def pose_of(msg: PoseStamped):
    p = msg.pose.position
    return (p.x, p.y, yaw_of(msg.pose.orientation))


def compose(a, b):
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.remainder(a[2] + b[2], 2 * math.pi))


def relative(ref, p):
    c, s = math.cos(ref[2]), math.sin(ref[2])
    dx, dy = p[0] - ref[0], p[1] - ref[1]
    return (c * dx + s * dy, -s * dx + c * dy, math.remainder(p[2] - ref[2], 2 * math.pi))


def grid_array(msg: OccupancyGrid) -> np.ndarray:
    return np.asarray(msg.data, np.int8).reshape(msg.info.height, msg.info.width)


class MapRecorder:
    """Records a robot's <ns>/map and <ns>/map_updates messages (map and update topics are separate connections, so
    their arrival order is not their publication order: everything is ordered by stamp and sequence number)."""

    def __init__(self, ns: str) -> None:
        self.lock = threading.Lock()
        self.maps = []        # (stamp, seq, geometry, array)
        self.updates = []     # (stamp, seq, x, y, array)
        rospy.Subscriber(f'{ns}/map', OccupancyGrid, self._on_map, queue_size=50, buff_size=1 << 24)
        rospy.Subscriber(f'{ns}/map_updates', OccupancyGridUpdate, self._on_update, queue_size=500,
                         buff_size=1 << 24)

    @staticmethod
    def geometry(info):
        o = info.origin.position
        return (info.width, info.height, round(o.x, 6), round(o.y, 6))

    def _on_map(self, msg: OccupancyGrid) -> None:
        with self.lock:
            self.maps.append((msg.header.stamp, msg.header.seq, self.geometry(msg.info), grid_array(msg)))

    def _on_update(self, msg: OccupancyGridUpdate) -> None:
        data = np.asarray(msg.data, np.int8).reshape(msg.height, msg.width)
        with self.lock:
            self.updates.append((msg.header.stamp, msg.header.seq, msg.x, msg.y, data))

    def check_pairs(self):
        """For every two consecutive full maps of the same geometry, paste the updates stamped between them into
        the first: it must give the second. Returns (pairs checked, updates used, cells wrong)."""
        with self.lock:
            maps = sorted(self.maps, key=lambda m: (m[0], m[1]))
            updates = sorted(self.updates, key=lambda u: (u[0], u[1]))
        pairs = used = wrong = 0
        for (s0, _, g0, a0), (s1, _, g1, a1) in zip(maps, maps[1:]):
            if g0 != g1:
                continue     # the map grew: an update cannot express that
            rebuilt = a0.copy()
            between = [u for u in updates if s0 <= u[0] <= s1]
            for _, _, x, y, data in between:
                rebuilt[y:y + data.shape[0], x:x + data.shape[1]] = data
            pairs += 1
            used += len(between)
            wrong += int(np.count_nonzero(rebuilt != a1))
        return pairs, used, wrong


class FleetSimCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.robots = rospy.get_param('~robots')
        cls.ns = [r['ns'] for r in cls.robots]
        cls.speedup = float(rospy.get_param('~speedup', 1.0))
        cls.timeout = float(rospy.get_param('~timeout', 40.0))
        cls.goal_ns = rospy.get_param('~goal_robot', cls.ns[0])
        cls.recorders = {ns: MapRecorder(ns) for ns in cls.ns}
        cls.tf_buffer = tf2_ros.Buffer()
        cls.tf_listener = tf2_ros.TransformListener(cls.tf_buffer)
        cls.world = rospy.wait_for_message('/fleet_sim/world_map', OccupancyGrid, timeout=30.0)
        cls.world_arr = grid_array(cls.world)
        free = (cls.world_arr == 0).astype(np.uint8)
        cls.world_clear = cv2.distanceTransform(free, cv2.DIST_L2, 5) * cls.world.info.resolution
        cls.wall_dist = cls.world_clear   # distance (m) from free cells to the nearest non-free cell
        cls.clients = {}

    # ------------------------------------------------------------------ helpers
    def world_cell(self, x, y):
        """World cell (col, row) arrays of point arrays, clipped into the grid."""
        info = self.world.info
        c = np.floor((np.asarray(x) - info.origin.position.x) / info.resolution).astype(int)
        r = np.floor((np.asarray(y) - info.origin.position.y) / info.resolution).astype(int)
        return np.clip(c, 0, info.width - 1), np.clip(r, 0, info.height - 1)

    def start_pose(self, ns):
        return pose_of(rospy.wait_for_message(f'{ns}/ground_truth/start_pose', PoseStamped, timeout=10.0))

    def true_pose(self, ns):
        return pose_of(rospy.wait_for_message(f'{ns}/ground_truth/pose', PoseStamped, timeout=10.0))

    def client(self, ns, key=''):
        if (ns, key) not in self.clients:
            c = actionlib.SimpleActionClient(f'{ns}/move_base', MoveBaseAction)
            self.assertTrue(c.wait_for_server(rospy.Duration(20.0)), f'{ns}/move_base not up')
            self.clients[(ns, key)] = c
        return self.clients[(ns, key)]

    def goal(self, ns, x, y, frame=None):
        g = MoveBaseGoal()
        g.target_pose.header.frame_id = f'{ns}/map' if frame is None else frame
        g.target_pose.header.stamp = rospy.Time.now()
        g.target_pose.pose.position.x, g.target_pose.pose.position.y = x, y
        g.target_pose.pose.orientation.w = 1.0
        return g

    def map_cells_world(self, ns, msg, value_test):
        """World (x, y) of the centres of the map cells whose value passes value_test."""
        start = self.start_pose(ns)
        data = grid_array(msg)
        rows, cols = np.nonzero(value_test(data))
        res, o = msg.info.resolution, msg.info.origin.position
        mx, my = o.x + (cols + 0.5) * res, o.y + (rows + 0.5) * res
        c, s = math.cos(start[2]), math.sin(start[2])
        return start[0] + c * mx - s * my, start[1] + s * mx + c * my

    def sim_sleep(self, seconds):
        """Sleep in sim time (rospy.sleep follows /clock when /use_sim_time is set)."""
        rospy.sleep(seconds)

    # ------------------------------------------------------------------ tests (run in name order)
    def test_01_world_and_start_poses(self):
        self.assertEqual(self.world.header.frame_id, 'world')
        self.assertGreater(int((self.world_arr == 0).sum()), 1000)
        for r in self.robots:
            p = self.start_pose(r['ns'])
            self.assertAlmostEqual(p[0], r['x'], places=6)
            self.assertAlmostEqual(p[1], r['y'], places=6)
            self.assertAlmostEqual(math.remainder(p[2] - r.get('yaw', 0.0), 2 * math.pi), 0.0, places=6)

    def test_02_clock_runs_at_speedup(self):
        first = rospy.wait_for_message('/clock', Clock, timeout=10.0).clock.to_sec()
        wall0 = time.monotonic()
        time.sleep(3.0)
        last = rospy.wait_for_message('/clock', Clock, timeout=10.0).clock.to_sec()
        rate = (last - first) / (time.monotonic() - wall0)
        # paced by the wall clock: never faster than speedup; slower only when the machine is overloaded
        self.assertGreater(rate, 0.5 * self.speedup, f'/clock runs at {rate:.2f} x real time')
        self.assertLess(rate, 1.2 * self.speedup, f'/clock runs at {rate:.2f} x real time')

    def test_03_tf_is_the_true_pose_in_the_map_frame(self):
        for ns in self.ns:
            t = self.tf_buffer.lookup_transform(f'{ns}/map', f'{ns}/base_link', rospy.Time(0), rospy.Duration(10.0))
            expected = relative(self.start_pose(ns), self.true_pose(ns))    # robots stand still here
            self.assertAlmostEqual(t.transform.translation.x, expected[0], places=3)
            self.assertAlmostEqual(t.transform.translation.y, expected[1], places=3)
            self.assertAlmostEqual(math.remainder(yaw_of(t.transform.rotation) - expected[2], 2 * math.pi), 0.0,
                                   places=3)

    def check_map_against_world(self, ns, msg):
        self.assertEqual(msg.header.frame_id, f'{ns}/map')
        # the map frame's origin (the start pose) lies inside the map
        o, res = msg.info.origin.position, msg.info.resolution
        self.assertTrue(o.x <= 0.0 < o.x + msg.info.width * res and o.y <= 0.0 < o.y + msg.info.height * res)
        ox, oy = self.map_cells_world(ns, msg, lambda d: d == 100)
        fx, fy = self.map_cells_world(ns, msg, lambda d: d == 0)
        self.assertGreater(ox.size, 50, f'{ns}: too few walls mapped')
        self.assertGreater(fx.size, 1000, f'{ns}: too little free space mapped')
        wc, wr = self.world_cell(ox, oy)
        # walls within a cell of true walls: a mapped wall cell centre is at most 1.5 cells from a blocking cell
        near_wall = self.wall_dist[wr, wc] <= 1.5 * self.world.info.resolution
        self.assertGreater(near_wall.mean(), 0.99, f'{ns}: {np.count_nonzero(~near_wall)} walls off true walls')
        fc, fr = self.world_cell(fx, fy)
        on_free = self.world_arr[fr, fc] == 0
        self.assertGreater(on_free.mean(), 0.99, f'{ns}: {np.count_nonzero(~on_free)} free cells on true walls')

    def test_04_maps_match_the_world(self):
        for ns in self.ns:
            self.check_map_against_world(ns, rospy.wait_for_message(f'{ns}/map', OccupancyGrid, timeout=10.0))

    def pick_free_goal(self, ns, lo=1.5, hi=3.5):
        """A map-frame goal on free space the robot has seen, lo..hi m away, well clear of true walls."""
        msg = rospy.wait_for_message(f'{ns}/map', OccupancyGrid, timeout=10.0)
        start = self.start_pose(ns)
        here = relative(start, self.true_pose(ns))
        wx, wy = self.map_cells_world(ns, msg, lambda d: d == 0)
        wc, wr = self.world_cell(wx, wy)
        clear = self.world_clear[wr, wc]
        rel = [relative(start, (x, y, 0.0)) for x, y in zip(wx, wy)]
        d = np.array([math.hypot(p[0] - here[0], p[1] - here[1]) for p in rel])
        ok = np.flatnonzero((clear >= 0.5) & (d >= lo) & (d <= hi))
        self.assertGreater(ok.size, 0, f'{ns}: no seen free cell {lo}..{hi} m away')
        k = ok[np.argmax(d[ok])]
        return rel[k][0], rel[k][1]

    def test_05_free_goal_succeeds_and_updates_rebuild_the_map(self):
        ns = self.goal_ns
        gx, gy = self.pick_free_goal(ns)
        feedback = []
        c = self.client(ns)
        c.send_goal(self.goal(ns, gx, gy), feedback_cb=lambda fb: feedback.append(fb))
        self.assertTrue(c.wait_for_result(rospy.Duration(self.timeout * max(self.speedup, 1.0))))
        self.assertEqual(c.get_state(), GoalStatus.SUCCEEDED, c.get_goal_status_text())
        self.assertGreater(len(feedback), 0, 'no feedback')
        self.assertEqual(feedback[-1].base_position.header.frame_id, f'{ns}/map')
        here = relative(self.start_pose(ns), self.true_pose(ns))
        self.assertLess(math.hypot(here[0] - gx, here[1] - gy), 0.3, f'robot at {here}, goal ({gx}, {gy})')
        # the robot stands still now: wait until the last changes are published
        self.sim_sleep(2.0)
        full = rospy.wait_for_message(f'{ns}/map', OccupancyGrid, timeout=10.0)
        pairs, used, wrong = self.recorders[ns].check_pairs()
        self.assertGreater(pairs, 0, 'no two full maps of the same size')
        self.assertGreater(used, 0, 'no map_updates between full maps')
        self.assertEqual(wrong, 0, f'{wrong} cells differ between full maps and full map + updates '
                         f'({pairs} pairs, {used} updates)')
        self.check_map_against_world(ns, full)

    def test_06_goal_in_a_wall_aborts(self):
        ns = self.goal_ns
        msg = rospy.wait_for_message(f'{ns}/map', OccupancyGrid, timeout=10.0)
        data = grid_array(msg)
        rows, cols = np.nonzero(data == 100)
        k = len(rows) // 2
        res, o = msg.info.resolution, msg.info.origin.position
        c = self.client(ns)
        c.send_goal(self.goal(ns, o.x + (cols[k] + 0.5) * res, o.y + (rows[k] + 0.5) * res))
        self.assertTrue(c.wait_for_result(rospy.Duration(self.timeout * max(self.speedup, 1.0))))
        self.assertEqual(c.get_state(), GoalStatus.ABORTED, c.get_goal_status_text())

    def test_07_enclosed_goal_aborts(self):
        for spec in rospy.get_param('~enclosed', []):
            ns, x, y = spec.split(',')
            g = relative(self.start_pose(ns), (float(x), float(y), 0.0))
            c = self.client(ns)
            c.send_goal(self.goal(ns, g[0], g[1]))
            self.assertTrue(c.wait_for_result(rospy.Duration(self.timeout * max(self.speedup, 1.0))))
            self.assertEqual(c.get_state(), GoalStatus.ABORTED, c.get_goal_status_text())

    def test_08_cancel_and_new_goal_preempt(self):
        ns = self.goal_ns
        start = self.start_pose(ns)
        here = self.true_pose(ns)
        # far goals: free world cells 4+ m away (reachable: the generated world is connected)
        rows, cols = np.nonzero(self.world_clear >= 0.5)
        res, o = self.world.info.resolution, self.world.info.origin.position
        wx, wy = o.x + (cols + 0.5) * res, o.y + (rows + 0.5) * res
        far = np.flatnonzero(np.hypot(wx - here[0], wy - here[1]) > 4.0)
        self.assertGreater(far.size, 1)
        goals = [relative(start, (wx[i], wy[i], 0.0)) for i in (far[0], far[-1])]
        fb = threading.Event()
        a = self.client(ns)
        a.send_goal(self.goal(ns, *goals[0][:2]), feedback_cb=lambda _: fb.set())
        self.assertTrue(fb.wait(30.0), 'no feedback for an active goal')
        a.cancel_goal()
        self.assertTrue(a.wait_for_result(rospy.Duration(30.0)))
        self.assertEqual(a.get_state(), GoalStatus.PREEMPTED, a.get_goal_status_text())
        # a new goal preempts the one being driven
        fb.clear()
        a.send_goal(self.goal(ns, *goals[0][:2]), feedback_cb=lambda _: fb.set())
        self.assertTrue(fb.wait(30.0), 'no feedback for an active goal')
        b = self.client(ns, 'second')
        b.send_goal(self.goal(ns, *goals[1][:2]))
        self.assertTrue(a.wait_for_result(rospy.Duration(30.0)))
        self.assertEqual(a.get_state(), GoalStatus.PREEMPTED, a.get_goal_status_text())
        b.cancel_goal()
        self.assertTrue(b.wait_for_result(rospy.Duration(30.0)))
        self.assertEqual(b.get_state(), GoalStatus.PREEMPTED, b.get_goal_status_text())

    def test_09_goal_in_a_foreign_frame_aborts(self):
        ns = self.goal_ns
        c = self.client(ns)
        c.send_goal(self.goal(ns, 0.5, 0.0, frame='world'))
        self.assertTrue(c.wait_for_result(rospy.Duration(30.0)))
        self.assertEqual(c.get_state(), GoalStatus.ABORTED, c.get_goal_status_text())


if __name__ == '__main__':
    rospy.init_node('fs_sim_checker')
    rostest.rosrun(PKG, 'fleet_sim_check', FleetSimCheck, sys.argv)
