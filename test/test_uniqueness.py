"""The check of a held placement on the merge that stands (estimation/uniqueness.py), on test/data/office_alias: a map
of a generated office (rooms every 8.5 m along a corridor) and the union of 26 maps of it."""
import json

import numpy as np
import pytest

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation.features import FeatureCache
from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.estimation.uniqueness import CONTRADICTS, StandingCheck
from multirobot_map_merge.grid import Grid
from multirobot_map_merge.mapio import load_map


@pytest.fixture(scope='module')
def office(repo_root):
    folder = repo_root / 'test' / 'data' / 'office_alias'
    truth = json.loads((folder / 'truth.json').read_text())
    robot, union = (load_map(str(folder / m['file'])) for m in truth['maps'])
    true_m = tf.inverse(tf.rigid(*truth['maps'][1]['pose'])) @ tf.rigid(*truth['maps'][0]['pose'])
    return robot, union, true_m


def _band(grid: Grid, rows: int) -> Grid:
    """The grid with only a band of `rows` rows across its known part known (a robot that has seen less)."""
    known = np.argwhere(grid.data >= 0)
    middle = int(known[:, 0].min() + 0.45 * np.ptp(known[:, 0]))
    data = np.full_like(grid.data, -1)
    data[middle - rows // 2:middle + rows // 2] = grid.data[middle - rows // 2:middle + rows // 2]
    return Grid(data, grid.resolution, grid.origin, grid.frame_id)


@pytest.mark.parametrize('settled', [False, True])
def test_a_map_the_merge_holds_in_two_places_is_refused_and_the_whole_map_is_confirmed(office, settled):
    """At the truth, a 7 m band of the robot's map agrees with the union, and so does it at a place along the
    corridor, with more support (the alike rooms the union holds further on): refused, whether or not the maps
    still grow. The whole map, at the truth, has no such place: confirmed."""
    robot, union, true_m = office
    band = StandingCheck([union, _band(robot, 140)], EstimationSettings(), FeatureCache(), 0.05)
    why = band(1, true_m, {0: np.eye(3)}, settled)
    assert why and 'another place' in why and not why.startswith(CONTRADICTS), why
    whole = StandingCheck([union, robot], EstimationSettings(), FeatureCache(), 0.05)
    assert whole(1, true_m, {0: np.eye(3)}, settled) == ''


def test_a_placement_that_contradicts_the_merge_that_stands_is_refused_and_one_beside_it_is_not_judged(office):
    robot, union, true_m = office
    check = StandingCheck([union, robot], EstimationSettings(), FeatureCache(), 0.05)
    assert check(1, true_m @ tf.rigid(0.0, 0.0, np.radians(4.0)), {0: np.eye(3)}).startswith(CONTRADICTS)
    assert check(1, tf.translation(500.0, 500.0) @ true_m, {0: np.eye(3)}) is None
