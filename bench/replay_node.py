#!/usr/bin/env python3
"""The map_merge node's estimations replayed offline (not a test: it prints figures).

    scripts/env.sh python bench/replay_node.py [--until 90] [--reveal 60] [--step S] [--threads N]
        [--opencv-threads N] [--processes] [--search-budget S] [--data DIR | --generated [NAMES]]
        [--save-budget FILE] [--budget-from FILE]

The 30-map scenario (../shared/data/dev/large30_hospital_section) revealed as bench_node publishes it (bench/reveal.py:
2 m tiles, nearest to each robot's start first, all known after --reveal s), estimated as the node estimates it (its
settings, one pipeline with its memory, each estimation tracking the last one's placements) at the times of a
clock: the next estimation starts --step s after the last one started, or (no --step) once it has ended, at least
one period of the node's default estimation_rate later. Prints per estimation its wall and CPU time, the maps placed
and those the shared scorer finds placed wrong; then the median and longest estimation and the CPU of all of them.

--generated replays the generated 36-robot buildings of bench_merge.py --generated instead (all of them, or NAMES,
comma-separated; made into out/bench on first use), one after the other, and ends with one line per building: the
estimations that published a map placed wrong, and the maps placed wrong by the last one. Buildings we have not
tuned on, growing as a live fleet's maps do.

What bench_node measures live comes with its noise (the same code: median 2.5-3.7 s from one run to the next, with
the publisher and roscore on the same two cores); with --step the same maps are estimated at the same times in every
run, so two revisions or settings can be compared on their CPU time, and every estimation is scored. Their
results still differ a little from run to run: the node's search budget is wall time (--search-budget inf: none,
the same results in every run, and the first estimations take half a minute each). --save-budget FILE writes the
search budget's answers of every estimation, and --budget-from FILE gives another run (another revision, the same
--step) those answers (growth.SearchBudget: beyond them the clock answers), so that two revisions are compared on
the same searches.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Tuple

import bench_merge  # bench/, beside this script (puts the repository on sys.path)
from reveal import reveal_order, revealed_grids, score_placements, scorer, wrong_of

DATA = bench_merge.REPO.parent / 'shared' / 'data' / 'dev' / 'large30_hospital_section'


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--data', type=Path, default=DATA, help='scenario folder with truth.json and its maps')
    ap.add_argument('--until', type=float, default=90.0, help='clock (s) at which no estimation starts any more')
    ap.add_argument('--reveal', type=float, default=60.0, help='s until every map is known (bench_node: half its run)')
    ap.add_argument('--step', type=float, help='s between the starts of two estimations (default: as they take)')
    ap.add_argument('--threads', type=int, help='EstimationSettings.threads (default: the node\'s)')
    ap.add_argument('--opencv-threads', type=int, help='cv2.setNumThreads before the first estimation')
    ap.add_argument('--processes', action='store_true', help='as ~estimation_processes:=true')
    ap.add_argument('--search-budget', type=float, help='s of correlation search per estimation (default: the '
                                                        'node\'s; inf: no limit)')
    ap.add_argument('--generated', nargs='?', const='buildings', metavar='NAMES',
                    help="the generated buildings instead of --data (default: all of them)")
    ap.add_argument('--save-budget', type=Path, metavar='FILE',
                    help='write the search budget\'s answers of every estimation into FILE (JSON)')
    ap.add_argument('--budget-from', type=Path, metavar='FILE',
                    help='answer the search budget as in FILE (--save-budget of another run, the same --step)')
    args = ap.parse_args()
    if args.budget_from is not None and not args.step:
        sys.exit('replay_node: --budget-from needs --step (else the clock depends on the wall time)')
    try:
        args.budgets = json.loads(args.budget_from.read_text()) if args.budget_from is not None else {}
    except (OSError, ValueError) as e:
        sys.exit(f'replay_node: cannot read {args.budget_from}: {e}')
    args.saved = {}
    score = scorer()
    if score is None:
        sys.exit('replay_node: ../shared/eval/score.py not found: nothing to score')
    if args.generated is None:
        if not (args.data / 'truth.json').is_file():
            sys.exit(f'replay_node: {args.data}/truth.json not found (--data)')
        replay(args.data, args, score)
        save_budget(args)
        return 0
    cache = bench_merge.REPO / 'out' / 'bench'
    rows = []
    for name in bench_merge.building_names(args.generated):
        bench_merge.ensure_generated(cache, name)
        rows.append((name,) + replay(cache / name, args, score))
    print('building: estimations publishing a map placed wrong; maps placed wrong at the last one')
    for name, count, wrong_estimations, last in rows:
        print(f'  {name}: {wrong_estimations} of {count}; ' + ('; '.join(f'{f} {r:.2f} deg {c:.1f} cells'
                                                                        for f, r, c in last) or 'none'))
    print(f'all: {sum(r[2] for r in rows)} of {sum(r[1] for r in rows)} estimations')
    save_budget(args)
    return 0


def save_budget(args: argparse.Namespace) -> None:
    if args.save_budget is not None:
        args.save_budget.write_text(json.dumps(args.saved))


def replay(data: Path, args: argparse.Namespace, score) -> Tuple[int, int, list]:
    """Replay the node's estimations on one scenario revealed; prints them, returns (estimations, estimations with
    a map placed wrong, the maps placed wrong by the last one)."""
    import cv2
    from multirobot_map_merge.pipeline import MergingPipeline
    from multirobot_map_merge.ros.params import MapMergeParams
    if args.opencv_threads is not None:
        cv2.setNumThreads(args.opencv_threads)
    params = MapMergeParams(estimation_processes=args.processes)
    period = 1.0 / params.estimation_rate   # the node's estimation loop at its default rate
    settings = params.estimation_settings()
    if args.threads is not None:
        settings = settings.replace(threads=args.threads)
    if args.search_budget is not None:
        settings = settings.replace(search_budget_s=args.search_budget)
    grids, truth = bench_merge.load_scenario(data)
    orders = [reveal_order(g) for g in grids]
    names = [f'robot_{k:02d}' for k in range(len(grids))]
    pipeline = MergingPipeline(settings)
    print(f'replay_node: {len(grids)} maps of {data.name}, revealed over {args.reveal:g} s, '
          f'{"every %g s" % args.step if args.step else "one estimation after the other"}; '
          f'threads {settings.threads}, processes {settings.processes}; {bench_merge.machine.describe()}')
    clock, walls, cpus, wrong_estimations, wrong = 0.0, [], [], 0, []
    scripts, answers = args.budgets.get(data.name, []), args.saved.setdefault(data.name, [])
    while clock < args.until:
        share = clock / args.reveal if args.reveal > 0 else 1.0
        pipeline.feed(revealed_grids(grids, orders, share))
        wall, cpu = time.perf_counter(), time.process_time()
        script = scripts[len(walls)] if len(walls) < len(scripts) else None
        found = pipeline.estimate(previous=pipeline.transforms or None, names=names, now=clock, budget_script=script)
        answers.append(list(found.budget_verdicts))
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        walls.append(wall)
        cpus.append(cpu)
        # what the node publishes: the pipeline's transforms (kept placements, new ones once confirmed)
        wrong = wrong_of(score_placements(score, truth, {k: t for k, t in enumerate(pipeline.transforms)
                                                         if t is not None}))
        wrong_estimations += bool(wrong)
        print(f'  t={clock:6.1f} s  estimation {wall:5.2f} s  CPU {cpu:5.2f} s  placed '
              f'{sum(t is not None for t in pipeline.transforms):2d}/{len(grids)}  held {found.held}  postponed '
              f'{found.postponed}' + (f'  WRONG {"; ".join(f"{f} {r:.2f} deg {c:.1f} cells" for f, r, c in wrong)}'
                                      if wrong else ''), flush=True)
        clock += args.step if args.step else max(period, wall)
    print(f'{len(walls)} estimations: median {statistics.median(walls):.2f} s, longest {max(walls):.2f} s, CPU '
          f'{sum(cpus):.1f} s in all (this process: its worker processes not included); '
          f'{wrong_estimations} with a map placed wrong')
    return len(walls), wrong_estimations, wrong


if __name__ == '__main__':
    sys.exit(main())
