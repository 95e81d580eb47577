#!/usr/bin/env python3
"""Make the project's sample maps: a generated building and robot maps cut from it with the laser mapper.

    python3 scripts/make_sample_maps.py [--out data/samples] [--preview DIR]

Writes <out>/world.yaml/.pgm and, per scenario, <out>/<scenario>/map_NN.yaml/.pgm (each map in its robot's own
frame: start pose at the origin) and truth.json in the format of the shared scorer (mmeval-truth-1). Deterministic:
the same files on every run.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import zlib
from typing import Dict, List, Sequence, Tuple

import cv2
import networkx as nx
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

from fleet_sim.laser import beam_angles, cast  # noqa: E402
from fleet_sim.mapping import LogOddsMap, relative_pose  # noqa: E402
from fleet_sim.world import make_floor_plan, obstacle_mask  # noqa: E402
from multirobot_map_merge.grid import Grid, crop_to_known  # noqa: E402
from multirobot_map_merge.mapio import save_map, save_png  # noqa: E402

WORLD_SEED = 3
WORLD_SIZE_M = (24.0, 16.0)
RES = 0.05
LASER = {'n_beams': 360, 'max_range': 6.0, 'sigma': 0.01, 'dropout': 0.01}
CLEARANCE_M = 0.35          # planned paths keep this far from walls
OVERLAP = {'cell_m': 0.1, 'min_shared_m2': 4.0, 'min_fraction': 0.05}
OVERLAP_DEFINITION = ('shared = area of world cells known (free or occupied) in both maps; fraction = shared / '
                      'known area of the smaller map; components = connected components (>= 2 maps, broken maps '
                      'excluded) of pairs meeting both thresholds, largest first; mergeable = the largest (an '
                      'equally large component is accepted instead when scoring)')

# per scenario: robots as (start x, start y, start yaw in degrees, goals [(x, y), ...]) in world metres
SCENARIOS: Dict[str, dict] = {
    'three_robots': {'kind': 'group', 'max_range': 6.0, 'fraction': (0.3, 0.6), 'robots': [
        (3.0, 7.0, 0.0, [(13.0, 7.0), (6.5, 10.0)]),
        (12.0, 7.1, 100.0, [(11.0, 10.5), (12.5, 13.8), (14.7, 10.0), (14.7, 13.5)]),
        (21.0, 6.9, -140.0, [(21.5, 3.0), (14.0, 7.0), (14.7, 3.5), (17.5, 3.0)]),
    ]},
    # a chain: the first and last robot maps share nothing, so the last is placed through the middle one
    'chain3': {'kind': 'group', 'max_range': 4.0, 'fraction': (0.0, 0.7), 'robots': [
        (3.0, 7.0, 0.0, [(7.5, 7.0)]),
        (12.0, 7.1, 100.0, [(5.0, 7.0), (19.0, 7.0)]),
        (21.0, 6.9, -140.0, [(16.5, 7.0)]),
    ]},
    'no_overlap': {'kind': 'pair_none', 'max_range': 4.0, 'fraction': (0.0, 0.0), 'robots': [
        (3.0, 5.0, 30.0, [(1.5, 2.0)]),
        (21.5, 14.0, -120.0, [(22.0, 10.0)]),
    ]},
}


# ----------------------------------------------------------------------------------------------- motion

def plan(free: np.ndarray, start: Tuple[float, float], goal: Tuple[float, float], res: float) -> List[Tuple]:
    """Shortest 8-connected path on a 0.1 m lattice of cells with clearance, shortcut by line of sight."""
    k = max(1, int(round(0.1 / res)))
    h, w = free.shape[0] // k, free.shape[1] // k
    coarse = free[:h * k, :w * k].reshape(h, k, w, k).all(axis=(1, 3))
    g = nx.grid_2d_graph(w, h)              # nodes (col, row)
    g.add_edges_from((((c, r), (c + 1, r + 1)) for c in range(w - 1) for r in range(h - 1)), weight=math.sqrt(2))
    g.add_edges_from((((c + 1, r), (c, r + 1)) for c in range(w - 1) for r in range(h - 1)), weight=math.sqrt(2))
    g.remove_nodes_from([(c, r) for r, c in zip(*np.nonzero(~coarse))])
    node = lambda p: (int(p[0] / (res * k)), int(p[1] / (res * k)))   # noqa: E731
    s, t = node(start), node(goal)
    if s not in g or t not in g:
        raise ValueError(f"start {start} or goal {goal} is not in free space with clearance")
    cells = nx.astar_path(g, s, t, heuristic=lambda a, b: math.dist(a, b), weight='weight')
    pts = [start] + [((c + 0.5) * res * k, (r + 0.5) * res * k) for c, r in cells[1:-1]] + [goal]

    def clear(a, b):
        n = int(math.dist(a, b) / (0.5 * res)) + 2
        xs = np.linspace(a[0], b[0], n) / res
        ys = np.linspace(a[1], b[1], n) / res
        return bool(free[ys.astype(int), xs.astype(int)].all())
    out, i = [pts[0]], 0
    while i < len(pts) - 1:
        j = len(pts) - 1
        while j > i + 1 and not clear(pts[i], pts[j]):
            j -= 1
        out.append(pts[j])
        i = j
    return out


def drive(free: np.ndarray, start: Tuple[float, float, float], goals: Sequence, res: float,
          step_m: float = 0.25, turn_deg: float = 20.0) -> List[Tuple[float, float, float]]:
    """Scan poses along planned paths through the goals: every step_m, and every turn_deg when turning on the spot."""
    poses = [start]
    here = start
    for goal in goals:
        for wp in plan(free, here[:2], goal, res)[1:]:
            heading = math.atan2(wp[1] - here[1], wp[0] - here[0])
            turn = math.remainder(heading - here[2], 2 * math.pi)
            for f in np.linspace(0, 1, int(abs(math.degrees(turn)) // turn_deg) + 2)[1:].tolist():
                poses.append((here[0], here[1], here[2] + f * turn))
            n = max(1, int(math.ceil(math.dist(here[:2], wp) / step_m)))
            for f in np.linspace(0, 1, n + 1)[1:].tolist():
                poses.append((here[0] + f * (wp[0] - here[0]), here[1] + f * (wp[1] - here[1]), heading))
            here = poses[-1]
    return poses


# ----------------------------------------------------------------------------------------------- maps

def crop_known(grid: Grid, margin: int = 10) -> Grid:
    r0, r1, c0, c1 = crop_to_known(grid.data, margin)
    ox, oy, _ = grid.origin
    return Grid(grid.data[r0:r1, c0:c1], grid.resolution, (ox + c0 * grid.resolution, oy + r0 * grid.resolution, 0.0),
                grid.frame_id)


def known_bbox(grid: Grid) -> List[List[float]]:
    r0, r1, c0, c1 = crop_to_known(grid.data, margin=0)
    corners = np.array([[c0, r0, 1], [c1, r0, 1], [c1, r1, 1], [c0, r1, 1]], float)
    pts = (grid.cell_to_map() @ corners.T).T[:, :2]
    return [[round(float(x), 6), round(float(y), 6)] for x, y in pts]


def known_in_world(grid: Grid, pose: Sequence[float], world_shape: Tuple[int, int], cell: float) -> np.ndarray:
    """Known mask of a map resampled (nearest) onto world cells of size ``cell``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    world_from_map = np.array([[c, -s, pose[0]], [s, c, pose[1]], [0, 0, 1.0]])
    world_from_wcell = np.array([[cell, 0, 0.5 * cell], [0, cell, 0.5 * cell], [0, 0, 1.0]])   # cell centres
    mcell_from_map = np.linalg.inv(grid.cell_to_map())
    m = mcell_from_map @ np.linalg.inv(world_from_map) @ world_from_wcell
    m[:2, 2] -= 0.5             # corner convention -> cv2 pixel-centre convention
    return cv2.warpAffine(grid.known_mask().astype(np.uint8), m[:2], (world_shape[1], world_shape[0]),
                          flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0).astype(bool)


def overlap_stats(maps: List[Grid], poses: List[Sequence[float]], world: Grid) -> dict:
    cell = OVERLAP['cell_m']
    shape = (int(math.ceil(world.height * world.resolution / cell)),
             int(math.ceil(world.width * world.resolution / cell)))
    masks = [known_in_world(g, p, shape, cell) for g, p in zip(maps, poses)]
    area = [float(m.sum()) * cell * cell for m in masks]
    n = len(maps)
    shared = [[0.0] * n for _ in range(n)]
    frac = [[0.0] * n for _ in range(n)]
    g = nx.Graph()
    g.add_nodes_from(range(n))
    for i in range(n):
        for j in range(i + 1, n):
            s = float((masks[i] & masks[j]).sum()) * cell * cell
            f = s / min(area[i], area[j]) if min(area[i], area[j]) > 0 else 0.0
            shared[i][j] = shared[j][i] = round(s, 2)
            frac[i][j] = frac[j][i] = round(f, 4)
            if s >= OVERLAP['min_shared_m2'] and f >= OVERLAP['min_fraction']:
                g.add_edge(i, j)
    comps = sorted((sorted(c) for c in nx.connected_components(g) if len(c) >= 2), key=lambda c: (-len(c), c))
    return {'shared_m2': shared, 'fraction': frac, 'components': comps}


def make_scenario(name: str, spec: dict, world: Grid, out_dir: str, preview: str) -> dict:
    occ = obstacle_mask(world)
    radius = int(round(CLEARANCE_M / RES))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2)
    free = cv2.erode((~occ).astype(np.uint8), k, borderValue=0).astype(bool)
    rng = np.random.default_rng(zlib.crc32(name.encode()))   # stable per scenario, unlike hash()
    angles = beam_angles(LASER['n_beams'])
    max_range = spec['max_range']
    os.makedirs(os.path.join(out_dir, name), exist_ok=True)
    maps, poses, entries = [], [], []
    for i, (sx, sy, syaw, goals) in enumerate(spec['robots']):
        start = (sx, sy, math.radians(syaw))
        path = drive(free, start, goals, RES)
        mapper = LogOddsMap(RES)
        for p in path:
            ranges = cast(occ, RES, p, LASER['n_beams'], max_range, rng, LASER['sigma'], LASER['dropout'])
            mapper.integrate(relative_pose(start, p), ranges, angles, max_range)
        grid = crop_known(mapper.to_grid(frame_id=f'robot{i + 1}/map'))
        fname = f'map_{i:02d}.yaml'
        save_map(grid, os.path.join(out_dir, name, fname[:-5]))
        if preview:
            save_png(grid, os.path.join(preview, f'{name}_{fname[:-5]}.png'))
        length = sum(math.dist(a[:2], b[:2]) for a, b in zip(path[:-1], path[1:]))
        maps.append(grid)
        poses.append(start)
        entries.append({'file': fname, 'pose': [round(sx, 6), round(sy, 6), round(math.radians(syaw), 6)],
                        'resolution': RES, 'size': [grid.width, grid.height], 'canvas': False, 'broken': False,
                        'broken_deg': 0.0, 'alt_poses': [], 'drift_max_m': 0.0, 'path_length_m': round(length, 2),
                        'n_scans': len(path), 'known_area_m2': round(float(grid.known_mask().sum()) * RES * RES, 2),
                        'known_bbox': known_bbox(grid)})
    ov = overlap_stats(maps, poses, world)
    mergeable = ov['components'][0] if ov['components'] else []
    for i, e in enumerate(entries):
        e['mergeable'] = i in mergeable
    truth = {'format': 'mmeval-truth-1', 'scenario': name, 'kind': spec['kind'], 'world': f'floor_plan_{WORLD_SEED}',
             'split': 'samples', 'seed': WORLD_SEED,
             'world_frame': 'ground-truth grid of the world: origin at its lower-left corner, x right, y up (m)',
             'world_size_m': [round(world.width * RES, 6), round(world.height * RES, 6)],
             'laser': dict(LASER, max_range=max_range), 'maps': entries, 'mergeable': mergeable,
             'components': ov['components'],
             'overlap': dict(OVERLAP, definition=OVERLAP_DEFINITION, shared_m2=ov['shared_m2'],
                             fraction=ov['fraction'])}
    with open(os.path.join(out_dir, name, 'truth.json'), 'w') as f:
        json.dump(truth, f, indent=1)
        f.write('\n')
    return truth


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', default=os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'data', 'samples'))
    ap.add_argument('--preview', default='', help='also write PNG previews of every map into this folder')
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    if args.preview:
        os.makedirs(args.preview, exist_ok=True)
    world = make_floor_plan(WORLD_SEED, *WORLD_SIZE_M, resolution=RES)
    save_map(world, os.path.join(args.out, 'world'))
    if args.preview:
        save_png(world, os.path.join(args.preview, 'world.png'))
    status = 0
    for name, spec in SCENARIOS.items():
        t = make_scenario(name, spec, world, args.out, args.preview)
        sizes = ', '.join(f"{m['size'][0]}x{m['size'][1]}" for m in t['maps'])
        fr = t['overlap']['fraction']
        print(f"{name}: maps {sizes}; mergeable {t['mergeable']}; fraction {fr}")
        lo, hi = spec['fraction']
        off = [f for i, row in enumerate(fr) for j, f in enumerate(row) if i < j and not lo <= f <= hi]
        if off:    # the world or the mapper changed: the routes need retuning
            print(f"{name}: pairwise overlap {off} outside [{lo}, {hi}]", file=sys.stderr)
            status = 1
    return status


if __name__ == '__main__':
    sys.exit(main())
