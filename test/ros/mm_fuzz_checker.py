#!/usr/bin/env python3
"""rostest node of map_merge_fuzz.test: while mm_fuzz_publisher.py floods bad robots with malformed maps and
updates, the node stays alive, merges at its rate and never publishes a malformed merged map; the good robots are
placed right at the end.

Params: ~topic (merged map), ~duration (s measured), ~merging_rate (Hz), ~window (s, default 5), ~min_sent
(messages the fuzz publisher must have sent), ~node (the map_merge node name), ~good (list "/ns=map.yaml" specs of
the good robots), ~truth (truth.json of their poses), ~shift ([x, y]: their init poses are the truth poses shifted
by this), ~bad (list of bad robot namespaces, each must be named in a warning of the node on /rosout).
"""
import math
import sys
import threading
import time
import unittest

import numpy as np
import rosnode
import rospy
import rostest
from nav_msgs.msg import OccupancyGrid
from rosgraph_msgs.msg import Log

from mm_common import rigid, robot_maps, truth_poses, wall_agreement

PKG = 'multirobot_map_merge'


def malformed(msg) -> str:
    """Why a merged map message is malformed, or ''."""
    w, h, res = msg.info.width, msg.info.height, msg.info.resolution
    if len(msg.data) != w * h or w * h == 0:
        return f'{len(msg.data)} cells for {w} x {h}'
    if not (math.isfinite(res) and res > 0):
        return f'resolution {res}'
    o = msg.info.origin
    if not all(math.isfinite(v) for v in (o.position.x, o.position.y, o.orientation.z, o.orientation.w)):
        return 'origin not finite'
    data = np.frombuffer(bytes(msg.data), np.int8) if isinstance(msg.data, bytes) else np.asarray(msg.data, np.int8)
    bad = int(np.count_nonzero((data < -1) | (data > 100)))
    return f'{bad} cells outside -1 and 0..100' if bad else ''


class FuzzCheck(unittest.TestCase):
    def test_merge_survives_the_fuzz(self):
        topic = rospy.get_param('~topic', '/map_merge/map')
        duration = float(rospy.get_param('~duration', 75.0))
        rate = float(rospy.get_param('~merging_rate', 4.0))
        window = float(rospy.get_param('~window', 5.0))
        node = rospy.get_param('~node', '/map_merge/map_merge')
        lock = threading.Lock()
        arrivals, problems, last = [], [], [None]
        warned = []

        def on_merged(msg):
            why = malformed(msg)
            with lock:
                arrivals.append(time.monotonic())
                last[0] = msg
                if why:
                    problems.append(why)

        def on_log(m):
            if m.name == node and m.level >= Log.WARN:
                warned.append(m.msg)
        rospy.Subscriber(topic, OccupancyGrid, on_merged, queue_size=200, buff_size=1 << 26)
        rospy.Subscriber('/rosout', Log, on_log, queue_size=500)
        deadline = time.monotonic() + 40.0
        while not arrivals and time.monotonic() < deadline and not rospy.is_shutdown():
            time.sleep(0.1)
        self.assertTrue(arrivals, 'no merged map within 40 s')
        time.sleep(window)   # warm-up: robots discovered, the fuzz under way
        start = time.monotonic()
        while time.monotonic() < start + duration and not rospy.is_shutdown():
            time.sleep(0.5)
        end = time.monotonic()
        with lock:
            times, found, final = [t for t in arrivals if start <= t < end], list(problems), last[0]
        seed = rospy.get_param('/mm_fuzz/seed', None)
        sent = int(rospy.get_param('/mm_fuzz/sent', 0))
        counts = [int(sum(a <= t < a + window for t in times)) for a in np.arange(start, end - window + 1e-6, window)]
        print(f'fuzz seed {seed} (replay: rostest with mm_fuzz_publisher _seed:={seed}); {sent} malformed or random '
              f'messages sent; merged maps per {window:.0f} s window: {counts}', flush=True)

        self.assertGreaterEqual(sent, int(rospy.get_param('~min_sent', 3000)), 'the fuzz publisher sent too little')
        self.assertEqual(found, [], f'malformed merged maps (seed {seed})')
        low = [c for c in counts if c < 0.9 * rate * window]
        self.assertFalse(low, f'merged rate below 90 % of {rate} Hz in {len(low)} of {len(counts)} windows of '
                              f'{window} s: {counts} (seed {seed})')
        self.assertTrue(rosnode.rosnode_ping(node, max_count=1), f'{node} does not answer (seed {seed})')

        maps = robot_maps(rospy.get_param('~good'))
        shift = rigid(*rospy.get_param('~shift', [0.0, 0.0]), 0.0)   # the init poses are the truth shifted by this
        truth = truth_poses(rospy.get_param('~truth'), rospy.get_param('~good'))
        poses = {ns: shift @ pose for ns, pose in truth.items()}
        for ns, grid in maps.items():
            agreement = wall_agreement(grid, poses[ns], final)
            self.assertGreaterEqual(agreement, 0.9, f'good robot {ns} misplaced: {agreement:.2f} of its walls on '
                                                    f'merged walls (seed {seed})')
        watched = end - start + 2 * window + 40.0   # the warm-up, at most
        for ns in rospy.get_param('~bad', []):
            mine = [w for w in warned if f'[{ns}]' in w]
            self.assertTrue(mine, f'no warning names the bad robot {ns}')
            # throttled: one per kind (map, tilt, update, cells, left_out) per 10 s
            self.assertLessEqual(len(mine), 5 * (watched / 10.0 + 1), f'warnings about {ns} not throttled')
        self.assertTrue(any('not a pure yaw' in w and '[/bad' in w for w in warned),
                        'the tilted-origin warning does not name the robot')
        print(f'{len(warned)} warnings from {node} in {watched:.0f} s at most', flush=True)


if __name__ == '__main__':
    rospy.init_node('mm_fuzz_checker')
    rostest.rosrun(PKG, 'mm_fuzz_checker', FuzzCheck, sys.argv)
