#!/usr/bin/env python3
"""Live fleet benchmark (not a test: it prints figures): the live demo (scripts/demo.sh) for fleets of several sizes
over a few seeds, and per run and per fleet size:

  * merge latency: per robot, sim seconds from *joinable* (its map at its true pose overlaps the union of the
    others' by >= 4 m² and 5 %) to *merged* (in map_merge's merged map from then until the end), as the demo
    supervisor writes them into summary.json; median and max per run. A robot joinable but never merged counts as
    "late": its latency is at least the rest of the run (shown as >X);
  * exploration: explored share of the reachable area and robots in the merged map at sim-time checkpoints (--at)
    and at the end;
  * map_merge CPU in cores (utime + stime from /proc of the map_merge process the demo started, sampled every
    --sample s): average over the run and the highest --window s window; and CPU seconds per sim second, which
    does not depend on the speed-up; the same average for all explorers together and for the simulator (they share
    the machine with map_merge: what they take, its estimations wait for);
  * the final placement error against the ground truth (largest rotation and corner error over the robots).

    scripts/env.sh python bench/bench_fleet.py [--robots 3 6 12] [--seeds 1 2] [--speedup X] [--world-seed S]
        [--limit-sim S] [--limit-wall S] [--at 60 120 240] [--out out/bench_fleet] [--json FILE]

Each run is `scripts/demo.sh --robots N --seed S --out OUT/rN_sS` (its default speed-up and limits unless given);
its summary stays in that folder. The machine is shared: wall-clock figures are inflated by other load, sim-time
latencies much less so (but a demo that cannot keep its speed-up runs its nodes at a lower effective rate).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Dict, List, Optional, Tuple

from machine import proc_cpu_seconds   # same directory

REPO = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------------- processes
def descendants(root: int) -> List[int]:
    """Pids of every process below ``root`` (from /proc/*/stat parent links)."""
    children: Dict[int, List[int]] = {}
    for entry in os.scandir('/proc'):
        if not entry.name.isdigit():
            continue
        try:
            ppid = int(Path(entry.path, 'stat').read_text().rsplit(')', 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue   # the process just ended
        children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [root]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _running(pid: int) -> bool:
    """Whether the process is there and not a zombie (state Z, or X: dead)."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] not in ('Z', 'X')
    except (OSError, IndexError):
        return False


NODES = ('map_merge', 'explore', 'fleet_sim')   # CPU sampled per node name (explore: every explorer together)
Samples = Dict[str, List[Tuple[float, float]]]   # node name -> (wall s, CPU s) samples


def find_nodes(root: int) -> Dict[str, List[int]]:
    """The pids of the ROS nodes named in NODES (``__name:=name``) started below ``root`` and running."""
    found: Dict[str, List[int]] = {}
    for pid in descendants(root):
        try:
            argv = Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
        except OSError:
            continue
        for name in NODES:
            if f'__name:={name}'.encode() in argv:
                found.setdefault(name, []).append(pid)
    return found


def run_demo(robots: int, seed: int, out: Path, args: argparse.Namespace) -> Tuple[int, Samples]:
    """Runs the demo once; returns its exit code and the CPU samples of its nodes (NODES): per name, the CPU
    seconds its processes have used so far, from the first sample that found it until one of them exited."""
    cmd = ['bash', str(REPO / 'scripts' / 'demo.sh'), '--robots', str(robots), '--seed', str(seed),
           '--world-seed', str(args.world_seed), '--out', str(out)]
    for opt in ('speedup', 'limit_sim', 'limit_wall'):
        if getattr(args, opt) is not None:
            cmd += ['--' + opt.replace('_', '-'), str(getattr(args, opt))]
    out.mkdir(parents=True, exist_ok=True)
    samples: Samples = {name: [] for name in NODES}
    with open(out / 'demo.log', 'w') as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)
        pids: Dict[str, List[int]] = {}
        ended = set()
        try:
            while proc.poll() is None:
                time.sleep(args.sample)
                # the explorers start over a second or two: their set grows until every node has been seen once
                for name, found in find_nodes(proc.pid).items():
                    if name not in ended and len(found) > len(pids.get(name, [])):
                        pids[name] = found
                        samples[name].clear()   # a new process: its CPU so far is not comparable
                for name, some in pids.items():
                    if name in ended:
                        continue
                    # proc_cpu_seconds counts a process that has gone as 0 s: a node whose process has gone (or
                    # is a zombie) has exited, and keeps its samples so far
                    if not all(_running(p) for p in some):
                        ended.add(name)
                        continue
                    samples[name].append((time.monotonic(), sum(proc_cpu_seconds(p) for p in some)))
        except KeyboardInterrupt:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(timeout=60)
            raise
    return proc.returncode, samples


# ---------------------------------------------------------------------------------------------- figures
def cpu_figures(samples: List[Tuple[float, float]], window: float) -> Dict[str, Optional[float]]:
    if len(samples) < 2:
        return {'cpu_cores_avg': None, 'cpu_cores_peak': None, 'cpu_s': None}
    (t0, c0), (t1, c1) = samples[0], samples[-1]
    peak = None
    j = 0
    for i in range(len(samples)):
        while j < i and samples[i][0] - samples[j + 1][0] >= window:
            j += 1
        if samples[i][0] - samples[j][0] >= window:
            cores = (samples[i][1] - samples[j][1]) / (samples[i][0] - samples[j][0])
            peak = cores if peak is None else max(peak, cores)
    return {'cpu_cores_avg': (c1 - c0) / (t1 - t0) if t1 > t0 else None, 'cpu_cores_peak': peak, 'cpu_s': c1 - c0}


def at_time(progress: List[dict], sim_s: float) -> Optional[dict]:
    """The last progress line at or before ``sim_s`` (None before the first, or beyond the end of the run)."""
    if not progress or sim_s > progress[-1]['sim_s'] + 5.0:
        return None
    before = [p for p in progress if p['sim_s'] <= sim_s]
    return before[-1] if before else None


def run_figures(summary: dict, samples: Samples, args: argparse.Namespace) -> dict:
    rows = summary['placement']
    end = summary['sim_time_s']
    latencies = [r['latency_s'] for r in rows if r.get('latency_s') is not None]
    # joinable, never merged (or dropped at the end): at least the rest of the run
    late = [end - r['joinable_sim_s'] for r in rows if not r.get('latency_reference')
            and r.get('joinable_sim_s') is not None and r.get('merged_sim_s') is None]
    placed = [r for r in rows if 'rotation_error_deg' in r]
    progress = summary.get('progress', [])
    checkpoints = {}
    for t in args.at:
        p = at_time(progress, t)
        checkpoints[str(t)] = None if p is None else {'explored_share': p['explored_share'], 'merged': p['merged']}
    cpu = cpu_figures(samples['map_merge'], args.window)
    timeline = summary.get('placement_timeline') or {}
    return dict(
        robots=summary['robots'], end=summary['end'], sim_s=end, real_s=summary['real_time_s'],
        speedup=summary['speedup'], explored_share=summary['explored_share'],
        latencies=latencies, latency_median=statistics.median(latencies) if latencies else None,
        latency_max=max(latencies) if latencies else None, late=late,
        never_joinable=sum(r.get('joinable_sim_s') is None for r in rows),
        merged_end=len(placed), checkpoints=checkpoints,
        rotation_error_max_deg=max((r['rotation_error_deg'] for r in placed), default=None),
        corner_error_max_m=max((r['corner_error_m'] for r in placed), default=None),
        off_s=timeline.get('off_s'), off_span_s=timeline.get('span_s'),
        cpu_s_per_sim_s=cpu['cpu_s'] / end if cpu['cpu_s'] is not None and end > 0 else None, **cpu,
        explore_cores_avg=cpu_figures(samples['explore'], args.window)['cpu_cores_avg'],
        sim_cores_avg=cpu_figures(samples['fleet_sim'], args.window)['cpu_cores_avg'])


def _f(v, fmt='{:.1f}') -> str:
    return '-' if v is None else fmt.format(v)


def _times100(v: Optional[float]) -> Optional[float]:   # share -> %, m -> cm
    return None if v is None else 100.0 * v


def _latency_max(latencies: List[float], late: List[float]) -> str:
    if late and (not latencies or max(late) > max(latencies)):
        return f'>{max(late):.0f}'
    return _f(max(latencies) if latencies else None)


def _checkpoint(c: Optional[dict]) -> str:
    if c is None:
        return '-'
    share = '-' if c['explored_share'] is None else f"{100 * c['explored_share']:.0f}%"
    return f"{share} {c['merged']}m"


def report(runs: List[dict], args: argparse.Namespace) -> None:
    at = ' | '.join(f'at {t:g} s' for t in args.at)
    print(f'\n| robots | seed | sim s (real s, x) | latency median | latency max | merged | {at} | end explored '
          f'| map_merge cores avg / peak {args.window:g} s | CPU s per sim s | explorers / simulator cores avg '
          f'| max error deg / cm | merge off while running (s of s) |')
    print('|' + '---|' * (12 + len(args.at)))
    for r in runs:
        cps = ' | '.join(_checkpoint(r['checkpoints'][str(t)]) for t in args.at)
        print(f"| {r['robots']} | {r['seed']} | {r['sim_s']:.0f} ({r['real_s']:.0f}, {r['speedup']:g}) "
              f"| {_f(r['latency_median'])} | {_latency_max(r['latencies'], r['late'])} "
              f"| {r['merged_end']}/{r['robots']} | {cps} | {_f(_times100(r['explored_share']))} % "
              f"| {_f(r['cpu_cores_avg'], '{:.2f}')} / {_f(r['cpu_cores_peak'], '{:.2f}')} "
              f"| {_f(r['cpu_s_per_sim_s'], '{:.3f}')} "
              f"| {_f(r['explore_cores_avg'], '{:.2f}')} / {_f(r['sim_cores_avg'], '{:.2f}')} "
              f"| {_f(r['rotation_error_max_deg'], '{:.2f}')} / {_f(_times100(r['corner_error_max_m']))} "
              f"| {_f(r['off_s'])} of {_f(r['off_span_s'], '{:.0f}')} |")
    print('\n(checkpoints: explored share and robots in the merged map "Nm"; "-": the run had ended or not begun; '
          'merge off: a robot more than 0.75 deg or 15 cm off, demo summary placement_timeline)')
    print('\n| robots | runs | latency median (all robots) | latency max | robots not merged at the end '
          '| map_merge cores avg | CPU s per sim s | explorers / simulator cores avg |')
    print('|---|---|---|---|---|---|---|---|')
    for n in sorted({r['robots'] for r in runs}):
        group = [r for r in runs if r['robots'] == n]
        lat = [v for r in group for v in r['latencies']]
        late = [v for r in group for v in r['late']]
        cores = [r['cpu_cores_avg'] for r in group if r['cpu_cores_avg'] is not None]
        per_sim = [r['cpu_s_per_sim_s'] for r in group if r['cpu_s_per_sim_s'] is not None]
        others = ' / '.join(_f(statistics.mean(v) if v else None, '{:.2f}') for v in (
            [r['explore_cores_avg'] for r in group if r['explore_cores_avg'] is not None],
            [r['sim_cores_avg'] for r in group if r['sim_cores_avg'] is not None]))
        print(f"| {n} | {len(group)} | {_f(statistics.median(lat) if lat else None)} | {_latency_max(lat, late)} "
              f"| {sum(r['robots'] - r['merged_end'] for r in group)} of {n * len(group)} "
              f"| {_f(statistics.mean(cores) if cores else None, '{:.2f}')} "
              f"| {_f(statistics.mean(per_sim) if per_sim else None, '{:.3f}')} | {others} |")


def main(argv: Optional[List[str]] = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--robots', type=int, nargs='+', default=[3, 6, 12], help='fleet sizes (1..12)')
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 2], help='demo --seed values (start poses)')
    ap.add_argument('--world-seed', type=int, default=0)
    ap.add_argument('--speedup', type=float, help="demo --speedup (default: the demo's, by fleet size)")
    ap.add_argument('--limit-sim', type=float, help='demo --limit-sim')
    ap.add_argument('--limit-wall', type=float, help='demo --limit-wall')
    ap.add_argument('--at', type=float, nargs='+', default=[60.0, 120.0, 240.0], help='sim-time checkpoints (s)')
    ap.add_argument('--sample', type=float, default=1.0, help='seconds between CPU samples')
    ap.add_argument('--window', type=float, default=10.0, help='seconds of the peak CPU window')
    ap.add_argument('--out', type=Path, default=REPO / 'out' / 'bench_fleet')
    ap.add_argument('--json', type=Path, help='write every run\'s figures here')
    args = ap.parse_args(argv)
    if any(not 1 <= n <= 12 for n in args.robots) or any(s < 0 for s in args.seeds):
        ap.error('--robots must be in 1..12 and --seeds non-negative')
    if args.sample <= 0 or args.window <= 0:
        ap.error('--sample and --window must be positive')
    runs = []
    for n in args.robots:
        for seed in args.seeds:
            out = (args.out / f'r{n}_s{seed}').resolve()
            print(f'bench_fleet: {n} robots, seed {seed} -> {out}', flush=True)
            code, samples = run_demo(n, seed, out, args)
            try:
                summary = json.loads((out / 'summary.json').read_text())
            except (OSError, ValueError):
                print(f'bench_fleet: the demo wrote no summary (exit {code}); see {out}/demo.log', flush=True)
                continue
            r = dict(run_figures(summary, samples, args), seed=seed, out=str(out))
            runs.append(r)
            print(f"  {r['end']}; sim {r['sim_s']:.0f} s, latency median {_f(r['latency_median'])} max "
                  f"{_latency_max(r['latencies'], r['late'])}, merged {r['merged_end']}/{n}, map_merge "
                  f"{_f(r['cpu_cores_avg'], '{:.2f}')} cores, explorers {_f(r['explore_cores_avg'], '{:.2f}')}, "
                  f"simulator {_f(r['sim_cores_avg'], '{:.2f}')}", flush=True)
    if not runs:
        sys.exit('bench_fleet: no run produced a summary')
    report(runs, args)
    if args.json:
        args.json.write_text(json.dumps(runs, indent=1))


if __name__ == '__main__':
    main()
