#!/usr/bin/env python3
"""How well do two maps themselves pin down their true placement? A diagnostic on scenarios with ground truth.

    scripts/env.sh python scripts/evidence_report.py [--data ../shared/data/dev] [--only pair_small]

For each two-map scenario it places map 0 on map 1 at the true placement and prints:
- truth: agreeing wall cells, agreement, contradictions well inside both views, expected corner error
  (precision.py) - what the acceptance rules see at the right answer;
- best fit: the placement near the truth or near the pipeline's best (within 3 degrees, 12 cells) that agrees with
  the most walls, by a smoothed count (walls near walls, less walls well inside the other's open floor), and its
  distance from the truth: if the maps fit better some cells away, no method that goes by the maps can be right to
  the eval's 3 cells;
- rival: another place, distinct from the truth, that passes the acceptance rules relaxed to the truth's own level
  (matching.find_rival): then the maps fit two places equally;
- the pipeline's verdict on the pair.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from multirobot_map_merge import transforms as tf  # noqa: E402
from multirobot_map_merge.estimation.estimator import estimate  # noqa: E402
from multirobot_map_merge.estimation.features import PreparedGrid, opposed, prepare  # noqa: E402
from multirobot_map_merge.estimation.pair import find_rival  # noqa: E402
from multirobot_map_merge.estimation.polish import descend  # noqa: E402
from multirobot_map_merge.estimation.precision import corner_error  # noqa: E402
from multirobot_map_merge.estimation.settings import EstimationSettings  # noqa: E402
from multirobot_map_merge.estimation.verify import verify  # noqa: E402
from multirobot_map_merge.mapio import load_map  # noqa: E402

NEAR = 3.0      # pixels: a wall this close to the other's wall counts, smoothly less with distance
FRINGE = 1.5    # pixels: a wall this close to the other's unknown area contradicts nothing


def fit(src: PreparedGrid, dst: PreparedGrid, model: np.ndarray) -> float:
    """Smoothed count of src's walls (placed by model) on dst's walls, less those on dst's open floor."""
    moved = np.rint(tf.apply(model, src.walls)).astype(np.int64)
    h, w = dst.work.shape
    inside = (moved[:, 0] >= 0) & (moved[:, 1] >= 0) & (moved[:, 0] < w) & (moved[:, 1] < h)
    x, y = moved[inside, 0], moved[inside, 1]
    known = dst.work[y, x] >= 0
    x, y = x[known], y[known]
    d = dst.wall_distance[y, x].astype(np.float64)
    faces = opposed(src.wall_normals[inside][known] @ model[:2, :2].T, dst.free_side[y, x])
    near = d <= NEAR
    reward = np.where(near & ~faces, 1.0 - (d / NEAR) ** 2, 0.0).sum()
    return float(reward - ((~near) & (dst.known_depth[y, x] > FRINGE)).sum())


def score(pi: PreparedGrid, pj: PreparedGrid, m: np.ndarray) -> float:
    return fit(pi, pj, m) + fit(pj, pi, tf.inverse(m))


def best_fit(pi: PreparedGrid, pj: PreparedGrid, start: np.ndarray) -> np.ndarray:
    """Grid search (0.25 degrees, 2 pixels) then pattern search of the symmetric fit around `start`."""
    centre = tf.apply(start, pi.walls).mean(axis=0)

    def moved(p) -> np.ndarray:
        turn = tf.translation(centre[0] + p[1], centre[1] + p[2]) @ tf.rigid(0.0, 0.0, p[0])
        return turn @ tf.translation(-centre[0], -centre[1]) @ start
    grid = [(math.radians(a), x, y) for a in np.arange(-3.0, 3.01, 0.25)
            for x in range(-12, 13, 2) for y in range(-12, 13, 2)]
    p = np.array(max(grid, key=lambda q: score(pi, pj, moved(q))))
    p += descend(lambda m: -score(pi, pj, m), lambda q: moved(p + q), (math.radians(0.125), 1.0), max_moves=200)
    return moved(p)


def report(folder: Path, settings: EstimationSettings) -> str:
    truth = json.loads((folder / 'truth.json').read_text())
    grids = [load_map(str(folder / m['file'])) for m in truth['maps']]
    res = max(min(g.resolution for g in grids), settings.min_work_resolution)
    pi, pj = (prepare(g, res, settings.feature) for g in grids)
    true_m = tf.inverse(tf.rigid(*truth['maps'][1]['pose'])) @ tf.rigid(*truth['maps'][0]['pose'])
    true_px = tf.inverse(pj.px_to_map) @ true_m @ pi.px_to_map
    h, w = pi.work.shape
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], float)

    def off(m: np.ndarray) -> str:
        rot, disp = tf.difference(m, true_px, corners)
        return f'{math.degrees(rot):.2f} deg / {disp:.1f} cells off'
    at = verify(pi, pj, true_px, settings)
    precision = corner_error(pi, pj, true_px, settings.verify_tolerance) * res
    result = estimate(grids, settings)
    pair = result.pairs[0]
    # from the truth and from the pipeline's placement: the better fit of the two neighbourhoods
    # the estimation matches the smaller map onto the larger: its pair may run from map 1 to map 0
    found = None if pair.best is None else pair.best.transform if pair.i == 0 else tf.inverse(pair.best.transform)
    starts = [true_px] + ([found] if found is not None else [])
    fitted = max((best_fit(pi, pj, m) for m in starts), key=lambda m: score(pi, pj, m))
    bf = verify(pi, pj, fitted, settings)
    relaxed = settings.replace(min_support=max(int(0.8 * at.support), 10), min_overlap_m2=0.8 * at.overlap_m2,
                               min_agreement=min(settings.min_agreement, at.agreement - 0.02))
    rival = find_rival(pi, pj, at, relaxed, keep=60)
    lines = [f'{folder.name}:',
             f'  truth:    {at.support} agreeing wall cells, agreement {at.agreement:.2f}, '
             f'{at.deep_conflicts} deep contradictions, expected corner error {precision:.2f} m',
             f'  best fit: {off(fitted)}, {bf.support} agreeing, agreement {bf.agreement:.2f}, '
             f'{bf.deep_conflicts} deep contradictions',
             '  rival:    ' + (f'{off(rival.transform)}, {rival.support} agreeing, agreement {rival.agreement:.2f}, '
                              f'{rival.deep_conflicts} deep contradictions' if rival else 'none found'),
             '  pipeline: ' + ('accepted, ' + off(found) if pair.accepted else pair.reason)]
    return '\n'.join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--data', default=str(REPO.parent / 'shared' / 'data' / 'dev'))
    ap.add_argument('--only', default='pair_small', help='scenario names containing this')
    args = ap.parse_args()
    folders = sorted(p.parent for p in Path(args.data).glob('*/truth.json') if args.only in p.parent.name)
    folders = [f for f in folders if len(json.loads((f / 'truth.json').read_text())['maps']) == 2]
    if not folders:
        print(f'evidence_report: no two-map scenario matching {args.only!r} in {args.data}', file=sys.stderr)
        return 2
    for folder in folders:
        print(report(folder, EstimationSettings()), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
