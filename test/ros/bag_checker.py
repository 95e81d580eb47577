#!/usr/bin/env python3
"""rostest node for bag_record_merge.test: record the fleet simulator's robot maps with `rosbag record` while the
robots drive, then merge the bag with merge_maps --bag.

Params: ~num_robots.
"""
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import unittest

import actionlib
import cv2
import numpy as np
import rosgraph
import rospy
import rostest
from geometry_msgs.msg import PoseStamped
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
from nav_msgs.msg import OccupancyGrid

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.mapio import load_map
from multirobot_map_merge.ros.conversions import grid_from_msg, yaw_from_quaternion

PKG = 'multirobot_map_merge'
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def yaw_of(q) -> float:
    return yaw_from_quaternion(q.x, q.y, q.z, q.w)


def goal_near(world, clearance, start, rng=(1.0, 2.0)):
    """A free world point 1-2 m from start, on a straight free line from it, well away from walls."""
    sx, sy = start
    res = world.resolution
    best = None
    for angle in np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False):
        for dist in np.arange(rng[1], rng[0] - 1e-9, -0.25):
            points = [(sx + t * math.cos(angle), sy + t * math.sin(angle)) for t in np.linspace(0.0, dist, 20)]
            cells = [(int(y / res), int(x / res)) for x, y in points]
            if all(0 <= r < clearance.shape[0] and 0 <= c < clearance.shape[1] and clearance[r, c] > 0.45
                   for r, c in cells):
                best = points[-1]
                break
        if best is not None:
            return best
    return None



def _group_alive(pgid: int) -> bool:
    """Whether any process of the process group is still running."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True

class BagRecordMerge(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix='bag_record_merge_')
        cls.n = int(rospy.get_param('~num_robots'))
        cls.ns = [f'robot_{i + 1}' for i in range(cls.n)]
        cls.world = grid_from_msg(rospy.wait_for_message('/fleet_sim/world_map', OccupancyGrid, timeout=30.0))
        cls.starts = {}
        for ns in cls.ns:
            msg = rospy.wait_for_message(f'/{ns}/ground_truth/start_pose', PoseStamped, timeout=30.0)
            cls.starts[ns] = (msg.pose.position.x, msg.pose.position.y, yaw_of(msg.pose.orientation))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def wait_for_recorder(self, topics, timeout=30.0):
        master = rosgraph.Master('/bag_checker')
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            _, subscribers, _ = master.getSystemState()
            subs = {t: nodes for t, nodes in subscribers}
            if all(any(n.startswith('/record') for n in subs.get(t, [])) for t in topics):
                return
            time.sleep(0.2)
        self.fail(f'rosbag record did not subscribe to {topics} within {timeout} s')

    def drive(self):
        free = (self.world.data == 0).astype(np.uint8)
        clearance = cv2.distanceTransform(free[:, :], cv2.DIST_L2, 5) * self.world.resolution
        clients = []
        for ns in self.ns:
            x, y, yaw = self.starts[ns]
            target = goal_near(self.world, clearance, (x, y))
            self.assertIsNotNone(target, f'no goal found near the start of {ns}')
            # the goal in the robot's map frame (its start pose)
            gx, gy = tf.apply(tf.inverse(tf.rigid(x, y, yaw)), np.array([target]))[0]
            client = actionlib.SimpleActionClient(f'/{ns}/move_base', MoveBaseAction)
            self.assertTrue(client.wait_for_server(rospy.Duration(30.0)), f'{ns}/move_base not available')
            goal = MoveBaseGoal()
            goal.target_pose.header.frame_id = f'{ns}/map'
            goal.target_pose.pose.position.x, goal.target_pose.pose.position.y = float(gx), float(gy)
            goal.target_pose.pose.orientation.w = 1.0
            client.send_goal(goal)
            clients.append(client)
        for client in clients:
            client.wait_for_result(rospy.Duration(60.0))

    def merge(self, *args):
        cmd = [sys.executable, os.path.join(REPO, 'nodes', 'merge_maps'), *args]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)

    def test_recorded_bag_merges(self):
        bag = os.path.join(self.tmp, 'fleet.bag')
        topics = [f'/{ns}/{t}' for ns in self.ns for t in ('map', 'map_updates')]
        recorder = subprocess.Popen(['rosbag', 'record', '-O', bag, '__name:=record_maps', *topics],
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                    stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            self.wait_for_recorder(topics)
            self.drive()
            time.sleep(1.0)   # the last updates reach the recorder
        finally:
            os.killpg(recorder.pid, signal.SIGINT)
            try:
                recorder.wait(timeout=20.0)
            except subprocess.TimeoutExpired:
                os.killpg(recorder.pid, signal.SIGKILL)
                recorder.wait()
        # `rosbag record` runs the recorder as its child, which may still be closing the bag when the parent has
        # exited (once in CI it renamed the bag while it was being reindexed): wait for the whole group, bounded
        deadline = time.monotonic() + 20.0
        while not os.path.isfile(bag) and _group_alive(recorder.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        if not os.path.isfile(bag) and os.path.isfile(bag + '.active'):
            # a recorder that did not close its bag within 20 s of SIGINT (once in CI) leaves it unindexed and
            # named .active: reindexed, it holds what was recorded
            rospy.logwarn('bag_checker: rosbag record did not close its bag; reindexing it')
            subprocess.run(['rosbag', 'reindex', bag + '.active'], capture_output=True, timeout=60,
                           stdin=subprocess.DEVNULL)
            os.replace(bag + '.active', bag)
        self.assertTrue(os.path.isfile(bag), os.listdir(self.tmp))

        # at the true start poses the merged map must lie on the world
        poses = os.path.join(self.tmp, 'poses.yaml')
        with open(poses, 'w') as f:
            f.write('poses:\n' + ''.join(f'  {ns}: {list(self.starts[ns])}\n' for ns in self.ns))
        out = os.path.join(self.tmp, 'known')
        done = self.merge('--bag', bag, '--known-poses', poses, '--output', out,
                          '--transforms-json', out + '.json')
        self.assertEqual(done.returncode, 0, done.stderr)
        self.assertIn('updates', done.stderr)
        counts = [(int(m), int(u)) for m, u in re.findall(r'\((\d+) maps, (\d+) updates', done.stderr)]
        self.assertEqual(len(counts), self.n, done.stderr)
        # the robots moved: each map was sent again, as an update or (when it grew) a full map; the bag holds
        # updates, which merge_maps applied
        self.assertTrue(all(m + u > 1 for m, u in counts), done.stderr)
        self.assertGreater(sum(u for _, u in counts), 0, done.stderr)
        doc = json.load(open(out + '.json'))
        self.assertEqual([m['robot'] for m in doc['maps']], [f'/{ns}' for ns in self.ns])
        self.assertTrue(all(m['included'] for m in doc['maps']))
        merged = load_map(out + '.yaml')
        self.assert_on_world(merged)
        self.assertTrue(os.path.getsize(out + '_overlay.png') > 0)

        # without known poses: written (whether the two maps overlap depends on the random starts)
        est = os.path.join(self.tmp, 'estimated')
        done = self.merge('--bag', bag, '--output', est, '--transforms-json', est + '.json')
        self.assertEqual(done.returncode, 0, done.stderr)
        self.assertTrue(os.path.isfile(est + '.yaml') and os.path.isfile(est + '_overlay.png'))
        self.assertEqual(len(json.load(open(est + '.json'))['maps']), self.n)

    def assert_on_world(self, merged):
        res = self.world.resolution
        walls = (self.world.data != 0).astype(np.uint8)   # occupied and unknown cells are the world's walls
        near_wall = cv2.distanceTransform(1 - walls, cv2.DIST_L2, 5) * res
        rows, cols = np.nonzero(merged.data >= 65)
        self.assertGreater(len(rows), 50)
        # cell centres in the world (the merged frame is the world: the poses are world poses)
        xs = merged.origin[0] + (cols + 0.5) * merged.resolution
        ys = merged.origin[1] + (rows + 0.5) * merged.resolution
        r = np.clip((ys / res).astype(int), 0, walls.shape[0] - 1)
        c = np.clip((xs / res).astype(int), 0, walls.shape[1] - 1)
        on_wall = float(np.mean(near_wall[r, c] <= 0.11))
        self.assertGreater(on_wall, 0.95, f'only {on_wall:.1%} of the merged walls lie on the world walls')
        rows, cols = np.nonzero(merged.data == 0)
        xs = merged.origin[0] + (cols + 0.5) * merged.resolution
        ys = merged.origin[1] + (rows + 0.5) * merged.resolution
        r = np.clip((ys / res).astype(int), 0, walls.shape[0] - 1)
        c = np.clip((xs / res).astype(int), 0, walls.shape[1] - 1)
        self.assertGreater(float(np.mean(walls[r, c] == 0)), 0.97)


if __name__ == '__main__':
    rospy.init_node('bag_checker')
    rostest.rosrun(PKG, 'bag_record_merge', BagRecordMerge, sys.argv)
