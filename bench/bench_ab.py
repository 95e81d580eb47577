#!/usr/bin/env python3
"""Interleaved comparison of the estimation of two revisions (not a test: it prints figures and their ratio).

    scripts/env.sh python bench/bench_ab.py [--base REV] [--rounds N] [--threads N] [--maps DIR | --large36 [CACHE]]
    scripts/env.sh python bench/bench_ab.py [--base REV] [--rounds N] --generated [NAMES]

Runs one estimation per process, alternating the base revision (default HEAD, checked out into a temporary git
worktree that is removed at the end) and the working tree, for --rounds rounds; prints per side the median and
lowest wall time, the median CPU time of the estimating process and of it with its worker processes, the maps
placed, and the ratio of the medians. The maps default to the shared 30-map scenario; --large36 uses the generated
36-map one (bench_merge.py --large36 makes it). --generated compares the two on each generated building (NAMES as
bench_merge.py --generated takes them: none for the thirteen <kind>36, unseen, unseen2, large or a comma-separated list;
made into out/bench on first use), alternating within each building, and prints per building the two medians and
their ratio, then each side's median and worst over the buildings: the time of one revision on this machine varies
by up to 1.4 times from day to day, its ratio to a fixed revision far less.

Why interleaved: on this 2-core machine the same code ran 4.9-7.3 s within one hour, CPU time included, so two
figures taken minutes apart cannot show a change of less than about a tenth; alternating one process each puts
both sides under the same conditions.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Dict, Iterator, List

import bench_merge  # bench/, beside this script
import machine

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MAPS = REPO.parent / 'shared' / 'data' / 'dev' / 'large30_hospital_section'

# one estimation of every map_*.yaml in a folder, with the package of `root`; prints wall, CPU and placed as JSON
ONE_ESTIMATION = '''
import glob, json, os, sys, time
sys.path.insert(0, {root!r})
sys.path.insert(0, {bench!r})
from machine import proc_cpu_seconds
from multirobot_map_merge.mapio import load_map
from multirobot_map_merge.estimation.estimator import estimate
from multirobot_map_merge.estimation.settings import EstimationSettings
grids = [load_map(p) for p in sorted(glob.glob({maps!r} + '/map_*.yaml'))]
wall, cpu, tree = time.perf_counter(), time.process_time(), proc_cpu_seconds(os.getpid())
found = estimate(grids, EstimationSettings(threads={threads}))
print(json.dumps({{'wall': time.perf_counter() - wall, 'cpu': time.process_time() - cpu,
                  'tree': proc_cpu_seconds(os.getpid()) - tree,
                  'placed': sum(t is not None for t in found.transforms)}}))
'''


def run_once(root: Path, maps: Path, threads: int) -> Dict[str, float]:
    code = ONE_ESTIMATION.format(root=str(root), bench=str(Path(__file__).resolve().parent), maps=str(maps),
                                 threads=threads)
    # from `root`: the worker processes of a revision before 38a0517 import the package from their working folder
    # (workers.SERVER_PRELOAD), and a base run from the working tree ran the working tree's matches
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True,
                         cwd=str(root)).stdout
    return json.loads(out.strip().splitlines()[-1])


def summary(name: str, runs: List[Dict[str, float]]) -> str:
    walls = [r['wall'] for r in runs]
    placed = sorted({int(r['placed']) for r in runs})
    return (f'| {name} | {statistics.median(walls):.2f} | {min(walls):.2f} | '
            f'{statistics.median(r["cpu"] for r in runs):.2f} | {statistics.median(r["tree"] for r in runs):.2f} | '
            f'{"/".join(map(str, placed))} | '
            f'{" ".join(f"{w:.2f}" for w in walls)} |')


@contextlib.contextmanager
def base_worktree(rev: str) -> Iterator[Path]:
    """The revision checked out into a temporary git worktree, removed at the end."""
    with tempfile.TemporaryDirectory(prefix='bench_ab_') as tmp:
        base = Path(tmp) / 'base'
        subprocess.run(['git', '-C', str(REPO), 'worktree', 'add', '--detach', '-q', str(base), rev], check=True)
        try:
            yield base
        finally:
            subprocess.run(['git', '-C', str(REPO), 'worktree', 'remove', '--force', str(base)], check=False)


def compare_buildings(args: argparse.Namespace, base_rev: str) -> int:
    """--generated: the two sides on each building, alternating within it; one table."""
    import make_sample_maps   # scripts/, on bench_merge's path
    names = bench_merge.building_names(args.generated)
    unknown = [n for n in names if n not in make_sample_maps.GENERATED]
    if unknown:
        print(f'bench_ab: unknown generated scenario {unknown[0]}', file=sys.stderr)
        return 2
    cache = REPO / 'out' / 'bench'
    for name in names:
        bench_merge.ensure_generated(cache, name)
    medians: Dict[str, Dict[str, float]] = {'base': {}, 'work': {}}
    rows = []
    with base_worktree(args.base) as base:
        for name in names:
            runs: Dict[str, List[Dict[str, float]]] = {'base': [], 'work': []}
            for _ in range(args.rounds):
                for side, root in (('base', base), ('work', REPO)):
                    runs[side].append(run_once(root, cache / name, args.threads))
            for side in runs:
                medians[side][name] = statistics.median(r['wall'] for r in runs[side])
            placed = {side: '/'.join(map(str, sorted({int(r['placed']) for r in runs[side]}))) for side in runs}
            rows.append(f"| {name} | {medians['base'][name]:.2f} | {medians['work'][name]:.2f} | "
                        f"{medians['work'][name] / medians['base'][name]:.2f} | {placed['base']} | {placed['work']} |")
            print(f'{name}: base {medians["base"][name]:.2f} s, work {medians["work"][name]:.2f} s', flush=True)
    print(f'\none estimation per building and side, {args.threads} threads, {args.rounds} rounds alternating; base = '
          f'{args.base} ({base_rev}), work = working tree; {machine.describe()}\n')
    print('| building | base median (s) | work median (s) | work / base | base placed | work placed |')
    print('|---|---|---|---|---|---|')
    print('\n'.join(rows))
    over = {side: (statistics.median(medians[side].values()), max(medians[side].values())) for side in medians}
    print(f"\n- median over the buildings: base {over['base'][0]:.2f} s, work {over['work'][0]:.2f} s "
          f"({over['work'][0] / over['base'][0]:.2f}); worst: base {over['base'][1]:.2f} s, work "
          f"{over['work'][1]:.2f} s ({over['work'][1] / over['base'][1]:.2f})")
    return 0


def main(argv: List[str] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--base', default='HEAD', help='revision compared with the working tree (default HEAD)')
    ap.add_argument('--rounds', type=int, default=5, help='estimations per side, alternating (default 5)')
    ap.add_argument('--threads', type=int, default=2, help='EstimationSettings.threads (default 2)')
    where = ap.add_mutually_exclusive_group()
    where.add_argument('--maps', type=Path, help='a folder of map_*.yaml (default: the shared 30-map scenario)')
    where.add_argument('--large36', nargs='?', const=REPO / 'out' / 'bench', type=Path, metavar='CACHE',
                       help='the generated 36-map scenario in CACHE/large36 (default out/bench)')
    where.add_argument('--generated', nargs='?', const='buildings', metavar='NAMES',
                       help='each generated building in out/bench (NAMES as bench_merge.py --generated: none for the '
                            'thirteen <kind>36, unseen, unseen2, large, or a comma-separated list)')
    args = ap.parse_args(argv)
    base_rev = subprocess.run(['git', '-C', str(REPO), 'rev-parse', '--short', args.base], capture_output=True,
                              text=True)
    if base_rev.returncode != 0:
        print(f'bench_ab: unknown revision {args.base}', file=sys.stderr)
        return 2
    if args.rounds < 1 or args.threads < 1:
        print('bench_ab: --rounds and --threads must be at least 1', file=sys.stderr)
        return 2
    if args.generated is not None:
        return compare_buildings(args, base_rev.stdout.strip())
    maps = (args.large36 / 'large36' if args.large36 is not None else (args.maps or DEFAULT_MAPS)).resolve()
    if not sorted(maps.glob('map_*.yaml')):
        print(f'bench_ab: no map_*.yaml in {maps}' + (' (run bench_merge.py --large36 first)'
                                                      if args.large36 is not None else ''), file=sys.stderr)
        return 2
    with base_worktree(args.base) as base:
        runs: Dict[str, List[Dict[str, float]]] = {'base': [], 'work': []}
        for n in range(args.rounds):
            for side, root in (('base', base), ('work', REPO)):
                runs[side].append(run_once(root, maps, args.threads))
            print(f'round {n + 1}/{args.rounds}: base {runs["base"][-1]["wall"]:.2f} s, '
                  f'work {runs["work"][-1]["wall"]:.2f} s', flush=True)
    print(f'\none estimation of {len(sorted(maps.glob("map_*.yaml")))} maps ({maps.name}), {args.threads} threads, '
          f'{args.rounds} rounds alternating; base = {args.base} ({base_rev.stdout.strip()}), work = working tree; '
          f'{machine.describe()}\n')
    print('| side | wall median (s) | wall lowest (s) | CPU median (s) | with its workers (s) | placed | walls (s) |')
    print('|---|---|---|---|---|---|---|')
    print(summary('base', runs['base']))
    print(summary('work', runs['work']))
    ratio = statistics.median(r['wall'] for r in runs['work']) / statistics.median(r['wall'] for r in runs['base'])
    print(f'\n- work / base, median wall: {ratio:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
