"""The angles a correlation search turns a grid by (orientation.near_turns): where both grids' long walls run in a
few directions (wall families), only the sweep's angles about the turns that make a family of one meet a family of the
other."""
import math

import cv2
import numpy as np
import pytest

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation import orientation, search
from multirobot_map_merge.estimation.features import prepare
from multirobot_map_merge.grid import Grid

from test_orientation import _rooms

RES = 0.05


def _families(work):
    length, angle = orientation.long_segments(work, RES)
    return orientation.wall_families(length * RES, angle)


def _off_degrees(angle, degrees):
    """How far `angle` (radians) is from `degrees`, modulo 90 degrees."""
    return (math.degrees(angle) - degrees + 45) % 90 - 45


@pytest.mark.parametrize('degrees', [0.0, 7.3, 41.0])
def test_rectilinear_walls_make_one_family(degrees):
    found = _families(_rooms(degrees))
    assert found is not None and len(found) == 1
    # OpenCV turns counter-clockwise on the image, whose rows go down: the walls' angle in pixels is -degrees
    assert abs(_off_degrees(found[0][0], -degrees)) < 0.2


def test_a_wing_of_another_direction_makes_a_family_of_its_own():
    """Two floors side by side, one turned 30 degrees (a radial building, a broken map): a family each."""
    work = np.concatenate([_rooms(0.0), _rooms(30.0)], axis=1)
    found = _families(work)
    assert found is not None and len(found) == 2
    assert sorted(round(_off_degrees(c, 0.0)) for c, _ in found) == [-30, 0]
    assert orientation.wall_orientation(work, RES) is None   # no single direction


def _round_hall():
    """A round hall with a round wall inside: no straight walls."""
    work = np.full((600, 600), -1, np.int8)
    cv2.circle(work, (300, 300), 250, 0, -1)
    for r in (250, 120):
        cv2.circle(work, (300, 300), r, 100, 1)
    return work


def test_round_walls_have_no_families():
    assert _families(_round_hall()) is None


def _part_turned(degrees):
    """(grid i: part of the floor of _rooms, turned by `degrees`; grid j: the whole floor; the pixel transform
    i -> j), both prepared."""
    j = _rooms(0.0)
    turn = np.vstack([cv2.getRotationMatrix2D((300.0, 300.0), degrees, 1.0), [0, 0, 1]])   # pixels of j -> i
    i = _rooms(degrees)
    keep = cv2.warpAffine(np.pad(np.ones((250, 330), np.uint8), ((90, 260), (90, 180))), turn[:2], (600, 600),
                          flags=cv2.INTER_NEAREST) > 0
    i[~keep] = -1
    pi, pj = (prepare(Grid(w, RES), RES, None) for w in (i, j))
    # prepare crops each grid to its known cells: a cell's centre in metres, then the working pixel of the crop
    of_cell = np.array([[RES, 0, RES / 2], [0, RES, RES / 2], [0, 0, 1.0]])
    to_i, to_j = (np.linalg.inv(p.px_to_map) @ of_cell for p in (pi, pj))
    truth = to_j @ tf.inverse(turn) @ np.linalg.inv(to_i)
    return pi, pj, truth


def _sweep(pi, pj):
    return search.rotation_candidates(search.coarse(pi, 4), search.coarse(pj, 4), 3.0)


def _turn_off_degrees(angle, true_angle):
    return abs(_off_degrees(angle, true_angle))


def test_the_sweep_keeps_its_angles_about_the_turns_where_the_families_meet():
    pi, pj, truth = _part_turned(23.4)
    true_angle = math.degrees(math.atan2(truth[1, 0], truth[0, 0]))
    sweep = _sweep(pi, pj)
    kept = orientation.near_turns(pi, pj, sweep)
    assert set(kept) <= set(sweep) and len(kept) < len(sweep) / 3
    # every angle within the window of a quarter turn of the truth is kept, none beyond it and the spreads
    window = orientation.TURN_WINDOW_DEGREES
    assert [a for a in sweep if _turn_off_degrees(a, true_angle) <= window - 0.1] == \
        [a for a in kept if _turn_off_degrees(a, true_angle) <= window - 0.1]
    assert all(_turn_off_degrees(a, true_angle) <= window + 0.5 for a in kept)


def test_without_families_the_sweep_keeps_every_angle():
    pi, pj, _ = _part_turned(23.4)
    cave = prepare(Grid(_round_hall(), RES), RES, None)
    assert orientation.near_turns(cave, pj, _sweep(cave, pj)) == _sweep(cave, pj)


def test_the_search_screens_only_the_angles_about_the_turns(monkeypatch):
    """A part of a floor turned 23.4 degrees, searched onto the whole floor: the screen correlates only the sweep's
    angles about the turns, and the search's candidates hold the truth, as with every angle."""
    pi, pj, truth = _part_turned(23.4)
    h, w = pi.work.shape
    corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]])

    def near_truth(found):   # within 1.5 degrees and 12 pixels (3 of the search's) at i's corners
        return any(rot < math.radians(1.5) and moved < 12
                   for rot, moved in (tf.difference(t, truth, corners) for t in found))

    correlated = []
    real = search._correlate
    monkeypatch.setattr(search, '_correlate', lambda *a, **k: correlated.append(a[9]) or real(*a, **k))
    assert near_truth(search.correlate_candidates(pi, pj))
    assert correlated[0] == orientation.near_turns(pi, pj, _sweep(pi, pj))   # the screen's angles
    correlated.clear()
    monkeypatch.setattr(search, 'near_turns', lambda pi, pj, angles: list(angles))
    assert near_truth(search.correlate_candidates(pi, pj))   # every angle
    assert len(correlated[0]) == len(_sweep(pi, pj))
