#!/usr/bin/env python3
"""rostest node: map_merge on a busy machine places robots late, never wrong (issue 33).

Keeps every core busy (~busy_per_core processes a core, each ending by itself after ~busy_seconds, and all ended in
tearDown, at exit and on SIGINT/SIGTERM), publishes the robot maps itself (latched, one robot every ~robot_delay
s), and checks every ~status the node publishes: each robot it includes is placed where the ground truth says
(relative to the first included robot of ~robots, within ~tolerance_m / ~tolerance_deg), and its walls are walls of
the merged map sent with that status (the same stamp: the merge cycle that sent it). A robot may be left out of a
status (a search the time budget cut is made in a later estimation), never misplaced. Every robot must be included
within ~timeout s of the last map (a liveness bound, not a speed figure); then statuses are watched ~hold s more.

Params: ~status_topic, ~merged_topic, ~robots (list of "ns=file.yaml" as mm_common; the checker publishes each on
<ns>/map), ~truth (truth.json, or a recorded demo's start_poses.json), ~data_dir (optional: the folder the map and
truth paths are relative to, instead of data/samples), ~busy_per_core (2), ~busy_seconds (120), ~robot_delay (0),
~timeout (90), ~hold (6), ~tolerance_m (0.3), ~tolerance_deg (2.0), ~min_walls (0.9).
"""
import atexit
import json
import os
import signal
import subprocess
import sys
import threading
import unittest

import numpy as np
import rospy
import rostest
from nav_msgs.msg import OccupancyGrid
from rospy.numpy_msg import numpy_msg

import mm_common as mm
from multirobot_map_merge.msg import MergeStatus
from multirobot_map_merge.ros.conversions import grid_to_msg

# a busy loop that ends by itself after its bound, or as soon as the checker is gone (even if it was killed)
BUSY = ('import os, time\n'
        'end = time.monotonic() + {seconds}\n'
        'while time.monotonic() < end and os.getppid() == {parent}:\n'
        '    for _ in range(100000):\n'
        '        pass\n')
PAIRING_WAIT = 10.0   # s a status waits for the merged map of its cycle (same stamp) before it counts as unpaired


class Busy:
    """Busy processes on every core, bounded in number and time; stop() ends them (idempotent). Each has a session
    of its own, as other jobs on the machine would: with the kernel's autogroup scheduling, the processes of one
    session share one group's CPU time, so busy processes in the checker's session barely slowed the node (roslaunch
    starts each node in a session of its own)."""

    def __init__(self, per_core: int, seconds: float) -> None:
        self.procs = []
        count = max(1, per_core) * (os.cpu_count() or 1)
        code = BUSY.format(seconds=float(seconds), parent=os.getpid())
        for _ in range(count):
            self.procs.append(subprocess.Popen([sys.executable, '-c', code], stdin=subprocess.DEVNULL,
                                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                               start_new_session=True))
        atexit.register(self.stop)

    def stop(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
        for p in self.procs:
            try:
                p.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                pass


class LoadCheck(unittest.TestCase):
    def setUp(self):
        self.busy = Busy(int(rospy.get_param('~busy_per_core', 2)), float(rospy.get_param('~busy_seconds', 120.0)))
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous = signal.getsignal(sig)

            def handler(signum, frame, previous=previous):
                self.busy.stop()
                if callable(previous):
                    previous(signum, frame)
            signal.signal(sig, handler)

    def tearDown(self):
        self.busy.stop()

    def test_late_never_wrong(self):
        specs = rospy.get_param('~robots')
        truth_path = rospy.get_param('~truth')
        data_dir = rospy.get_param('~data_dir', '')
        if data_dir:
            specs = ['='.join((s.split('=', 1)[0], os.path.join(data_dir, s.split('=', 1)[1]))) for s in specs]
            truth_path = os.path.join(data_dir, truth_path)
        names = [s.split('=', 1)[0] for s in specs]
        grids = mm.robot_maps(specs)
        truth = truth_of(truth_path, specs)
        tol_m, tol_deg = float(rospy.get_param('~tolerance_m', 0.3)), float(rospy.get_param('~tolerance_deg', 2.0))
        min_walls = float(rospy.get_param('~min_walls', 0.9))
        lock = threading.Lock()
        maps = {}        # stamp -> merged map message (numpy data: a list of ints per cell would take GBs)
        statuses = []    # statuses not judged yet

        def on_map(m):
            with lock:
                maps[_key(m.header.stamp)] = m
                for key in [k for k in maps if k[0] < m.header.stamp.secs - 2 * PAIRING_WAIT]:
                    del maps[key]   # long past pairing

        def on_status(s):
            with lock:
                statuses.append(s)
        maps_sub = rospy.Subscriber(rospy.get_param('~merged_topic'), numpy_msg(OccupancyGrid), on_map,
                                    queue_size=100, buff_size=1 << 26)
        status_sub = rospy.Subscriber(rospy.get_param('~status_topic'), MergeStatus, on_status, queue_size=100)

        # the robots' maps, latched: one robot every robot_delay s
        delay = float(rospy.get_param('~robot_delay', 0.0))
        pubs = {ns: rospy.Publisher(ns + '/map', OccupancyGrid, queue_size=1, latch=True) for ns in names}
        start = rospy.get_time()
        for k, ns in enumerate(names):
            while rospy.get_time() < start + k * delay and not rospy.is_shutdown():
                rospy.sleep(0.05)
            pubs[ns].publish(grid_to_msg(grids[ns], stamp=rospy.Time.now()))
        last_map = rospy.get_time()

        timeout = float(rospy.get_param('~timeout', 90.0))
        hold = float(rospy.get_param('~hold', 6.0))
        checked, failures, all_at = 0, [], None
        done_until = None
        while not rospy.is_shutdown():
            now = rospy.get_time()
            ready = []
            with lock:
                for s in list(statuses):
                    m = maps.get(_key(s.header.stamp))
                    if m is not None or now - s.header.stamp.to_sec() > PAIRING_WAIT:
                        ready.append((s, m))
                        statuses.remove(s)
            for s, m in ready:
                checked += 1
                rospy.loginfo('mm_load_checker: status at %.2f (estimation %.2f s): %s included',
                              s.header.stamp.to_sec(), s.estimation_time,
                              ', '.join(r.robot_namespace for r in s.robots if r.included))
                failures += self.judge(s, m, names, grids, truth, tol_m, tol_deg, min_walls)
                included = {r.robot_namespace for r in s.robots if r.included}
                if all_at is None and included >= set(names):
                    all_at = now
                    done_until = now + hold
            if failures:
                break
            if done_until is not None and now >= done_until:
                break
            if all_at is None and now > last_map + timeout:
                break
            rospy.sleep(0.1)
        maps_sub.unregister()
        status_sub.unregister()
        self.busy.stop()
        self.assertFalse(failures, '\n'.join(failures))
        self.assertIsNotNone(all_at, f'not every robot included within {timeout:.0f} s of the last map '
                                     f'({checked} statuses checked)')
        rospy.loginfo('mm_load_checker: %d statuses checked, every robot in %.1f s after the last map', checked,
                      all_at - last_map)

    def judge(self, status, merged, names, grids, truth, tol_m, tol_deg, min_walls):
        """The failures of one status: a robot included but placed off the truth, or off the merged map's walls."""
        at = f'status at {status.header.stamp.to_sec():.2f}'
        if not any(r.included for r in status.robots):
            return []   # nothing placed (no robot map yet): nothing to judge, and no merged map was sent with it
        if merged is None:
            return [f'{at}: no merged map with its stamp within {PAIRING_WAIT:.0f} s']
        placed = {ns: t for ns, t in mm.status_transforms(status).items() if t is not None and ns in grids}
        out = []
        anchor = next((ns for ns in names if ns in placed), None)
        for ns, t in placed.items():
            if ns != anchor:
                estimated = np.linalg.inv(placed[anchor]) @ t
                expected = np.linalg.inv(truth[anchor]) @ truth[ns]
                dist, angle = mm.pose_error(estimated, expected)
                if dist >= tol_m or angle >= tol_deg:
                    out.append(f'{at}: {ns} relative to {anchor} placed {dist:.3f} m, {angle:.2f} deg from the truth')
            walls = mm.wall_agreement(grids[ns], t, merged)
            if walls <= min_walls:
                out.append(f'{at}: {ns}: only {walls:.0%} of its walls are walls of the merged map sent with it')
        return out


def truth_of(path: str, specs) -> dict:
    """{robot namespace: pose of its map frame in the world}: from a truth.json (mm_common), or from a
    start_poses.json of a recorded demo (test/data: {map file name without .yaml: [x, y, yaw]})."""
    data = json.loads(open(mm.sample_path(path)).read())
    if 'maps' in data:
        return mm.truth_poses(path, specs)
    out = {}
    for spec in specs:
        ns, map_path = spec.split('=', 1)
        out[ns] = mm.rigid(*data[os.path.splitext(os.path.basename(mm.split_kind(map_path)[0]))[0]])
    return out


def _key(stamp) -> tuple:
    return stamp.secs, stamp.nsecs


if __name__ == '__main__':
    rospy.init_node('mm_load_checker')
    rostest.rosrun('multirobot_map_merge', 'map_merge_under_load', LoadCheck, sys.argv)
