#!/usr/bin/env python3
"""Make the project's sample maps: a generated building and robot maps cut from it with the laser mapper.

    python3 scripts/make_sample_maps.py [--out data/samples] [--preview DIR]
    python3 scripts/make_sample_maps.py --scenario large36 --out DIR [--preview DIR]

Writes <out>/world.yaml/.pgm and, per scenario, <out>/<scenario>/map_NN.yaml/.pgm (each map in its robot's own
frame: start pose at the origin) and truth.json in the format of the shared scorer (mmeval-truth-1). Deterministic:
the same files on every run. --scenario NAME writes only the generated scenario NAME (see GENERATED: 36 robots in a
building of their own, a quarter with broken maps; large36*: fleet_sim.world's floor plans, random robots; <kind>36:
a building of fleet_sim.buildings, robots in chains, stars or clusters) to <out>/NAME; not part of the default run.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import zlib
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import networkx as nx
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

from fleet_sim.buildings import make_building  # noqa: E402
from fleet_sim.laser import beam_angles, cast  # noqa: E402
from fleet_sim.mapping import LogOddsMap, compose, relative_pose  # noqa: E402
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

_GRAPHS: Dict[bytes, nx.Graph] = {}   # lattice graphs of the last free masks: building one takes seconds


def lattice_graph(free: np.ndarray, k: int) -> nx.Graph:
    """plan()'s 8-connected lattice of k x k cell blocks that are all free, built once per free mask (the same
    graph, built in the same order, as before it was kept: the same paths)."""
    h, w = free.shape[0] // k, free.shape[1] // k
    coarse = free[:h * k, :w * k].reshape(h, k, w, k).all(axis=(1, 3))
    key = np.packbits(coarse).tobytes() + np.array(coarse.shape).tobytes()
    if key not in _GRAPHS:
        g = nx.grid_2d_graph(w, h)              # nodes (col, row)
        g.add_edges_from((((c, r), (c + 1, r + 1)) for c in range(w - 1) for r in range(h - 1)), weight=math.sqrt(2))
        g.add_edges_from((((c + 1, r), (c, r + 1)) for c in range(w - 1) for r in range(h - 1)), weight=math.sqrt(2))
        g.remove_nodes_from([(c, r) for r, c in zip(*np.nonzero(~coarse))])
        _GRAPHS.clear()                         # one world at a time: a graph is hundreds of MB
        _GRAPHS[key] = g
    return _GRAPHS[key]


def plan(free: np.ndarray, start: Tuple[float, float], goal: Tuple[float, float], res: float) -> List[Tuple]:
    """Shortest 8-connected path on a 0.1 m lattice of cells with clearance, shortcut by line of sight."""
    k = max(1, int(round(0.1 / res)))
    g = lattice_graph(free, k)
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


def save_robot_map(grid: Grid, i: int, start: Tuple[float, float, float], path: List[Tuple], name: str, out_dir: str,
                   preview: str, broken_deg: Optional[float] = None, alt_poses: Sequence = ()) -> dict:
    """Write robot i's map as <out_dir>/<name>/map_NN.yaml/.pgm (and its preview) and return its truth.json entry
    (`mergeable` is added once every map is known); broken_deg: the map is broken, turned by this after its break."""
    fname = f'map_{i:02d}.yaml'
    save_map(grid, os.path.join(out_dir, name, fname[:-5]))
    if preview:
        save_png(grid, os.path.join(preview, f'{name}_{fname[:-5]}.png'))
    length = sum(math.dist(a[:2], b[:2]) for a, b in zip(path[:-1], path[1:]))
    return {'file': fname, 'pose': [round(start[0], 6), round(start[1], 6), round(start[2], 6)],
            'resolution': RES, 'size': [grid.width, grid.height], 'canvas': False, 'broken': broken_deg is not None,
            'broken_deg': broken_deg if broken_deg is not None else 0.0,
            'alt_poses': [[round(float(v), 6) for v in a] for a in alt_poses], 'drift_max_m': 0.0,
            'path_length_m': round(length, 2), 'n_scans': len(path),
            'known_area_m2': round(float(grid.known_mask().sum()) * RES * RES, 2), 'known_bbox': known_bbox(grid)}


def make_scenario(name: str, spec: dict, world: Grid, out_dir: str, preview: str) -> dict:
    occ, free = free_with_clearance(world)
    rng = np.random.default_rng(zlib.crc32(name.encode()))   # stable per scenario, unlike hash()
    max_range = spec['max_range']
    os.makedirs(os.path.join(out_dir, name), exist_ok=True)
    maps, poses, entries = [], [], []
    for i, (sx, sy, syaw, goals) in enumerate(spec['robots']):
        start = (sx, sy, math.radians(syaw))
        path = drive(free, start, goals, RES)
        grid = crop_known(map_robot(occ, path, max_range, rng)[0].to_grid(frame_id=f'robot{i + 1}/map'))
        entries.append(save_robot_map(grid, i, start, path, name, out_dir, preview))
        maps.append(grid)
        poses.append(start)
    ov = overlap_stats(maps, poses, world)
    mergeable = ov['components'][0] if ov['components'] else []
    for i, e in enumerate(entries):
        e['mergeable'] = i in mergeable
    return write_truth(out_dir, name, spec['kind'], WORLD_SEED, 'samples', world, max_range, entries, mergeable,
                       ov['components'], ov)


def write_truth(out_dir: str, name: str, kind: str, world_seed: int, split: str, world: Grid, max_range: float,
                entries: List[dict], mergeable: List[int], components: list, ov: dict,
                world_label: str = '') -> dict:
    """Write <out_dir>/<name>/truth.json in the shared scorer's format (mmeval-truth-1) and return it. Written last:
    its presence means the scenario is complete (bench_merge caches on it)."""
    truth = {'format': 'mmeval-truth-1', 'scenario': name, 'kind': kind,
             'world': world_label or f'floor_plan_{world_seed}',
             'split': split, 'seed': world_seed,
             'world_frame': 'ground-truth grid of the world: origin at its lower-left corner, x right, y up (m)',
             'world_size_m': [round(world.width * RES, 6), round(world.height * RES, 6)],
             'laser': dict(LASER, max_range=max_range), 'maps': entries, 'mergeable': mergeable,
             'components': components,
             'overlap': dict(OVERLAP, definition=OVERLAP_DEFINITION, shared_m2=ov['shared_m2'],
                             fraction=ov['fraction'])}
    with open(os.path.join(out_dir, name, 'truth.json'), 'w') as f:
        json.dump(truth, f, indent=1)
        f.write('\n')
    return truth


# ----------------------------------------------------------------------------------------------- generated scenarios
# Scenarios whose robots are drawn at random (seeded) in a building of their own, not written by default (several
# MB): `--scenario NAME --out DIR` writes DIR/NAME only. large36: issue #13's benchmark, a fleet of 36 robots in
# another building with 9 broken maps, like the thesis' §4.6 scenario.
GENERATED: Dict[str, dict] = {
    'large36': {'kind': 'large', 'world_seed': 5, 'world_size_m': (48.0, 32.0), 'seed': 36, 'n_robots': 36,
                'n_broken': 9, 'max_range': 8.0,
                'goals': (2, 3),              # goals per robot (inclusive)
                'goal_step_m': (3.0, 9.0),    # driving distance of a goal from the previous one (8-connected
                                              # steps of plan()'s 0.1 m lattice, a diagonal counting as one)
                'break_at': (0.35, 0.65),     # break point as a fraction of the robot's scans
                'broken_deg': (10.0, 40.0),   # |rotation| of the part after the break
                'min_linked': 0.75},          # healthy maps with an overlapping neighbour, else retune the spec
}
# the same fleet spec in three more buildings, with other robots: large36 alone flatters (it is the fastest of the
# four to estimate)
for _name, _world_seed, _seed in (('large36_b', 6, 37), ('large36_c', 7, 38), ('large36_d', 8, 39)):
    GENERATED[_name] = dict(GENERATED['large36'], world_seed=_world_seed, seed=_seed)

# issue #33: the fleet in many kinds of buildings (fleet_sim.buildings), each with its own overlap pattern and path
# lengths (see patterned_robots), so that the estimation is measured on buildings it was not tuned on.
# kind -> (pattern and its parameter, goals per robot, goal_step_m)
BUILDING_FLEETS: Dict[str, Tuple[dict, Tuple[int, int], Tuple[float, float]]] = {
    'hospital': ({'pattern': 'chain', 'chains': 3}, (2, 3), (4.0, 10.0)),
    'warehouse': ({'pattern': 'star', 'hubs': 3}, (1, 2), (8.0, 16.0)),
    'office': ({'pattern': 'clusters', 'clusters': 4}, (2, 3), (2.0, 6.0)),
    'cave': ({'pattern': 'random'}, (2, 3), (3.0, 9.0)),
    'pillar_hall': ({'pattern': 'clusters', 'clusters': 3}, (2, 3), (3.0, 8.0)),
    'courtyard': ({'pattern': 'chain', 'chains': 2}, (2, 3), (4.0, 9.0)),
    'campus': ({'pattern': 'clusters', 'clusters': 4}, (2, 3), (3.0, 7.0)),
    'classic': ({'pattern': 'star', 'hubs': 4}, (1, 3), (5.0, 12.0)),
    'mall': ({'pattern': 'random'}, (1, 2), (2.0, 5.0)),
    'tunnels': ({'pattern': 'chain', 'chains': 4}, (2, 3), (3.0, 8.0)),
    'school': ({'pattern': 'star', 'hubs': 2}, (1, 2), (6.0, 14.0)),
    'radial': ({'pattern': 'star', 'hubs': 1}, (1, 2), (6.0, 14.0)),
    'maze': ({'pattern': 'random'}, (3, 4), (3.0, 7.0)),
}
# <kind>36_u: the same fleets in other buildings of each kind (other world and robot seeds), held out: measured
# (bench_merge.py --generated unseen), never tuned on; <kind>36_v: a second such set (--generated unseen2), to check
# that a change found on a building of the first holds on buildings no rule was looked for on; <kind>36_w: a third
# (--generated unseen3), made once the rules had been checked on both others
for _i, (_kind, (_pattern, _goals, _step)) in enumerate(BUILDING_FLEETS.items()):
    GENERATED[f'{_kind}36'] = dict(GENERATED['large36'], kind=_kind, building=_kind, world_seed=100 + _i,
                                   seed=200 + _i, goals=_goals, goal_step_m=_step, **_pattern)
    GENERATED[f'{_kind}36_u'] = dict(GENERATED[f'{_kind}36'], world_seed=300 + _i, seed=400 + _i)
    GENERATED[f'{_kind}36_v'] = dict(GENERATED[f'{_kind}36'], world_seed=500 + _i, seed=600 + _i)
    GENERATED[f'{_kind}36_w'] = dict(GENERATED[f'{_kind}36'], world_seed=700 + _i, seed=800 + _i)


def free_with_clearance(world: Grid) -> Tuple[np.ndarray, np.ndarray]:
    """(obstacles, free space eroded by CLEARANCE_M) as make_scenario uses them."""
    occ = obstacle_mask(world)
    radius = int(round(CLEARANCE_M / RES))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2)
    return occ, cv2.erode((~occ).astype(np.uint8), k, borderValue=0).astype(bool)


def reachable_lattice(free: np.ndarray, res: float) -> Tuple[np.ndarray, float]:
    """(mask, step in metres) of the largest 8-connected part of plan()'s 0.1 m lattice (cell (r, c) centred at
    ((c + 0.5) step, (r + 0.5) step)): starts and goals drawn from it are always joined by a path, so plan() never
    fails on a random draw."""
    k = max(1, int(round(0.1 / res)))
    h, w = free.shape[0] // k, free.shape[1] // k
    coarse = free[:h * k, :w * k].reshape(h, k, w, k).all(axis=(1, 3)).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(coarse, connectivity=8)
    if n < 2:
        raise RuntimeError('no free space with clearance in the world')
    return labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])), res * k


def lattice_steps(mask: np.ndarray, cell: Tuple[int, int], max_steps: int) -> np.ndarray:
    """Steps (8-connected, as plan()'s lattice; -1: more than max_steps) from cell (row, col) through mask: a
    geodesic distance, so a goal drawn by it is a few metres of driving away, not just across a wall."""
    steps = np.full(mask.shape, -1, np.int32)
    steps[cell] = 0
    front = np.zeros(mask.shape, np.uint8)
    front[cell] = 1
    allowed = mask.astype(np.uint8)
    square = np.ones((3, 3), np.uint8)
    for n in range(1, max_steps + 1):
        grown = cv2.dilate(front, square) & allowed
        new = (grown > 0) & (steps < 0)
        if not new.any():
            break
        steps[new] = n
        front = grown
    return steps


def random_robots(spec: dict, mask: np.ndarray, step: float, rng: np.random.Generator) -> List[Tuple]:
    """Robots as in SCENARIOS (x, y, yaw in degrees, goals): random start and yaw, each goal a few metres of
    driving from the previous one (as a fleet's exploration goals are, near the frontier the robot is at), so maps
    overlap in chains and groups as a real fleet's do."""
    cells = np.argwhere(mask)                          # (row, col), row-major: a stable order to draw from
    lo, hi = (int(round(v / step)) for v in spec['goal_step_m'])
    centre = lambda rc: (round(float((rc[1] + 0.5) * step), 6), round(float((rc[0] + 0.5) * step), 6))  # noqa: E731
    robots = []
    for _ in range(spec['n_robots']):
        here = tuple(cells[rng.integers(len(cells))])
        start = centre(here)
        yaw = round(float(rng.uniform(-180.0, 180.0)), 1)
        goals = []
        for _ in range(int(rng.integers(spec['goals'][0], spec['goals'][1] + 1))):
            d = lattice_steps(mask, here, hi)
            near = np.argwhere(d >= lo)
            if not len(near):                          # a dead end smaller than lo: anywhere it can reach
                near = np.argwhere(d > 0)
            here = tuple(near[rng.integers(len(near))])
            goals.append(centre(here))
        robots.append((*start, yaw, goals))
    return robots


def draw_goals(here: Tuple[int, int], n: int, mask: np.ndarray, lo: int, hi: int, rng: np.random.Generator,
               away_from: Optional[Tuple[int, int]] = None) -> List[Tuple[int, int]]:
    """n goal cells, each lo..hi lattice steps of driving from the one before; with away_from, each the farthest
    from that cell of a few drawn (a robot pushing on, as a chain's does)."""
    goals = []
    for _ in range(n):
        d = lattice_steps(mask, here, hi)
        near = np.argwhere(d >= lo)
        if not len(near):                              # a dead end smaller than lo: anywhere it can reach
            near = np.argwhere(d > 0)
        if not len(near):
            break
        picks = near[rng.integers(len(near), size=4 if away_from is not None else 1)]
        if away_from is not None:
            picks = picks[np.argsort(-np.hypot(*(picks - np.array(away_from)).T), kind='stable')]
        here = tuple(picks[0])
        goals.append(here)
    return goals


def near_cell(mask: np.ndarray, cell: Tuple[int, int], steps: int, rng: np.random.Generator) -> Tuple[int, int]:
    """A random cell within `steps` of driving from cell."""
    d = lattice_steps(mask, cell, steps)
    near = np.argwhere(d >= 0)
    return tuple(near[rng.integers(len(near))])


def spread_cells(mask: np.ndarray, n: int, rng: np.random.Generator) -> List[Tuple[int, int]]:
    """n cells far apart (farthest-point sampling from a random first one)."""
    cells = np.argwhere(mask)
    out = [tuple(cells[rng.integers(len(cells))])]
    dist = np.full(len(cells), np.inf)
    while len(out) < n:
        dist = np.minimum(dist, np.hypot(*(cells - np.array(out[-1])).T))
        out.append(tuple(cells[int(np.argmax(dist))]))
    return out


def patterned_robots(spec: dict, mask: np.ndarray, step: float, rng: np.random.Generator) -> List[Tuple]:
    """Robots as random_robots draws them, but in an overlap pattern (spec['pattern']):
    chain: spec['chains'] chains, each robot starting where the one before it ended and pushing on;
    star: robots starting around spec['hubs'] hubs and driving far out from them;
    clusters: spec['clusters'] groups of robots exploring around far-apart centres, the last robot of each group
    driving to the next group's centre (the groups meet late, through few maps)."""
    pattern, n = spec['pattern'], spec['n_robots']
    if pattern == 'random':
        return random_robots(spec, mask, step, rng)
    lo, hi = (int(round(v / step)) for v in spec['goal_step_m'])
    centre = lambda rc: (round(float((rc[1] + 0.5) * step), 6), round(float((rc[0] + 0.5) * step), 6))  # noqa: E731
    n_goals = lambda: int(rng.integers(spec['goals'][0], spec['goals'][1] + 1))   # noqa: E731
    starts_goals: List[Tuple[Tuple[int, int], List[Tuple[int, int]]]] = []
    if pattern == 'chain':
        per = -(-n // spec['chains'])
        for first in spread_cells(mask, spec['chains'], rng):
            here = first
            for _ in range(min(per, n - len(starts_goals))):
                goals = draw_goals(here, n_goals(), mask, lo, hi, rng, away_from=here)
                starts_goals.append((here, goals))
                here = goals[-1] if goals else here
    elif pattern == 'star':
        hubs = spread_cells(mask, spec['hubs'], rng)
        for i in range(n):
            start = near_cell(mask, hubs[i % len(hubs)], int(round(1.5 / step)), rng)
            starts_goals.append((start, draw_goals(start, n_goals(), mask, lo, hi, rng, away_from=start)))
    elif pattern == 'clusters':
        centres = spread_cells(mask, spec['clusters'], rng)
        for i in range(n):
            c = i % len(centres)
            start = near_cell(mask, centres[c], int(round(3.0 / step)), rng)
            goals = draw_goals(start, n_goals(), mask, lo, hi, rng)
            if i >= n - len(centres):                  # the last robot of each group: to the next group
                goals.append(centres[(c + 1) % len(centres)])
            starts_goals.append((start, goals))
    else:
        raise ValueError(f'unknown robot pattern {pattern!r}')
    return [(*centre(s), round(float(rng.uniform(-180.0, 180.0)), 1), [centre(g) for g in goals])
            for s, goals in starts_goals]


def rotation_about(pivot: Sequence[float], deg: float) -> Tuple[float, float, float]:
    """The rigid transform (as a pose) that rotates by deg about pivot: q -> R q + (p - R p)."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return (pivot[0] - c * pivot[0] + s * pivot[1], pivot[1] - s * pivot[0] - c * pivot[1], a)


def draw_breaks(spec: dict, rng: np.random.Generator) -> Dict[int, Tuple[float, float]]:
    """Broken robots -> (break point as a fraction of the scans, signed rotation in degrees)."""
    broken = sorted(int(i) for i in rng.choice(spec['n_robots'], spec['n_broken'], replace=False))
    out = {}
    for i in broken:
        frac = float(rng.uniform(*spec['break_at']))
        deg = float(rng.uniform(*spec['broken_deg'])) * (1.0 if rng.random() < 0.5 else -1.0)
        out[i] = (frac, round(deg, 3))
    return out


def map_robot(occ: np.ndarray, path: List[Tuple[float, float, float]], max_range: float, rng: np.random.Generator,
              brk: Optional[Tuple[float, float]] = None) -> Tuple[LogOddsMap, Tuple[float, float, float]]:
    """Laser-map a path in the robot's own frame; with brk = (fraction, degrees) a simulated SLAM failure: from the
    break scan on, every pose is rotated by the angle about the break point (the robot's map-frame position there),
    so the rest of the map is built rotated. Returns the mapper and the correction D (identity if not broken): the
    part after the break shows world content q (map frame) at D q."""
    start = path[0]
    angles = beam_angles(LASER['n_beams'])
    mapper = LogOddsMap(RES)
    b = int(brk[0] * len(path)) if brk else len(path)
    rel = [relative_pose(start, p) for p in path]
    d = rotation_about(rel[b][:2], brk[1]) if brk else (0.0, 0.0, 0.0)
    for k, p in enumerate(path):
        ranges = cast(occ, RES, p, LASER['n_beams'], max_range, rng, LASER['sigma'], LASER['dropout'])
        mapper.integrate(rel[k] if k < b else compose(d, rel[k]), ranges, angles, max_range)
    return mapper, d


def healthy_components(maps: List[Grid], poses: List[Sequence[float]], world: Grid, broken: Sequence[int]) -> list:
    """OVERLAP_DEFINITION's components: those of the healthy maps only, in the indices of all maps."""
    keep = [i for i in range(len(maps)) if i not in set(broken)]
    ov = overlap_stats([maps[i] for i in keep], [poses[i] for i in keep], world)
    return sorted(([keep[j] for j in c] for c in ov['components']), key=lambda c: (-len(c), c))


def generated_world(spec: dict) -> Grid:
    """The world of a generated scenario: a building of fleet_sim.buildings, or fleet_sim.world's floor plan."""
    if 'building' in spec:
        return make_building(spec['building'], spec['world_seed'])
    # the furniture rule of the buildings these scenarios were made in (a robot's bare radius): their robots follow
    # scripted paths, not the simulated move_base, and a newer rule would change the maps their figures come from
    return make_floor_plan(spec['world_seed'], *spec['world_size_m'], resolution=RES, clearance_m=0.2)


def world_name(spec: dict) -> str:
    return f"{spec['building']}_{spec['world_seed']}" if 'building' in spec else f"floor_plan_{spec['world_seed']}"


def make_generated(name: str, spec: dict, out_dir: str, preview: str) -> dict:
    """Write out_dir/name (maps and truth.json, the format of make_scenario plus broken maps); returns the truth."""
    world = generated_world(spec)
    occ, free = free_with_clearance(world)
    mask, step = reachable_lattice(free, RES)
    layout = np.random.default_rng(spec['seed'])                    # robots and breaks
    noise = np.random.default_rng(zlib.crc32(name.encode()))         # laser noise, as make_scenario
    robots = patterned_robots(dict(spec, pattern=spec.get('pattern', 'random')), mask, step, layout)
    breaks = draw_breaks(spec, layout)
    max_range = spec['max_range']
    os.makedirs(os.path.join(out_dir, name), exist_ok=True)
    if preview:
        save_png(world, os.path.join(preview, f'{name}_world.png'))
    maps, poses, entries = [], [], []
    for i, (sx, sy, syaw, goals) in enumerate(robots):
        start = (sx, sy, math.radians(syaw))
        path = drive(free, start, goals, RES)
        mapper, d = map_robot(occ, path, max_range, noise, breaks.get(i))
        grid = crop_known(mapper.to_grid(frame_id=f'robot{i + 1}/map'))
        # the map frame's pose that fits the part after the break: world = start ∘ D^-1 ∘ (corrupted map)
        alt = [compose(start, relative_pose(d, (0.0, 0.0, 0.0)))] if i in breaks else []
        entries.append(save_robot_map(grid, i, start, path, name, out_dir, preview,
                                      breaks[i][1] if i in breaks else None, alt))
        maps.append(grid)
        poses.append(start)
    # shared area of a broken map is counted at its main pose; broken maps are left out of the components
    ov = overlap_stats(maps, poses, world)
    comps = healthy_components(maps, poses, world, sorted(breaks))
    mergeable = comps[0] if comps else []
    for i, e in enumerate(entries):
        e['mergeable'] = i in mergeable
    return write_truth(out_dir, name, spec['kind'], spec['world_seed'], 'generated', world, max_range, entries,
                       mergeable, comps, ov, world_name(spec))


def linked_healthy(truth: dict) -> List[int]:
    """Healthy maps that overlap at least one other healthy map enough to be merged with it."""
    ov = truth['overlap']
    healthy = [i for i, m in enumerate(truth['maps']) if not m['broken']]
    return [i for i in healthy if any(ov['shared_m2'][i][j] >= ov['min_shared_m2'] and
                                      ov['fraction'][i][j] >= ov['min_fraction'] for j in healthy if j != i)]


def summarize_generated(name: str, spec: dict, truth: dict, seconds: float) -> int:
    """Print the scenario's figures; 1 if too few healthy maps overlap another (the spec needs retuning)."""
    ms = truth['maps']
    areas = sorted(m['known_area_m2'] for m in ms)
    paths = sorted(m['path_length_m'] for m in ms)
    cells = sorted(m['size'][0] * m['size'][1] for m in ms)
    broken = [(i, m['broken_deg']) for i, m in enumerate(ms) if m['broken']]
    linked = linked_healthy(truth)
    healthy = len(ms) - len(broken)
    print(f"{name}: {len(ms)} maps in {truth['world']} ({truth['world_size_m'][0]:g} x {truth['world_size_m'][1]:g} m) "
          f"generated in {seconds:.1f} s; map cells {cells[0]}..{cells[-1]} (median {cells[len(cells) // 2]}), "
          f"known area {areas[0]:.0f}..{areas[-1]:.0f} m2, paths {paths[0]:.0f}..{paths[-1]:.0f} m")
    print(f"{name}: broken {broken}; mergeable {len(truth['mergeable'])} of {healthy} healthy maps "
          f"(components {[len(c) for c in truth['components']]}); {len(linked)} healthy maps overlap another")
    if len(linked) < spec['min_linked'] * healthy:
        print(f"{name}: only {len(linked)} of {healthy} healthy maps overlap another", file=sys.stderr)
        return 1
    return 0


def main_generated(name: str, out: str, preview: str) -> int:
    t0 = time.perf_counter()
    truth = make_generated(name, GENERATED[name], out, preview)
    return summarize_generated(name, GENERATED[name], truth, time.perf_counter() - t0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', default=os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'data', 'samples'))
    ap.add_argument('--preview', default='', help='also write PNG previews of every map into this folder')
    ap.add_argument('--scenario', choices=list(GENERATED),
                    help='write only this generated scenario (not made by default: several MB) to <out>/NAME')
    args = ap.parse_args(argv)
    if args.scenario and os.path.realpath(args.out) == os.path.realpath(ap.get_default('out')):
        ap.error('--scenario needs --out DIR: a generated scenario is several MB, not one for data/samples')
    os.makedirs(args.out, exist_ok=True)
    if args.preview:
        os.makedirs(args.preview, exist_ok=True)
    if args.scenario:
        return main_generated(args.scenario, args.out, args.preview)
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
