"""fleet_sim core: floor plans, ray casting, log-odds mapping, and the committed sample maps."""
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from fleet_sim.laser import beam_angles, cast
from fleet_sim.mapping import LogOddsMap, compose, relative_pose
from fleet_sim.world import load_world, make_floor_plan, obstacle_mask
from multirobot_map_merge.mapio import load_map, save_map

SAMPLES = Path(__file__).resolve().parent.parent / 'data' / 'samples'


def n_components(mask, radius_cells=0):
    m = mask.astype(np.uint8)
    if radius_cells:
        m = cv2.erode(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_cells + 1,) * 2), borderValue=0)
    return cv2.connectedComponents(m, connectivity=4)[0] - 1


def dist_to_wall_cells(world):
    """Distance (cells) from every world cell to the nearest non-free cell."""
    return cv2.distanceTransform((world.data == 0).astype(np.uint8), cv2.DIST_L2, 5)


# ---------------------------------------------------------------- floor plans

@pytest.fixture(scope='module')
def plan():
    return make_floor_plan(11, 20.0, 14.0)


def test_floor_plan_is_deterministic_per_seed(plan):
    again = make_floor_plan(11, 20.0, 14.0)
    np.testing.assert_array_equal(plan.data, again.data)
    assert plan.extra['rooms'] == again.extra['rooms']
    assert not np.array_equal(make_floor_plan(12, 20.0, 14.0).data, plan.data)


@pytest.mark.parametrize('seed', range(6))
def test_floor_plan_connected_and_enclosed(seed):
    g = make_floor_plan(seed, 18.0, 12.0)
    free = g.data == 0
    assert set(np.unique(g.data)) == {-1, 0, 100}
    assert n_components(free) == 1
    assert n_components(free, radius_cells=4) == 1          # a 0.4 m wide robot reaches every part
    assert (g.data[0] == -1).all() and (g.data[:, -1] == -1).all()   # unknown outside
    # walls enclose the free space: no free cell touches an unknown one
    unknown_grown = cv2.dilate((g.data < 0).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert not (unknown_grown & free).any()
    # several rooms, each with some free space the robot can reach
    assert len(g.extra['rooms']) >= 4
    eroded = cv2.erode(free.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9)))
    for x0, y0, x1, y1 in g.extra['rooms']:
        r0, r1, c0, c1 = [int(round(v / g.resolution)) for v in (y0, y1, x0, x1)]
        assert eroded[r0:r1, c0:c1].any(), (x0, y0, x1, y1)


def test_doors_are_wide_enough(plan):
    free = plan.data == 0
    res = plan.resolution
    assert len(plan.extra['doors']) >= 4
    for x, y in plan.extra['doors']:
        c, r = int(x / res), int(y / res)
        assert free[r, c]
        # free run through the door centre along both axes; the one along the wall is the door width
        runs = []
        for line, i in ((free[r, :], c), (free[:, c], r)):
            lo, hi = i, i
            while lo > 0 and line[lo - 1]:
                lo -= 1
            while hi < line.size - 1 and line[hi + 1]:
                hi += 1
            runs.append((hi - lo + 1) * res)
        assert min(runs) >= 0.8 - 1e-9, (x, y, runs)


def test_walls_thin_and_thick(plan):
    # interior walls are 1-3 cells thick: some 1-cell walls exist (the hard case for ray casting)
    wall = (plan.data == 100).astype(np.uint8)
    thin_h = wall[1:-1] & ~wall[:-2].astype(bool) & ~wall[2:].astype(bool)
    assert thin_h.sum() + (wall[:, 1:-1] & ~wall[:, :-2].astype(bool) & ~wall[:, 2:].astype(bool)).sum() > 50


def test_load_world_round_trip(plan, tmp_path):
    yaml_path, _ = save_map(plan, str(tmp_path / 'world'))
    w = load_world(yaml_path)
    np.testing.assert_array_equal(w.data, plan.data)
    occ = obstacle_mask(w)
    assert occ[w.data < 0].all() and occ[w.data == 100].all() and not occ[w.data == 0].any()


def test_too_small_floor_plan_rejected():
    with pytest.raises(ValueError):
        make_floor_plan(1, 5.0, 5.0)


# ---------------------------------------------------------------- ray casting

def brute_ranges(occ, res, pose, angles, max_range, step=1e-3):
    """Reference: march every beam in tiny steps (cells) and report the first blocked sample."""
    out = np.full(angles.size, np.inf)
    px, py = pose[0] / res, pose[1] / res
    t = np.arange(0.0, max_range / res, step)
    for i, a in enumerate(pose[2] + angles):
        xs, ys = px + t * math.cos(a), py + t * math.sin(a)
        c, r = np.floor(xs).astype(int), np.floor(ys).astype(int)
        inside = (c >= 0) & (c < occ.shape[1]) & (r >= 0) & (r < occ.shape[0])
        blocked = ~inside
        blocked[inside] = occ[r[inside], c[inside]]
        k = np.flatnonzero(blocked)
        if k.size:
            out[i] = t[k[0]] * res
    return out


def test_cast_matches_brute_force_on_small_map():
    rng = np.random.default_rng(5)
    occ = rng.random((30, 40)) < 0.08
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    res = 0.1
    for _ in range(5):
        while True:
            x, y = rng.uniform(0.1, 3.9), rng.uniform(0.1, 2.9)
            if not occ[int(y / res), int(x / res)]:
                break
        pose = (x, y, rng.uniform(-math.pi, math.pi))
        angles = beam_angles(90)
        got = cast(occ, res, pose, 90, 2.0)
        ref = brute_ranges(occ, res, pose, angles, 2.0)
        assert np.array_equal(np.isinf(got), np.isinf(ref))
        fin = np.isfinite(ref)
        assert fin.sum() > 20
        np.testing.assert_allclose(got[fin], ref[fin], atol=2e-3 * res)


def test_cast_range_to_wall_surface():
    occ = np.zeros((20, 20), bool)
    occ[:, 15] = True                               # wall surface at x = 15 cells
    r = cast(occ, 0.05, (0.5 * 0.05 * 10, 0.5, 0.0), 4, 5.0)   # beams at 0, 90, 180, -90 deg from yaw 0
    angles = beam_angles(4)
    ahead = int(np.argmin(np.abs(angles)))
    assert r[ahead] == pytest.approx((15 - 5) * 0.05)
    assert np.isfinite(r).all()                     # out of the array counts as blocked


def thin_diagonal_world(n=60, anti=False):
    occ = np.zeros((n, n), bool)
    idx = np.arange(n)
    occ[idx, n - 1 - idx if anti else idx] = True   # 8-connected, 1 cell thick
    return occ


@pytest.mark.parametrize('anti', [False, True])
def test_no_leak_through_thin_diagonal_wall(anti):
    n, res = 60, 0.05
    occ = thin_diagonal_world(n, anti)
    rng = np.random.default_rng(2)
    for _ in range(20):
        # a point strictly on one side of the diagonal
        u, v = rng.uniform(2, n - 2, 2)
        if anti:
            if u + v > n - 3:
                u, v = n - 1 - v - 2, n - 1 - u - 2
            if u + v > n - 3 or min(u, v) < 0.5:
                continue
        else:
            if u - v < 2:
                u, v = v, u
            if u - v < 2:
                continue
        pose = (u * res, v * res, rng.uniform(-math.pi, math.pi))
        r = cast(occ, res, pose, 720, 10.0)
        a = pose[2] + beam_angles(720)
        ex = (pose[0] + r * np.cos(a)) / res
        ey = (pose[1] + r * np.sin(a)) / res
        if anti:
            assert np.all(ex + ey <= n + 1e-6)      # every end point stays on the robot's side
        else:
            assert np.all(ex - ey >= -1 - 1e-6)


def test_fixed_step_marching_would_leak_here():
    """The diagonal-wall test above is a real trap: a half-cell-step marcher goes through it."""
    n, res = 60, 0.05
    occ = thin_diagonal_world(n)
    pose = (40.3 * res, 10.7 * res, 0.0)
    angles = beam_angles(720)
    leaks = 0
    for a in pose[2] + angles:
        for t in np.arange(0, 80, 0.5):
            c, r = int(pose[0] / res + t * math.cos(a)), int(pose[1] / res + t * math.sin(a))
            if not (0 <= c < n and 0 <= r < n) or occ[r, c]:
                break
            if c - r < -1:
                leaks += 1
                break
    assert leaks > 0


def test_cast_noise_dropout_and_no_return():
    occ = np.zeros((200, 200), bool)
    occ[:, 150] = True
    pose = (5.0, 5.0, 0.0)
    clean = cast(occ, 0.05, pose, 360, 3.0)
    # only beams within acos(2.5 / 3) of the wall normal reach the wall at 2.5 m within 3 m
    expect = np.count_nonzero(np.abs(beam_angles(360)) < math.acos(2.5 / 3.0))
    assert abs(np.isfinite(clean).sum() - expect) <= 2 and np.isinf(clean).sum() > 250
    noisy = cast(occ, 0.05, pose, 360, 3.0, rng=np.random.default_rng(0), sigma=0.02)
    fin = np.isfinite(clean)
    assert np.array_equal(np.isfinite(noisy), fin)
    d = noisy[fin] - clean[fin]
    assert 0 < np.abs(d).max() < 0.2
    again = cast(occ, 0.05, pose, 360, 3.0, rng=np.random.default_rng(0), sigma=0.02)
    np.testing.assert_array_equal(noisy, again)
    dropped = cast(occ, 0.05, pose, 360, 3.0, rng=np.random.default_rng(1), dropout=0.5)
    assert 100 < np.isnan(dropped).sum() < 260
    assert np.isnan(cast(occ, 0.05, pose, 10, 3.0, rng=np.random.default_rng(1), dropout=1.0)).all()


def test_cast_from_inside_a_wall_is_zero():
    occ = np.ones((5, 5), bool)
    assert (cast(occ, 0.1, (0.25, 0.25, 0.0), 8, 1.0) == 0).all()


# ---------------------------------------------------------------- poses

def test_relative_pose_inverts_compose():
    a, b = (1.0, -2.0, 2.5), (0.3, 4.0, -1.0)
    c = compose(a, b)
    np.testing.assert_allclose(relative_pose(a, c), b, atol=1e-12)
    np.testing.assert_allclose(compose(a, relative_pose(a, b)), b, atol=1e-12)
    assert relative_pose(a, a) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


# ---------------------------------------------------------------- mapping

def drive_and_map(world, start, path, n_beams=180, max_range=5.0, seed=0, mapper=None, snapshots=None):
    occ = obstacle_mask(world)
    mapper = mapper or LogOddsMap(world.resolution)
    rng = np.random.default_rng(seed)
    angles = beam_angles(n_beams)
    for i, p in enumerate(path):
        r = cast(occ, world.resolution, p, n_beams, max_range, rng, sigma=0.01, dropout=0.01)
        mapper.integrate(relative_pose(start, p), r, angles, max_range)
        if snapshots is not None:
            snapshots(i, mapper)
    return mapper


@pytest.fixture(scope='module')
def small_world():
    return make_floor_plan(4, 14.0, 10.0)


def corridor_path(world, n=12):
    x0, y0, x1, y1 = world.extra['corridors'][0]
    yc = 0.5 * (y0 + y1)
    return [(x, yc + 0.05 * math.sin(x), 0.3 * math.sin(x)) for x in np.linspace(x0 + 1.0, x1 - 1.0, n)]


def test_map_matches_world_through_start_pose(small_world):
    path = corridor_path(small_world)
    start = (path[0][0], path[0][1], math.radians(100.0))    # the map frame's pose in the world
    grid = drive_and_map(small_world, start, path).to_grid('robot/map')
    # the map frame origin is inside the map, on a cell corner
    ox, oy, _ = grid.origin
    assert ox <= 0 < ox + grid.width * grid.resolution and oy <= 0 < oy + grid.height * grid.resolution
    assert ox / grid.resolution == pytest.approx(round(ox / grid.resolution))
    rows, cols = np.nonzero(grid.data >= 0)
    pts = (grid.cell_to_map() @ np.c_[cols + 0.5, rows + 0.5, np.ones(rows.size)].T).T[:, :2]
    c, s = math.cos(start[2]), math.sin(start[2])
    wx = start[0] + c * pts[:, 0] - s * pts[:, 1]
    wy = start[1] + s * pts[:, 0] + c * pts[:, 1]
    wc, wr = (wx / small_world.resolution).astype(int), (wy / small_world.resolution).astype(int)
    dist = dist_to_wall_cells(small_world)[wr, wc]
    occ_m = grid.data[rows, cols] == 100
    free_m = grid.data[rows, cols] == 0
    assert occ_m.sum() > 200 and free_m.sum() > 5000
    # walls within a cell of true walls (cell-centre distance <= 1.5 cells to the nearest wall cell)
    assert np.all(dist[occ_m] <= 1.5), np.sort(dist[occ_m])[-10:]
    # free space lies on free world cells (a rotated map may clip a wall corner)
    assert np.mean(small_world.data[wr[free_m], wc[free_m]] == 0) > 0.995
    # and the walls next to the corridor were seen: many world wall cells near the path are mapped
    assert occ_m.sum() > 0.3 * np.count_nonzero(dist[free_m] <= 1.0)


def test_map_grows_and_keeps_content(small_world):
    path = corridor_path(small_world)
    mapper = LogOddsMap(small_world.resolution, chunk_m=1.0)
    drive_and_map(small_world, path[0], path[:2], mapper=mapper)
    first = mapper.to_grid()
    drive_and_map(small_world, path[0], path, mapper=mapper)
    later = mapper.to_grid()
    assert later.width > first.width
    # cells known in the first map are still known, at the same map-frame place
    dc = int(round((first.origin[0] - later.origin[0]) / first.resolution))
    dr = int(round((first.origin[1] - later.origin[1]) / first.resolution))
    part = later.data[dr:dr + first.height, dc:dc + first.width]
    known = first.data >= 0
    assert np.mean(part[known] >= 0) > 0.99


def test_changed_rect_covers_every_change(small_world):
    path = corridor_path(small_world, n=16)
    mapper = LogOddsMap(small_world.resolution)
    state = {'prev': None, 'checked': 0, 'full': 0}

    def check(i, m):
        if i % 2:
            return
        rect = m.changed_rect()
        cur = m.values()
        prev = state['prev']
        if rect is not None and rect.full:
            assert (rect.x, rect.y, rect.width, rect.height) == (0, 0, cur.shape[1], cur.shape[0])
            state['full'] += 1
        elif prev is None or prev.shape != cur.shape:
            raise AssertionError("shape changed without a full update")
        else:
            diff = prev != cur
            inside = np.zeros_like(diff)
            if rect is not None:
                inside[rect.y:rect.y + rect.height, rect.x:rect.x + rect.width] = True
            assert not (diff & ~inside).any()
            state['checked'] += 1
        state['prev'] = cur
    drive_and_map(small_world, path[0], path, mapper=mapper, snapshots=check)
    assert state['full'] >= 1 and state['checked'] >= 3
    assert mapper.changed_rect() is not None        # the last scan came after the last check
    assert mapper.changed_rect() is None            # nothing new since the last call


def test_no_return_and_dropout_handling():
    m = LogOddsMap(0.1)
    angles = np.array([0.0, math.pi / 2, math.pi])
    m.integrate((0.0, 0.0, 0.0), np.array([1.0, np.inf, np.nan]), angles, 2.0)
    g = m.to_grid()
    ox, oy, _ = g.origin

    def val(x, y):
        return g.data[int(math.floor((y - oy) / 0.1)), int(math.floor((x - ox) / 0.1))]
    assert val(0.55, 0.05) == 0 and val(1.05, 0.05) == 100      # free along the beam, wall at the end
    assert val(0.05, 1.5) == 0 and val(0.05, 2.5) == -1         # no return: free up to max range only
    assert val(-0.55, 0.05) == -1                                # dropout: nothing
    m2 = LogOddsMap(0.1)
    m2.integrate((0.0, 0.0, 0.0), np.array([1.0, np.inf, np.nan]), angles, 2.0, clear_no_return=False)
    assert m2.to_grid().data[int((1.5 - m2.origin[1]) / 0.1), int((0.05 - m2.origin[0]) / 0.1)] == -1


# ---------------------------------------------------------------- committed sample maps

@pytest.mark.skipif(not (SAMPLES / 'world.yaml').is_file(), reason='data/samples not generated')
@pytest.mark.parametrize('scenario', ['three_robots', 'no_overlap'])
def test_sample_maps_agree_with_world_and_truth(scenario):
    world = load_world(str(SAMPLES / 'world.yaml'))
    truth = json.loads((SAMPLES / scenario / 'truth.json').read_text())
    assert truth['format'] == 'mmeval-truth-1' and truth['scenario'] == scenario
    dist = dist_to_wall_cells(world)
    for m in truth['maps']:
        g = load_map(str(SAMPLES / scenario / m['file']))
        assert [g.width, g.height] == m['size'] and 100 <= max(m['size']) <= 400
        rows, cols = np.nonzero(g.data == 100)
        pts = (g.cell_to_map() @ np.c_[cols + 0.5, rows + 0.5, np.ones(rows.size)].T).T[:, :2]
        x, y, yaw = m['pose']
        wx = x + math.cos(yaw) * pts[:, 0] - math.sin(yaw) * pts[:, 1]
        wy = y + math.sin(yaw) * pts[:, 0] + math.cos(yaw) * pts[:, 1]
        d = dist[(wy / world.resolution).astype(int), (wx / world.resolution).astype(int)]
        assert np.all(d <= 1.5)
    fr = np.array(truth['overlap']['fraction'])
    pairs = fr[np.triu_indices(len(truth['maps']), 1)]
    if scenario == 'three_robots':
        assert np.all((pairs >= 0.3) & (pairs <= 0.6)) and truth['mergeable'] == [0, 1, 2]
        yaws = sorted(round(math.degrees(m['pose'][2])) for m in truth['maps'])
        assert yaws == [-140, 0, 100]
    else:
        assert np.all(pairs == 0) and truth['mergeable'] == []
