"""The C++ test suite (test_merging_pipeline.cpp, tests_and_launch.md §3) ported to the Python pipeline, on the
maps of ../shared/data/dev, with expectations derived from their ground truth."""
import json
import math

import numpy as np
import pytest

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.compose import compose
from multirobot_map_merge.grid import Grid, crop_to_known
from multirobot_map_merge.known_poses import InitPose
from multirobot_map_merge.mapio import load_map
from multirobot_map_merge.pipeline import MergingPipeline

RNG = np.random.default_rng(156468754)


def scenario(shared_dir, name):
    folder = shared_dir / 'data' / 'dev' / name
    truth = json.loads((folder / 'truth.json').read_text())
    grids = [load_map(str(folder / m['file'])) for m in truth['maps']]
    return grids, truth


def truth_transforms(truth):
    return [tf.rigid(*m['pose']) for m in truth['maps']]


def assert_valid(grid):
    assert grid is not None
    assert grid.data.shape == (grid.height, grid.width) and grid.data.size == grid.width * grid.height
    assert grid.resolution > 0


def placement_error(truth, transforms, i, j):
    """(rotation error deg, largest corner error in cells) of map j relative to map i, against the truth."""
    t_true = truth_transforms(truth)
    rel_est = tf.inverse(transforms[i]) @ transforms[j]
    rel_true = tf.inverse(t_true[i]) @ t_true[j]
    corners = np.array(truth['maps'][j]['known_bbox'], float)
    rot, disp = tf.difference(rel_est, rel_true, corners)
    return math.degrees(rot), disp / truth['maps'][j]['resolution']


def test_can_stitch_0_grids():
    p = MergingPipeline()
    p.feed([])
    result = p.estimate()
    assert result.transforms == [] and result.reference is None
    assert p.compose() is None
    assert p.transforms == []


def test_can_stitch_1_grid(shared_dir):
    grids, _ = scenario(shared_dir, 'pair_large_autolab_1')
    p = MergingPipeline()
    p.feed(grids[:1])
    p.estimate()
    merged = p.compose()
    assert_valid(merged)
    assert np.array_equal(p.transforms[0], np.eye(3))
    # the merged map is the input's known part, cell for cell, at the same place
    r0, r1, c0, c1 = crop_to_known(grids[0].data, margin=0)
    assert np.array_equal(merged.data, grids[0].data[r0:r1, c0:c1])
    assert merged.resolution == grids[0].resolution
    ox, oy, _ = grids[0].origin
    assert merged.origin[:2] == pytest.approx((ox + c0 * merged.resolution, oy + r0 * merged.resolution))


@pytest.mark.parametrize('name', ['pair_large_autolab_1', 'pair_large_hospital_section_1'])
def test_can_stitch_2_grids(shared_dir, name):
    grids, truth = scenario(shared_dir, name)
    p = MergingPipeline()
    p.feed(grids)
    p.estimate()
    merged = p.compose()
    assert_valid(merged)
    # the truth, expressed in the estimate's merged frame (the reference map's frame)
    t_true = truth_transforms(truth)
    expected = compose(grids, [tf.inverse(t_true[p.reference]) @ t for t in t_true])
    assert abs(merged.width - expected.width) <= 30 and abs(merged.height - expected.height) <= 30
    # a successful merge is larger than either input
    assert merged.width * merged.height > max((g.data >= 0).sum() for g in grids)
    rot, cells = placement_error(truth, p.transforms, 0, 1)
    assert rot <= 1.5 and cells <= 3


def test_estimation_accuracy(shared_dir):
    """A map and a copy of it turned by 30 degrees and shifted: the estimate recovers the turn and the shift."""
    grids, _ = scenario(shared_dir, 'pair_large_cave_1')
    g = grids[0]
    angle, shift = math.radians(30.0), (1.5, -2.0)
    turned = compose([g], [tf.rigid(shift[0], shift[1], angle)])
    p = MergingPipeline()
    p.feed([g, turned])
    p.estimate(preferred_reference=0)
    assert np.array_equal(p.transforms[0], np.eye(3))
    x, y, yaw, scale = tf.params(p.transforms[1])
    # transform 1 maps the turned copy back onto the original: the inverse motion
    expected = tf.params(tf.inverse(tf.rigid(shift[0], shift[1], angle)))
    assert abs(tf.wrap_angle(yaw - expected[2])) < 1e-2
    assert abs(x - expected[0]) < 2 * g.resolution and abs(y - expected[1]) < 2 * g.resolution
    assert abs(scale - 1.0) < 1e-9


def test_transforms_round_trip():
    for _ in range(1000):
        x, y = RNG.uniform(-1000, 1000, 2)
        yaw = RNG.uniform(-math.pi, math.pi)
        px, py, pyaw, scale = tf.params(tf.rigid(x, y, yaw))
        assert px == pytest.approx(x) and py == pytest.approx(y)
        assert pyaw == pytest.approx(yaw) and scale == pytest.approx(1.0)


def test_set_known_poses_metric_points():
    g = Grid(np.zeros((10, 10), np.int8), 0.1, (-0.5, -0.5, 0.0))
    p = MergingPipeline()
    p.feed([g])
    for _ in range(1000):
        x, y, yaw = RNG.uniform(-1000, 1000), RNG.uniform(-1000, 1000), RNG.uniform(0, 2 * math.pi)
        p.set_known_poses([InitPose(x, y, yaw)])
        for pt in ((1.0, 0.0), (0.0, 1.0)):
            expected = (x + math.cos(yaw) * pt[0] - math.sin(yaw) * pt[1],
                        y + math.sin(yaw) * pt[0] + math.cos(yaw) * pt[1])
            assert tf.apply(p.transforms[0], np.array([pt]))[0] == pytest.approx(expected, abs=1e-9)


def test_cell_transforms_match_metric_ones(shared_dir):
    grids, _ = scenario(shared_dir, 'hetero3_cave')
    p = MergingPipeline()
    p.feed(grids)
    p.estimate()
    ref = p.reference
    for k, g in enumerate(grids):
        if p.transforms[k] is None:
            continue
        cells = RNG.uniform(0, 100, (5, 2))
        via_cells = tf.apply(grids[ref].cell_to_map(), tf.apply(p.cell_transform(k), cells))
        via_metric = tf.apply(p.transforms[k], tf.apply(g.cell_to_map(), cells))
        assert np.allclose(via_cells, via_metric)


def test_set_empty_transforms():
    p = MergingPipeline()
    p.feed([None, None])
    p.set_transforms([None, None])
    assert p.compose() is None
    assert len(p.transforms) == 2


def test_empty_image_with_transform():
    p = MergingPipeline()
    p.feed([None])
    p.set_transforms([tf.rigid(0, 0, math.pi)])
    assert p.compose() is None
    assert len(p.transforms) == 1


def test_one_empty_image(shared_dir):
    grids, _ = scenario(shared_dir, 'pair_large_depot_1')
    p = MergingPipeline()
    p.feed([None, grids[0]])
    p.estimate()
    merged = p.compose()
    assert_valid(merged)
    assert p.transforms[0] is None
    assert np.array_equal(p.transforms[1], np.eye(3))
    assert (merged.data >= 0).sum() == (grids[0].data >= 0).sum()


def test_known_init_positions(shared_dir):
    grids, _ = scenario(shared_dir, 'pair_large_depot_1')
    p = MergingPipeline()
    p.feed(grids)
    for _ in range(5):
        poses = [InitPose(*RNG.uniform(-50, 50, 2), RNG.uniform(0, 2 * math.pi)) for _ in grids]
        p.set_known_poses(poses)
        merged = p.compose()
        assert_valid(merged)
        # nothing is lost: every known cell of every input is somewhere in the merge (up to resampling)
        known = sum(int((g.data >= 0).sum()) for g in grids)
        assert (merged.data >= 0).sum() >= 0.5 * max((g.data >= 0).sum() for g in grids)
        assert (merged.data >= 0).sum() <= known * 1.1
