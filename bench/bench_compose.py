#!/usr/bin/env python3
"""Composition of a merged map again and again, as the node's merging loop composes (not a test: it prints figures).

    scripts/env.sh python bench/bench_compose.py [--data DIR] [--rounds N] [--seed S]

The maps of a scenario (default: the shared 30-map one) at their true places, composed --rounds times: without a
cache (compose afresh) and with one compose.PatchCache (what MergingPipeline.compose uses), with none, a quarter and
all of the maps replaced by new Grid objects (same cells) before each composition: as the node composes at
merging_rate while the robots' maps change about once a second. Prints milliseconds per composition and the ratio
to composing afresh, and checks that each merge has the cells of the one composed afresh.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from multirobot_map_merge import transforms as tf  # noqa: E402
from multirobot_map_merge.compose import PatchCache, compose  # noqa: E402
from multirobot_map_merge.grid import Grid  # noqa: E402
from multirobot_map_merge.mapio import load_map  # noqa: E402

DEFAULT_DATA = REPO.parent / 'shared' / 'data' / 'dev' / 'large30_hospital_section'


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--data', type=Path, default=DEFAULT_DATA, help='scenario folder with truth.json and its maps')
    ap.add_argument('--rounds', type=int, default=20)
    ap.add_argument('--seed', type=int, default=0, help='which maps are replaced')
    args = ap.parse_args()
    if not (args.data / 'truth.json').is_file():
        sys.exit(f'bench_compose: {args.data}/truth.json not found (--data)')
    truth = json.loads((args.data / 'truth.json').read_text())
    grids = [load_map(str(args.data / m['file'])) for m in truth['maps']]
    poses = [tf.rigid(*m['pose']) for m in truth['maps']]
    placed = [tf.inverse(poses[0]) @ p for p in poses]
    rng = np.random.default_rng(args.seed)

    start = time.perf_counter()
    for _ in range(args.rounds):
        afresh = compose(grids, placed)
    base = (time.perf_counter() - start) / args.rounds
    print(f'{len(grids)} maps ({sum(g.data.size for g in grids)} cells), merged {afresh.data.shape[1]} x '
          f'{afresh.data.shape[0]}; composed afresh: {1000 * base:.1f} ms')
    cache = PatchCache()
    compose(grids, placed, cache=cache)
    for changed in (0, len(grids) // 4, len(grids)):
        spent = 0.0
        for _ in range(args.rounds):
            for k in rng.choice(len(grids), changed, replace=False):
                g = grids[k]
                grids[k] = Grid(g.data.copy(), g.resolution, g.origin, g.frame_id)
            start = time.perf_counter()
            merged = compose(grids, placed, cache=cache)
            spent += time.perf_counter() - start
        same = merged.origin == afresh.origin and np.array_equal(merged.data, compose(grids, placed).data)
        print(f'  with the cache, {changed:2d} maps new each time: {1000 * spent / args.rounds:.1f} ms '
              f'({spent / args.rounds / base:.2f} x){"" if same else "  DIFFERENT CELLS"}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
