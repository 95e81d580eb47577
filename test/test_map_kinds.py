"""Maps as SLAM packages publish them: trinary (gmapping, slam_toolbox, map_server), probabilistic (Cartographer)
and thin walls on a mostly unknown canvas (hector). Admission reads them through two thresholds for matching and
keeps their values for the merged map; merge_maps places each kind of a real_dev pair where its truth.json says.
(The node: test/ros/map_merge_map_kinds.test.)"""
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from multirobot_map_merge import cli
from multirobot_map_merge import transforms as tf
from multirobot_map_merge.admission import admit, trinary_cells
from multirobot_map_merge.grid import Grid
from multirobot_map_merge.mapio import load_map
from multirobot_map_merge.pipeline import MergingPipeline
from multirobot_map_merge.ros.params import MapMergeParams

sys.path.insert(0, str(Path(__file__).resolve().parent / 'ros'))
import map_kinds  # noqa: E402

SEED = 3217
PAIR = 'data/real_dev/pair_large_real_csail_clean'


def all_values() -> np.ndarray:
    return np.arange(-1, 101, dtype=np.int8).reshape(1, -1)


def test_trinary_cells_by_the_thresholds():
    values = all_values()
    out = trinary_cells(values, 25, 65)
    assert (out[values <= 25] == np.where(values[values <= 25] < 0, -1, 0)).all()
    assert (out[(values > 25) & (values < 65)] == -1).all()
    assert (out[values >= 65] == 100).all()
    strict = trinary_cells(values, 0, 100)   # only the trinary values are known
    assert set(np.unique(strict[(values > 0) & (values < 100)])) == {-1}


def test_a_trinary_grid_is_not_copied():
    data = np.random.default_rng(SEED).choice(np.array([-1, 0, 100], np.int8), (40, 50))
    assert trinary_cells(data) is data
    grid = Grid(data, 0.05)
    admitted = admit(grid, 0.05)
    assert admitted.grid is grid and admitted.matching is grid


def test_admission_matches_trinary_and_composes_as_published():
    print('seed', SEED)
    grid = map_kinds.probabilistic(Grid(np.random.default_rng(SEED).choice(np.array([-1, 0, 100], np.int8),
                                                                           (60, 80)), 0.05), seed=SEED)
    admitted = admit(grid, 0.05)
    assert admitted.grid is grid   # composed as published
    assert set(np.unique(admitted.matching.data)) <= {-1, 0, 100}
    assert (admitted.matching.data[(grid.data >= 10) & (grid.data <= 25)] == 0).all()
    assert (admitted.matching.data[(grid.data > 25) & (grid.data < 65)] == -1).all()
    assert admit(grid).matching is None   # not for matching: nothing is read
    pipeline = MergingPipeline()
    pipeline.feed([grid])
    pipeline.set_transforms([np.eye(3)])
    merged = pipeline.compose()
    assert np.array_equal(merged.data, grid.data)   # the merged map keeps the probabilities


def test_the_composition_keeps_the_original_maximum():
    """occupied > any probability > free > unknown, as the C++ node combines cells."""
    a = Grid(np.array([[-1, 0, 10, 49, 100]], np.int8), 1.0)
    b = Grid(np.array([[30, 30, 0, 70, 50]], np.int8), 1.0)
    pipeline = MergingPipeline()
    pipeline.feed([a, b], matching=False)
    pipeline.set_transforms([np.eye(3), np.eye(3)])
    assert pipeline.compose().data.tolist() == [[30, 30, 10, 70, 100]]


@pytest.mark.parametrize('free, occupied', [(65, 25), (30, 30), (-1, 65), (25, 101), (2.5, 65), (True, 65)])
def test_node_thresholds_that_cannot_be_are_the_defaults_with_a_warning(free, occupied):
    warnings = []
    params = MapMergeParams.read(lambda name, default: {'~free_threshold': free,
                                                        '~occupied_threshold': occupied}.get(name, default),
                                 warn=warnings.append)
    assert (params.free_threshold, params.occupied_threshold) == (25, 65)
    assert warnings and 'threshold' in warnings[-1]


def test_node_thresholds_reach_the_estimation():
    params = MapMergeParams.read(lambda name, default: {'~free_threshold': 10,
                                                        '~occupied_threshold': 90}.get(name, default))
    settings = params.estimation_settings()
    assert (settings.free_threshold, settings.occupied_threshold) == (10, 90)


def test_merge_maps_refuses_thresholds_that_cannot_be(tmp_path, capsys):
    assert cli.main(['--free-threshold', '70', '--output', str(tmp_path / 'm'), 'x.yaml']) == 2
    assert 'free_threshold' in capsys.readouterr().err


def relative_error(doc, truth):
    """(metres, degrees) of map 1 relative to map 0 as merge_maps placed it, against the truth."""
    placed = [tf.rigid(m['transform']['x'], m['transform']['y'], m['transform']['yaw']) for m in doc['maps']]
    true = [tf.rigid(*m['pose']) for m in truth['maps']]
    d = tf.inverse(tf.inverse(true[0]) @ true[1]) @ (tf.inverse(placed[0]) @ placed[1])
    return math.hypot(d[0, 2], d[1, 2]), abs(math.degrees(math.atan2(d[1, 0], d[0, 0])))


@pytest.mark.parametrize('kinds', [(kind, kind) for kind in map_kinds.KINDS]
                         + [('trinary', 'probabilistic'), ('thin', 'probabilistic')], ids='-'.join)
def test_merge_maps_places_each_kind_of_a_real_pair(kinds, shared_dir, tmp_path):
    """Each kind alone, and fleets that mix SLAM packages."""
    folder = shared_dir / PAIR
    truth = json.loads((folder / 'truth.json').read_text())
    paths = []
    for k, (entry, kind) in enumerate(zip(truth['maps'], kinds)):
        grid = map_kinds.as_kind(load_map(str(folder / entry['file'])), kind, seed=SEED + k)
        paths.append(map_kinds.save_raw(grid, str(tmp_path / f'{kind}_{k}')))
    print('seed', SEED)
    between = [bool(((load_map(p).data > 0) & (load_map(p).data < 100)).any()) for p in paths]
    assert between == [kind == 'probabilistic' for kind in kinds]   # the files hold those kinds
    out = tmp_path / 'placed.json'
    assert cli.main(['--transforms-json', str(out), '--output', str(tmp_path / 'merged')] + paths) == 0
    doc = json.loads(out.read_text())
    assert all(m['included'] for m in doc['maps']), doc
    metres, degrees = relative_error(doc, truth)
    assert metres < 0.25 and degrees < 0.5, (metres, degrees)
