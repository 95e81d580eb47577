#!/usr/bin/env python3
"""Where one estimation's time goes, and what a second core gives it (not a test: it prints figures).

    scripts/env.sh python bench/profile_estimation.py [MAPS] [--threads-gain] [--phases] [--kinds]
    scripts/env.sh python bench/profile_estimation.py [MAPS] --cores
    scripts/env.sh python bench/profile_estimation.py [MAPS ...] --timeline

MAPS: a folder of map_*.yaml (default: the generated hospital36 of bench_merge.py --generated, out/bench). The
estimation runs serially (its thread pools replaced by loops, no worker processes, OpenCV on one thread) under
cProfile, and the time of its parts is printed: ICP, the verification of candidates, descriptor distances, the
correlation search, the polish, detection, RANSAC. With --threads-gain it also prints the wall time of the serial
estimation alone, of the estimation with its defaults (matches on worker processes), and of two serial estimations
in two processes at once: what the second core can give. With --phases it also prints where the wall time of an
estimation with its defaults goes, as its main thread sees it: waiting for the batches of matches and the group
matches made ahead (both on the workers), and the work it does alone (group matches, single-grid searches, the
searches at the end of the maps left out and of the members a search placed, the relaxation, the rest); and how busy
the batches kept the worker processes (the share of the batches' wall time they spent reading grids and matching).
With --kinds it also prints the CPU of each kind of match in a serial estimation without the profiler (KINDS: by the
growth's method that asked for it): how many, how many accepted, their CPU and its share of the estimation's (a
grid's keypoints are detected in the first match that needs them); the CPU of the accepted and the refused matches,
and of those where a correlation search ran, with the search's own; the CPU of the accepted matches and the rest
together, and half of it (what an estimation that made no refused match would take on two cores kept busy, with today's
cost per match); and the costliest kinds by verdict (accepted, or the reason of the refusal) and whether a correlation
search ran; and the matches made again: a grid onto a grid or a group (by its seed) that it was matched onto before in
the estimation in the same way (by descriptors alone, or with a correlation search), the group's union grown since, in
all and by kind; and for a generated building (a truth.json beside the maps) the CPU of the matches of its broken maps,
of the maps placed, of the mergeable maps left out and of the maps that are not mergeable (by the grid matched, group
matches aside).
With --cores it prints only the CPU of a serial estimation and of one with its defaults, neither under the profiler:
the estimating process's and its worker processes', their ratio to the serial CPU (what the processes add: the grids
written and read, the workers' own caches, the threads of the estimating process), and the cores the estimation kept
busy on average (that CPU over its wall time; a core idles while the estimating process works alone between
batches, or while one worker ends a batch).
With --timeline it prints only, for each folder of maps, an estimation with its defaults (not under the profiler)
stage by stage as its main thread runs them (TIMELINE: when each starts, how long it takes, and how much of that
the batches of matches on the worker processes take, the estimating process's preparation of their grids
included), then the wall time in batches and in the main thread's own work between them, during which one core at
most is busy (its OpenCV calls aside); and the thread time that process spent in the batches detecting keypoints
and computing wall fields (done there once, before the workers match), and writing grids for the workers.
"""
from __future__ import annotations

import argparse
import glob
import pstats
import subprocess
import sys
from pathlib import Path
from typing import List, Tuple

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MAPS = REPO / 'out' / 'bench' / 'hospital36'

# the parts: (label, (file suffix, function name)) whose cumulative time is reported; OpenCV's functions ('~')
# by a part of their name, which differs between OpenCV builds
PARTS = [('ICP', ('refine.py', 'icp')), ('verification', ('verify.py', 'verify')),
         ('descriptor distances', ('~', 'batchDistance')),
         ('correlation search', ('search.py', 'correlate_candidates')), ('polish', ('polish.py', 'polish')),
         ('detection', ('~', 'detectAndCompute')),
         ('RANSAC', ('hypotheses.py', 'ransac_rigid'))]

# the main thread's phases of an estimation with its defaults: label, its parts ((file suffix, function), callers
# (file suffix, function) whose calls count, None: all); cProfile sees only the main thread, so a batch on the workers
# is the time spent waiting for its results
PHASES = [('batches of matches in parallel', [(('growth.py', 'match'), [('growth.py', '_match_tried')]),
                                              (('workers.py', 'match_all'), [('stronger.py', 'of')]),
                                              (('_base.py', 'result_iterator'), [('growth.py', 'confirm_searches')])]),
          ('preparing the grids', [(('_base.py', 'result_iterator'), [('estimator.py', '_estimate')])]),
          ('group matches (searches included)', [(('growth.py', '_match_groups'), None)]),
          ('group matches made ahead, in parallel', [(('growth.py', '_match_ahead'), None)]),
          ('single-grid searches, in parallel', [(('growth.py', '_search'), None)]),
          ('the maps left out searched again', [(('growth.py', 'search_left_out'), None)]),
          ('search-placed members searched again', [(('searched_again.py', 'search_placed_again'), None)]),
          ('the final relaxation', [(('estimator.py', 'relax_group'), None)])]

# the stages of an estimation afresh in the order its main thread runs them (--timeline): (module, function), the
# module's attribute replaced ('Grower': a method of growth.Grower); a stage called inside another is part of that one
TIMELINE = [('estimator', 'descriptor_groups'), ('estimator', 'search_grow'), ('Grower', 'confirm_searches'),
            ('Grower', 'evict_contradicted'), ('Grower', 'search_left_out'), ('estimator', 'search_side_groups'),
            ('estimator', 'search_placed_again'), ('estimator', 'relax_group'),
            ('estimator', 'search_doubted_again'), ('estimator', 'contradicting_pairs'),
            ('estimator', '_consistent_of')]

# the kinds of match (--kinds): the first of these functions found up the stack of a match_pair call names it
# (grow: onto one grid or onto a union)
KINDS = [('PairEvidence.of', 'pair evidence (stronger.py)'), ('search_left_out', 'the maps left out searched again'),
         ('search_placed_again', 'members a search placed, searched again'),
         ('_match_groups', 'group matches'), ('_match_ahead', 'group matches'), ('_search', 'single-grid searches'),
         ('grow', 'growth by descriptors')]

# one estimation of the maps in a folder; serial: pools replaced by loops, no worker processes, OpenCV on one
# thread; profile: the file cProfile writes to ('' for none); kinds: the CPU of each kind of match printed; prints
# the wall time in s
ONE = '''
import cProfile, collections, glob, os, sys, time
sys.path.insert(0, {root!r})
serial, profile, kinds, cores, timeline = {serial!r}, {profile!r}, {kinds!r}, {cores!r}, {timeline!r}
import cv2
from multirobot_map_merge.mapio import load_map
from multirobot_map_merge.estimation.settings import EstimationSettings
import multirobot_map_merge.estimation.estimator as estimator, multirobot_map_merge.estimation.search as search
class Loop:
    def __init__(self, max_workers=None): pass
    def __enter__(self): return self
    def __exit__(self, *exc): return False
    def map(self, f, *its): return [f(*a) for a in zip(*its)]
if serial:
    cv2.setNumThreads(1)
    estimator.ThreadPoolExecutor = search.ThreadPoolExecutor = Loop
else:
    import logging
    class Said(logging.Handler):   # how busy the batches kept the workers (workers.BatchStats)
        def emit(self, record):
            if 'worker processes' in record.getMessage():
                print('  ' + record.getMessage())
    workers = logging.getLogger('rosout.multirobot_map_merge.estimation.workers')
    workers.setLevel(logging.DEBUG)
    workers.addHandler(Said())
if kinds:
    import re
    import multirobot_map_merge.estimation.pair as pair, multirobot_map_merge.estimation.workers as workers
    # (kind, verdict, searched) -> matches, CPU s, of it the correlation search's
    verdicts = collections.defaultdict(lambda: [0, 0.0, 0.0])
    searching = [0, 0.0]   # correlation searches of the match being made, their CPU s
    seen = set()   # (grid, grid or group seed, searched) of the matches so far
    # (searched, kind) -> matches made again, accepted, CPU s
    again = collections.defaultdict(lambda: [0, 0, 0.0])
    of_grid = collections.defaultdict(lambda: [0, 0.0])   # grid matched (not a group's union) -> matches, CPU s
    correlate = pair.correlate_candidates
    def correlate_timed(*args, **options):
        started = time.process_time()
        found = correlate(*args, **options)
        if options.get('angles') is None:   # not the correlation at the best's angle alone (slid alternatives)
            searching[0] += 1
            searching[1] += time.process_time() - started
        return found
    pair.correlate_candidates = correlate_timed
    match_pair = workers.match_pair
    def timed(i, j, pi, pj, s, **options):
        frame, kind = sys._getframe(1), 'other'
        while frame is not None and kind == 'other':
            name = frame.f_code.co_qualname
            kind = next((label for function, label in {kinds!r} if name.endswith(function)), 'other')
            frame = frame.f_back
        if kind == 'growth by descriptors':
            kind += ', onto a union' if options.get('onto_union') else ', onto one grid'
        searching[:] = [0, 0.0]
        started = time.process_time()
        m = match_pair(i, j, pi, pj, s, **options)
        took = time.process_time() - started
        # the verdict: accepted, or the refusal's reason without its figures
        verdict = 'accepted' if m.accepted else re.sub(r'[-+]?[0-9][0-9.]*', '#', m.reason or '').split(':')[0][:38]
        if not options.get('between_groups'):
            of_grid[i][0] += 1
            of_grid[i][1] += took
        row = verdicts[(kind, verdict, searching[0] > 0)]
        row[0] += 1
        row[1] += took
        row[2] += searching[1]
        made = (i, j, searching[0] > 0)
        if made in seen:   # the same work again: the grid onto the same grid, or the same group's union grown since
            row = again[(searching[0] > 0, kind)]
            row[0] += 1
            row[1] += m.accepted
            row[2] += took
        seen.add(made)
        return m
    workers.match_pair = timed
if timeline:
    import multirobot_map_merge.estimation.growth as growth, multirobot_map_merge.estimation.workers as workers
    from multirobot_map_merge.estimation.features import PreparedGrid
    stages, depth = [], [0]   # (stage, start, wall s, of it in batches); stages under way on the main thread
    spent = collections.Counter()   # wall s in batches; thread s detecting, computing wall fields, writing grids
    def stage(f, name):
        def g(*args, **options):
            started, before = time.perf_counter(), spent['batches']
            depth[0] += 1
            try:
                return f(*args, **options)
            finally:
                depth[0] -= 1
                if not depth[0]:   # a stage called inside another is part of it
                    stages.append((name, started, time.perf_counter() - started, spent['batches'] - before))
        return g
    def counted(f, label, needed=lambda self: True):
        def g(self, *args, **options):
            if not needed(self):
                return f(self, *args, **options)
            started = time.perf_counter()
            try:
                return f(self, *args, **options)
            finally:
                spent[label] += time.perf_counter() - started
        return g
    for owner, function in {timeline_stages!r}:
        where = growth.Grower if owner == 'Grower' else estimator
        setattr(where, function, stage(getattr(where, function), function))
    workers.ParallelMatcher._on_processes = counted(workers.ParallelMatcher._on_processes, 'batches')
    workers.ParallelMatcher._path = counted(workers.ParallelMatcher._path, 'writing')
    PreparedGrid.describe = counted(PreparedGrid.describe, 'detection', lambda p: p.keypoints is None)
    PreparedGrid.wall_fields = counted(PreparedGrid.wall_fields, 'wall fields', lambda p: p._fields is None)
grids = [load_map(p) for p in sorted(glob.glob({maps!r} + '/map_*.yaml'))]
settings = EstimationSettings(processes=not serial)
wall, cpu = time.perf_counter(), time.process_time()
if profile:
    cProfile.run('estimator.estimate(grids, settings)', profile)
else:
    result = estimator.estimate(grids, settings)
if kinds:
    cpu = time.process_time() - cpu
    spent = collections.defaultdict(lambda: [0, 0, 0.0])   # kind -> matches, accepted, CPU s
    for (kind, verdict, _), (n, seconds, _) in verdicts.items():
        row = spent[kind]
        row[0] += n
        row[1] += n if verdict == 'accepted' else 0
        row[2] += seconds
    for kind, (n, accepted, seconds) in sorted(spent.items(), key=lambda kv: -kv[1][2]):
        print(f'  {{kind:45s}} {{n:4d}} matches, {{accepted:3d}} accepted, {{seconds:6.2f}} s CPU '
              f'{{100 * seconds / cpu:5.1f}} %')
    rest = cpu - sum(row[2] for row in spent.values())
    print(f'  {{"the rest (no match)":45s}}                          {{rest:6.2f}} s CPU {{100 * rest / cpu:5.1f}} %')
    for label, accepted in (('accepted', True), ('refused', False)):
        rows = [(v, searched) for (_, verdict, searched), v in verdicts.items() if (verdict == 'accepted') == accepted]
        all_s = sum(v[1] for v, _ in rows)
        searched_s = sum(v[1] for v, searched in rows if searched)
        search_s = sum(v[2] for v, _ in rows)   # none where no search ran
        print(f'  {{label}}: {{all_s:.2f}} s CPU ({{100 * all_s / cpu:.0f}} %), {{searched_s:.2f}} s of it where a '
              f'search ran ({{search_s:.2f}} s the search itself)')
        if accepted:
            kept = all_s + rest
    # a floor of the design's per-match costs: had it made no refused match, the accepted ones and the rest
    print(f'  the accepted matches and the rest: {{kept:.2f}} s CPU ({{100 * kept / cpu:.0f}} %), half of it '
          f'{{kept / 2:.2f}} s')
    for searched in sorted({{searched for searched, _ in again}}):
        rows = sorted(((kind, v) for (was, kind), v in again.items() if was == searched), key=lambda kv: -kv[1][2])
        n, accepted, seconds = [sum(v[column] for _, v in rows) for column in range(3)]
        print(f'  made again onto the same grid or group, {{"searched" if searched else "descriptors only":16s}} '
              f'{{n:4d}} matches, {{accepted:3d}} accepted, {{seconds:6.2f}} s CPU {{100 * seconds / cpu:5.1f}} %')
        for kind, (n, accepted, seconds) in rows:
            print(f'    {{kind:54s}} {{n:4d}} matches, {{accepted:3d}} accepted, {{seconds:6.2f}} s CPU '
                  f'{{100 * seconds / cpu:5.1f}} %')
    truth_file = os.path.join({maps!r}, 'truth.json')
    if os.path.exists(truth_file):
        # a generated building: the matches of its broken maps (never placed right), of the maps placed and of the
        # mergeable ones left out, by the grid matched (group matches aside)
        import json
        truth = {{m['file']: m for m in json.load(open(truth_file))['maps']}}
        names = [os.path.basename(p) for p in sorted(glob.glob({maps!r} + '/map_*.yaml'))]
        classes = collections.defaultdict(lambda: [0, 0, 0.0])   # class -> grids, matches, CPU s
        for k, name in enumerate(names):
            m = truth.get(name, {{}})
            label = ('broken maps' if m.get('broken') else 'maps placed' if result.transforms[k] is not None
                     else 'mergeable maps left out' if m.get('mergeable', True) else 'maps not mergeable')
            classes[label][0] += 1
            classes[label][1] += of_grid[k][0]
            classes[label][2] += of_grid[k][1]
        for label, (n, matches, seconds) in sorted(classes.items(), key=lambda kv: -kv[1][2]):
            print(f'  the matches of the {{n}} {{label}} (the truth): {{matches}} matches, {{seconds:.2f}} s CPU '
                  f'{{100 * seconds / cpu:5.1f}} %')
    print('  by verdict (the 12 costliest; searched: a correlation search over all angles ran, its CPU in brackets):')
    for (kind, verdict, searched), (n, seconds, search) in sorted(verdicts.items(), key=lambda kv: -kv[1][1])[:12]:
        what = f'{{kind}}: {{verdict}}' + (', searched' if searched else '')
        print(f'    {{what:84s}} {{n:4d}} matches {{seconds:6.2f}} s CPU ({{search:5.2f}}) '
              f'{{100 * seconds / cpu:5.1f}} %')
if timeline:
    total = time.perf_counter() - wall
    folder = os.path.basename({maps!r})
    print(f'{{folder}}: {{total:.2f}} s with its defaults')
    for name, started, took, batches in stages:
        print(f'  {{started - wall:6.2f}} s  {{name:22s}} {{took:6.2f}} s, in batches {{batches:5.2f}} s')
    alone = total - spent['batches']
    print(f'  in batches {{spent["batches"]:.2f}} s, the main thread alone {{alone:.2f}} s '
          f'({{100 * alone / total:.0f}} %); in the batches the estimating process detected keypoints '
          f'{{spent["detection"]:.2f}} s, computed wall fields {{spent["wall fields"]:.2f}} s and wrote grids '
          f'{{spent["writing"]:.2f}} s (thread time)')
if cores:   # the CPU of this process and of its worker processes (utime + stime), before the pool ends with it
    import os
    from multirobot_map_merge.estimation import workers as pool
    executor = pool._POOL._executor
    ticks = 0
    for pid in (executor._processes if executor is not None else ()):
        with open(f'/proc/{{pid}}/stat') as f:
            ticks += sum(int(v) for v in f.read().rsplit(')', 1)[1].split()[11:13])
    print(f'cpu {{time.process_time() - cpu}} {{ticks / os.sysconf("SC_CLK_TCK")}}')
print(time.perf_counter() - wall)
'''


def run(maps: Path, serial: bool, profile: str = '', kinds: bool = False, cores: bool = False,
        timeline: bool = False) -> subprocess.Popen:
    code = ONE.format(root=str(REPO), maps=str(maps), serial=serial, profile=profile, kinds=KINDS if kinds else [],
                      cores=cores, timeline=timeline, timeline_stages=TIMELINE)
    return subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE, text=True)


def seconds(process: subprocess.Popen) -> float:
    """The wall time the estimation printed last; what it printed before that is printed here."""
    return _lines(process)[1]


def cpu_seconds(maps: Path, serial: bool) -> Tuple[float, float, float]:
    """One estimation without the profiler: its wall time, the CPU of its process and of its worker processes."""
    said, wall = _lines(run(maps, serial, cores=True))
    main, workers = (float(v) for v in said[-1].split()[1:])
    return wall, main, workers


def _lines(process: subprocess.Popen) -> Tuple[List[str], float]:
    """What the estimation printed before its wall time, and that time; lines other than its CPU are printed."""
    out, _ = process.communicate()
    if process.returncode:
        sys.exit(f'profile_estimation: the estimation failed (exit {process.returncode})')
    *said, last = out.rstrip().split('\n')
    shown = [line for line in said if not line.startswith('cpu ')]
    if shown:
        print('\n'.join(shown))
    return said, float(last)


def cumulative(stats: dict, suffix: str, name: str, callers=None) -> float:
    """Cumulative seconds of the functions named `name` in files ending in `suffix` (OpenCV's, '~': those whose name
    holds `name`); with `callers` ((file suffix, function), ...), only their calls from those."""
    spent = 0.0
    for (path, _, func), v in stats.items():
        if not (path.endswith(suffix) and (func == name or suffix == '~' and name in func)):
            continue
        if callers is None:
            spent += v[3]
        else:
            spent += sum(c[3] for (cpath, _, cfunc), c in v[4].items()
                         if any(cpath.endswith(cs) and cfunc == cn for cs, cn in callers))
    return spent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('maps', nargs='*', type=Path, default=[DEFAULT_MAPS],
                    help='folders of map_*.yaml (more than one only with --timeline)')
    ap.add_argument('--threads-gain', action='store_true', help='also time the defaults and two processes')
    ap.add_argument('--phases', action='store_true', help='also split an estimation with its defaults into phases')
    ap.add_argument('--kinds', action='store_true', help='also the CPU of each kind of match, serially')
    ap.add_argument('--cores', action='store_true',
                    help='only the CPU of a serial estimation and of one with its defaults (its process and its '
                         'workers), and the cores it kept busy on average')
    ap.add_argument('--timeline', action='store_true',
                    help='only the stages of an estimation with its defaults over its wall time, for each folder')
    args = ap.parse_args()
    for maps in args.maps:
        if not glob.glob(str(maps / 'map_*.yaml')):
            sys.exit(f'profile_estimation: no map_*.yaml in {maps} (bench_merge.py --generated makes them)')
    if args.timeline:
        for maps in args.maps:
            seconds(run(maps, False, timeline=True))
        return
    if len(args.maps) > 1:
        sys.exit('profile_estimation: one folder of maps, except with --timeline')
    args.maps = args.maps[0]
    if args.cores:
        wall, serial, _ = cpu_seconds(args.maps, True)
        print(f'{args.maps.name}: serial {wall:.2f} s, CPU {serial:.2f} s')
        wall, main, workers = cpu_seconds(args.maps, False)
        print(f'{args.maps.name}: with its defaults {wall:.2f} s, CPU {main:.2f} s + {workers:.2f} s on its workers '
              f'({(main + workers) / serial:.2f} x the serial), {(main + workers) / wall:.2f} cores busy on average')
        return
    out = Path('/tmp') / f'profile_estimation_{args.maps.name}.prof'
    total = seconds(run(args.maps, True, str(out)))
    stats = pstats.Stats(str(out)).stats
    print(f'{args.maps.name}: serial estimation under cProfile {total:.2f} s')
    for label, (suffix, name) in PARTS:
        spent = cumulative(stats, suffix, name)
        print(f'  {label:22s} {spent:6.2f} s  {100 * spent / total:4.1f} %')
    if args.phases:
        total = seconds(run(args.maps, False, str(out)))
        stats = pstats.Stats(str(out)).stats
        print(f'{args.maps.name}: with its defaults {total:.2f} s (its main thread under cProfile)')
        shown = 0.0
        for label, parts in PHASES:
            spent = sum(cumulative(stats, suffix, name, callers) for (suffix, name), callers in parts)
            shown += spent
            print(f'  {label:38s} {spent:6.2f} s  {100 * spent / total:4.1f} %')
        print(f'  {"the rest, on the main thread":38s} {total - shown:6.2f} s  {100 * (total - shown) / total:4.1f} %')
    if args.kinds:
        print(f'{args.maps.name}: the matches of a serial estimation by kind')
        total = seconds(run(args.maps, True, kinds=True))
        print(f'  serial estimation {total:.2f} s')
    if args.threads_gain:
        alone = seconds(run(args.maps, True))
        threads = seconds(run(args.maps, False))
        both = [run(args.maps, True), run(args.maps, True)]
        two = [seconds(p) for p in both]
        print(f'  serial {alone:.2f} s; with its defaults {threads:.2f} s ({alone / threads:.2f} x); '
              f'two serial ones in two processes at once {two[0]:.2f} and {two[1]:.2f} s '
              f'({2 * alone / max(two):.2f} x the work per second)')


if __name__ == '__main__':
    main()
