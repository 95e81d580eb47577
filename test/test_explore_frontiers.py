"""explore frontier search: hand-made grids, equivalence with a literal port of the original, timing."""
import math
import re
import time
from collections import deque

import numpy as np
import pytest

import explore.frontier_search as fs
from explore.costmap import FREE_SPACE, LETHAL_OBSTACLE, NO_INFORMATION, Costmap
from explore.frontier_search import FrontierSearch, frontier_cell_mask, frontier_cost, search_frontiers

CHARS = {'.': FREE_SPACE, '?': NO_INFORMATION, '#': LETHAL_OBSTACLE, 'c': 128}


def grid(*rows: str) -> np.ndarray:
    """Cost grid from text; the first string is row my = 0 (lowest y)."""
    return np.array([[CHARS[c] for c in r] for r in rows], dtype=np.uint8)


def cells_of(points: np.ndarray, res: float, origin=(0.0, 0.0)):
    """World centres back to (mx, my) cells."""
    return {(int(round((x - origin[0]) / res - 0.5)), int(round((y - origin[1]) / res - 0.5))) for x, y in points}


# ---- a literal, queue-based port of explore.md §5, the yardstick for the vectorised search -----------------------

def _nhood4(i, sx, sy):
    out = []
    if i % sx > 0:
        out.append(i - 1)
    if i % sx < sx - 1:
        out.append(i + 1)
    if i >= sx:
        out.append(i - sx)
    if i < sx * (sy - 1):
        out.append(i + sx)
    return out


def _nhood8(i, sx, sy):
    out = _nhood4(i, sx, sy)
    c, last = i % sx, sx * (sy - 1)
    if c > 0 and i >= sx:
        out.append(i - 1 - sx)
    if c > 0 and i < last:
        out.append(i - 1 + sx)
    if c < sx - 1 and i >= sx:
        out.append(i + 1 - sx)
    if c < sx - 1 and i < last:
        out.append(i + 1 + sx)
    return out


def reference_search(data, res, origin, cell, ps, gs, mfs):
    sy, sx = data.shape
    m = [int(v) for v in data.ravel()]
    pos = cell[1] * sx + cell[0]

    def world(i):
        return origin[0] + (i % sx + 0.5) * res, origin[1] + (i // sx + 0.5) * res

    start, q, seen = pos, deque([pos]), {pos}
    while q:  # nearestCell: 8-neighbourhood BFS ignoring values
        i = q.popleft()
        if m[i] == 0:
            start = i
            break
        for n in _nhood8(i, sx, sy):
            if n not in seen:
                seen.add(n)
                q.append(n)
    flag, visited = [False] * (sx * sy), [False] * (sx * sy)

    def is_new(i):
        return m[i] == 255 and not flag[i] and any(m[n] == 0 for n in _nhood4(i, sx, sy))

    def build(init):
        f = dict(size=1, sx=0.0, sy=0.0, md=math.inf, middle=(0.0, 0.0), points=[], initial=world(init))
        rx, ry = world(pos)
        q = deque([init])
        while q:
            i = q.popleft()
            for n in _nhood8(i, sx, sy):
                if is_new(n):
                    flag[n] = True
                    wx, wy = world(n)
                    f['points'].append((wx, wy))
                    f['size'] += 1
                    f['sx'] += wx
                    f['sy'] += wy
                    # pow(x, 2.0) in the C++ compiles to x*x (exact); Python's ** calls libm pow, which can
                    # differ in the last bit
                    d = math.sqrt((rx - wx) * (rx - wx) + (ry - wy) * (ry - wy))
                    if d < f['md']:
                        f['md'], f['middle'] = d, (wx, wy)
                    q.append(n)
        f['centroid'] = (f['sx'] / f['size'], f['sy'] / f['size'])
        return f

    out, q = [], deque([start])
    visited[start] = True
    while q:
        i = q.popleft()
        for n in _nhood4(i, sx, sy):
            if m[n] <= m[i] and not visited[n]:
                visited[n] = True
                q.append(n)
            elif is_new(n):
                flag[n] = True
                f = build(n)
                if f['size'] * res >= mfs:
                    out.append(f)
    for f in out:
        f['cost'] = ps * f['md'] * res - gs * f['size'] * res
    out.sort(key=lambda f: (math.isnan(f['cost']), f['cost']))
    return out


def same_frontier(ref, f):
    cost_eq = ref['cost'] == f.cost or (math.isnan(ref['cost']) and math.isnan(f.cost))
    return (ref['size'] == f.size and ref['md'] == f.min_distance and ref['initial'] == f.initial
            and ref['centroid'] == f.centroid and ref['middle'] == f.middle and cost_eq
            and np.array_equal(np.array(ref['points']).reshape(-1, 2), f.points))


def random_grid(rng, kind, sy, sx):
    if kind == 0:  # salt and pepper
        return rng.choice(np.array([0, 255, 254, 100], np.uint8), size=(sy, sx), p=[0.5, 0.3, 0.15, 0.05])
    if kind == 1:  # free/unknown only: many touching frontier groups
        return rng.choice(np.array([0, 255], np.uint8), size=(sy, sx))
    if kind == 2:  # every cost value, incl. the ramp
        d = rng.integers(0, 256, size=(sy, sx)).astype(np.uint8)
        d[rng.random((sy, sx)) < 0.4] = 0
        d[rng.random((sy, sx)) < 0.3] = 255
        return d
    d = np.full((sy, sx), 255, np.uint8)  # an explored blob in unknown space, with obstacles
    y0, x0 = rng.integers(0, sy), rng.integers(0, sx)
    d[max(0, y0 - sy // 3):y0 + sy // 3, max(0, x0 - sx // 3):x0 + sx // 4] = 0
    d[rng.random((sy, sx)) < 0.1] = 254
    return d


@pytest.mark.parametrize('small_level', [0, 10 ** 9, 24])
def test_matches_literal_port_on_random_grids(monkeypatch, small_level):
    # small_level 0: every BFS level in numpy; 10**9: every level in the Python loop; 24: the shipped mix
    monkeypatch.setattr(fs, '_SMALL_LEVEL', small_level)
    rng = np.random.default_rng(small_level % 1000 + 7)
    for t in range(300):
        big = t % 10 == 0
        sy, sx = rng.integers(20, 70, 2) if big else rng.integers(1, 22, 2)
        data = random_grid(rng, t % 4, sy, sx)
        res = float(rng.choice([0.05, 0.1, 0.3, 1.0]))
        origin = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)))
        cell = (int(rng.integers(0, sx)), int(rng.integers(0, sy)))
        ps, gs = float(rng.choice([0.0, 1e-3, 3.0])), float(rng.choice([0.0, 1.0]))
        mfs = float(rng.choice([0.0, 0.3, 0.5]))
        ref = reference_search(data, res, origin, cell, ps, gs, mfs)
        got = search_frontiers(data, res, origin, cell, ps, gs, mfs)
        assert len(ref) == len(got), (t, data, cell)
        assert all(same_frontier(r, f) for r, f in zip(ref, got)), (t, data, cell)


# ---- hand-made grids ---------------------------------------------------------------------------------------------

L_SHAPE = grid('?????',
               '?..#?',
               '?.???',
               '?????')
L_FRONTIER = {(1, 0), (2, 0), (0, 1), (0, 2), (2, 2), (1, 3)}  # unknown cells with a free 4-neighbour


def test_frontier_cell_predicate():
    mask = frontier_cell_mask(L_SHAPE)
    assert {(int(x), int(y)) for y, x in zip(*np.nonzero(mask))} == L_FRONTIER
    # diagonal contact with free space is not enough; non-255 cells never qualify
    assert not mask[0, 0] and not mask[1, 3]


def test_one_group_size_points_centroid_quirk():
    res = 0.5
    (f,) = search_frontiers(L_SHAPE, res, (0.0, 0.0), (1, 1), 1e-3, 1.0, 0.0)
    assert f.size == len(L_FRONTIER)
    seed = cells_of([f.initial], res)
    pts = cells_of(f.points, res)
    assert seed | pts == L_FRONTIER and not seed & pts and len(f.points) == f.size - 1
    # the seed is counted in size but not summed: the centroid is pulled towards (0, 0) by (size-1)/size
    assert f.centroid == pytest.approx(tuple(f.points.sum(axis=0) / f.size))
    rx, ry = (1.5 * res, 1.5 * res)
    d = np.hypot(f.points[:, 0] - rx, f.points[:, 1] - ry)
    assert f.min_distance == pytest.approx(d.min())
    assert f.middle == tuple(f.points[np.argmin(d)])
    assert f.cost == frontier_cost(f.min_distance, f.size, res, 1e-3, 1.0)


def two_gap_room():
    d = np.full((7, 12), LETHAL_OBSTACLE, np.uint8)
    d[1:6, 1:11] = FREE_SPACE
    d[2:5, 11] = NO_INFORMATION  # 3-cell gap in the right wall
    d[6, 3:8] = NO_INFORMATION   # 5-cell gap in the top wall
    return d


def test_separate_groups_sizes_and_filter():
    d, res = two_gap_room(), 0.25
    found = search_frontiers(d, res, (0.0, 0.0), (10, 3), 0.0, 1.0, 0.0)
    assert sorted(f.size for f in found) == [3, 5]
    groups = {f.size: cells_of(f.points, res) | cells_of([f.initial], res) for f in found}
    assert groups[3] == {(11, 2), (11, 3), (11, 4)}
    assert groups[5] == {(x, 6) for x in range(3, 8)}
    # min_frontier_size compares size·resolution, inclusive
    assert [f.size for f in search_frontiers(d, res, (0.0, 0.0), (10, 3), 0.0, 1.0, 5 * res)] == [5]
    assert search_frontiers(d, res, (0.0, 0.0), (10, 3), 0.0, 1.0, 5 * res + 0.01) == []
    assert len(search_frontiers(d, res, (0.0, 0.0), (10, 3), 0.0, 1.0, 3 * res)) == 2


def test_cost_ordering_follows_scales():
    d, res = two_gap_room(), 0.25
    by_gain = search_frontiers(d, res, (0.0, 0.0), (10, 3), 0.0, 1.0, 0.0)
    by_distance = search_frontiers(d, res, (0.0, 0.0), (10, 3), 1.0, 0.0, 0.0)
    assert [f.size for f in by_gain] == [5, 3]        # larger first
    assert [f.size for f in by_distance] == [3, 5]    # the right gap is nearer to the robot
    for found, (ps, gs) in ((by_gain, (0.0, 1.0)), (by_distance, (1.0, 0.0))):
        assert [f.cost for f in found] == sorted(f.cost for f in found)
        assert all(f.cost == frontier_cost(f.min_distance, f.size, res, ps, gs) for f in found)
    # orientation has no say; potential_scale trades distance against size
    mixed = search_frontiers(d, res, (0.0, 0.0), (10, 3), 3.0, 1.0, 0.0)
    near, far = sorted(mixed, key=lambda f: f.min_distance)
    expect_near_first = 3.0 * near.min_distance * res - near.size * res < 3.0 * far.min_distance * res - far.size * res
    assert (mixed[0] is near) == expect_near_first


TWO_ROOMS = grid('?....#####....?',
                 '?....#####....?',
                 '?....#####....?')


@pytest.mark.parametrize('robot_x,expect_x', [(6, 0), (8, 14), (2, 0)])
def test_robot_on_obstacle_starts_from_nearest_clear_cell(robot_x, expect_x):
    res = 1.0
    found = search_frontiers(TWO_ROOMS, res, (0.0, 0.0), (robot_x, 1), 1e-3, 1.0, 0.0)
    assert len(found) == 1
    f = found[0]
    assert {c[0] for c in cells_of(f.points, res) | cells_of([f.initial], res)} == {expect_x}
    # distances are measured from the robot's own cell, not from the start cell
    assert f.min_distance == pytest.approx(np.hypot(f.points[:, 0] - (robot_x + 0.5), f.points[:, 1] - 1.5).min())


def test_no_free_cell_warns_and_finds_nothing(caplog):
    d = grid('???', '?#?', '???')
    with caplog.at_level('WARNING'):
        assert search_frontiers(d, 1.0, (0.0, 0.0), (1, 1)) == []
    assert 'Could not find nearby clear cell' in caplog.text


def test_closed_explored_room_has_no_frontiers():
    d = np.full((12, 12), NO_INFORMATION, np.uint8)
    d[2:10, 2:10] = LETHAL_OBSTACLE
    d[3:9, 3:9] = FREE_SPACE
    d[5, 5] = 128  # an inflated cell inside does not matter
    assert search_frontiers(d, 0.05, (0.0, 0.0), (4, 4), 1e-3, 1.0, 0.0) == []
    d[9, 6] = NO_INFORMATION  # one unknown cell in the wall opens a one-cell frontier
    (f,) = search_frontiers(d, 0.05, (0.0, 0.0), (4, 4), 1e-3, 1.0, 0.0)
    assert f.size == 1 and f.centroid == (0.0, 0.0) and math.isinf(f.min_distance) and math.isinf(f.cost)


def test_single_cell_frontier_with_zero_potential_scale_sorts_last():
    d = grid('#?#???#',
             '#.....?',
             '#######')
    # groups: {(1,0)} alone; {(3,0),(4,0),(5,0)} joined diagonally by (6,1)
    found = search_frontiers(d, 1.0, (0.0, 0.0), (2, 1), 0.0, 1.0, 0.0)
    assert [f.size for f in found] == [4, 1]
    assert found[0].cost == -4.0 and math.isnan(found[1].cost)  # 0 * inf is NaN, as in the original


def test_grouping_crosses_walls():
    # (1,1) touches only the free cell (2,1) of a room the robot cannot reach, yet joins the group of (1,0)
    d = grid('.?#',
             '#?.',
             '###')
    (f,) = search_frontiers(d, 1.0, (0.0, 0.0), (0, 0), 1e-3, 1.0, 0.0)
    assert f.size == 2
    assert cells_of(f.points, 1.0) | cells_of([f.initial], 1.0) == {(1, 0), (1, 1)}


def test_search_from_world_position_and_out_of_bounds(caplog):
    cm = Costmap()
    occ = np.where(two_gap_room() == NO_INFORMATION, -1, np.where(two_gap_room() == 0, 0, 100)).astype(np.int8)
    cm.update_full(12, 7, 0.25, -1.0, -1.0, occ.ravel(), 'map')
    search = FrontierSearch(cm, 0.0, 1.0, 0.0)
    inside = search.search_from(-1.0 + 10.5 * 0.25, -1.0 + 3.5 * 0.25)
    assert sorted(f.size for f in inside) == [3, 5]
    assert all(f.initial[0] >= -1.0 and f.initial[1] >= -1.0 for f in inside)
    with caplog.at_level('ERROR'):
        assert search.search_from(-1.01, 0.0) == []
        assert search.search_from(5.0, 0.0) == []
    assert 'Robot out of costmap bounds' in caplog.text


def load_trinary_map(path):
    """map_server trinary PGM (254 free, 0 occupied, 205 unknown; row 0 = highest y) → Costmap."""
    import cv2
    meta = path.with_suffix('.yaml').read_text()
    res = float(re.search(r'resolution:\s*([-\d.e]+)', meta).group(1))
    ox, oy = (float(v) for v in re.search(r'origin:\s*\[([^,]+),([^,]+),', meta).groups())
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[::-1]
    occ = np.full(img.shape, -1, np.int8)
    occ[img == 254] = 0
    occ[img == 0] = 100
    cm = Costmap()
    cm.update_full(img.shape[1], img.shape[0], res, ox, oy, occ.ravel(), 'map')
    return cm


@pytest.mark.parametrize('scenario', ['group3_autolab', 'pair_small_depot_1'])
def test_matches_literal_port_on_real_maps(shared_dir, scenario):
    cm = load_trinary_map(shared_dir / 'data' / 'dev' / scenario / 'map_00.pgm')
    rng = np.random.default_rng(5)
    free_cells = np.argwhere(cm.data == FREE_SPACE)
    starts = [cm.world_to_map(0.0, 0.0)] + [tuple(int(v) for v in free_cells[rng.integers(len(free_cells))][::-1])]
    for i, cell in enumerate(starts):
        args = (cm.data, cm.resolution, (cm.origin_x, cm.origin_y), cell, 3.0, 1.0, 0.75)
        ref, got = reference_search(*args), search_frontiers(*args)
        assert len(ref) == len(got)
        assert got or i > 0  # from the robot's start pose a partial map always has frontiers
        assert all(same_frontier(r, f) for r, f in zip(ref, got))


def test_timing_2000x2000_with_400x400_explored(capsys):
    rng = np.random.default_rng(0)
    d = np.full((2000, 2000), NO_INFORMATION, np.uint8)
    d[800:1200, 800:1200] = FREE_SPACE
    d[800:1200, 800:1200][rng.random((400, 400)) < 0.02] = LETHAL_OBSTACLE
    times = []
    for _ in range(3):
        t = time.perf_counter()
        found = search_frontiers(d, 0.05, (0.0, 0.0), (1000, 1000), 1e-3, 1.0, 0.5)
        times.append(time.perf_counter() - t)
    with capsys.disabled():
        print(f"\n[timing] frontier search 2000x2000, 400x400 explored: best {min(times) * 1e3:.1f} ms "
              f"of {len(times)}, {len(found)} frontiers")
    assert found
