"""Property tests of the pure core with random hostile input (numpy random, seed printed so that a failure replays).

Messages -> grids / updates (GridError is the only documented error), admission (never raises), update application
(never raises, for every rectangle and data length) and composition (never raises, leaves out what does not fit):
no merged or stored-for-merge cell ever holds a value outside {-1} and 0..100.
Replay: HOSTILE_SEED=<seed> scripts/env.sh python -m pytest test/test_hostile_input.py
"""
import math
import os

import numpy as np
import pytest
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.admission import admit, clean_cells
from multirobot_map_merge.compose import compose, select_parts
from multirobot_map_merge.grid import MAX_CELLS, Grid, GridError
from multirobot_map_merge.pipeline import MergingPipeline
from multirobot_map_merge.ros.conversions import grid_from_msg, update_from_msg
from multirobot_map_merge.ros.robot_maps import RobotMap

SEED = int(os.environ.get('HOSTILE_SEED', np.random.SeedSequence().entropy % (1 << 32)))
ROUNDS = 300
ABSURD = [0.0, -0.0, 1e-300, -1e-300, 1e-30, 1e30, 1e300, -1e300, math.inf, -math.inf, math.nan, 2.0 ** 31, -2.0 ** 63]
BIG_INTS = [0, 1, 2 ** 31 - 1, 2 ** 31 + 7, 2 ** 32 - 1, 2 ** 16, 65535, 100000]


@pytest.fixture(scope='module')
def rng():
    print(f'\nhostile input seed {SEED} (replay: HOSTILE_SEED={SEED})')
    return np.random.default_rng(SEED)


def valid_cells(data: np.ndarray) -> bool:
    return bool(np.all((data == -1) | ((data >= 0) & (data <= 100))))


def a_number(rng, typical: float, spread: float) -> float:
    if rng.random() < 0.25:
        return float(rng.choice(ABSURD))
    return typical + spread * float(rng.standard_normal())


def a_size(rng) -> int:
    r = rng.random()
    if r < 0.15:
        return int(rng.choice(BIG_INTS))
    return int(rng.integers(0, 60))


def random_cells(rng, n: int) -> np.ndarray:
    kind = rng.integers(3)
    if kind == 0:
        return rng.integers(-128, 128, n).astype(np.int8)               # any int8
    if kind == 1:
        return rng.choice(np.array([-1, 0, 100], np.int8), n)           # a clean ternary map
    return rng.choice(np.array([-1, 0, 50, 100, 101, 127, -2, -128], np.int8), n)


def random_map_msg(rng) -> OccupancyGrid:
    m = OccupancyGrid()
    w, h = a_size(rng), a_size(rng)
    m.info.width, m.info.height = w % (1 << 32), h % (1 << 32)
    m.info.resolution = a_number(rng, 0.05, 0.02)
    m.info.origin.position.x = a_number(rng, 0.0, 10.0)
    m.info.origin.position.y = a_number(rng, 0.0, 10.0)
    q = m.info.origin.orientation
    if rng.random() < 0.8:   # else the all-zero quaternion of a default message
        q.x, q.y = (a_number(rng, 0.0, 0.5) if rng.random() < 0.3 else 0.0 for _ in range(2))
        q.z, q.w = a_number(rng, 0.0, 0.5), a_number(rng, 1.0, 0.5)
    n = w * h if w * h <= 10000 and rng.random() < 0.8 else int(rng.integers(0, 200))
    m.data = random_cells(rng, n)
    return m


def random_update_msg(rng, grid_shape) -> OccupancyGridUpdate:
    u = OccupancyGridUpdate()
    gh, gw = grid_shape
    u.x = int(rng.integers(-3, gw + 4)) if rng.random() < 0.8 else int(rng.choice(BIG_INTS)) * int(rng.choice([1, -1]))
    u.y = int(rng.integers(-3, gh + 4)) if rng.random() < 0.8 else int(rng.choice(BIG_INTS)) * int(rng.choice([1, -1]))
    u.width, u.height = a_size(rng), a_size(rng)
    n = u.width * u.height if u.width * u.height <= 10000 and rng.random() < 0.8 else int(rng.integers(0, 100))
    u.data = random_cells(rng, n)
    u.header.stamp.secs = int(rng.integers(0, 5))
    return u


def test_clean_cells_rule(rng):
    for _ in range(ROUNDS):
        data = random_cells(rng, int(rng.integers(0, 500))).reshape(-1, 1)
        out, n = clean_cells(data)
        assert valid_cells(out)
        bad = (data < -1) | (data > 100)
        assert n == int(bad.sum())
        np.testing.assert_array_equal(out[~bad], data[~bad])   # valid cells untouched
        assert np.all(out[bad] == -1)                           # the rule: read as unknown
        if n == 0:
            assert out is data                                   # no copy in the common case


def test_messages_grids_updates_never_raise_undocumented(rng):
    robot = RobotMap()
    robot.set_full(Grid(np.zeros((20, 30), np.int8), 0.05))
    refused = applied = 0
    for _ in range(ROUNDS):
        try:
            g = grid_from_msg(random_map_msg(rng))
            a = admit(g, 0.05)
            assert a.grid is None or valid_cells(a.grid.data)
            if a.grid is not None and rng.random() < 0.3:
                robot.set_full(a.grid)
        except GridError:
            refused += 1
        stored = robot.snapshot()
        for _ in range(3):
            try:
                upd = update_from_msg(random_update_msg(rng, stored.data.shape))
            except GridError:
                refused += 1
                continue
            result = robot.apply_update(upd)     # must never raise, whatever the rectangle
            applied += result.applied
            assert robot.snapshot().data.shape == stored.data.shape   # an update never resizes the map
        admitted = admit(robot.snapshot(), 0.05).grid   # None for an empty map
        assert admitted is None or valid_cells(admitted.data)
    print(f'{refused} refused, {applied} updates applied')
    assert refused and applied   # both paths were exercised


def test_degenerate_update_rectangles():
    robot = RobotMap()
    robot.set_full(Grid(np.zeros((10, 10), np.int8), 0.05, stamp=1.0))
    before = robot.snapshot()
    for x, y, w, h in [(0, 0, 0, 2 ** 31 - 1), (0, 5000, 0, 2 ** 31 + 175), (3, 3, 2 ** 31, 0), (9, 9, 0, 0),
                       (20, 0, 0, 5), (0, 20, 5, 0), (2 ** 40, 2 ** 40, 1, 1)]:
        from multirobot_map_merge.ros.conversions import GridUpdate
        result = robot.apply_update(GridUpdate(x, y, w, h, np.zeros((h, w) if w * h == 0 else (1, 1), np.int8), 2.0))
        assert not result.applied and result.reason
        assert robot.snapshot() is before


def random_transform(rng) -> np.ndarray:
    if rng.random() < 0.2:   # absurd (non-finite, huge) translation and rotation entries
        m = tf.rigid(0.0, 0.0, float(rng.uniform(-3.2, 3.2)))
        m[0, 2], m[1, 2] = a_number(rng, 0.0, 5.0), a_number(rng, 0.0, 5.0)
        if rng.random() < 0.3:
            m[0, 0] = m[1, 1] = a_number(rng, 1.0, 0.1)
        return m
    return tf.rigid(float(rng.normal(0, 5)), float(rng.normal(0, 5)), float(rng.uniform(-3.2, 3.2)))


def random_grid(rng) -> Grid:
    h, w = (int(v) for v in rng.integers(1, 40, 2))
    res = float(rng.choice([0.05, 0.1, 0.025])) if rng.random() < 0.8 else float(10.0 ** rng.uniform(-4, 4))
    origin = (float(rng.normal(0, 3)), float(rng.normal(0, 3)), float(rng.uniform(-3.2, 3.2)))
    if rng.random() < 0.15:
        origin = (float(rng.choice([1e9, -1e12, 1e300, 4e5])), origin[1], origin[2])
    return Grid(random_cells(rng, h * w).reshape(h, w), res, origin)


def test_pipeline_compose_never_fails_and_never_holds_a_bad_cell(rng):
    pipeline = MergingPipeline()
    merged_some = 0
    for _ in range(ROUNDS // 2):
        n = int(rng.integers(1, 7))
        grids = [random_grid(rng) if rng.random() < 0.9 else None for _ in range(n)]
        pipeline.feed(grids)
        pipeline.set_transforms([random_transform(rng) if rng.random() < 0.9 else None for _ in range(n)])
        merged = pipeline.compose('world')
        if merged is None:
            continue
        merged_some += 1
        assert valid_cells(merged.data)
        assert merged.data.size <= MAX_CELLS
        assert all(math.isfinite(v) for v in merged.origin) and merged.resolution > 0
        for k in pipeline.left_out:
            assert pipeline.composable[k] is not None and pipeline.transforms[k] is not None
    assert merged_some


def test_one_far_robot_is_left_out_the_others_merged():
    good = Grid(np.zeros((20, 20), np.int8), 0.05)
    far = Grid(np.full((20, 20), 100, np.int8), 0.05, (1e9, -3e9, 0.0))
    left_out = {}
    merged = compose([far, good, good.copy()], [np.eye(3), np.eye(3), tf.rigid(0.5, 0.0, 0.0)], left_out=left_out)
    assert set(left_out) == {0} and 'too large' in left_out[0]
    assert merged is not None and merged.width == 30 and merged.height == 20 and not (merged.data == 100).any()


def test_select_parts_keeps_the_largest_group():
    near = [np.array([0.0, 0.0, 10.0, 10.0]) + d for d in (0.0, 5.0, 20.0)]
    far = [np.array([1e6, 1e6, 1e6 + 10, 1e6 + 10]), np.array([-1e7, 5.0, -1e7 + 3, 8.0]),
           np.array([0.0, math.nan, 1.0, 1.0])]
    keep, reasons = select_parts(dict(enumerate(far + near)))
    assert keep == [3, 4, 5]
    assert set(reasons) == {0, 1, 2} and 'not finite' in reasons[2]


def test_absurd_resolution_is_refused_for_the_merge_not_the_others():
    pipeline = MergingPipeline()
    coarse = Grid(np.zeros((2000, 2000), np.int8), 1e3)   # 2000 km: 1.6e15 working pixels
    fine = Grid(np.zeros((10, 10), np.int8), 0.05)
    pipeline.feed([coarse, fine])
    assert pipeline.grids[0] is None and 'working resolution' in pipeline.refused[0]
    assert pipeline.grids[1] is fine


def test_estimation_of_random_small_grids_never_fails(rng):
    """Tiny, one-row, one-cell, very fine or very coarse maps: the estimation places what it can and never raises."""
    pipeline = MergingPipeline()
    for _ in range(40):
        grids = []
        for _ in range(int(rng.integers(1, 5))):
            h, w = (int(v) for v in rng.integers(1, 12, 2))
            res = float(10.0 ** rng.uniform(-5, 0.3)) if rng.random() < 0.5 else 0.05   # coarse: see below
            grids.append(Grid(random_cells(rng, h * w).reshape(h, w), res, (float(rng.normal(0, 2)), 0.0, 0.0)))
        pipeline.feed(grids)
        result = pipeline.estimate()
        assert len(result.transforms) == len(grids)
        for k in pipeline.refused:
            assert result.transforms[k] is None
        merged = pipeline.compose()
        assert merged is None or valid_cells(merged.data)


def test_one_bad_robot_never_stops_the_estimation_of_the_others(shared_dir, rng):
    """A real pair plus hostile grids (absurd resolution, out-of-range cells, far origin): the pair is still placed
    as without them, and composing never fails."""
    import json
    folder = shared_dir / 'data' / 'dev' / 'pair_large_hospital_section_1'
    truth = json.loads((folder / 'truth.json').read_text())
    from multirobot_map_merge.mapio import load_map
    good = [load_map(str(folder / m['file'])) for m in truth['maps']]
    noise = Grid(rng.integers(-128, 128, (50, 60)).astype(np.int8), 0.05, (1e12, 3.0, 0.5))
    coarse = Grid(np.zeros((3000, 3000), np.int8), 500.0)
    tiny = Grid(rng.choice(np.array([0, 100, 127], np.int8), (40, 40)), 1e-6, (-1e300, 0.0, 0.0))
    one_cell = Grid(np.array([[100]], np.int8), 0.05)
    reference = MergingPipeline()
    reference.feed(good)
    reference.estimate(preferred_reference=0)
    pipeline = MergingPipeline()
    pipeline.feed([noise, good[0], coarse, good[1], tiny, one_cell])
    assert set(pipeline.refused) == {2, 4, 5} and set(pipeline.invalid_cells) == {0, 4}
    pipeline.estimate(preferred_reference=1)
    assert pipeline.transforms[1] is not None and pipeline.transforms[3] is not None
    rot, disp = tf.difference(tf.inverse(pipeline.transforms[1]) @ pipeline.transforms[3], reference.transforms[1],
                              np.array(truth['maps'][1]['known_bbox'], float))
    assert rot < 0.01 and disp < 0.1
    merged = pipeline.compose('world')
    assert merged is not None and valid_cells(merged.data)


def test_an_absurd_resolution_does_not_set_the_merged_one():
    """A 1 um map at the identity would set the merged resolution (the original's rule) and push every other map
    out: the resolution of the others is taken instead."""
    tiny = Grid(np.zeros((10, 10), np.int8), 1e-6)
    good = [Grid(np.full((40, 60), 100, np.int8), 0.05, (1.0, 2.0, 0.0)) for _ in range(2)]
    left_out = {}
    merged = compose([tiny] + good, [np.eye(3), tf.rigid(3.0, 0.0, 0.0), tf.rigid(0.0, 4.0, 1.0)], left_out=left_out)
    assert merged.resolution == 0.05 and not left_out   # the tiny map fits within one 5 cm cell
    merged = compose([tiny] + good, [np.eye(3), tf.rigid(3.0, 0.0, 0.0), tf.rigid(0.0, 4.0, 1.0)], left_out=left_out,
                     max_cells=10 ** 6)
    assert merged.resolution == 0.05 and (merged.data == 100).sum() >= 2 * 40 * 60 * 0.9


def test_a_coarse_absurd_resolution_does_not_take_over_the_merge():
    """Fuzz seed 490771560: with a far map left out at the reference's 5 cm, a 10 m map would keep every map in (all
    fit in few cells) and blur the good maps to nothing: the resolution most maps share is kept."""
    good = [Grid(np.full((40, 60), 100, np.int8), 0.05) for _ in range(2)]
    coarse = Grid(np.zeros((30, 30), np.int8), 10.0)
    far = Grid(np.zeros((10, 10), np.int8), 0.05)
    left_out = {}
    merged = compose(good + [coarse, far], [np.eye(3), tf.rigid(3.0, 0.0, 0.0), tf.rigid(5.0, 5.0, 0.0),
                                            tf.rigid(1e5, 0.0, 0.0)], left_out=left_out, max_cells=10 ** 6)
    assert merged.resolution == 0.05 and 0 not in left_out and 1 not in left_out and 3 in left_out
    assert (merged.data == 100).sum() >= 2 * 40 * 60 * 0.9


# ------------------------------------------------------------------ offline merge_maps: same rules, one line each
def _write_map(folder, name, data, origin=(0.0, 0.0, 0.0), mode='trinary'):
    """A map_server map; in raw mode the pixels are the cell values (as uint8), so any int8 value can be written."""
    import cv2
    from multirobot_map_merge.mapio import data_to_image
    img = data.view(np.uint8)[::-1] if mode == 'raw' else data_to_image(data)
    cv2.imwrite(str(folder / f'{name}.pgm'), np.ascontiguousarray(img))
    x, y, yaw = (f'{v:.6e}' for v in origin)   # PyYAML reads 1e+300 as a string, 1.000000e+300 as a float
    (folder / f'{name}.yaml').write_text(f'image: {name}.pgm\nresolution: 0.05\norigin: [{x}, {y}, {yaw}]\n'
                                         f'negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: {mode}\n')
    return str(folder / f'{name}.yaml')


def _merge_maps(args):
    import subprocess
    import sys
    from pathlib import Path
    tool = Path(__file__).resolve().parents[1] / 'nodes' / 'merge_maps'
    return subprocess.run([sys.executable, str(tool), *args], capture_output=True, text=True, timeout=120)


def test_merge_maps_reads_bad_cells_as_unknown_and_leaves_out_far_maps(tmp_path, rng):
    import json
    room = np.zeros((40, 40), np.int8)
    room[0, :] = room[-1, :] = room[:, 0] = room[:, -1] = 100
    corrupt = room.copy()
    corrupt[5:10, 5:10] = rng.choice(np.array([101, 127, -2, -128], np.int8), (5, 5))
    maps = [_write_map(tmp_path, 'good', room), _write_map(tmp_path, 'corrupt', corrupt, mode='raw'),
            _write_map(tmp_path, 'far', room, origin=(4e12, 0.0, 0.0))]
    poses = tmp_path / 'poses.yaml'
    poses.write_text('poses: [[0, 0, 0], [3, 0, 0], [0, 0, 0]]\n')
    out = tmp_path / 'merged'
    proc = _merge_maps(['--known-poses', str(poses), '--output', str(out), '--transforms-json',
                        str(tmp_path / 't.json'), *maps])
    assert proc.returncode == 0, proc.stderr
    warnings = [line for line in proc.stderr.splitlines() if 'warning' in line]
    assert len(warnings) == 2, proc.stderr
    assert 'corrupt.yaml: 25 cell(s)' in warnings[0] and 'read as unknown' in warnings[0]
    assert 'far.yaml: left out' in warnings[1]
    doc = json.loads((tmp_path / 't.json').read_text())
    assert [m['included'] for m in doc['maps']] == [True, True, False]
    from multirobot_map_merge.mapio import load_map
    merged = load_map(str(out) + '.yaml')
    assert merged.width == 100 and merged.height == 40   # the two rooms side by side, nothing of the far one


def test_merge_maps_exit_codes(tmp_path):
    room = np.zeros((20, 20), np.int8)
    far = _write_map(tmp_path, 'far', room, origin=(1e300, 0.0, 0.0))
    proc = _merge_maps(['--known-poses', str(tmp_path / 'p.yaml'), far])
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1   # unreadable poses file
    (tmp_path / 'p.yaml').write_text('poses: [[.nan, 0, 0]]\n')
    proc = _merge_maps(['--known-poses', str(tmp_path / 'p.yaml'), far])
    assert proc.returncode == 2 and 'not finite' in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    (tmp_path / 'p.yaml').write_text('poses: [[0, 0, 0]]\n')
    proc = _merge_maps(['--known-poses', str(tmp_path / 'p.yaml'), '--output', str(tmp_path / 'm'), far])
    assert proc.returncode == 1, proc.stderr                                          # the only map is left out
    assert 'far.yaml: left out' in proc.stderr and 'nothing to merge' in proc.stderr


# ------------------------------------------------------------------ explore's costmap: same rule, never a stray error
def test_explore_costmap_reads_invalid_cells_as_unknown_and_survives_any_update(rng):
    from explore.costmap import NO_INFORMATION, Costmap, CostmapError
    cm = Costmap()
    assert cm.update_full(3, 1, 0.05, 0.0, 0.0, np.array([101, -2, 100], np.int8)) == 2
    assert list(cm.data[0]) == [NO_INFORMATION, NO_INFORMATION, 254]
    refused = 0
    for _ in range(ROUNDS):
        u = random_update_msg(rng, cm.data.shape)
        before = cm.data.shape
        try:
            invalid = cm.update_partial(u.x, u.y, u.width, u.height, u.data)
            assert 0 <= invalid <= len(u.data)
        except CostmapError:
            refused += 1
        assert cm.data.shape == before
        if rng.random() < 0.1:
            m = random_map_msg(rng)
            try:
                cm.update_full(m.info.width, m.info.height, m.info.resolution, m.info.origin.position.x,
                               m.info.origin.position.y, m.data)
            except CostmapError:
                refused += 1
        translated = cm.data.reshape(-1)
        # only the costs a valid occupancy can give: FREE, the ramp, INSCRIBED, LETHAL, NO_INFORMATION
        assert set(np.unique(translated)) <= set(cm.table[:101]) | {NO_INFORMATION}
    assert refused


# ------------------------------------------------------------------ fleet_sim: a world file with invalid cells
def test_fleet_sim_world_file_invalid_cells_read_as_unknown(tmp_path, caplog):
    from fleet_sim.params import FleetSimParams
    from fleet_sim.sim import build_world
    world = np.zeros((60, 80), np.int8)
    world[0, :] = world[-1, :] = world[:, 0] = world[:, -1] = 100
    world[10:12, 10:14] = [[101, 127, -2, -128], [120, 0, 100, -1]]
    path = _write_map(tmp_path, 'world', world, mode='raw')
    with caplog.at_level('WARNING'):
        grid = build_world(FleetSimParams(world=path))
    assert valid_cells(grid.data)
    assert (grid.data[10:12, 10:14] == [[-1, -1, -1, -1], [-1, 0, 100, -1]]).all()
    assert any('5 cell(s)' in r.getMessage() and 'world.yaml' in r.getMessage() for r in caplog.records)


def test_tilted_origin_is_recorded_not_logged(caplog):
    msg = OccupancyGrid()
    msg.info.width = msg.info.height = 1
    msg.info.resolution = 0.05
    msg.info.origin.orientation.x, msg.info.origin.orientation.w = 0.3, 0.95
    msg.data = [0]
    with caplog.at_level('DEBUG'):
        g = grid_from_msg(msg)
    assert g.extra['tilted_origin'] == (0.3, 0.0, 0.0, 0.95) and not caplog.records   # the node warns, naming
    msg.info.origin.orientation.x = 0.0
    assert 'tilted_origin' not in grid_from_msg(msg).extra
