#!/usr/bin/env python3
"""Benchmark of the fleet simulator (not a test: it prints figures and their ratio to the target).

    scripts/env.sh python bench/bench_fleet_sim.py [--sim-seconds S] [--robots 1,3] [--no-ros] [--world-seed N]

Every robot drives to random free goals one after another (a new one as soon as a goal ends), in the generated
floor plan. Two ways, each unpaced (as fast as the machine allows):
  * core: fleet_sim.sim.FleetSim.step() alone (motion, laser, mapping, planning);
  * ros: fleet_sim.node.FleetSimNode.step() with a private rosmaster and /use_sim_time, i.e. the node's own loop with
    everything it publishes (/clock, TF, maps, updates, ground truth, feedback), while a subscriber process listens
    to all of it (as explore + map_merge would; it does not deserialise, so its CPU is not counted).
Real-time factor (RTF) = sim seconds / wall seconds. "CPU RTF" = sim seconds / CPU seconds of this process: above 10
means 3 robots at 10x fit in one core. Target: 3 robots at >= 10x on this 2-core machine (shared machines inflate
timings).
"""
from __future__ import annotations

import argparse
import math
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

TARGET_RTF = 10.0

SUBSCRIBER = r'''
import sys, rospy
rospy.init_node('fs_bench_listener', anonymous=True)
subs = [rospy.Subscriber(t, rospy.AnyMsg, lambda m: None, queue_size=50) for t in sys.argv[1:]]
rospy.spin()
'''


def make_params(n: int, world_seed: int, extra=None):
    from fleet_sim.params import FleetSimParams
    values = {'num_robots': n, 'world_seed': world_seed, 'seed': 7, 'speedup': 1.0}
    values.update(extra or {})
    return FleetSimParams.from_mapping(values)


class GoalFeeder:
    """Random free goals (world frame), re-issued whenever a robot's goal ends."""

    def __init__(self, sim, seed: int = 1) -> None:
        self.sim = sim
        self.rng = np.random.default_rng(seed)
        self.goals = 0
        self.outcomes = {'succeeded': 0, 'aborted': 0}
        # drawn before the timing starts
        self.pool = sim.clearance.random_free_poses(self.rng, 400, 0.3, 0.0)

    def issue(self, i: int) -> None:
        from fleet_sim.mapping import relative_pose
        r = self.sim.robots[i]
        for _ in range(20):
            x, y, _ = self.pool[int(self.rng.integers(len(self.pool)))]
            if math.hypot(x - r.pose[0], y - r.pose[1]) > 2.0:
                break
        gx, gy, _ = relative_pose(r.start, (x, y, 0.0))
        self.goals += 1
        o = self.sim.set_goal(i, gx, gy)
        if o is not None:
            self.outcomes[o.status] += 1
            if self.goals < 10000:
                self.issue(i)

    def ended(self, outcomes) -> None:
        for i, o in outcomes:
            self.outcomes[o.status] += 1
            self.issue(i)


def run_core(n: int, sim_seconds: float, world_seed: int):
    from fleet_sim.sim import FleetSim
    sim = FleetSim(make_params(n, world_seed))
    feeder = GoalFeeder(sim)
    for i in range(n):
        feeder.issue(i)
    wall, cpu = time.perf_counter(), time.process_time()
    while sim.t < sim_seconds:
        _, outcomes = sim.step()
        feeder.ended(outcomes)
    return sim.t, time.perf_counter() - wall, time.process_time() - cpu, feeder


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('localhost', 0))
        return s.getsockname()[1]


def run_ros(n: int, sim_seconds: float, world_seed: int):
    """The node's loop in this process against a private master (the caller sets ROS_MASTER_URI first)."""
    import rospy
    from fleet_sim.node import FleetSimNode
    from fleet_sim.robot import ACTIVE
    from fleet_sim.sim import FleetSim
    rospy.set_param('/use_sim_time', True)
    if not rospy.core.is_initialized():
        rospy.init_node('fleet_sim_bench', disable_signals=True)
    params = make_params(n, world_seed)
    sim = FleetSim(params)
    node = FleetSimNode(params, sim, use_sim_time=True)
    topics = ['/clock', '/tf'] + [f'/{r.ns}/{t}' for r in sim.robots
                                  for t in ('map', 'map_updates', 'ground_truth/pose', 'move_base/feedback')]
    listener = subprocess.Popen([sys.executable, '-c', SUBSCRIBER] + topics, env=os.environ.copy(),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(3.0)      # let the listener connect to every topic
        node.publish_static()
        feeder = GoalFeeder(sim)
        for i in range(n):
            feeder.issue(i)
        # goals come straight from the feeder, not through actionlib (the action servers stay idle)
        wall, cpu = time.perf_counter(), time.process_time()
        start_t = sim.t
        while sim.t - start_t < sim_seconds:
            before = [r.state for r in sim.robots]
            node.step()
            for i, r in enumerate(sim.robots):
                if before[i] == ACTIVE and r.state != ACTIVE:
                    feeder.issue(i)
        return sim.t - start_t, time.perf_counter() - wall, time.process_time() - cpu, feeder
    finally:
        listener.terminate()
        listener.wait()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--sim-seconds', type=float, default=120.0)
    ap.add_argument('--robots', default='1,3')
    ap.add_argument('--world-seed', type=int, default=0)
    ap.add_argument('--no-ros', action='store_true', help='core loop only')
    ap.add_argument('--ros-only', action='store_true', help=argparse.SUPPRESS)
    args = ap.parse_args()
    counts = [int(v) for v in args.robots.split(',')]

    rows = []
    if not args.ros_only:
        for n in counts:
            sim_t, wall, cpu, feeder = run_core(n, args.sim_seconds, args.world_seed)
            rows.append(('core', n, sim_t, wall, cpu, feeder.goals))
    if not args.no_ros:
        # each ROS run in a child process (one rospy node per process) with its own master
        for n in counts:
            port = free_port()
            env = dict(os.environ, ROS_MASTER_URI=f'http://localhost:{port}')
            master = subprocess.Popen(['rosmaster', '--core', '-p', str(port)], env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            try:
                time.sleep(1.5)
                out = subprocess.run([sys.executable, __file__, '--ros-only', '--robots', str(n), '--sim-seconds',
                                      str(args.sim_seconds), '--world-seed', str(args.world_seed), '--child'],
                                     env=env, capture_output=True, text=True, timeout=1800)
                line = [ln for ln in out.stdout.splitlines() if ln.startswith('ROW ')]
                if not line:
                    print(out.stdout[-2000:], out.stderr[-4000:], file=sys.stderr)
                    continue
                _, sim_t, wall, cpu, goals = line[-1].split()
                rows.append(('ros', n, float(sim_t), float(wall), float(cpu), int(goals)))
            finally:
                master.terminate()
                master.wait()

    print(f'fleet_sim benchmark: generated world seed {args.world_seed}, {args.sim_seconds:.0f} s of sim time per '
          f'row, robots driving to random goals; target RTF >= {TARGET_RTF:.0f} with 3 robots')
    print(f'{"loop":6} {"robots":>6} {"sim s":>7} {"wall s":>7} {"CPU s":>7} {"RTF":>7} {"CPU RTF":>8} {"goals":>6}')
    for kind, n, sim_t, wall, cpu, goals in rows:
        print(f'{kind:6} {n:6d} {sim_t:7.1f} {wall:7.2f} {cpu:7.2f} {sim_t / wall:7.1f} {sim_t / cpu:8.1f} {goals:6d}')
    return 0


def child() -> int:
    """--ros-only --child: one ROS row, printed as 'ROW sim wall cpu goals'."""
    ap = argparse.ArgumentParser()
    ap.add_argument('--sim-seconds', type=float)
    ap.add_argument('--robots')
    ap.add_argument('--world-seed', type=int)
    ap.add_argument('--ros-only', action='store_true')
    ap.add_argument('--child', action='store_true')
    args = ap.parse_args()
    sim_t, wall, cpu, feeder = run_ros(int(args.robots), args.sim_seconds, args.world_seed)
    print(f'ROW {sim_t} {wall} {cpu} {feeder.goals}', flush=True)
    import rospy
    rospy.signal_shutdown('bench done')
    return 0


if __name__ == '__main__':
    sys.exit(child() if '--child' in sys.argv else main())
