#!/usr/bin/env python3
"""Replay a live demo's merge offline and score it against the simulator's ground truth.

    scripts/env.sh python scripts/replay_demo.py [OUT_DIR] [setting=value ...]

OUT_DIR (default out/demo) is what `make demo` or the demo rostest (with MMM_KEEP_TEST_OUTPUT=1) wrote: the robots'
final maps in robots/*.yaml and their true start poses in summary.json. The maps are merged with the estimation
settings (EstimationSettings fields, e.g. polish=False), and each robot's placement error, and each pair's, is
printed against the truth (relative to the first robot, as the demo's summary).
"""
import json
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

from explore.coverage import known_corners, placement_errors  # noqa: E402
from multirobot_map_merge import transforms as tf  # noqa: E402
from multirobot_map_merge.estimation.estimator import estimate  # noqa: E402
from multirobot_map_merge.estimation.settings import EstimationSettings  # noqa: E402
from multirobot_map_merge.mapio import load_map  # noqa: E402


def settings_from(args):
    changes = {}
    for arg in args:
        key, _, value = arg.partition('=')
        default = getattr(EstimationSettings, key, None)
        if default is None or not value:
            raise SystemExit(f'replay_demo: not an estimation setting: {arg}')
        changes[key] = value == 'True' if isinstance(default, bool) else type(default)(value)
    return EstimationSettings(**changes)


def main(argv):
    out = argv[0] if argv and '=' not in argv[0] else 'out/demo'
    settings = settings_from([a for a in argv if '=' in a])
    try:
        with open(os.path.join(out, 'summary.json')) as f:
            starts = json.load(f)['start_poses']
        names = sorted(starts)
        grids = {n: load_map(os.path.join(out, 'robots', n + '.yaml')) for n in names}
    except (OSError, KeyError, ValueError) as e:
        raise SystemExit(f'replay_demo: cannot read a demo output in {out}: {e}')
    result = estimate([grids[n] for n in names], settings)
    placed = {n: tf.params(t)[:3] for n, t in zip(names, result.transforms) if t is not None}
    for row in placement_errors(placed, starts, grids):
        print(f"{row['robot']}: rotation {row['rotation_error_deg']:.2f} deg, corners "
              f"{100 * row['corner_error_m']:.1f} cm")
    for n in names:
        if n not in placed:
            print(f'{n}: not placed')
    for p in result.pairs:
        a, b = names[p.i], names[p.j]
        line = f'pair {a} -> {b}: ' + ('accepted' if p.accepted else f'refused ({p.reason})')
        if p.best is not None:
            true = tf.inverse(tf.rigid(*starts[b])) @ tf.rigid(*starts[a])
            rot, disp = tf.difference(p.transform_m, true, known_corners(grids[a]))
            line += (f', off by {math.degrees(rot):.2f} deg / {100 * disp:.1f} cm; agreement {p.best.agreement:.3f}, '
                     f'support {p.best.support}, overlap {p.best.overlap_m2:.1f} m2')
        print(line)


if __name__ == '__main__':
    main(sys.argv[1:])
