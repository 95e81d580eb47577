"""explore.merge_latency: overlap of one robot map with the union of the others at true poses, the joinable
thresholds, and the joinable / merged / latency bookkeeping of the demo summary."""
import math

import numpy as np
import pytest

from explore.coverage import KnownRaster, PlacementTimeline
from explore.merge_latency import (MIN_FRACTION, MIN_SHARED_M2, LatencyTracker, is_joinable, joinable_robots,
                                   union_overlaps)
from multirobot_map_merge import transforms as tf
from multirobot_map_merge.grid import Grid

RES = 0.05


def robot_map(pose, known_world_rects, size_m=30.0):
    """A robot map whose frame sits at ``pose`` in the world; known (free) exactly where a cell centre falls into
    one of the world rectangles (x0, y0, x1, y1), unknown elsewhere. The grid is centred on its frame's origin."""
    n = int(size_m / RES)
    origin = (-size_m / 2, -size_m / 2, 0.0)
    grid = Grid(np.full((n, n), -1, np.int8), RES, origin, frame_id='m')
    rows, cols = np.mgrid[0:n, 0:n]
    pts = np.vstack([cols.ravel() + 0.5, rows.ravel() + 0.5, np.ones(n * n)])
    world = tf.rigid(*pose) @ grid.cell_to_map() @ pts
    known = np.zeros(n * n, bool)
    for x0, y0, x1, y1 in known_world_rects:
        known |= (world[0] >= x0) & (world[0] < x1) & (world[1] >= y0) & (world[1] < y1)
    grid.data[known.reshape(n, n)] = 0
    return grid


RASTER_BOUNDS = (-5.0, -5.0, 35.0, 25.0)


def known_by_sampling(grid, pose, cell):
    """Oracle: the known map cell under each world point of a fine lattice, looked up point by point."""
    x0, y0, x1, y1 = RASTER_BOUNDS
    xs, ys = np.meshgrid(np.arange(x0 + cell / 2, x1, cell), np.arange(y0 + cell / 2, y1, cell))
    local = tf.inverse(tf.rigid(*pose) @ grid.cell_to_map()) @ np.vstack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    c, r = np.floor(local[0]).astype(int), np.floor(local[1]).astype(int)
    inside = (c >= 0) & (c < grid.width) & (r >= 0) & (r < grid.height)
    known = np.zeros(xs.size, bool)
    known[inside] = grid.data[r[inside], c[inside]] >= 0
    return known


def shared_by_sampling(maps, name, cell=0.05):
    own = known_by_sampling(*maps[name], cell)
    others = np.zeros_like(own)
    for n, m in maps.items():
        if n != name:
            others |= known_by_sampling(*m, cell)
    return (own & others).sum() * cell * cell, own.sum() * cell * cell


def test_union_overlap_matches_point_sampling():
    seed = 20261123
    rng = np.random.default_rng(seed)
    print('seed', seed)
    rects = {'a': [(0, 0, 12, 4)], 'b': [(10, 0, 14, 10), (2, 3, 5, 8)], 'c': [(4, 6, 16, 9)]}
    maps = {}
    for name, rs in rects.items():
        pose = (rng.uniform(0, 15), rng.uniform(0, 10), rng.uniform(-math.pi, math.pi))
        maps[name] = (robot_map(pose, rs), pose)
    raster = KnownRaster.box(RASTER_BOUNDS, 0.1)
    got = union_overlaps({n: raster.known(g, p) for n, (g, p) in maps.items()}, raster.cell_m)
    for name in maps:
        shared, own = shared_by_sampling(maps, name)
        assert own > 10.0
        assert got[name][1] == pytest.approx(own, rel=0.03), name
        assert got[name][0] == pytest.approx(shared, rel=0.05, abs=0.3), name


def test_union_joins_where_no_single_map_would():
    # c overlaps a by 3 m² and b by 3 m² (different places): no pair reaches 4 m², the union does (6 m²)
    a = robot_map((3.0, 2.0, 0.4), [(0, 0, 10, 4)])
    b = robot_map((20.0, 1.0, -2.0), [(14, 0, 24, 4)])
    c = robot_map((12.0, 5.0, 1.3), [(7, 3, 17, 4)])     # 10 m² own; 3 m² with a, 3 m² with b
    raster = KnownRaster.box(RASTER_BOUNDS)
    truth = {'a': (a, (3.0, 2.0, 0.4)), 'b': (b, (20.0, 1.0, -2.0)), 'c': (c, (12.0, 5.0, 1.3))}
    overlaps = union_overlaps({n: raster.known(g, p) for n, (g, p) in truth.items()}, raster.cell_m)
    assert overlaps['c'][0] == pytest.approx(6.0, abs=0.3) and overlaps['c'][1] == pytest.approx(10.0, abs=0.4)
    assert overlaps['a'][0] == pytest.approx(3.0, abs=0.3)
    assert joinable_robots(raster, truth) == ['c']
    assert joinable_robots(raster, {n: truth[n] for n in ('a', 'c')}) == []
    # at a wrong pose the same map overlaps nothing: the true poses are what counts
    wrong = dict(truth, c=(c, (12.0, 5.0, 1.3 + math.pi / 2)))
    assert 'c' not in joinable_robots(raster, wrong)


def test_fraction_threshold_of_own_area():
    # d shares 6 m² with e, but that is under 5 % of d's own 200 m²: e is joinable, d is not
    d = robot_map((10.0, 5.0, 0.0), [(0, 0, 20, 10)])
    e = robot_map((20.0, 2.0, 2.5), [(18, 0, 24, 3)])    # 18 m², 6 m² of them inside d
    raster = KnownRaster.box(RASTER_BOUNDS)
    truth = {'d': (d, (10.0, 5.0, 0.0)), 'e': (e, (20.0, 2.0, 2.5))}
    assert joinable_robots(raster, truth) == ['e']
    assert joinable_robots(raster, truth, min_fraction=0.02) == ['d', 'e']


def test_thresholds():
    assert (MIN_SHARED_M2, MIN_FRACTION) == (4.0, 0.05)     # the shared scorer's (truth.json overlap)
    assert is_joinable(4.0, 80.0) and not is_joinable(3.9, 10.0) and not is_joinable(4.0, 81.0)
    assert not is_joinable(0.0, 0.0)


def test_raster_around_world_and_empty_map():
    world = Grid(np.zeros((40, 60), np.int8), 0.5, (1.0, 2.0, 0.0), frame_id='world')
    raster = KnownRaster.around(world, 0.25)
    assert raster.shape == (80, 120)
    empty = Grid(np.full((10, 10), -1, np.int8), RES, (0.0, 0.0, 0.0))
    assert not raster.known(empty, (5.0, 5.0, 0.0)).any()
    with pytest.raises(ValueError):
        KnownRaster.box((0, 0, 0, 5))


def test_latency_tracker():
    t = LatencyTracker(['r1', 'r2', 'r3', 'r4'])
    t.joinable(10.0, ['r2', 'r3'])
    t.included(14.0, ['r2', 'r3'])
    t.joinable(20.0, ['r1', 'r2', 'r3'])          # r2, r3 keep their first time
    t.included(26.0, ['r2', 'r3', 'r1'])
    t.included(30.0, ['r2', 'r3'])                # r1 dropped ...
    t.included(38.0, ['r1', 'r2', 'r3'])          # ... and back: merged counts from here
    t.joinable(40.0, ['r4'])
    rows = {r['robot']: r for r in t.rows()}
    assert t.reference() == 'r2'
    assert rows['r2'] == {'robot': 'r2', 'joinable_sim_s': 10.0, 'merged_sim_s': 14.0, 'latency_s': None,
                          'latency_reference': True}
    assert rows['r3']['latency_s'] == 4.0 and not rows['r3']['latency_reference']
    assert (rows['r1']['joinable_sim_s'], rows['r1']['merged_sim_s'], rows['r1']['latency_s']) == (20.0, 38.0, 18.0)
    assert (rows['r4']['merged_sim_s'], rows['r4']['latency_s']) == (None, None)
    assert LatencyTracker(['x']).reference() is None


def test_placement_timeline_counts_the_time_from_a_status_off_to_the_next():
    """A status whose worst robot is off by more than 0.75 degrees or 15 cm counts until the next status; the span
    starts at the first status with two robots placed; the worst errors are kept with their robots."""

    def rows(*errors):
        return [{'robot': f'robot_{k}', 'rotation_error_deg': deg, 'corner_error_m': m}
                for k, (deg, m) in enumerate(errors)]
    timeline = PlacementTimeline()
    timeline.add(8.0, rows((0.0, 0.0)))                   # one robot: nothing to score yet
    timeline.add(10.0, rows((0.0, 0.0), (0.1, 0.05)))
    timeline.add(12.0, rows((0.0, 0.0), (1.2, 0.10)))     # turned: off until 15
    timeline.add(15.0, rows((0.0, 0.0), (0.2, 0.05)))
    timeline.add(22.0, rows((0.0, 0.0), (0.1, 0.30), (0.5, 0.1)))   # shifted: off until the end
    summary = timeline.summary(25.0)
    assert summary['span_s'] == 15.0 and summary['off_s'] == 6.0
    assert (summary['worst_cm'], summary['worst_cm_robot']) == (30.0, 'robot_1')
    assert (summary['worst_deg'], summary['worst_deg_robot']) == (1.2, 'robot_1')
    assert [t for t, _ in timeline.offs] == [12.0, 22.0]


def walls_map(pose, world_walls, size_m=30.0):
    """A robot map whose frame sits at ``pose`` in the world, with walls (occupied) where the world's wall
    segments (x0, y0, x1, y1) fall and free floor elsewhere in a 12 m box around its frame."""
    n = int(size_m / RES)
    grid = Grid(np.full((n, n), -1, np.int8), RES, (-size_m / 2, -size_m / 2, 0.0), frame_id='m')
    rows, cols = np.mgrid[0:n, 0:n]
    inside = (np.abs(cols - n / 2) < 6 / RES) & (np.abs(rows - n / 2) < 6 / RES)
    grid.data[inside] = 0
    to_cells = np.linalg.inv(grid.cell_to_map()) @ tf.inverse(tf.rigid(*pose))
    for x0, y0, x1, y1 in world_walls:
        t = np.linspace(0.0, 1.0, int(math.hypot(x1 - x0, y1 - y0) / (RES / 2)) + 2)
        pts = tf.apply(to_cells, np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
        c, r = np.floor(pts).astype(int).T
        ok = (c >= 0) & (r >= 0) & (c < n) & (r < n)
        grid.data[r[ok], c[ok]] = 100
    return grid


def test_a_drifted_map_placed_where_its_walls_fit_is_right_by_the_data():
    """A SLAM map that drifted holds its walls 25 cm from where its start pose puts them: placed where they fit,
    it is off by the strict errors but right by the data; turned by 1.5 degrees, it is neither."""
    from explore.coverage import placement_errors, right_by_the_data
    world = [(0, 0, 10, 0), (10, 0, 10, 6), (10, 6, 0, 6), (0, 6, 0, 0), (4, 0, 4, 2.5), (7, 6, 7, 4)]
    a_pose, b_start = (2.0, 2.0, 0.3), (6.0, 3.0, -0.4)
    b_content = (6.25, 3.1, -0.4)          # where b's walls really sit: its drift
    maps = {'a': walls_map(a_pose, world), 'b': walls_map(b_content, world)}
    truth = {'a': a_pose, 'b': b_start}
    fitted = {'a': a_pose, 'b': b_content}
    row = placement_errors(fitted, truth, maps)[1]
    assert row['corner_error_m'] > 0.15
    verdict, placed, true = right_by_the_data(row, fitted, truth, maps)
    assert verdict and placed[1] > true[1], (placed, true)
    # placements off the other way fit worse than the start pose, or are too far from it to be judged by the data
    for wrong in ((5.8, 2.95, -0.4), (6.25, 3.1, -0.4 + math.radians(1.5)), (6.6, 3.3, -0.4)):
        placed_at = {'a': a_pose, 'b': wrong}
        row = placement_errors(placed_at, truth, maps)[1]
        verdict, placed, true = right_by_the_data(row, placed_at, truth, maps)
        assert not verdict, (wrong, placed, true)
    verdict, placed, true = right_by_the_data(placement_errors({'a': a_pose, 'b': (5.8, 2.95, -0.4)}, truth, maps)[1],
                                              {'a': a_pose, 'b': (5.8, 2.95, -0.4)}, truth, maps)
    assert placed[1] < 0.95 * true[1], (placed, true)
