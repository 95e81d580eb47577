#!/usr/bin/env python3
"""Benchmark of the map_merge node (not a test: it prints figures and compares them with the issue's targets).

    scripts/env.sh python bench/bench_node.py [--duration 600] [--robots 30] [--content reveal|grow|static]
        [--late N] [--map-rate 1] [--update-rate 1] [--merging-rate 4] [--param name:=value ...] [--json FILE]
        [--show-wrong]

It starts its own roscore (on a free port), a publisher process for the robots of the large dev scenario
(../shared/data/dev/large30_hospital_section, or --data) and the map_merge node, then measures from outside:
  * merged maps: received per second on the merged topic (overall, and the lowest 10 s window), longest gap;
  * node CPU in cores: utime + stime of the node process and the processes under it (its estimation's workers;
    /proc), overall and per sampling interval;
  * node memory: RSS of the node and the processes under it sampled over time, the node's own peak (VmHWM), the
    RSS growth over the second half of the run;
  * estimation time: `estimation_time` of every ~status, and how many robots the last one includes;
  * wrong placements: every ~status's placements scored by the shared scorer (../shared/eval/score.py) against the
    scenario's truth: robots included but placed wrong (a broken map placed consistently with one of its parts is
    not wrong), the most in any one status and in how many statuses, so that "never wrong" is measured live too.
The node runs in estimation mode (known_init_poses false) at merging_rate 4; everything else keeps the node's
defaults (discovery every 20 s, estimation_rate 0.5, estimation_confidence 1.0) unless --param.

Robot `robot_NN` publishes `robot_NN/map` (latched, frame robot_NN/map) at --map-rate Hz and
`robot_NN/map_updates` at --update-rate Hz (each robot at its own phase):
  * --content reveal (default): as a fleet exploring: at first only the 2 m tiles within 3 m of the robot's start
    are known; then tiles are revealed nearest first, so that the whole map is known after --reveal s (default:
    half the run). Each update tick sends one message per newly revealed tile; each full map the current state.
    After the reveal the maps no longer change: each tick re-sends one tile with unchanged content.
  * --content grow: as reveal, but each full map is only the tile-aligned bounding box of the known tiles (its size
    and origin grow as gmapping's do); a tile outside the current box sends a full map instead of an update.
  * --content static: the whole map from the start, updates re-send tiles (content never changes).
  * --late N: the last N robots appear late: each advertises its topics and starts publishing at its own time,
    evenly spread over the first --late-window seconds (default: a third of the run).
The publisher and the measuring subscriber run in other processes than the node; on this shared 2-core machine
wall-clock figures are inflated by other load, CPU-seconds much less so.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Dict, List, Optional

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from multirobot_map_merge import transforms as tf  # noqa: E402
from machine import proc_cpu_seconds, process_tree  # noqa: E402
from reveal import TILE, reveal_order, revealed, score_placements, scorer, tiles_due, wrong_of  # noqa: E402

DEFAULT_DATA = REPO.parent / 'shared' / 'data' / 'dev' / 'large30_hospital_section'
TARGET_HZ, TARGET_CORES = 4.0, 1.0


# ---------------------------------------------------------------------------------------------- publisher process
def run_publisher(args: argparse.Namespace) -> None:
    """The robots: full maps and map_updates of the scenario's maps (runs as its own process)."""
    import numpy as np
    import rospy
    from map_msgs.msg import OccupancyGridUpdate
    from nav_msgs.msg import OccupancyGrid

    from multirobot_map_merge.mapio import load_map
    from multirobot_map_merge.ros.conversions import grid_to_msg

    rospy.init_node('bench_robots')
    truth = json.loads((Path(args.data) / 'truth.json').read_text())
    robots = []
    rng = np.random.default_rng(0)
    for k, m in enumerate(truth['maps'][:args.robots]):
        ns = f'robot_{k:02d}'
        grid = load_map(str(Path(args.data) / m['file']), ns + '/map')
        tiles, n_start = reveal_order(grid)
        n_start = len(tiles) if args.content == 'static' else n_start
        shown = revealed(grid, tiles, n_start)
        robots.append(dict(ns=ns, grid=grid, tiles=tiles, revealed=n_start, shown=shown, map_pub=None, upd_pub=None,
                           box=tile_box(tiles[:n_start], grid.data.shape), phase=rng.uniform(0.0, 1.0)))
    reveal_s = args.reveal if args.reveal is not None else args.duration / 2.0
    late_window = args.late_window if args.late_window is not None else args.duration / 3.0
    first_late = len(robots) - min(args.late, len(robots))
    joins = {id(r): (k - first_late + 1) * late_window / max(args.late, 1) if k >= first_late else 0.0
             for k, r in enumerate(robots)}

    def advertise(robot) -> None:
        robot['map_pub'] = rospy.Publisher(robot['ns'] + '/map', OccupancyGrid, queue_size=2, latch=True)
        robot['upd_pub'] = rospy.Publisher(robot['ns'] + '/map_updates', OccupancyGridUpdate, queue_size=10)

    def full_map(robot) -> OccupancyGrid:
        g = robot['grid']
        from multirobot_map_merge.grid import Grid
        r0, r1, c0, c1 = robot['box'] if args.content == 'grow' else (0, g.height, 0, g.width)
        origin = tuple((g.cell_to_map() @ [c0, r0, 1.0])[:2]) + (g.origin[2],)
        return grid_to_msg(Grid(robot['shown'][r0:r1, c0:c1], g.resolution, origin, g.frame_id),
                           stamp=rospy.Time.now())

    def tile_update(robot, r: int, c: int) -> OccupancyGridUpdate:
        block = robot['shown'][r:r + TILE, c:c + TILE]
        r0, _, c0, _ = robot['box'] if args.content == 'grow' else (0, 0, 0, 0)
        u = OccupancyGridUpdate()
        u.header.stamp = rospy.Time.now()
        u.header.frame_id = robot['grid'].frame_id
        u.x, u.y, u.height, u.width = c - c0, r - r0, block.shape[0], block.shape[1]
        u.data = block.reshape(-1).tolist()
        return u

    def updates(robot, t: float) -> List[OccupancyGridUpdate]:
        """One message per tile revealed since the last tick; once all is known, one unchanged tile."""
        tiles, g = robot['tiles'], robot['grid']
        due = len(tiles) if reveal_s <= 0 else tiles_due(tiles, 0, t / reveal_s)
        out = []
        while args.content != 'static' and robot['revealed'] < due:
            r, c = tiles[robot['revealed']]
            robot['revealed'] += 1
            robot['shown'][r:r + TILE, c:c + TILE] = g.data[r:r + TILE, c:c + TILE]
            box = tile_box(tiles[:robot['revealed']], g.data.shape)
            if args.content == 'grow' and box != robot['box']:
                robot['box'] = box
                out.append(None)   # the map grew: a full map, as gmapping sends when it resizes
            else:
                out.append(tile_update(robot, r, c))
        if not out:
            r, c = tiles[int(rng.integers(robot['revealed']))]   # a known tile, content unchanged
            out.append(tile_update(robot, r, c))
        return out

    for robot in robots[:first_late]:
        advertise(robot)
        robot['map_pub'].publish(full_map(robot))
    print('publisher: ready', flush=True)
    t0 = time.monotonic()
    next_map = {id(r): t0 + joins[id(r)] + r['phase'] / args.map_rate for r in robots}
    next_upd = {id(r): t0 + joins[id(r)] + r['phase'] / args.update_rate for r in robots}
    while not rospy.is_shutdown():
        now = time.monotonic()
        for robot in robots:
            if robot['map_pub'] is None:
                if now < t0 + joins[id(robot)]:
                    continue
                advertise(robot)   # a late robot appears
                print(f"publisher: {robot['ns']} appears at {now - t0:.0f} s", flush=True)
            if now >= next_upd[id(robot)]:
                next_upd[id(robot)] += 1.0 / args.update_rate
                for msg in updates(robot, now - t0):
                    if msg is None:
                        robot['map_pub'].publish(full_map(robot))
                    else:
                        robot['upd_pub'].publish(msg)
            if now >= next_map[id(robot)]:
                next_map[id(robot)] += 1.0 / args.map_rate
                robot['map_pub'].publish(full_map(robot))
        soonest = min(min(next_map.values()), min(next_upd.values()))
        time.sleep(max(0.0, min(soonest - time.monotonic(), 0.05)))


def tile_box(tiles, shape):
    """(row0, row1, col0, col1) of the tiles (TILE-aligned, clipped to the map shape)."""
    rows = [r for r, _ in tiles]
    cols = [c for _, c in tiles]
    return (min(rows), min(max(rows) + TILE, shape[0]), min(cols), min(max(cols) + TILE, shape[1]))


# ---------------------------------------------------------------------------------------------- measurement
def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def proc_memory_mib(pid: int) -> Dict[str, float]:
    """VmRSS: of the process and the processes under it; VmHWM: the process's own peak."""
    out = {'VmRSS': 0.0}
    for p in process_tree(pid):
        try:
            lines = Path(f'/proc/{p}/status').read_text().splitlines()
        except OSError:
            continue
        for line in lines:
            key = line.split(':', 1)[0]
            if key == 'VmRSS' or key == 'VmHWM' and p == pid:
                out[key] = out.get(key, 0.0) + int(line.split()[1]) / 1024.0
    return out


def node_executable() -> str:
    import roslib.packages
    found = roslib.packages.find_node('multirobot_map_merge', 'map_merge')
    if not found:
        raise SystemExit('bench_node: map_merge executable not found (run under scripts/env.sh after make setup)')
    return found[0]


def stop(proc: Optional[subprocess.Popen], timeout: float = 10.0) -> Optional[float]:
    """SIGINT a process group, wait; returns the seconds it took (SIGKILL after timeout)."""
    if proc is None or proc.poll() is not None:
        return None
    started = time.monotonic()
    try:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    except ProcessLookupError:
        pass
    return time.monotonic() - started


def window_rates(times: List[float], start: float, end: float, width: float = 10.0) -> List[float]:
    edges = [start + k * width for k in range(int((end - start) // width))]
    return [sum(e <= t < e + width for t in times) / width for e in edges]


def run(args: argparse.Namespace) -> dict:
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI=f'http://127.0.0.1:{port}', ROS_HOSTNAME='127.0.0.1')
    env.pop('ROS_IP', None)
    os.environ.update(ROS_MASTER_URI=env['ROS_MASTER_URI'], ROS_HOSTNAME='127.0.0.1')
    log_dir = Path(os.environ.get('ROS_LOG_DIR', '/tmp'))
    log_dir.mkdir(parents=True, exist_ok=True)
    logs = {name: open(log_dir / f'bench_node_{name}.log', 'w') for name in ('roscore', 'robots', 'node')}
    procs: Dict[str, subprocess.Popen] = {}

    def spawn(name: str, cmd: List[str]) -> subprocess.Popen:
        procs[name] = subprocess.Popen(cmd, env=env, stdout=logs[name], stderr=subprocess.STDOUT,
                                       stdin=subprocess.DEVNULL, start_new_session=True)
        return procs[name]

    try:
        import rosgraph
        spawn('roscore', ['roscore', '-p', str(port)])
        deadline = time.monotonic() + 30.0
        while not rosgraph.Master('/bench_node').is_online():
            if time.monotonic() > deadline or procs['roscore'].poll() is not None:
                raise SystemExit(f'bench_node: roscore did not start (log {logs["roscore"].name})')
            time.sleep(0.2)

        publisher_cmd = [sys.executable, str(Path(__file__).resolve()), '--publisher', '--data', str(args.data),
                         '--robots', str(args.robots), '--content', args.content, '--map-rate', str(args.map_rate),
                         '--update-rate', str(args.update_rate), '--duration', str(args.duration)]
        if args.reveal is not None:
            publisher_cmd += ['--reveal', str(args.reveal)]
        if args.late:
            publisher_cmd += ['--late', str(args.late)]
        if args.late_window is not None:
            publisher_cmd += ['--late-window', str(args.late_window)]
        spawn('robots', publisher_cmd)
        deadline = time.monotonic() + 120.0
        while 'publisher: ready' not in Path(logs['robots'].name).read_text():
            if time.monotonic() > deadline or procs['robots'].poll() is not None:
                raise SystemExit(f'bench_node: the robot publisher did not start (log {logs["robots"].name})')
            time.sleep(0.5)

        params = ['_known_init_poses:=false', f'_merging_rate:={args.merging_rate}'] + \
                 [p if p.startswith('_') else '_' + p for p in args.param]
        node = spawn('node', [node_executable(), '__name:=map_merge', '__ns:=/map_merge', *params])

        import rospy
        from multirobot_map_merge.msg import MergeStatus
        from multirobot_map_merge.ros.status import included_poses
        rospy.init_node('bench_node_probe', disable_signals=True)
        merged_times: List[float] = []
        statuses: List[dict] = []
        lock = threading.Lock()

        def on_merged(msg) -> None:
            with lock:
                merged_times.append(time.monotonic())

        def on_status(msg) -> None:
            placed = included_poses(msg)
            with lock:
                statuses.append(dict(t=time.monotonic(), estimation_time=msg.estimation_time,
                                     robots=len(msg.robots), included=sum(r.included for r in msg.robots),
                                     pairs_used=sum(p.used for p in msg.pairs), placed=placed))
        rospy.Subscriber('/map_merge/map', rospy.AnyMsg, on_merged, queue_size=100, buff_size=1 << 26)
        rospy.Subscriber('/map_merge/map_merge/status', MergeStatus, on_status, queue_size=10)

        t_start = time.monotonic()
        cpu0 = proc_cpu_seconds(node.pid)
        samples = []
        last_t, last_cpu = t_start, cpu0
        print(f'bench_node: {args.robots} robots ({args.content}), node pid {node.pid}, {args.duration:.0f} s; '
              f'sampling every {args.sample:.0f} s', flush=True)
        while time.monotonic() - t_start < args.duration:
            time.sleep(min(args.sample, max(args.duration - (time.monotonic() - t_start), 0.1)))
            if node.poll() is not None:
                raise SystemExit(f'bench_node: the node exited with {node.returncode} (log {logs["node"].name})')
            now, cpu = time.monotonic(), proc_cpu_seconds(node.pid)
            mem = proc_memory_mib(node.pid)
            with lock:
                n_merged = sum(t > last_t for t in merged_times)
                last_status = statuses[-1] if statuses else None
            sample = dict(t=round(now - t_start, 1), cores=(cpu - last_cpu) / (now - last_t),
                          merged_hz=n_merged / (now - last_t), rss_mib=mem['VmRSS'], hwm_mib=mem['VmHWM'],
                          included=last_status['included'] if last_status else 0, load1=os.getloadavg()[0],
                          last_estimation_s=last_status['estimation_time'] if last_status else None)
            samples.append(sample)
            last_est = sample['last_estimation_s']
            print(f"  t={sample['t']:6.0f} s  cpu {sample['cores']:.2f} cores  merged {sample['merged_hz']:.2f} Hz  "
                  f"rss {sample['rss_mib']:.0f} MiB  included {sample['included']}/{args.robots}  "
                  f"last estimation {'-' if last_est is None else f'{last_est:.1f}'} s", flush=True)
            last_t, last_cpu = now, cpu
        t_end = time.monotonic()
        cpu_total = proc_cpu_seconds(node.pid) - cpu0
        mem = proc_memory_mib(node.pid)
        exit_s = stop(node, timeout=20.0)
        procs.pop('node')
        with lock:
            times, sts = list(merged_times), list(statuses)
    finally:
        for name in ('node', 'robots', 'roscore'):
            stop(procs.get(name))
        for f in logs.values():
            f.close()

    in_run = [t for t in times if t_start <= t <= t_end]
    gaps = [b - a for a, b in zip(in_run, in_run[1:])]
    warm = [s for s in samples if s['t'] >= args.duration / 2.0]
    reveal_s = (args.reveal if args.reveal is not None else args.duration / 2.0) if args.content != 'static' else 0.0

    def phase_cpu(lo: float, hi: float) -> Optional[float]:
        """Average cores over the samples that end in (lo, hi] (each sample covers the interval before it)."""
        picked = [s['cores'] for s in samples if lo < s['t'] <= hi]
        return sum(picked) / len(picked) if picked else None
    est = [s['estimation_time'] for s in sts]
    wrong = wrong_placements(args.data, [s['placed'] for s in sts], args.show_wrong)
    for s in sts:
        s.pop('placed')
    result = dict(
        robots=args.robots, content=args.content, duration_s=round(t_end - t_start, 1), merging_rate=args.merging_rate,
        merged_msgs=len(in_run), merged_hz=len(in_run) / (t_end - t_start),
        merged_hz_min_10s=min(window_rates(in_run, t_start, t_end)) if t_end - t_start >= 10 else None,
        longest_gap_s=max(gaps) if gaps else None,
        cpu_cores_avg=cpu_total / (t_end - t_start), cpu_cores_max_sample=max(s['cores'] for s in samples),
        reveal_s=reveal_s, cpu_cores_while_revealing=phase_cpu(0.0, reveal_s) if reveal_s > 0 else None,
        cpu_cores_after_reveal=phase_cpu(reveal_s + args.sample, math.inf),
        rss_first_mib=samples[0]['rss_mib'], rss_last_mib=mem['VmRSS'], rss_peak_mib=mem['VmHWM'],
        rss_growth_second_half_mib=(warm[-1]['rss_mib'] - warm[0]['rss_mib']) if len(warm) >= 2 else None,
        estimations=len(est), estimation_s_median=statistics.median(est) if est else None,
        estimation_s_max=max(est) if est else None,
        included_last=sts[-1]['included'] if sts else 0, sigint_exit_s=exit_s,
        wrong_max=max(wrong) if wrong else None, statuses_with_wrong=sum(w > 0 for w in wrong) if wrong else None,
        machine_load_avg=statistics.mean(s['load1'] for s in samples), cpu_count=os.cpu_count(), samples=samples)
    return result


def wrong_placements(data: Path, statuses: List[Dict[str, tuple]], verbose: bool) -> Optional[List[int]]:
    """For each ~status (robot name -> (x, y, yaw) of the robots it includes, status.included_poses): how many
    of them the shared scorer finds placed wrong against the scenario's truth (robot_NN is the scenario's map NN;
    the others count as left out). None without the scorer."""
    score = scorer()
    if score is None:
        return None
    truth = json.loads((data / 'truth.json').read_text())
    counts = []
    for placed in statuses:
        scored = score_placements(score, truth, {int(name.split('_')[-1]): tf.rigid(*pose)
                                                 for name, pose in placed.items()})
        counts.append(scored['wrong'])
        if verbose and scored['wrong']:
            print(f"  placed wrong (reference {scored['reference']}; file, degrees, cells): {wrong_of(scored)}")
    return counts


def report(r: dict) -> None:
    def f(v, fmt='{:.2f}'):
        return 'n/a' if v is None else fmt.format(v)
    print(f"\nmap_merge node, {r['robots']} robots ({r['content']} maps), {r['duration_s']:.0f} s, "
          f"merging_rate {r['merging_rate']}:")
    rows = [
        ('merged map rate (Hz)', f(r['merged_hz']), f'{TARGET_HZ} sustained',
         f"lowest 10 s window {f(r['merged_hz_min_10s'])} Hz, longest gap {f(r['longest_gap_s'])} s"),
        ('node CPU (cores, average)', f(r['cpu_cores_avg']), f'< {TARGET_CORES}',
         f"while maps change {f(r['cpu_cores_while_revealing'])}, once all known {f(r['cpu_cores_after_reveal'])}; "
         f"highest {f(r['cpu_cores_max_sample'])} over one sample"),
        ('node memory (MiB)', f"{f(r['rss_last_mib'], '{:.0f}')} (peak {f(r['rss_peak_mib'], '{:.0f}')})", 'flat',
         f"first sample {f(r['rss_first_mib'], '{:.0f}')}, change over the 2nd half "
         f"{f(r['rss_growth_second_half_mib'], '{:+.0f}')}"),
        ('estimation time (s)', f"{f(r['estimation_s_median'])} median", '-',
         f"max {f(r['estimation_s_max'])}, {r['estimations']} estimations, last includes "
         f"{r['included_last']}/{r['robots']} robots"),
        ('exit after SIGINT (s)', f(r['sigint_exit_s']), '< 2', ''),
        ('robots placed wrong (shared scorer)', f"{f(r['wrong_max'], '{:.0f}')} at most", '0',
         f"in {f(r['statuses_with_wrong'], '{:.0f}')} of {r['estimations']} statuses"),
    ]
    print(f"(machine: {r['cpu_count']} cores, 1-minute load average {r['machine_load_avg']:.1f} on average "
          'during the run, this benchmark included)')
    print('| figure | measured | target | notes |\n|---|---|---|---|')
    for row in rows:
        print('| ' + ' | '.join(row) + ' |')


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--duration', type=float, default=600.0, help='seconds measured (the issue: 10 minutes)')
    ap.add_argument('--robots', type=int, default=30)
    ap.add_argument('--data', type=Path, default=DEFAULT_DATA, help='scenario folder with truth.json + maps')
    ap.add_argument('--content', choices=('reveal', 'grow', 'static'), default='reveal')
    ap.add_argument('--late', type=int, default=0, help='robots (the last ones) that appear late')
    ap.add_argument('--late-window', type=float, default=None,
                    help='seconds over which the late robots appear (default: a third of the run)')
    ap.add_argument('--reveal', type=float, default=None, help='seconds until every map is known (default: half)')
    ap.add_argument('--map-rate', type=float, default=1.0, help='Hz of full maps per robot')
    ap.add_argument('--update-rate', type=float, default=1.0, help='Hz of map_updates per robot')
    ap.add_argument('--merging-rate', type=float, default=4.0)
    ap.add_argument('--param', action='append', default=[], help='extra node parameter name:=value')
    ap.add_argument('--sample', type=float, default=10.0, help='seconds between CPU/memory samples')
    ap.add_argument('--json', type=Path, help='write the figures and samples here')
    ap.add_argument('--show-wrong', action='store_true',
                    help='print the robots placed wrong in each ~status (file, rotation and corner errors)')
    ap.add_argument('--publisher', action='store_true', help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if not (args.map_rate > 0 and args.update_rate > 0 and args.duration > 0 and args.robots > 0):
        ap.error('rates, duration and robots must be positive')
    if not args.publisher and not (args.data / 'truth.json').is_file():
        ap.error(f'{args.data}/truth.json not found (--data)')
    return args


def main(argv: Optional[List[str]] = None) -> None:
    args = parse_args(argv)
    if args.publisher:
        run_publisher(args)
        return
    result = run(args)
    report(result)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))


if __name__ == '__main__':
    main()
