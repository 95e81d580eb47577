"""explore node helpers: threshold translation (the node's default), team goals, coverage, frontier markers."""
import math

import numpy as np
import pytest

from explore.costmap import (FREE_SPACE, LETHAL_OBSTACLE, NO_INFORMATION, Costmap, translate,
                             translation_table)
from explore.coverage import explored_share, reachable_mask
from explore.frontier_search import Frontier, FrontierSearch
from explore.team import TeamGoals
from multirobot_map_merge.grid import Grid


# ---- translation by threshold --------------------------------------------------------------------------------------

def test_threshold_table_keeps_the_ramp_between_thresholds():
    t = translation_table(by_threshold=True, free_threshold=20, occupied_threshold=70)
    orig = translation_table()
    assert (t[:21] == FREE_SPACE).all() and (t[70:101] == LETHAL_OBSTACLE).all()
    # in between: the original's ramp, neither free nor unknown
    assert (t[21:70] == orig[21:70]).all() and not ((t[21:70] == 0) | (t[21:70] == 255)).any()
    assert t[255] == NO_INFORMATION and (t[101:255] == orig[101:255]).all()
    # free_threshold 0: only exact 0 is free, as the original
    t0 = translation_table(by_threshold=True, free_threshold=0)
    assert ((t0 == 0) == (orig == 0)).all() and ((t0 == 255) == (orig == 255)).all()


def test_threshold_mode_leaves_ternary_maps_unchanged():
    occ = np.random.default_rng(4).choice(np.array([-1, 0, 100], np.int8), size=300)
    assert (translate(occ, translation_table(by_threshold=True)) == translate(occ)).all()


def test_threshold_mode_finds_frontiers_of_a_probability_map():
    occ = np.full((30, 30), -1, np.int8)
    occ[5:20, 5:20] = 12          # observed room, 'free' with probability values
    occ[5:20, 19] = 45            # uncertain rim on the right: neither free nor unknown here
    found = {}
    for by_threshold in (False, True):
        cm = Costmap(by_threshold=by_threshold)
        cm.update_full(30, 30, 0.1, 0.0, 0.0, occ.ravel(), 'map')
        found[by_threshold] = FrontierSearch(cm, 1e-3, 1.0, 0.5).search_from(1.0, 1.0)
    assert found[False] == []
    xs = np.concatenate([f.points[:, 0] for f in found[True]])
    ys = np.concatenate([f.points[:, 1] for f in found[True]])
    # frontiers on the left (x 0.45), bottom (y 0.45) and top (y 2.05) edges; the rim on the right is not one
    assert np.isclose(xs, 0.45).any() and np.isclose(ys, 0.45).any() and np.isclose(ys, 2.05).any()
    assert not (xs > 1.9).any()


# ---- team goals ----------------------------------------------------------------------------------------------------

def test_team_goals_store_latest_per_sender_and_ignore_own():
    team = TeamGoals('/robot_1/explore')
    assert not team.update('/robot_1/explore', (1.0, 1.0), 5.0, 5.0)
    team.update('/robot_2/explore', (1.0, 1.0), 5.0, 5.0)
    team.update('/robot_2/explore', (4.0, 1.0), 6.0, 6.0)
    team.update('/robot_3/explore', (9.0, 9.0), 6.0, 6.0)
    assert [(g.sender, g.point) for g in team.active(10.0)] == [('/robot_2/explore', (4.0, 1.0)),
                                                               ('/robot_3/explore', (9.0, 9.0))]
    team.update('/robot_3/explore', None, 7.0, 7.0)   # withdrawn
    assert team.senders() == ['/robot_2/explore']
    assert not team.update('/robot_2/explore', (math.nan, 0.0), 8.0, 8.0)


def test_team_goals_go_stale():
    team = TeamGoals('/a', stale_after=10.0)
    team.update('/b', (1.0, 1.0), 0.0, 0.0)
    assert len(team.active(10.0)) == 1
    assert team.active(10.5) == [] and team.senders() == []


def test_later_goal_near_own_goal_yields():
    """Two robots heading for the same area: the one that chose first keeps its goal, the other moves on."""
    a, b = TeamGoals('/a'), TeamGoals('/b')
    a.update('/b', (5.2, 5.0), 20.0, 21.0)   # b chose at t=20
    b.update('/a', (5.0, 5.0), 10.0, 21.0)   # a chose at t=10
    # a chose first: a ignores b's goal near its own, b counts a's goal (and is penalised there)
    assert a.active(22.0, own_goal=(5.0, 5.0), own_chosen_at=10.0, radius=3.0) == []
    assert [g.sender for g in b.active(22.0, own_goal=(5.2, 5.0), own_chosen_at=20.0, radius=3.0)] == ['/a']
    # far from the own goal, every teammate goal counts
    assert len(a.active(22.0, own_goal=(50.0, 5.0), own_chosen_at=10.0, radius=3.0)) == 1
    # equal times: the larger name yields
    a2, b2 = TeamGoals('/a'), TeamGoals('/b')
    a2.update('/b', (5.0, 5.0), 10.0, 10.0)
    b2.update('/a', (5.0, 5.0), 10.0, 10.0)
    assert a2.active(11.0, (5.0, 5.0), 10.0, 3.0) == [] and len(b2.active(11.0, (5.0, 5.0), 10.0, 3.0)) == 1


def test_nearer_robot_keeps_a_contested_goal_whoever_chose_first():
    """Two robots heading for the same area with known remaining distances: the nearer one keeps it although the
    other chose first, and both agree (exactly one of them counts the other's goal)."""
    a, b = TeamGoals('/a'), TeamGoals('/b')
    a.update('/b', (5.2, 5.0), 20.0, 21.0, distance=2.0)    # b chose later but is 2 m away
    b.update('/a', (5.0, 5.0), 10.0, 21.0, distance=30.0)   # a chose first, 30 m away
    assert [g.sender for g in a.active(22.0, (5.0, 5.0), 10.0, 3.0, own_distance=30.0)] == ['/b']
    assert b.active(22.0, (5.2, 5.0), 20.0, 3.0, own_distance=2.0) == []


@pytest.mark.parametrize('missing', [math.inf, math.nan, -1.0])
def test_unknown_distance_falls_back_to_who_chose_first(missing):
    a, b = TeamGoals('/a'), TeamGoals('/b')
    a.update('/b', (5.2, 5.0), 20.0, 21.0, distance=2.0)
    b.update('/a', (5.0, 5.0), 10.0, 21.0, distance=missing)   # a sent no usable distance
    assert a.active(22.0, (5.0, 5.0), 10.0, 3.0) == []         # a chose first and keeps it
    assert [g.sender for g in b.active(22.0, (5.2, 5.0), 20.0, 3.0, own_distance=2.0)] == ['/a']


# ---- coverage ------------------------------------------------------------------------------------------------------

def _world():
    data = np.full((40, 60), 100, np.int8)
    data[1:-1, 1:29] = 0        # left room
    data[1:-1, 31:-1] = 0       # right room, closed off: unreachable from the left
    return Grid(data, 0.1, (2.0, 3.0, 0.0), 'world')


def test_reachable_is_the_start_component():
    world = _world()
    m = reachable_mask(world, [(2.5, 3.5)])
    assert m.sum() == 38 * 28 and not m[:, 31:].any()
    assert reachable_mask(world, [(0.0, 0.0)]).sum() == 0                      # outside the world
    assert reachable_mask(world, [(2.5, 3.5), (5.5, 3.5)]).sum() == 2 * 38 * 28


@pytest.mark.parametrize('yaw', [0.0, math.pi / 2])
def test_explored_share_places_maps_by_their_pose(yaw):
    world = _world()
    reach = reachable_mask(world, [(2.5, 3.5)])
    # a robot map covering the left half of the left room, in a frame at world pose (2.0, 3.0, yaw)
    known = np.zeros((38, 14), np.int8)
    # the map's grid origin, expressed in its own frame, puts its cells on world cells (1..14, 1..38)
    ox, oy = 0.1, 0.1
    grid = Grid(known if yaw == 0.0 else known.T.copy(), 0.1,
                (ox, oy, 0.0) if yaw == 0.0 else (oy, -ox - 1.4, 0.0), 'robot/map')
    share = explored_share(world, reach, [(grid, (2.0, 3.0, yaw))])
    assert share == pytest.approx(0.5)
    unknown = Grid(np.full(grid.data.shape, -1, np.int8), 0.1, grid.origin)
    assert explored_share(world, reach, [(unknown, (2.0, 3.0, yaw))]) == 0.0
    assert explored_share(world, reach, [(grid, (2.0, 3.0, yaw)), (unknown, (0.0, 0.0, 0.0))]) == share


# ---- markers -------------------------------------------------------------------------------------------------------

def test_frontier_markers_ids_colours_and_deletes():
    pytest.importorskip('visualization_msgs')
    from visualization_msgs.msg import Marker

    from explore.markers import frontier_markers

    def fr(x, cost):
        return Frontier(size=3, min_distance=1.0, cost=cost, initial=(x, 0.0), centroid=(x, 0.0), middle=(x, 0.0),
                        points=np.array([[x, 0.0], [x, 0.1]]))
    fs = [fr(1.0, -2.0), fr(2.0, -1.0)]
    arr = frontier_markers(fs, 'map', 0, lambda f: f.centroid[0] == 2.0, last_count=6)
    ms = arr.markers
    assert [m.id for m in ms] == [0, 1, 2, 3, 4, 5]
    assert [m.action for m in ms] == [Marker.ADD] * 4 + [Marker.DELETE] * 2
    assert ms[0].type == Marker.POINTS and ms[1].type == Marker.SPHERE
    assert (ms[0].color.b, ms[2].color.r) == (1.0, 1.0)          # blue, red = blacklisted
    assert ms[1].scale.x == pytest.approx(0.4) and ms[3].scale.x == pytest.approx(0.5)  # min(|-2·0.4/-1|, 0.5)
    assert len(ms[0].points) == 2 and all(m.header.frame_id == 'map' and m.ns == 'frontiers' for m in ms)


# ---- frontiers already mapped by the team --------------------------------------------------------------------------

def _half_known_costmap():
    """20x20 cells of 0.1 m: the left half (x < 1 m) is free, the right half unknown: one frontier at x 1.0-1.1."""
    occ = np.full((20, 20), -1, np.int8)
    occ[:, :10] = 0
    cm = Costmap(by_threshold=True)
    cm.update_full(20, 20, 0.1, 0.0, 0.0, occ.ravel(), 'robot/map')
    return cm, FrontierSearch(cm, 1e-3, 1.0, 0.5).search_from(0.5, 1.0)


def test_beyond_points_lie_three_cells_past_the_frontier():
    from explore.team import beyond_points
    cm, frontiers = _half_known_costmap()
    assert len(frontiers) == 1
    pts = beyond_points(frontiers[0].points, cm.data, cm.resolution, (cm.origin_x, cm.origin_y))
    assert len(pts) == len(frontiers[0].points) and np.allclose(pts[:, 0], 1.35)


@pytest.mark.parametrize('yaw', [0.0, 1.0])
def test_frontier_dropped_only_when_the_team_has_mapped_beyond_it(yaw):
    from explore.team import drop_explored_by_team, grid_known_at, known_by_team
    cm, frontiers = _half_known_costmap()
    c, s = math.cos(yaw), math.sin(yaw)
    team_from_map = np.array([[c, -s, 5.0], [s, c, 2.0], [0.0, 0.0, 1.0]])

    def team_map(known_below_x):
        """A team map, in the team frame, knowing every point whose robot-map x is below known_below_x."""
        grid = Grid(np.full((120, 120), -1, np.int8), 0.05, (3.0, 0.0, 0.0), 'world')
        cols, rows = np.meshgrid(np.arange(120), np.arange(120))
        pts = grid.cell_to_map() @ np.vstack([cols.ravel() + 0.5, rows.ravel() + 0.5, np.ones(cols.size)])
        in_map = np.linalg.inv(team_from_map) @ pts
        grid.data[(in_map[0] < known_below_x).reshape(120, 120)] = 0
        return grid

    args = (cm.data, cm.resolution, (cm.origin_x, cm.origin_y))
    # the teammate mapped the whole right side: nothing left to explore here
    seen = grid_known_at(team_map(2.0), team_from_map)
    assert known_by_team(frontiers[0], *args, seen) == 1.0
    assert drop_explored_by_team(frontiers, *args, seen) == []
    # the team map knows the frontier cells and two cells beyond (e.g. this robot's own map, placed a cell off):
    # that is no evidence of a teammate having been there
    near = grid_known_at(team_map(1.3), team_from_map)
    assert known_by_team(frontiers[0], *args, near) == 0.0
    assert drop_explored_by_team(frontiers, *args, near) == frontiers
