"""The merge overlay: each robot's map in its own colour at its placement, walls over tints, and the legend."""
import subprocess
import sys
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.grid import Grid
from multirobot_map_merge.overlay import (BACKGROUND, colour, overlay_path, render_overlay, save_overlay,
                                          used_pairs)


def room(shift_cols=0):
    data = np.full((40, 60), -1, np.int8)
    data[5:35, 5 + shift_cols:55] = 0
    data[5, 5 + shift_cols:55] = 100
    return Grid(data, 0.1)


def test_each_map_is_drawn_in_its_colour_where_it_is_placed():
    a, b = room(), room()
    # b placed 10 m to the right of a: two separate rooms, a on the left in a's colour, b on the right in b's
    img = render_overlay([a, b], [np.eye(3), tf.rigid(10.0, 0.0, 0.0)], ['a', 'b'])
    maps = img[:, :160]
    left, right = maps[:, :60].reshape(-1, 3), maps[:, 100:160].reshape(-1, 3)
    for part, mine, other in ((left, colour(0), colour(1)), (right, colour(1), colour(0))):
        assert (part == mine).all(axis=1).sum() > 100          # its walls
        assert not (part == other).all(axis=1).any()
    # free space is tinted (neither the background nor white nor the full colour)
    centre = maps[20, 30]   # the grid is 40 rows high (the legend may pad the picture below)
    assert tuple(centre) != BACKGROUND and tuple(centre) != colour(0) and not (centre == 255).all()
    # +y up: the wall at row 5 of the grid (low y) is near the bottom of the picture
    rows = np.nonzero((maps[:, :60] == colour(0)).all(axis=2))[0]
    assert rows.mean() > 20


def test_walls_go_over_other_maps_tints():
    a, b = room(), room()
    img = render_overlay([a, b], [np.eye(3), np.eye(3)], ['a', 'b'])
    # b's walls (drawn last) coincide with a's: the wall row is in b's colour, not hidden by a's tint
    assert (img[:, :60] == colour(1)).all(axis=2).sum() > 100


def test_legend_lists_excluded_robots_and_used_pairs():
    a, b, c = room(), room(), room()
    pairs = used_pairs([SimpleNamespace(i=0, j=1, accepted=True, confidence=2.5),
                        SimpleNamespace(i=1, j=2, accepted=True, confidence=1.7),
                        SimpleNamespace(i=0, j=2, accepted=False, confidence=0.4)],
                       [np.eye(3), np.eye(3), None])
    assert [(p.a, p.b, p.confidence) for p in pairs] == [(0, 1, 2.5)]
    with_c = render_overlay([a, b, c], [np.eye(3), np.eye(3), None], ['a', 'b', 'c'], pairs)
    without = render_overlay([a, b, c], [np.eye(3), np.eye(3), np.eye(3)], ['a', 'b', 'c'])
    assert with_c.shape[1] > without.shape[1]     # the legend is wider: "c (excluded)", the pair line
    # the legend shows each robot's colour swatch
    legend = with_c[:, 60:]
    for k in range(3):
        assert (legend == colour(k)).all(axis=2).sum() >= 100


def test_nothing_placed_still_gives_a_picture_and_bad_lengths_are_refused():
    img = render_overlay([room()], [None], ['a'])
    assert img.ndim == 3 and img.shape[0] >= 200
    with pytest.raises(ValueError):
        render_overlay([room()], [np.eye(3)], ['a', 'b'])


def test_saved_overlay_is_a_colour_png(tmp_path):
    path = save_overlay(str(tmp_path / 'x_overlay.png'), [room()], [np.eye(3)], ['a'])
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    assert img.ndim == 3 and img.shape[2] == 3
    assert overlay_path('/a/merged.png') == '/a/merged_overlay.png' and overlay_path('m') == 'm_overlay.png'


def test_merge_maps_writes_the_overlay_beside_the_preview(repo_root, tmp_path):
    maps = sorted(str(p) for p in (repo_root / 'data' / 'samples' / 'chain3').glob('map_*.yaml'))
    proc = subprocess.run([sys.executable, str(repo_root / 'nodes' / 'merge_maps'), '--output', str(tmp_path / 'm'),
                           '--png', str(tmp_path / 'preview.png'), *maps],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    img = cv2.imread(str(tmp_path / 'preview_overlay.png'))
    grey = cv2.imread(str(tmp_path / 'preview.png'), cv2.IMREAD_UNCHANGED)
    assert img is not None and grey.ndim == 2
    # every map's wall colour appears: all three were placed
    for k in range(3):
        assert (img == colour(k)).all(axis=2).sum() > 200
    # not a terminal: no progress line in the output
    assert '\r' not in proc.stderr


def test_named_overlay_places_by_pose_and_excludes_robots_without_one(tmp_path):
    from multirobot_map_merge.overlay import save_named_overlay
    maps = {'robot_2': room(), 'robot_1': room(), 'robot_3': room()}
    path = save_named_overlay(str(tmp_path / 'o.png'), maps, {'robot_1': (0.0, 0.0, 0.0), 'robot_2': (10.0, 0.0, 0.0)},
                              [('robot_1', 'robot_2', 2.0), ('robot_1', 'ghost', 1.0)])
    img = cv2.imread(path)
    # name order: robot_1 colour 0 on the left, robot_2 colour 1 on the right, robot_3 excluded (swatch only)
    assert (img[:, :60] == colour(0)).all(axis=2).sum() > 100
    assert (img[:, 100:160] == colour(1)).all(axis=2).sum() > 100
    assert (img[:, :160] == colour(2)).all(axis=2).sum() == 0
