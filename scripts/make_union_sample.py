#!/usr/bin/env python3
"""Make data/samples/union_join: four robot maps cut from a real building, where the fourth overlaps every single
one of the others by less than a pair needs, but their union well.

    python3 scripts/make_union_sample.py [--dev ../shared/data/dev] [--out data/samples/union_join]

The building is the dev scenario large30_hospital_section composed at its ground truth (broken maps left out).
Robots a (west half), b (east half) and c (a strip across the seam, so that a, b and c merge) are cut from it, and
the newcomer n is a small box on the seam between a and b: under 4 m2 of it is known to each of them alone, about
6 m2 to their union. Each map is expressed in its own frame (a pose turned by a multiple of 90 degrees, so that no
cell is resampled); truth.json gives those poses (format of the shared scorer, as the other samples). Deterministic.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

from multirobot_map_merge import transforms as tf  # noqa: E402
from multirobot_map_merge.compose import compose  # noqa: E402
from multirobot_map_merge.grid import Grid  # noqa: E402
from multirobot_map_merge.mapio import load_map, save_map  # noqa: E402

SEAM = 24.0   # x (m) between robot a and robot b
# name: (world box x0, y0, x1, y1 in m; pose of the map frame in the world: x, y, quarter turns)
ROBOTS = {
    'a': ((1.0, 10.0, SEAM, 28.0), (8.0, 22.0, 0)),
    'b': ((SEAM, 10.0, 43.0, 28.0), (30.0, 22.5, 1)),
    'c': ((SEAM - 5.0, 10.0, SEAM + 5.0, 20.0), (SEAM, 15.0, 2)),
    'n': ((SEAM - 1.3, 20.5, SEAM + 1.3, 23.5), (SEAM - 0.3, 21.5, 3)),
}


def building(dev: str) -> Grid:
    folder = os.path.join(dev, 'large30_hospital_section')
    with open(os.path.join(folder, 'truth.json')) as f:
        truth = json.load(f)
    good = [m for m in truth['maps'] if not m['broken']]
    merged = compose([load_map(os.path.join(folder, m['file'])) for m in good], [tf.rigid(*m['pose']) for m in good])
    return Grid(merged.data, merged.resolution, (0.0, 0.0, 0.0))   # the world frame starts at its corner


def cut(world: Grid, box, pose) -> Grid:
    """The world inside `box`, expressed in the frame whose pose in the world is `pose`."""
    res = world.resolution
    c0, r0, c1, r1 = (int(round(v / res)) for v in box)
    part = Grid(world.data[r0:r1, c0:c1], res, (c0 * res, r0 * res, 0.0))
    x, y, quarters = pose
    return compose([part], [tf.inverse(tf.rigid(x, y, quarters * math.pi / 2))], res)


def main(argv=None) -> int:
    repo = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--dev', default=os.path.join(repo, '..', 'shared', 'data', 'dev'))
    ap.add_argument('--out', default=os.path.join(repo, 'data', 'samples', 'union_join'))
    args = ap.parse_args(argv)
    if not os.path.isdir(os.path.join(args.dev, 'large30_hospital_section')):
        print(f'make_union_sample: {args.dev}/large30_hospital_section not found (use --dev)', file=sys.stderr)
        return 2
    world = building(args.dev)
    os.makedirs(args.out, exist_ok=True)
    maps = []
    for k, (name, (box, pose)) in enumerate(ROBOTS.items()):
        grid = cut(world, box, pose)
        save_map(grid, os.path.join(args.out, f'map_{k:02d}'))
        maps.append({'file': f'map_{k:02d}.yaml', 'robot': name, 'pose': [pose[0], pose[1], pose[2] * math.pi / 2],
                     'resolution': grid.resolution, 'broken': False, 'mergeable': True, 'world_box_m': list(box)})
    truth = {'format': 'mmeval-truth-1', 'scenario': 'union_join', 'kind': 'group',
             'world': 'large30_hospital_section at ground truth', 'split': 'samples',
             'world_frame': 'corner of the composed building, x right, y up (m)',
             'mergeable': list(range(len(maps))), 'components': [list(range(len(maps)))], 'maps': maps}
    with open(os.path.join(args.out, 'truth.json'), 'w') as f:
        json.dump(truth, f, indent=1)
    print(f'wrote {len(maps)} maps and truth.json to {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
