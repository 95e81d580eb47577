#!/usr/bin/env python3
"""merge_maps' estimation of each generated building seeded by one mergeable map after another (not a test: it prints
figures).

    scripts/env.sh python bench/seed_sweep.py [--generated NAMES] [--every K] [--why]

The growth starts from one map, the seed (merge_maps: the largest; the node: its reference), and what it places
depends on it: the order in which groups form. Here each building of `bench_merge.py --generated` (NAMES as there:
every kind by default, `unseen`, `unseen2` or a list; made into out/bench on first use) is estimated with the
defaults, seeded by every K-th of its mergeable maps in turn (`estimate(..., preferred_reference=seed)`), and scored
by the shared scorer. Prints per building the maps placed right from each seed, the seeds that place fewer than the
most, and the maps placed wrong (W); then the seeds short of the most in all. With --why, under each building, for
each seed short of the most: every mergeable map it does not place right, with the reason of its last refused match
(the estimate's pairs) and the right-placed maps it shares most with by the truth (m2).
"""
from __future__ import annotations

import argparse
import sys
from typing import List

import bench_merge  # bench/, beside this script (puts the repository on sys.path)
from reveal import score_placements, scorer, wrong_of


def sweep(name: str, every: int, score, why: bool = False) -> tuple:
    """(mergeable maps, [(seed, placed right, placed wrong, lines saying why the others are not placed right)]) of
    one building (the lines only with `why`)."""
    from multirobot_map_merge.estimation.estimator import estimate
    from multirobot_map_merge.estimation.settings import EstimationSettings
    cache = bench_merge.REPO / 'out' / 'bench'
    bench_merge.ensure_generated(cache, name)
    grids, truth = bench_merge.load_scenario(cache / name)
    mergeable = truth['mergeable']
    files = [m['file'] for m in truth['maps']]
    rows = []
    for seed in mergeable[::every]:
        found = estimate(grids, EstimationSettings(), preferred_reference=seed)
        placed = {k: t for k, t in enumerate(found.transforms) if t is not None}
        wrong = {files.index(f) for f, _, _ in wrong_of(score_placements(score, truth, placed))}
        right = (set(placed) - wrong) & set(mergeable)
        rows.append((seed, len(right), len(wrong), left_out_lines(found, truth, right) if why else []))
    return len(mergeable), rows


def left_out_lines(found, truth: dict, right: set) -> List[str]:
    """For each mergeable map not in `right` (placed right): placed wrong, or the reason of its last refused match,
    and the maps of `right` it shares most with by the truth."""
    refused = {m.i: m for m in found.pairs if found.transforms[m.i] is None}
    shared = truth['overlap']['shared_m2']
    lines = []
    for k in truth['mergeable']:
        if k in right:
            continue
        m = refused.get(k)
        verdict = 'placed wrong' if found.transforms[k] is not None else (m.reason if m is not None else 'no match')
        near = sorted(right, key=lambda j: -shared[k][j])[:3]
        lines.append(f'map {k}: {verdict}; shares with right-placed maps '
                     + ', '.join(f'{j} {shared[k][j]:.0f} m2' for j in near if shared[k][j] > 0))
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--generated', default='buildings', metavar='NAMES',
                    help='buildings (default), unseen, unseen2, large or a comma-separated list, as bench_merge.py')
    ap.add_argument('--every', type=int, default=3, help='seed the estimation by every K-th mergeable map')
    ap.add_argument('--why', action='store_true',
                    help='under each building, why each seed short of the most leaves its maps out')
    args = ap.parse_args()
    if args.every < 1:
        sys.exit('seed_sweep: --every must be 1 or more')
    score = scorer()
    if score is None:
        sys.exit('seed_sweep: ../shared/eval/score.py not found: nothing to score')
    short = runs = 0
    print(f'seed_sweep: every {args.every}. mergeable map as the seed; {bench_merge.machine.describe()}')
    for name in bench_merge.building_names(args.generated):
        mergeable, rows = sweep(name, args.every, score, args.why)
        most = max(right for _, right, _, _ in rows)
        fewer = [f'{seed} ({right})' for seed, right, _, _ in rows if right < most]
        short += len(fewer)
        runs += len(rows)
        print(f'  {name}: {mergeable} mergeable; placed right by seed: '
              + ' '.join(f'{seed}:{right}' + (f'W{wrong}' if wrong else '') for seed, right, wrong, _ in rows)
              + (f'; short of {most}: {", ".join(fewer)}' if fewer else ''), flush=True)
        for seed, right, _, lines in rows:
            if right < most:
                for line in lines:
                    print(f'    seed {seed}: {line}', flush=True)
    print(f'{short} of {runs} seeds place fewer maps right than the best seed of their building')
    return 0


if __name__ == '__main__':
    sys.exit(main())
