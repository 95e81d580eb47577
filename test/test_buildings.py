"""The generated buildings (fleet_sim.buildings) and the fleets scripts/make_sample_maps.py drives through them."""
import importlib.util
import math

import cv2
import numpy as np
import pytest

from fleet_sim.buildings import KINDS, make_building
from fleet_sim.world import free_components
from multirobot_map_merge.grid import FREE, OCCUPIED, UNKNOWN
from multirobot_map_merge.mapio import load_map


@pytest.fixture(scope='module')
def samples(repo_root):
    spec = importlib.util.spec_from_file_location('make_sample_maps', repo_root / 'scripts' / 'make_sample_maps.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize('kind', sorted(KINDS))
def test_building_is_seeded_closed_and_one_piece(kind):
    a, b, other = make_building(kind, 7), make_building(kind, 7), make_building(kind, 8)
    assert np.array_equal(a.data, b.data), 'the same seed must draw the same building'
    assert not np.array_equal(a.data, other.data) if a.data.shape == other.data.shape else True
    d = a.data
    free = (d == FREE).astype(np.uint8)
    assert free.sum() * a.resolution ** 2 > 250.0, 'a building for 36 robots needs room'
    # closed walls: no free cell touches the unknown outside, nor the grid's border
    touches = cv2.dilate((d == UNKNOWN).astype(np.uint8), np.ones((3, 3), np.uint8)) & free
    assert not touches.any()
    assert not (free[0].any() or free[-1].any() or free[:, 0].any() or free[:, -1].any())
    radius = int(round(a.extra['robot_radius_m'] / a.resolution))
    assert free_components(d) == 1 and free_components(d, radius) == 1
    assert set(np.unique(d)) <= {FREE, OCCUPIED, UNKNOWN}
    assert a.extra['kind'] == kind


def test_kinds_and_fleets_as_issue_33_asks(samples):
    fleets = {name: spec for name, spec in samples.GENERATED.items() if 'building' in spec}
    assert len(KINDS) >= 12 and {spec['building'] for spec in fleets.values()} == set(KINDS)
    assert {spec['pattern'] for spec in fleets.values()} >= {'chain', 'star', 'clusters', 'random'}
    for spec in fleets.values():
        assert spec['n_robots'] == 36 and spec['n_broken'] == 9


@pytest.mark.parametrize('kind', ['hospital', 'warehouse', 'campus'])   # a chain, a star, clusters
def test_small_fleet_truth_is_consistent(samples, tmp_path, kind):
    name = f'{kind}36'
    spec = dict(samples.GENERATED[name], n_robots=8, n_broken=2, goals=(1, 2))
    print(f'seed {spec["seed"]}, world seed {spec["world_seed"]}')
    truth = samples.make_generated(name, spec, str(tmp_path), '')
    again = samples.make_generated(name, spec, str(tmp_path / 'again'), '')
    assert truth == dict(again), 'a scenario must be the same on every run'
    world = samples.generated_world(spec)
    occ, clear = samples.free_with_clearance(world)
    maps = truth['maps']
    assert len(maps) == 8 and sum(m['broken'] for m in maps) == 2
    res = world.resolution
    for i, m in enumerate(maps):
        x, y, yaw = m['pose']
        assert clear[int(y / res), int(x / res)], f'robot {i} starts in a wall'
        assert m['broken'] == (m['broken_deg'] != 0.0) and len(m['alt_poses']) == int(m['broken'])
        if m['broken']:
            continue
        # a healthy map's walls land on the world's walls at its true pose
        grid = load_map(str(tmp_path / name / m['file']))
        rows, cols = np.nonzero(grid.data >= 65)
        pts = (grid.cell_to_map() @ np.stack([cols + 0.5, rows + 0.5, np.ones(len(rows))]))[:2]
        c, s = math.cos(yaw), math.sin(yaw)
        wx, wy = c * pts[0] - s * pts[1] + x, s * pts[0] + c * pts[1] + y
        near_wall = cv2.dilate(occ.astype(np.uint8), np.ones((3, 3), np.uint8))
        hit = near_wall[np.clip((wy / res).astype(int), 0, occ.shape[0] - 1),
                        np.clip((wx / res).astype(int), 0, occ.shape[1] - 1)]
        assert hit.mean() > 0.95, f'map {i}: only {hit.mean():.2f} of its walls on walls'
    # mergeable: the largest component of healthy maps that overlap enough, as the scorer reads it
    ov = truth['overlap']

    def linked(i: int, j: int) -> bool:
        return ov['shared_m2'][i][j] >= ov['min_shared_m2'] and ov['fraction'][i][j] >= ov['min_fraction']
    assert truth['mergeable'] == (truth['components'][0] if truth['components'] else [])
    assert all(len(c) <= len(truth['mergeable']) for c in truth['components'])
    for comp in truth['components']:
        assert not any(maps[i]['broken'] for i in comp)
        for i in comp:
            assert any(linked(i, j) for j in comp if j != i)
    assert all(m['mergeable'] == (i in truth['mergeable']) for i, m in enumerate(maps))
