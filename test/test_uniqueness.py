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


RES = 0.05


def _draw(data: np.ndarray, origin, box, value: int) -> None:
    """Cells of `data` (origin: the metric position of its cell (0, 0)) inside the metric box (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = box
    c0, c1 = (int(round((v - origin[0]) / RES)) for v in (x0, x1))
    r0, r1 = (int(round((v - origin[1]) / RES)) for v in (y0, y1))
    data[max(r0, 0):max(r1, 0), max(c0, 0):max(c1, 0)] = value


def _rooms_world(distinct_last: bool):
    """A row of four alike rooms, 8 m each, below a corridor, as (list of (box, value)) in metres: each room has a
    door in its upper wall and the same furniture; with distinct_last the last one also holds a wall of its own."""
    shapes = []
    for i in range(4):
        x = 8.0 * i
        shapes += [((x, 0.0, x + 8.0, 8.0), 0),
                   ((x, 0.0, x + 8.0, 0.1), 100), ((x, 0.0, x + 0.1, 8.0), 100), ((x + 7.9, 0.0, x + 8.0, 8.0), 100),
                   ((x, 7.9, x + 3.0, 8.0), 100), ((x + 4.5, 7.9, x + 8.0, 8.0), 100),
                   ((x + 2.0, 2.0, x + 3.0, 2.5), 100), ((x + 2.0, 2.0, x + 2.5, 3.5), 100),
                   ((x + 6.0, 5.0, x + 6.6, 5.6), 100)]
    if distinct_last:
        shapes.append(((28.5, 3.0, 29.0, 6.5), 100))
    return shapes


def _rooms_grid(origin, size_m, layers) -> Grid:
    """A grid with each layer's shapes drawn where they fall inside its known box (metres), the rest unknown."""
    data = np.full((int(size_m[1] / RES), int(size_m[0] / RES)), -1, np.int8)
    for shapes, known_box in layers:
        for box, value in shapes:
            clipped = (max(box[0], known_box[0]), max(box[1], known_box[1]),
                       min(box[2], known_box[2]), min(box[3], known_box[3]))
            if clipped[2] > clipped[0] and clipped[3] > clipped[1]:
                _draw(data, origin, clipped, value)
    return Grid(data, RES, (origin[0], origin[1], 0.0), 'map')


@pytest.mark.parametrize('distinct_last', [False, True])
def test_a_map_whose_part_on_the_merge_repeats_there_is_refused(distinct_last):
    """The merge knows the four rooms and the corridor above the first three; the robot saw the last room and a
    wall across the corridor above it, which the merge has not seen. Placed in the last room it agrees; in any other
    that wall would stand on the merge's open corridor, so no other place fits the whole map. But the part that the
    placement rests on, the room, fits the three others as well: nothing in the merge singles out this place (the
    robot's room could be a fifth one further on). Refused, unless the last room holds a wall of its own."""
    shapes = _rooms_world(distinct_last)
    corridor = [((0.0, 8.0, 32.0, 14.0), 0), ((0.0, 13.9, 32.0, 14.0), 100), ((26.0, 10.8, 30.0, 11.0), 100)]
    union = _rooms_grid((-1.0, -1.0), (34.0, 16.0), [(shapes, (-1.0, -1.0, 33.0, 15.0)),
                                                     (corridor, (-1.0, -1.0, 24.0, 15.0))])
    robot = _rooms_grid((23.0, -1.0), (10.0, 16.0), [(shapes + corridor, (23.9, -1.0, 33.0, 14.1))])
    check = StandingCheck([union, robot], EstimationSettings(), FeatureCache(), RES)
    why = check(1, np.eye(3), {0: np.eye(3)})
    if distinct_last:
        assert why == '', why
    else:
        assert why and 'part of it' in why, why
