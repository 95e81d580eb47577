#!/usr/bin/env python3
"""rostest node: map_merge ends within 2 s of SIGINT (the issue's requirement; the original waits up to 20 s), and
its loops follow ROS time.

It starts map_merge nodes itself (so that it can signal them and time their exit) against the robot maps the launch
file publishes:
  * wall clock, estimation mode, estimating back to back (estimation_rate 20 Hz): SIGINT while it works;
  * /use_sim_time true and no /clock yet: the node must still discover and merge (stamps 0), then follow a /clock
    running at 1/4 of real time (at most merging_rate maps per second of ROS time, not per wall second), then,
    with /clock paused, end within 2 s of SIGINT.
Params: ~robots (namespaces the launch publishes maps for), ~max_exit_s (2.0).
"""
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import unittest

import roslib.packages
import rospy
import rostest
from nav_msgs.msg import OccupancyGrid
from rosgraph_msgs.msg import Clock

import mm_common as mm
from multirobot_map_merge.msg import MergeStatus

MERGING_RATE = 4.0


def start_node(ns, *params):
    exe = roslib.packages.find_node('multirobot_map_merge', 'map_merge')[0]
    log = tempfile.NamedTemporaryFile('w', prefix=f'mm_sigint{ns.replace("/", "_")}_', suffix='.log', delete=False,
                                      dir=os.environ.get('ROS_LOG_DIR') or None)
    cmd = [exe, '__name:=map_merge', f'__ns:={ns}', '_merged_map_topic:=merged', '_discovery_rate:=2.0',
           '_known_init_poses:=false', f'_merging_rate:={MERGING_RATE}', *params]
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL), log.name


class SigintCheck(unittest.TestCase):
    def stop_and_time(self, proc, log):
        started = time.monotonic()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=30.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        took = time.monotonic() - started
        print(f'map_merge exited {took:.2f} s after SIGINT (exit code {proc.returncode}); log {log}')
        limit = float(rospy.get_param('~max_exit_s', 2.0))
        self.assertLess(took, limit, f'map_merge took {took:.2f} s to end after SIGINT (log {log})')
        self.assertEqual(proc.returncode, 0, f'exit code {proc.returncode} (log {log})')
        os.unlink(log)   # kept only when the test fails

    def all_included(self, status):
        return {r.robot_namespace for r in status.robots if r.included} >= set(rospy.get_param('~robots'))

    def test_a_sigint_while_estimating(self):
        proc, log = start_node('/sig_a', '_estimation_rate:=20.0')
        try:
            mm.wait_for('/sig_a/map_merge/status', MergeStatus, self.all_included, 40.0, 'status with every robot')
            rospy.sleep(1.3)   # somewhere inside a later estimation
        finally:
            self.stop_and_time(proc, log)

    def test_b_sim_time(self):
        rospy.set_param('/use_sim_time', True)
        proc, log = start_node('/sig_b', '_estimation_rate:=1.0')
        clock_pub = rospy.Publisher('/clock', Clock, queue_size=10)
        running = threading.Event()
        done = threading.Event()

        def clock_loop():   # /clock at 1/4 of real time from t = 1000 s, while `running`
            now = rospy.Time(1000)
            while not done.is_set():
                if running.is_set():
                    now += rospy.Duration(0.0025)
                    clock_pub.publish(Clock(clock=now))
                time.sleep(0.01)
        thread = threading.Thread(target=clock_loop, daemon=True)
        thread.start()
        try:
            # no /clock yet: ROS time is 0, the node still discovers and merges
            first = mm.wait_for('/sig_b/merged', OccupancyGrid, lambda m: True, 30.0, 'merged map before /clock')
            self.assertEqual(first.header.stamp.to_sec(), 0.0, 'the node does not run on simulated time')

            running.set()
            mm.wait_for('/sig_b/merged', OccupancyGrid, lambda m: m.header.stamp.to_sec() >= 1000.0, 20.0,
                        'merged map stamped with /clock time')
            stamps = []
            sub = rospy.Subscriber('/sig_b/merged', OccupancyGrid, lambda m: stamps.append(m.header.stamp.to_sec()))
            rospy.sleep(8.0)   # = 2 s of ROS time
            sub.unregister()
            stamps = sorted(set(s for s in stamps if s >= 1000.0))
            self.assertGreaterEqual(len(stamps), 2, 'the node stopped merging once /clock ran')
            span = stamps[-1] - stamps[0]
            # paced on ROS time: about merging_rate maps per ROS second; a wall-clock pace would give 4 x as many
            self.assertLessEqual(len(stamps) - 1, MERGING_RATE * span + 2,
                                 f'{len(stamps)} merged maps in {span:.2f} s of ROS time: not paced on /clock')

            running.clear()   # /clock paused: the loops wait on a time that does not move
            rospy.sleep(1.0)
        finally:
            done.set()
            self.stop_and_time(proc, log)
            rospy.set_param('/use_sim_time', False)


if __name__ == '__main__':
    rospy.init_node('mm_sigint_checker')
    rostest.rosrun('multirobot_map_merge', 'map_merge_sigint', SigintCheck, sys.argv)
