#!/usr/bin/env python3
"""The node's estimation loop on maps that no longer change, with the search budget's answers drawn at random (not a
test: it prints one line per run and the runs that left a robot out).

    scripts/env.sh python bench/budget_fuzz.py [--maps DIR] [--seeds A B] [--shares P ...]

A loaded machine cuts the node's correlation searches short (EstimationSettings.search_budget_s, wall time), and
which searches it cuts depends on the load. Here each answer of the budget (growth.SearchBudget: spent or not, asked
before each search) is drawn at random: spent with probability P (each of --shares in turn, per seed), redrawn from
0, 0.3, 0.6, 0.9 and 1 for each later estimation, an unlimited budget never spent. The loop is the node's
(map_merge's estimation settings, its memory, ros.robot_maps.EstimationGate): estimations on the same maps, 1.5-4 s
of ROS time apart, until the gate stops them (the maps unchanged, every search made, no placement held) or after
30. The node must then show every robot the maps can place: a robot left out for good shows as LEFT OUT. The maps
default to test/data/demo_late_group (the six early maps of a live demo; the node's rostest under load), all six
placeable. Exits 1 when a run left a robot out.
"""
from __future__ import annotations

import argparse
import math
import random
import sys
from pathlib import Path
from typing import List, Tuple

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from multirobot_map_merge.estimation import growth  # noqa: E402
from multirobot_map_merge.mapio import load_map  # noqa: E402
from multirobot_map_merge.pipeline import MergingPipeline  # noqa: E402
from multirobot_map_merge.ros.params import MapMergeParams  # noqa: E402
from multirobot_map_merge.ros.robot_maps import EstimationGate  # noqa: E402

DEFAULT_MAPS = REPO / 'test' / 'data' / 'demo_late_group'
ESTIMATIONS = 30
LATER_SHARES = (0.0, 0.3, 0.6, 0.9, 1.0)


class RandomBudget:
    """growth.SearchBudget.spent answered at random while installed."""

    def __init__(self, rng: random.Random, share: float):
        self.rng, self.share = rng, share

    def spent(self, budget: growth.SearchBudget, seconds: float, limit: float) -> bool:
        verdict = not math.isinf(limit) and (seconds >= limit or self.rng.random() < self.share)
        budget.verdicts.append(verdict)
        return verdict


def run(maps: Path, seed: int, share: float) -> Tuple[int, int, List[tuple]]:
    """(robots placed at the end, robots, (placed, postponed, held) of each estimation) of one run."""
    files = sorted(maps.glob('*.yaml'))
    names = [f.stem for f in files]
    grids = [load_map(str(f)) for f in files]
    rng = random.Random(seed)
    answers = RandomBudget(rng, share)
    real = growth.SearchBudget.spent
    growth.SearchBudget.spent = lambda budget, seconds, limit: answers.spent(budget, seconds, limit)
    try:
        pipeline = MergingPipeline(MapMergeParams().estimation_settings().replace(processes=False))
        gate = EstimationGate()
        now, steps = 1000.0, []
        for _ in range(ESTIMATIONS):
            if not gate.wanted((names, grids)):
                break
            pipeline.feed(grids)
            # as the node: the last placements of every robot (none yet: each None), its reference preferred
            result = pipeline.estimate(previous=pipeline.transforms or [None] * len(grids), names=names, now=now)
            gate.estimated((names, grids), complete=not result.postponed and not result.held)
            steps.append((sum(t is not None for t in result.transforms), result.postponed, result.held))
            now += rng.uniform(1.5, 4.0)
            answers.share = rng.choice(LATER_SHARES)
    finally:
        growth.SearchBudget.spent = real
    return steps[-1][0], len(names), steps


def main(argv: List[str] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--maps', type=Path, default=DEFAULT_MAPS, help='a folder of map yaml files, every one placeable')
    ap.add_argument('--seeds', type=int, nargs=2, default=(0, 40), metavar=('A', 'B'), help='seeds A..B-1')
    ap.add_argument('--shares', type=float, nargs='+', default=[0.5, 0.95],
                    help='chance that the first estimation finds its budget spent at each question')
    args = ap.parse_args(argv)
    if not sorted(args.maps.glob('*.yaml')):
        print(f'budget_fuzz: no map yaml files in {args.maps}', file=sys.stderr)
        return 2
    left = 0
    for seed in range(*args.seeds):
        for share in args.shares:
            placed, robots, steps = run(args.maps, seed, share)
            mark = '' if placed == robots else '  LEFT OUT'
            left += placed < robots
            print(f'seed {seed} share {share}: {placed}/{robots} placed after {len(steps)} estimations '
                  f'(placed, postponed, held): {steps}{mark}', flush=True)
    runs = (args.seeds[1] - args.seeds[0]) * len(args.shares)
    print(f'\n{left} of {runs} runs left a robot out')
    return 1 if left else 0


if __name__ == '__main__':
    sys.exit(main())
