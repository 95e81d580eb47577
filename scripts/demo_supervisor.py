#!/usr/bin/env python3
"""demo_supervisor: watches the live demo (launch/demo.launch), prints its progress and writes the results.

Progress line (every ~2 s): sim time, explored share of the reachable area (the robots' own maps placed at their
true poses, against the simulator's ground truth), robots in the merged map, explorers still exploring.
The demo ends when every explorer has logged "Exploration stopped." or at ~limit_sim (sim s) / ~limit_wall (real
s). It then waits (up to SETTLE_WAIT_S) for a merged map and for map_merge to settle: no new ~status for QUIET_S
plus two estimation periods plus twice the longest estimation so far (map_merge estimates the final maps, then twice
more: its checks on them, then its estimate afresh; and rests). Then the newest merged map is written to
~out/merged.{yaml,pgm,png} and a summary to ~out/summary.{txt,json}: explored share, the share the merged map
covers, times, and map_merge's placement error per robot against the ground truth (rotation, and the largest
displacement of the robot map's known-area corners), relative to the first placed robot, as
scripts/placement_report.py reports it offline. Finally the node shuts down, which ends the launch
(it is `required`).

Merge latency (explore.merge_latency): every ~0.5 s the robots' maps are drawn at their true poses on a 0.1 m world
raster; a robot is joinable once its map overlaps the union of the others' by the shared scorer's thresholds (4 m²
and 5 % of its own known area), stamped with the newest map stamp used. map_merge's ~status (stamp, included)
gives when each robot entered the merged map, and each status is scored as the end is (explore.coverage
PlacementTimeline: placement_timeline in summary.json holds how long the merge was off by more than 0.75 degrees or
15 cm while the run went on). summary.json's placement rows carry joinable_sim_s, merged_sim_s
(start of the stretch in the merged map that lasts until the end) and latency_s; `progress` holds the progress
lines (sim s, real s, explored share, robots merged and joinable) for the fleet benchmark (bench/bench_fleet.py).

With realistic robots (fleet_sim's drift), the summary also gives each robot's SLAM pose error at the end (its pose
on TF, <ns>/map -> <ns>/base_link, against the true pose seen from its start pose) and its loop closures (from
fleet_sim's log).

Params: ~num_robots (robots robot_1..robot_N), ~out, ~limit_sim, ~limit_wall, ~speedup and ~realistic (fleet_sim's
realistic profile; both for the summary),
~merged_topic, ~status_topic, ~world_topic (default /fleet_sim/world_map).
"""
import json
import math
import os
import re
import sys
import threading
import time
from typing import Dict, List, Optional, Tuple

import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import OccupancyGrid
from rosgraph_msgs.msg import Log
from rospy.numpy_msg import numpy_msg

from explore.coverage import (KnownRaster, PlacementTimeline, explored_share, placement_errors, reachable_mask,
                             right_by_the_data, truth_from_estimate)
from explore.merge_latency import LatencyTracker, joinable_robots
from fleet_sim.mapping import relative_pose
from multirobot_map_merge.grid import Grid, GridError
from multirobot_map_merge.mapio import save_map, save_png
from multirobot_map_merge.msg import MergeStatus
from multirobot_map_merge.overlay import save_named_overlay
from multirobot_map_merge.ros.conversions import grid_from_msg, yaw_from_quaternion
from multirobot_map_merge.ros.status import included_poses

Pose = Tuple[float, float, float]
# a robot placed further off than this at the end (the live targets) is judged by the data too
OFF_DEGREES, OFF_METRES = 1.0, 0.15
# maps arrive with their cells as one numpy array (genpy's default is a tuple of ints: ~20x slower for 12 robots)
GridMsg = numpy_msg(OccupancyGrid)


def _pose(msg: PoseStamped) -> Pose:
    q = msg.pose.orientation
    return msg.pose.position.x, msg.pose.position.y, yaw_from_quaternion(q.x, q.y, q.z, q.w)


SETTLE_WAIT_S = 60.0   # wall s the end waits at most for the merged map and map_merge's last estimations
LOOP_CLOSED = re.compile(r'^(\S+): loop closed after .* jumped ([0-9.]+) cm, ([0-9.]+) deg')
QUIET_S = 3.0          # wall s without a new status (plus two estimation periods): map_merge has settled


class Supervisor:
    def __init__(self) -> None:
        n = int(rospy.get_param('~num_robots', 3))
        self.names = [f'robot_{i + 1}' for i in range(n)]
        self.out = os.path.abspath(os.path.expanduser(rospy.get_param('~out', 'demo_out')))
        self.limit_sim = float(rospy.get_param('~limit_sim', 1200.0))
        self.limit_wall = float(rospy.get_param('~limit_wall', 240.0))
        self.speedup = float(rospy.get_param('~speedup', 1.0))
        self.realistic = bool(rospy.get_param('~realistic', False))
        self.estimation_rate = float(rospy.get_param('/map_merge/map_merge/estimation_rate', 0.5))
        self.lock = threading.Lock()   # owns everything below, written by the callbacks
        self.world: Optional[Grid] = None
        self.starts: Dict[str, Pose] = {}
        self.maps: Dict[str, Grid] = {}
        self.status: Optional[MergeStatus] = None
        self.merged: Optional[Grid] = None
        self.merged_at = 0.0           # wall time the newest merged map arrived
        self.status_at = 0.0           # wall time the newest status arrived
        self.longest_estimation = 0.0  # wall s, the longest estimation_time of a status
        self.stopped: set = set()
        self.true_poses: Dict[str, Pose] = {}
        self.closures: Dict[str, List[Tuple[float, float]]] = {n: [] for n in self.names}   # (cm, deg) jumps
        self.tf = tf2_ros.Buffer() if self.realistic else None
        self._tf_listener = tf2_ros.TransformListener(self.tf) if self.tf is not None else None
        self.reach: Optional[np.ndarray] = None
        self.latency = LatencyTracker(self.names)
        self.timeline = PlacementTimeline()   # main loop only, as the two below
        self._scored: Optional[MergeStatus] = None   # the last status the timeline scored
        self._raster: Optional[KnownRaster] = None   # main loop only
        self.progress: List[dict] = []   # owned by the main loop
        rospy.Subscriber(rospy.get_param('~world_topic', '/fleet_sim/world_map'), GridMsg, self.on_world,
                         queue_size=1, buff_size=1 << 24)
        for name in self.names:
            rospy.Subscriber(f'/{name}/ground_truth/start_pose', PoseStamped, self.on_start, callback_args=name)
            if self.realistic:
                rospy.Subscriber(f'/{name}/ground_truth/pose', PoseStamped, self.on_true_pose, callback_args=name)
            rospy.Subscriber(f'/{name}/map', GridMsg, self.on_map, callback_args=name, queue_size=1,
                             buff_size=1 << 24)
        rospy.Subscriber(rospy.get_param('~status_topic', '/map_merge/map_merge/status'), MergeStatus,
                         self.on_status, queue_size=1)
        rospy.Subscriber(rospy.get_param('~merged_topic', '/map_merge/map'), GridMsg, self.on_merged,
                         queue_size=1, buff_size=1 << 25)
        rospy.Subscriber('/rosout', Log, self.on_log, queue_size=500)

    # ------------------------------------------------------------------ callbacks: convert + store
    def _grid(self, msg: OccupancyGrid) -> Optional[Grid]:
        try:
            return grid_from_msg(msg)
        except GridError as e:
            rospy.logwarn_throttle(10.0, f'demo_supervisor: bad map refused: {e}')
            return None

    def on_world(self, msg):
        grid = self._grid(msg)
        with self.lock:
            self.world, self.reach = grid, None

    def on_start(self, msg, name):
        with self.lock:
            self.starts[name] = _pose(msg)
            self.reach = None

    def on_true_pose(self, msg, name):
        with self.lock:
            self.true_poses[name] = _pose(msg)

    def on_map(self, msg, name):
        grid = self._grid(msg)
        if grid is not None:
            with self.lock:
                self.maps[name] = grid

    def on_status(self, msg):
        stamp = msg.header.stamp.to_sec() or rospy.get_time()
        with self.lock:
            self.status, self.status_at = msg, time.monotonic()
            self.longest_estimation = max(self.longest_estimation, msg.estimation_time)
            self.latency.included(stamp, [e.robot_namespace.strip('/') for e in msg.robots if e.included])

    def on_merged(self, msg):
        grid = self._grid(msg)
        if grid is not None:
            with self.lock:
                self.merged, self.merged_at = grid, time.monotonic()

    def on_log(self, msg):
        closed = LOOP_CLOSED.match(msg.msg) if msg.name == '/fleet_sim' else None
        if closed and closed.group(1) in self.closures:
            with self.lock:
                self.closures[closed.group(1)].append((float(closed.group(2)), float(closed.group(3))))
        if msg.msg.startswith('Exploration stopped.'):
            for name in self.names:
                if msg.name == f'/{name}/explore':
                    with self.lock:
                        self.stopped.add(name)

    # ------------------------------------------------------------------ figures
    def explored(self) -> Optional[float]:
        with self.lock:
            world, starts, maps = self.world, dict(self.starts), dict(self.maps)
            if world is None or len(starts) < len(self.names):
                return None
            if self.reach is None:
                self.reach = reachable_mask(world, [p[:2] for p in starts.values()])
            reach = self.reach
        return explored_share(world, reach, [(maps[n], starts[n]) for n in self.names if n in maps])

    def update_joinable(self) -> int:
        """Marks the robots whose maps now overlap the union of the others' (true poses); returns how many are."""
        with self.lock:
            world, starts, maps = self.world, dict(self.starts), dict(self.maps)
        if world is None:
            return 0
        if self._raster is None:
            self._raster = KnownRaster.around(world)
        placed = {n: (maps[n], starts[n]) for n in self.names if n in maps and n in starts}
        if not placed:
            return 0
        # the state holds from the newest map in it on (maps arrive every sim second or so)
        stamp = max(grid.stamp or 0.0 for grid, _ in placed.values()) or rospy.get_time()
        names = joinable_robots(self._raster, placed)
        with self.lock:
            self.latency.joinable(stamp, names)
        return len(names)

    def placements(self) -> Tuple[List[dict], Optional[Pose]]:
        """Per robot: included, and the placement errors against the ground truth; plus the pose of map_merge's
        world frame in the ground-truth world (None before any placement)."""
        with self.lock:
            status, starts, maps = self.status, dict(self.starts), dict(self.maps)
        estimated = self.estimated(status)
        errors = {r['robot']: r for r in placement_errors(estimated, starts, maps)}
        rows = []
        for n in self.names:
            row = {'robot': n, 'included': n in estimated}
            if n in errors:
                row.update(errors[n])
                res = maps[n].resolution if n in maps else 0.05
                row['corner_error_cells'] = row['corner_error_m'] / res
                if row['rotation_error_deg'] > OFF_DEGREES or row['corner_error_m'] > OFF_METRES:
                    # off by the strict errors: judged by the maps too (a drifting SLAM map's start pose is not
                    # where its walls fit best), as ../shared/eval's score_real judges real maps
                    row['by_data'], row['wall_fit_placed'], row['wall_fit_true'] = right_by_the_data(
                        row, estimated, starts, maps)
            rows.append(row)
        return rows, truth_from_estimate(estimated, starts)

    def estimated(self, status: Optional[MergeStatus]) -> Dict[str, Pose]:
        """The placements of a status, robot -> pose in map_merge's world, in the order of self.names (the first is
        the one errors are relative to)."""
        poses = included_poses(status)
        return {n: poses[n] for n in self.names if n in poses}

    def score_status(self) -> None:
        """Scores a status not scored yet against the ground truth, with the robots' maps as they are now."""
        with self.lock:
            status, starts, maps = self.status, dict(self.starts), dict(self.maps)
        if status is None or status is self._scored:
            return
        self._scored = status
        self.timeline.add(status.header.stamp.to_sec() or rospy.get_time(),
                          placement_errors(self.estimated(status), starts, maps))

    def slam_errors(self) -> Dict[str, dict]:
        """Per robot: its pose on TF (the SLAM's belief) against its true pose seen from its start pose, and its
        loop closures."""
        out = {}
        for n in self.names:
            with self.lock:
                start, true, closures = self.starts.get(n), self.true_poses.get(n), list(self.closures[n])
            row = {'loop_closures': len(closures),
                   'largest_jump_cm': max((c[0] for c in closures), default=None)}
            try:
                t = self.tf.lookup_transform(f'{n}/map', f'{n}/base_link', rospy.Time(0), rospy.Duration(1.0))
            except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException):
                t = None
            if start is not None and true is not None and t is not None:
                q = t.transform.rotation
                belief = (t.transform.translation.x, t.transform.translation.y,
                          yaw_from_quaternion(q.x, q.y, q.z, q.w))
                truth = relative_pose(start, true)
                row['slam_error_cm'] = 100 * math.hypot(belief[0] - truth[0], belief[1] - truth[1])
                row['slam_error_deg'] = abs(math.degrees(math.remainder(belief[2] - truth[2], 2 * math.pi)))
            out[n] = row
        return out

    def merged_share(self, truth_from_merged: Optional[Pose]) -> Optional[float]:
        with self.lock:
            merged, world, reach = self.merged, self.world, self.reach
        if merged is None or world is None or reach is None or truth_from_merged is None:
            return None
        return explored_share(world, reach, [(merged, truth_from_merged)])

    # ------------------------------------------------------------------ main loop
    def run(self) -> None:
        wall0 = time.monotonic()
        tty = sys.stdout.isatty()
        last_print = -math.inf
        reason = ''
        while not rospy.is_shutdown():
            time.sleep(0.5)
            wall, sim = time.monotonic() - wall0, rospy.get_time()
            joinable = self.update_joinable()
            self.score_status()
            with self.lock:
                stopped = len(self.stopped)
                included = sum(1 for e in (self.status.robots if self.status else []) if e.included)
            if wall - last_print >= 2.0:
                last_print = wall
                share = self.explored()
                self.progress.append({'sim_s': round(sim, 2), 'real_s': round(wall, 2), 'explored_share': share,
                                      'merged': included, 'joinable': joinable})
                line = (f"[demo] sim {sim:7.1f} s | explored {'  -  ' if share is None else f'{100 * share:5.1f}'} % "
                        f"| merged {included}/{len(self.names)} robots | exploring {len(self.names) - stopped}/"
                        f"{len(self.names)} | real {wall:5.1f} s")
                print(('\r' + line) if tty else line, end='' if tty else '\n', flush=True)
            if stopped == len(self.names):
                reason = 'finished: every explorer has stopped'
            elif sim >= self.limit_sim:
                reason = f'limit: {self.limit_sim:.0f} s of sim time'
            elif wall >= self.limit_wall:
                reason = f'limit: {self.limit_wall:.0f} s of real time'
            if reason:
                break
        if tty:
            print(flush=True)
        if rospy.is_shutdown():
            return
        self.finish(reason, sim, wall, wall0)
        rospy.signal_shutdown('demo finished')

    def finish(self, reason: str, sim: float, wall: float, wall0: float) -> None:
        # one more merge cycle so the merged map includes the robots' final maps, and map_merge settled: it estimates
        # the final maps, then twice more (checking its placements on them, then comparing them with an estimate
        # afresh, estimator.py) and goes quiet; the summary reports what a user watching the merged map then sees
        end = time.monotonic()
        while time.monotonic() - end < SETTLE_WAIT_S and not rospy.is_shutdown():
            with self.lock:
                merged = self.merged is not None and self.merged_at > end + 1.0
                # quiet for longer than an estimation takes: two periods, and twice the longest one seen (wall s),
                # since the last estimation, the one afresh, can take that long (12 robots: 3-7 s each)
                quiet = QUIET_S + 2.0 / (self.estimation_rate * self.speedup) + 2.0 * self.longest_estimation
                settled = time.monotonic() - max(self.status_at, end) >= quiet
            if merged and settled:
                break
            time.sleep(0.2)
        share = self.explored()
        rows, truth_from_merged = self.placements()
        self.score_status()
        timeline = self.timeline.summary(rospy.get_time())
        self.update_joinable()
        with self.lock:
            latency = {r['robot']: r for r in self.latency.rows()}
        for r in rows:
            r.update({k: v for k, v in latency[r['robot']].items() if k != 'robot'})
        if self.realistic:
            slam = self.slam_errors()
            for r in rows:
                r.update(slam[r['robot']])
        merged_share = self.merged_share(truth_from_merged)
        os.makedirs(self.out, exist_ok=True)
        files = {}
        with self.lock:
            merged, robot_maps = self.merged, dict(self.maps)
        # each robot's own map too, so a merge can be replayed offline (nodes/merge_maps out/demo/robots/*.yaml)
        os.makedirs(os.path.join(self.out, 'robots'), exist_ok=True)
        for name, grid in robot_maps.items():
            save_map(grid, os.path.join(self.out, 'robots', name))
        if merged is not None:
            yaml_path, pgm_path = save_map(merged, os.path.join(self.out, 'merged'))
            png_path = save_png(merged, os.path.join(self.out, 'merged.png'))
            files = {'yaml': yaml_path, 'pgm': pgm_path, 'png': png_path}
            with self.lock:
                status = self.status
            if status is not None:   # each robot's map in its colour where map_merge placed it
                files['overlay'] = save_named_overlay(
                    os.path.join(self.out, 'merged_overlay.png'), robot_maps,
                    included_poses(status),
                    [(p.robot_a.strip('/'), p.robot_b.strip('/'), p.confidence) for p in status.pairs if p.used])
        summary = {'end': reason, 'sim_time_s': sim, 'real_time_s': wall, 'speedup': self.speedup,
                   'realistic': self.realistic,
                   'robots': len(self.names), 'explored_share': share, 'merged_map_share': merged_share,
                   'placement': rows, 'placement_timeline': timeline, 'files': files, 'progress': self.progress,
                   # ground-truth start poses (x, y, yaw in the world): with robots/*.yaml, a merge replays offline
                   'start_poses': {name: list(pose) for name, pose in sorted(self.starts.items())}}
        lines = [f'demo: {reason} after {sim:.1f} s of sim time ({wall:.1f} s real, speed-up {self.speedup:g}'
                 + (', realistic robots)' if self.realistic else ')'),
                 f"demo: explored {_pct(share)} of the reachable area (the robots' maps at their "
                 f"true poses); the merged map covers {_pct(merged_share)}",
                 f"demo: map_merge placed {sum(r['included'] for r in rows)} of {len(rows)} robots without known "
                 f"initial poses; error against the ground truth:"]
        for r in rows:
            if 'rotation_error_deg' in r:
                lines.append(f"demo:   {r['robot']}: rotation {r['rotation_error_deg']:.2f} deg, corners "
                             f"{100 * r['corner_error_m']:.1f} cm ({r['corner_error_cells']:.1f} cells)"
                             + (' (reference)' if r['robot'] == r['reference'] else '')
                             + (_by_data(r) if 'by_data' in r else ''))
            else:
                lines.append(f"demo:   {r['robot']}: not in the merged map")
        if self.realistic:
            lines.append("demo: the robots' SLAM pose error at the end (TF against the truth, in each map frame) and "
                         "loop closures:")
            for r in rows:
                error = f"{r['slam_error_cm']:.1f} cm, {r['slam_error_deg']:.2f} deg" if 'slam_error_cm' in r \
                    else 'n/a'
                jump = '' if r['largest_jump_cm'] is None else f", largest jump {r['largest_jump_cm']:.1f} cm"
                lines.append(f"demo:   {r['robot']}: {error}; {r['loop_closures']} loop closures{jump}")
        lines.append(f"demo: while it ran, the merge was off by more than {timeline['degrees']:g} deg or "
                     f"{timeline['cm']:g} cm for {timeline['off_s']:.1f} of {timeline['span_s']:.1f} sim s (worst "
                     f"{timeline['worst_cm']:.1f} cm, {timeline['worst_deg']:.2f} deg)")
        lines.append('demo: merge latency in sim s (joinable: its map overlaps the others\' at true poses by '
                     '>= 4 m² and 5 %):')
        for r in rows:
            latency = '- (reference)' if r['latency_reference'] else \
                'n/a' if r['latency_s'] is None else f"{r['latency_s']:.1f}"
            lines.append(f"demo:   {r['robot']}: joinable {_sec(r['joinable_sim_s'])}, "
                         f"merged {_sec(r['merged_sim_s'])}, latency {latency}")
        lines.append(f"demo: merged map {files['yaml']} (+ .pgm, .png)" if files else 'demo: no merged map received')
        text = '\n'.join(lines)
        with open(os.path.join(self.out, 'summary.json'), 'w') as f:
            json.dump(summary, f, indent=2)
        with open(os.path.join(self.out, 'summary.txt'), 'w') as f:
            f.write(text + '\n')
        print(text, flush=True)


def _by_data(row: dict) -> str:
    (near_p, close_p), (near_t, close_t) = row['wall_fit_placed'], row['wall_fit_true']
    verdict = 'right by the data' if row['by_data'] else 'off'
    return (f"; {verdict}: its walls fit the others' {close_p}/{near_p} where placed, {close_t}/{near_t} at the "
            f"true poses")


def _pct(v: Optional[float]) -> str:
    return 'n/a' if v is None else f'{100 * v:.1f} %'


def _sec(v: Optional[float]) -> str:
    return 'never' if v is None else f'{v:.1f}'


if __name__ == '__main__':
    rospy.init_node('demo_supervisor')
    Supervisor().run()
