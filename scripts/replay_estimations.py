#!/usr/bin/env python3
"""Estimate a live node's recorded estimations again, one by one, with their exact inputs (a diagnostic).

    scripts/env.sh python scripts/replay_estimations.py RUN.estimations [--summary SUMMARY.json] [--budget S]
        [--own] [--until N] [--why ROBOT] [--exposure]

RUN.estimations is what the map_merge node records with MAP_MERGE_RECORD_ESTIMATIONS set (`make demo DEMO_ARGS="...
--record RUN.bag"` writes it beside the bag; multirobot_map_merge/recording.py): per estimation the snapshots of the
robots' maps it started from, its reference and the placements it tracked. The replay feeds them to one pipeline
with the node's settings in the same order (its memory and confirmation evolve as the node's did, if the results
agree), and prints per estimation: its index and ROS time, what the node placed and what the replay places (robots
placed by one and not the other; the largest difference between the two placements of a robot, in metres at its
map's corners, as the estimator measures moves) and both wall times; with the demo's summary.json, the worst
placement error of each against the ground truth (start poses; relative to the first placed robot by name, as the
summary measures). Each estimation starts from the node's recorded placements (what it tracked live) unless --own
(then from the replay's own last result, as a node running this code would).

The search budget (wall time, so the live node's cuts depend on its machine's load) answers as it did live: each
estimation makes the searches its live run made (growth.SearchBudget). --budget S instead gives each estimation a
budget of S wall seconds of this machine (0: none), to see what the same inputs give with more or fewer searches.
--why ROBOT prints, at each estimation, how that robot was placed or why it was refused.

--exposure (with --summary) estimates nothing: at each estimation it matches every robot the node had not placed
onto the union of those it had, composed at their true poses, as the growth matches a grid onto a union (search
included), and prints each match the pair rules accept, right or wrong (more than 1 degree or 0.5 m off the truth),
then how many were made, accepted and wrong: the aliases that only the rules after a pair's (waiting for a stronger
pair, confirmation, uniqueness) stand between and a published merge. A recorded 12-robot run of seed 1 showed
robot_5 fitting the merge 28.0 m along a corridor of alike rooms, on 5 m2 with 116 agreeing walls.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from typing import Dict, List, Optional

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

import numpy as np  # noqa: E402

from multirobot_map_merge import transforms as tf  # noqa: E402
from multirobot_map_merge.compose import compose  # noqa: E402
from multirobot_map_merge.estimation.features import FeatureCache, content_key, prepare  # noqa: E402
from multirobot_map_merge.estimation.pair import match_pair  # noqa: E402
from multirobot_map_merge.estimation.union import known_corners  # noqa: E402
from multirobot_map_merge.pipeline import MergingPipeline  # noqa: E402
from multirobot_map_merge.recording import read_estimations  # noqa: E402
from multirobot_map_merge.ros.node import CACHE_SPARE  # noqa: E402
from multirobot_map_merge.ros.params import MapMergeParams  # noqa: E402
from replay_bag_estimation import worst_error  # noqa: E402  (scripts/, beside this one)


def differences(names: List[str], grids, live: Dict[str, np.ndarray], replay: Dict[str, np.ndarray]) -> str:
    """What one placed and the other did not, and the largest move between the two placements of a robot."""
    only_live = [n for n in names if n in live and n not in replay]
    only_replay = [n for n in names if n in replay and n not in live]
    moves = [(tf.difference(live[n], replay[n], known_corners(g))[1], n) for n, g in zip(names, grids)
             if n in live and n in replay and g is not None]
    out = []
    if only_live:
        out.append('only live: ' + ' '.join(only_live))
    if only_replay:
        out.append('only replay: ' + ' '.join(only_replay))
    if moves:
        worst, n = max(moves)
        if worst > 0.05:
            out.append(f'moved {n} {worst:.2f} m')
    return '; '.join(out) if out else 'same'


# a placement this far off the truth is wrong (the live target: no status with a robot off by more)
WRONG_DEG, WRONG_M = 1.0, 0.5


def exposure(record: str, starts: Dict[str, tuple], settings) -> int:
    """--exposure: each robot not placed matched onto the union of the placed ones at their true poses."""
    res = settings.min_work_resolution
    truth = {n: tf.rigid(*p[:3]) for n, p in starts.items()}
    cache = FeatureCache()   # a map's content recurs over estimations, onto other placed maps
    made = accepted = wrong = 0
    seen = set()
    for rec in read_estimations(record):
        grid_of = dict(zip(rec.names, rec.grids))
        placed = sorted(n for n in rec.placed if grid_of.get(n) is not None and n in truth)
        union = compose([grid_of[n] for n in placed], [truth[n] for n in placed], res) if placed else None
        target = prepare(union, res, settings.feature) if union is not None else None
        for k, n in enumerate(rec.names):
            grid = grid_of[n]
            key = (n, content_key(grid) if grid is not None else None, tuple(placed))
            if target is None or grid is None or n in rec.placed or n not in truth or key in seen:
                continue
            seen.add(key)   # the same map onto the same placed maps: the same match
            part = cache.get(grid, res, settings.feature)
            if part is None:
                continue
            m = match_pair(k, len(rec.names), part, target, settings, onto_union=len(placed) > 1)
            made += 1
            if not m.accepted:
                continue
            accepted += 1
            rot, off = tf.difference(truth[n], m.transform_m, known_corners(grid))
            off_target = math.degrees(rot) > WRONG_DEG or off > WRONG_M
            wrong += off_target
            print(f'#{rec.index:3d} t {rec.now:7.2f}  {n} onto {len(placed)} placed: '
                  f'{"WRONG" if off_target else "right"} {math.degrees(rot):.2f} deg, '
                  f'{off:.2f} m off; {m.best.support} agreeing walls, agreement {m.best.agreement:.2f}, '
                  f'{m.best.overlap_m2:.1f} m2')
    print(f'{made} matches onto the placed robots, {accepted} accepted, {wrong} wrong')
    return 0


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('record')
    ap.add_argument('--summary', help="the demo's summary.json (ground truth)")
    ap.add_argument('--budget', type=float, default=None,
                    help="search budget per estimation, wall s of this machine (0: none; default: as live)")
    ap.add_argument('--own', action='store_true', help="start each estimation from the replay's own last result")
    ap.add_argument('--until', type=int, default=None, help='stop after the estimation of this index')
    ap.add_argument('--why', default=None, help='print how this robot was placed or refused at each estimation')
    ap.add_argument('--exposure', action='store_true',
                    help='match each robot not placed onto the placed ones at their true poses (needs --summary)')
    args = ap.parse_args(argv)
    if args.exposure and not args.summary:
        print('replay_estimations: --exposure needs --summary (the true poses)', file=sys.stderr)
        return 2
    starts: Dict[str, tuple] = {}
    if args.summary:
        try:
            summary = json.load(open(args.summary))
        except (OSError, ValueError) as e:
            print(f'replay_estimations: cannot read {args.summary}: {e}', file=sys.stderr)
            return 2
        starts = {'/' + n.strip('/'): tuple(p) for n, p in summary.get('start_poses', {}).items()}
    settings = MapMergeParams().estimation_settings()
    if args.exposure:
        try:
            return exposure(args.record, starts, settings)
        except (OSError, ValueError, KeyError) as e:
            print(f'replay_estimations: cannot read the record {args.record}: {e}', file=sys.stderr)
            return 2
    if args.budget is not None:
        settings = settings.replace(search_budget_s=args.budget if args.budget > 0 else math.inf)
    pipeline = MergingPipeline(settings)
    capacity = 0
    own: Dict[str, np.ndarray] = {}
    own_reference: Optional[str] = None
    why = '/' + args.why.strip('/') if args.why else None
    try:
        for rec in read_estimations(args.record):
            if args.until is not None and rec.index > args.until:
                break
            if len(rec.names) + CACHE_SPARE != capacity:   # as the node keeps its feature cache
                capacity = len(rec.names) + CACHE_SPARE
                pipeline.cache = FeatureCache(capacity=capacity)
            pipeline.feed(rec.grids)
            reference = own_reference if args.own else rec.reference
            previous = [own.get(n) for n in rec.names] if args.own else rec.previous
            preferred = rec.names.index(reference) \
                if reference in rec.names and rec.grids[rec.names.index(reference)] is not None else None
            t0 = time.perf_counter()
            result = pipeline.estimate(preferred_reference=preferred, previous=previous, names=rec.names,
                                       now=rec.now, budget_script=rec.budget_verdicts if args.budget is None else None)
            took = time.perf_counter() - t0
            own = {n: t for n, t in zip(rec.names, result.transforms) if t is not None}
            own_reference = rec.names[result.reference] if result.reference is not None else None
            grid_of = dict(zip(rec.names, rec.grids))
            print(f'#{rec.index:3d} t {rec.now:7.2f}  live {len(rec.placed):2d} placed, held {rec.held}, '
                  f'{rec.seconds:.2f} s{worst_error(rec.placed, starts, grid_of)}\n'
                  f'              replay {len(own):2d} placed, held {result.held}, {took:.2f} s'
                  f'{worst_error(own, starts, grid_of)}; {differences(rec.names, rec.grids, rec.placed, own)}')
            if why in grid_of:
                k = rec.names.index(why)
                for p in result.pairs:
                    if p.i == k:
                        print(f'      {why}: {"placed" if p.accepted else "refused"} against {rec.names[p.j]}'
                              f' ({p.inliers} inliers, confidence {p.confidence:.2f})'
                              f'{": " + p.reason if p.reason else ""}')
    except (OSError, ValueError, KeyError) as e:
        print(f'replay_estimations: cannot read the record {args.record}: {e}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
