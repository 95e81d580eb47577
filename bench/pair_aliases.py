#!/usr/bin/env python3
"""What tells an alias from a right placement among the pair matches of partial maps (not a test: it prints figures).

    scripts/env.sh python bench/pair_aliases.py [--share 0.25] [--rivals] [NAMES ...]

Estimates each generated building (bench_merge.py --generated; default: the six whose partial maps are merged wrong
most, NAMES for others) once with merge_maps' settings on its maps revealed to --share (bench/reveal.py), and keeps
every pair match of two single healthy maps it accepts. By the truth each is right or an alias (over 1.5 degrees or
0.3 m off at the map's known corners). Prints the 10th, 50th and 90th percentiles of the figures the acceptance
rules see, for each kind; with --rivals it also searches each accepted match for a rival (pair.find_rival: another
place that passes the rules but precision, however small) and prints how often each kind has one, how large, and
how many of each a rival of a given share of the best's support would single out.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import List

import numpy as np

import bench_merge  # bench/, beside this script (puts the repository on sys.path)
from reveal import reveal_order, revealed_grids

DEFAULT = ['office36', 'hospital36', 'mall36', 'maze36', 'courtyard36', 'campus36']
FIGURES = ('overlap_m2', 'agreement', 'support', 'corner_error_m', 'descriptor_inliers')
RIVAL_SHARES = (0.2, 0.3, 0.4)


def accepted_pairs(folder: Path, share: float, rivals: bool) -> List[dict]:
    from multirobot_map_merge import transforms as tf
    from multirobot_map_merge.estimation import pair, workers
    from multirobot_map_merge.estimation.estimator import estimate
    from multirobot_map_merge.estimation.settings import EstimationSettings
    from multirobot_map_merge.estimation.union import known_corners
    grids, truth = bench_merge.load_scenario(folder)
    shown = revealed_grids(grids, [reveal_order(g) for g in grids], share)
    maps = truth['maps']
    rows: List[dict] = []
    matched = workers.match_pair

    def kept(i, j, pi, pj, s, **options):
        m = matched(i, j, pi, pj, s, **options)
        single = not options.get('onto_union') and not options.get('between_groups')
        if m.accepted and single and not maps[i].get('broken') and not maps[j].get('broken'):
            true = tf.inverse(tf.rigid(*maps[j]['pose'])) @ tf.rigid(*maps[i]['pose'])
            rot, shift = tf.difference(m.transform_m, true, known_corners(shown[i]))
            row = {name: float(getattr(m.best, name, 0.0)) for name in FIGURES[:4]}
            row.update(descriptor_inliers=float(m.descriptor_inliers),
                       alias=math.degrees(rot) > 1.5 or shift > 0.3, rival_share=0.0, rival_m2=0.0)
            if rivals:
                rival = pair.find_rival(pi, pj, m.best, s)
                if rival is not None:
                    row.update(rival_share=rival.support / max(m.best.support, 1), rival_m2=rival.overlap_m2)
            rows.append(row)
        return m

    workers.match_pair = kept   # the matcher calls it through the module (no worker processes below)
    try:
        estimate(shown, EstimationSettings().replace(processes=False))
    finally:
        workers.match_pair = matched
    return rows


def percentiles(rows: List[dict], key: str) -> str:
    if not rows:
        return '-'
    return '/'.join(f'{v:.3g}' for v in np.percentile([r[key] for r in rows], [10, 50, 90]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('names', nargs='*', default=DEFAULT, help='generated buildings (default: %(default)s)')
    ap.add_argument('--share', type=float, default=0.25, help='share of the reveal (0..1)')
    ap.add_argument('--rivals', action='store_true', help='search each accepted match for a rival')
    args = ap.parse_args()
    cache = bench_merge.REPO / 'out' / 'bench'
    rows: List[dict] = []
    for name in args.names:
        bench_merge.ensure_generated(cache, name)
        rows += accepted_pairs(cache / name, args.share, args.rivals)
    aliases, right = [r for r in rows if r['alias']], [r for r in rows if not r['alias']]
    print(f'pair_aliases: {", ".join(args.names)} at {args.share:.0%} revealed; {bench_merge.machine.describe()}')
    print(f'{len(rows)} pair matches of single healthy maps accepted, {len(aliases)} of them aliases')
    keys = FIGURES + (('rival_share', 'rival_m2') if args.rivals else ())
    for key in keys:
        print(f'  {key}: right {percentiles(right, key)}, aliases {percentiles(aliases, key)} (10th/50th/90th)')
    if args.rivals:
        print(f'  with a rival: right {sum(r["rival_share"] > 0 for r in right)} of {len(right)}, aliases '
              f'{sum(r["rival_share"] > 0 for r in aliases)} of {len(aliases)}')
        for share in RIVAL_SHARES:
            print(f'  a rival of {share:g} x the best support or more: right '
                  f'{sum(r["rival_share"] >= share for r in right)}, aliases '
                  f'{sum(r["rival_share"] >= share for r in aliases)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
