#!/usr/bin/env python3
"""How far the truth of each overlapping pair of maps lies from the nearest turn where the two maps' wall families
meet (orientation.wall_families, near_turns): the premise of the correlation search's angles (not a test: it prints
figures).

    scripts/env.sh python bench/wall_family_turns.py FOLDER [FOLDER ...]

FOLDER: maps with a truth.json (../shared/data/dev/*, ../shared/data/real_dev/*_clean, out/bench/<kind>36). Every
ordered pair of maps whose known areas share 4 m2 or more at their true places (a broken map at each of its poses)
and that both have wall families: the angle from the truth's turn to the nearest turn of the families, modulo 90
degrees. Prints the maps, those with families, the pairs, those with families on both sides, and the largest angles,
healthy maps apart from broken ones.
"""
from __future__ import annotations

import glob
import json
import math
import os
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from multirobot_map_merge import transforms as tf  # noqa: E402
from multirobot_map_merge.estimation.features import prepare  # noqa: E402
from multirobot_map_merge.estimation.orientation import families  # noqa: E402
from multirobot_map_merge.mapio import load_map  # noqa: E402

MIN_SHARED_M2 = 4.0


def study(folder: str, out: list, counts: dict) -> None:
    truth = json.loads(Path(folder, 'truth.json').read_text())
    info = {m['file']: m for m in truth['maps']}
    maps = {}
    for path in sorted(glob.glob(os.path.join(folder, 'map_*.yaml'))):
        m = info.get(os.path.basename(path))
        grid = load_map(path)
        p = prepare(grid, max(grid.resolution, 0.05), None, lazy=True) if m is not None else None
        if p is None:
            continue
        poses = [m['pose']] + (list(m.get('alt_poses') or []) if m.get('broken') else [])
        maps[path] = (p, [tf.rigid(*q) for q in poses], families(p), bool(m.get('broken')))
        counts['maps'] += 1
        counts['maps with families'] += families(p) is not None
    for a, (pi, poses_i, fi, broken_i) in maps.items():
        for b, (pj, poses_j, fj, broken_j) in maps.items():
            if a == b:
                continue
            for pose_i in poses_i:
                t = np.linalg.inv(pj.px_to_map) @ np.linalg.inv(poses_j[0]) @ pose_i @ pi.px_to_map
                h, w = pj.work.shape
                known = cv2.warpAffine((pi.work >= 0).astype(np.uint8), t[:2], (w, h), flags=cv2.INTER_NEAREST)
                if ((known > 0) & (pj.work >= 0)).sum() * pj.resolution ** 2 < MIN_SHARED_M2:
                    continue
                counts['pairs'] += 1
                if fi is None or fj is None:
                    continue
                counts['pairs with families'] += 1
                turn = math.atan2(t[1, 0], t[0, 0])
                off = min(abs(((cj - ci - turn) + math.pi / 4) % (math.pi / 2) - math.pi / 4)
                          for ci, _ in fi for cj, _ in fj)
                out.append((math.degrees(off), broken_i or broken_j, os.path.basename(folder), a[-11:-5], b[-11:-5]))


def main() -> None:
    if len(sys.argv) < 2:
        sys.exit('usage: wall_family_turns.py FOLDER [FOLDER ...]')
    out: list = []
    counts = dict.fromkeys(('maps', 'maps with families', 'pairs', 'pairs with families'), 0)
    for folder in (f for f in sys.argv[1:] if Path(f).is_dir()):
        if not Path(folder, 'truth.json').is_file():
            sys.exit(f'wall_family_turns.py: no truth.json in {folder}')
        study(folder, out, counts)
    print(', '.join(f'{k} {v}' for k, v in counts.items()))
    for label, rows in (('healthy', [r for r in out if not r[1]]), ('with a broken map', [r for r in out if r[1]])):
        if rows:
            worst = max(rows)
            print(f'{label}: {len(rows)} pairs, the truth at most {worst[0]:.2f} degrees from a turn '
                  f'({worst[2]} {worst[3]} onto {worst[4]}); over 1.5 degrees: {sum(r[0] > 1.5 for r in rows)}')


if __name__ == '__main__':
    main()
