"""explore in large buildings: ~path_distance (frontiers ranked by their distance along free space), the progress
clock of a goal area that the robot leaves and comes back to (the two causes of goal thrashing), and the team map's
frontiers, ranked together with the robot's own."""
import math

import numpy as np
import pytest

from explore.costmap import FREE_SPACE, LETHAL_OBSTACLE, NO_INFORMATION, translation_table
from explore.coverage import KnownRaster
from explore.frontier_search import Frontier, frontier_cost, search_frontiers
from explore.goal_logic import GoalLogic, PlanAction
from explore.team import costmap_known_at, team_frontiers
from multirobot_map_merge import transforms as tf
from multirobot_map_merge.grid import Grid

RES = 0.5


def wall_between():
    """A room split by a wall with a gap at its far end (x = 18); the robot at x = 2 just below the wall.
    Above the wall, near in a straight line but far round the wall: a frontier at the left (x = 0..2, y = 8);
    below it, farther in a straight line but straight ahead: a frontier at the right end (x = 19, y = 1..3)."""
    d = np.full((9, 20), LETHAL_OBSTACLE, np.uint8)
    d[1:8, 1:19] = FREE_SPACE
    d[4, 1:17] = LETHAL_OBSTACLE          # the wall; the gap is x = 17, 18
    d[8, 1:4] = NO_INFORMATION             # frontier above the wall, near the robot's x
    d[1:4, 19] = NO_INFORMATION            # frontier below the wall, at the far right
    return d


def by_position(found):
    return {('up' if f.initial[1] > 3.0 else 'right'): f for f in found}


def test_straight_line_is_the_default():
    found = by_position(search_frontiers(wall_between(), RES, (0.0, 0.0), (2, 3), 1.0, 0.0, 0.0))
    robot = np.array([2.5 * RES, 3.5 * RES])
    for f in found.values():
        assert f.min_distance == pytest.approx(np.hypot(*(f.points - robot).T).min())
    assert found['up'].min_distance < found['right'].min_distance


def test_path_distance_goes_round_the_wall():
    d = wall_between()
    found = search_frontiers(d, RES, (0.0, 0.0), (2, 3), 1.0, 0.0, 0.0, path_distance=True)
    f = by_position(found)
    # round the wall: right along y = 3 to x = 17, up to y = 7, back left: far more than the straight line
    assert f['up'].min_distance >= RES * ((17 - 2) + (7 - 3) + (17 - 3)) - 1e-9
    # 4-connected steps: the right frontier's cell at y = 3 lies 17 steps straight ahead, but it is the seed
    # (left out of min_distance, as the original); the next one, at y = 2, one step more
    assert f['right'].min_distance == pytest.approx(RES * (19 - 2 + 1))
    assert found[0] is f['right']                  # nearest along free space first (distance only)
    assert all(g.cost == frontier_cost(g.min_distance, g.size, RES, 1.0, 0.0) for g in found)
    # the same groups, sizes and centroids as the straight-line search: only distances differ
    plain = by_position(search_frontiers(d, RES, (0.0, 0.0), (2, 3), 1.0, 0.0, 0.0))
    for k in f:
        assert (f[k].size, f[k].centroid) == (plain[k].size, plain[k].centroid)
        assert tuple(f[k].middle) in {tuple(p) for p in f[k].points}


def test_path_distance_shrinks_as_the_robot_drives_round():
    """Driving towards the far side of the wall brings the frontier above it nearer along free space (in a
    straight line it first gets farther): the choice does not flip back and forth."""
    d = wall_between()
    dist = [by_position(search_frontiers(d, RES, (0.0, 0.0), (x, 3), 1.0, 0.0, 0.0, path_distance=True))
            ['up'].min_distance for x in (2, 6, 10, 14)]
    assert dist == sorted(dist, reverse=True) and dist[0] > dist[-1]


def frontier(x, y, min_distance, cost=0.0):
    return Frontier(size=10, min_distance=min_distance, cost=cost, initial=(x, y), centroid=(x, y), middle=(x, y),
                    points=np.zeros((9, 2)))


def test_switching_back_and_forth_does_not_restart_the_clock():
    """Two goals chosen in turn, neither getting nearer: the original restarts the timeout at every switch and
    never gives up; here each area's clock runs while it is pursued, so one of them is blacklisted."""
    logic = GoalLogic(progress_timeout=30.0)
    a, b = frontier(2.0, 2.0, 3.0), frontier(9.0, 9.0, 5.0)
    t, blacklisted = 0.0, []
    for k in range(60):
        res = logic.plan([a, b] if k % 2 == 0 else [b, a], RES, t)
        blacklisted += res.blacklisted
        if blacklisted:
            break
        assert res.action is PlanAction.SEND_GOAL
        t += 4.0
    assert len(blacklisted) == 1 and res.action is PlanAction.SEND_GOAL    # the other one is pursued alone now
    assert 60.0 <= t <= 72.0         # 30 s of pursuit of each, plus one plan period
    kept = res.target
    assert all(logic.plan([a, b], RES, t + dt).target == kept for dt in (2.0, 20.0))   # its clock starts afresh


def test_an_area_left_for_longer_than_the_timeout_starts_afresh():
    logic = GoalLogic(progress_timeout=30.0)
    a, b = frontier(2.0, 2.0, 3.0), frontier(9.0, 9.0, 5.0, cost=-1.0)
    logic.plan([a], RES, 0.0)
    logic.plan([a], RES, 25.0)                     # 25 s on a without progress
    for t in range(27, 90, 2):                     # then b for a long while (getting nearer)
        assert logic.plan([b], RES, float(t)).blacklisted == []
        b = frontier(9.0, 9.0, b.min_distance - 0.01, cost=-1.0)
    # back to a after more than progress_timeout: a new pursuit, not 25 s already used
    assert logic.plan([a], RES, 100.0).action is PlanAction.SEND_GOAL
    assert logic.plan([a], RES, 125.0).action is PlanAction.KEEP_GOAL
    res = logic.plan([a], RES, 131.0)
    assert res.blacklisted == [a.centroid]


# ---- the team map's frontiers: the part of the building only teammates' maps show -------------------------------

def team_grid():
    """A corridor 10 m x 1 m (0.1 m cells) known free up to x = 6 m in the team frame, unknown beyond; its
    origin rotated by 90 degrees to check the frames."""
    data = np.full((10, 100), -1, np.int8)
    data[:, :60] = 0
    return Grid(data, 0.1, (5.0, 1.0, math.pi / 2), 'world')


def test_team_frontiers_are_found_in_the_team_map_and_given_in_the_own_frame():
    grid = team_grid()
    own_from_team = tf.inverse(tf.rigid(2.0, -1.0, 0.3))         # the robot's map frame in the team frame
    robot_team = tuple(tf.apply(grid.cell_to_map(), np.array([[10.5, 5.5]]))[0])   # 1 m into the corridor
    (f,) = team_frontiers(grid, translation_table(), robot_team, own_from_team, 1.0, 0.0, 0.5, True)
    # the frontier is the first unknown column (x = 6.0..6.1 m along the corridor): back to grid cells
    cells = tf.apply(np.linalg.inv(own_from_team @ grid.cell_to_map()), f.points)
    assert np.all(np.floor(cells[:, 0]) == 60) and f.size == 10
    assert f.min_distance == pytest.approx(0.1 * (60 - 10 + 1), abs=0.15)   # along the corridor
    centroid_cell = tf.apply(np.linalg.inv(own_from_team @ grid.cell_to_map()), np.array([f.centroid]))[0]
    # the true centroid, in the middle of the frontier's column (the original's quirk would pull it far off,
    # towards the grid's corner)
    assert centroid_cell == pytest.approx((60.5, 5.0))


def test_team_frontiers_the_own_map_contradicts_are_left_out():
    grid = team_grid()
    robot_team = tuple(tf.apply(grid.cell_to_map(), np.array([[10.5, 5.5]]))[0])
    everything_known = lambda pts: np.ones(len(pts), bool)      # noqa: E731  the own map saw beyond already
    nothing_known = lambda pts: np.zeros(len(pts), bool)        # noqa: E731
    assert team_frontiers(grid, translation_table(), robot_team, np.eye(3), 1.0, 0.0, 0.5, True,
                          everything_known) == []
    assert len(team_frontiers(grid, translation_table(), robot_team, np.eye(3), 1.0, 0.0, 0.5, True,
                              nothing_known)) == 1
    outside = (-50.0, -50.0)
    assert team_frontiers(grid, translation_table(), outside, np.eye(3), 1.0, 0.0, 0.5, True) == []


def test_costmap_known_at_reads_the_own_map():
    data = np.full((4, 4), NO_INFORMATION, np.uint8)
    data[0, 0], data[3, 3] = FREE_SPACE, LETHAL_OBSTACLE
    known_at = costmap_known_at(data, 0.5, (1.0, 1.0))
    pts = np.array([[1.2, 1.2], [2.7, 2.7], [1.7, 1.2], [0.0, 0.0]])
    assert known_at(pts).tolist() == [True, True, False, False]


def test_known_raster_values_place_the_occupancy():
    data = np.array([[0, 100], [-1, 0]], np.int8)               # 2 x 2 cells of 1 m, row 0 lowest y
    grid = Grid(data, 1.0, (0.0, 0.0, 0.0), 'map')
    raster = KnownRaster.box((0.0, 0.0, 6.0, 6.0), 1.0)
    out = raster.values(grid, (2.0, 3.0, 0.0))                  # the map's frame at (2, 3) in the world
    assert out.dtype == np.int8 and out.shape == (6, 6)
    assert out[3:5, 2:4].tolist() == data.tolist()
    assert np.count_nonzero(out != -1) == 3                      # -1 wherever the map has no (known) cell
    assert (raster.values(grid, (2.0, 3.0, 0.0)) >= 0).tolist() == raster.known(grid, (2.0, 3.0, 0.0)).tolist()


def _frontier(x, cost, size=10, min_distance=1.0):
    return Frontier(size=size, min_distance=min_distance, cost=cost, initial=(x, 0.0), centroid=(x, 0.0),
                    middle=(x, 0.0), points=np.zeros((size - 1, 2)))


def test_team_frontiers_rank_with_the_own_by_cost():
    """A large unexplored part that only the team map shows outranks a small leftover of the robot's own map (the
    robot does not finish every leftover near it while one teammate explores the rest of the building alone)."""
    from explore.team import rank_with_team
    scrap = _frontier(1.0, cost=-0.5, size=15, min_distance=2.0)
    own_big = _frontier(3.0, cost=-4.0, size=90, min_distance=3.0)
    wing = _frontier(30.0, cost=-10.0, size=300, min_distance=30.0)
    tie = _frontier(9.0, cost=-4.0)
    assert rank_with_team([own_big, scrap], [wing, tie]) == [wing, own_big, tie, scrap]   # own first on a tie
    nan = _frontier(5.0, cost=math.nan)
    assert rank_with_team([nan, scrap], []) == [scrap, nan]
    assert rank_with_team([], []) == []
