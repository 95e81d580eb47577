"""fleet_sim pure core beyond the world/laser/mapping basics: parameters, planner, motion, the move_base stand-in,
the simulation loop, the fast laser and the map messages (no ROS master)."""
import io
import math

import numpy as np
import pytest

from fleet_sim.laser import beam_angles, cast, cast_stepwise
from fleet_sim.mapping import LogOddsMap, relative_pose
from fleet_sim.motion import Clearance, FollowerConfig, PathFollower, integrate, path_blocked_index, \
    step_with_collision, values_occupied
from fleet_sim.params import FleetSimParams, ParamError, describe
from fleet_sim.planner import PlannerConfig, plan_path
from fleet_sim.robot import ABORTED, ACTIVE, SUCCEEDED
from fleet_sim.sim import FleetSim
from fleet_sim.world import make_floor_plan
from multirobot_map_merge.grid import Grid

RES = 0.05


def box_map(w=80, h=60, walls=()):
    """A known-free map with a wall border and extra wall rectangles (c0, r0, c1, r1), origin (-1, -1)."""
    v = np.zeros((h, w), np.int8)
    v[0, :] = v[-1, :] = v[:, 0] = v[:, -1] = 100
    for c0, r0, c1, r1 in walls:
        v[r0:r1, c0:c1] = 100
    return v, (-1.0, -1.0, 0.0)


def cell_xy(origin, c, r):
    return origin[0] + (c + 0.5) * RES, origin[1] + (r + 0.5) * RES


# ---------------------------------------------------------------- parameters

def test_params_defaults_and_types():
    p = FleetSimParams.from_mapping({})
    assert p.num_robots == 1 and p.robots == [] and p.speedup == 1.0 and p.map_rate == 1.0
    assert FleetSimParams.from_mapping({'speedup': 10}).speedup == 10.0        # int accepted for a double
    names = [d.name for d in describe()]
    assert {'world', 'world_seed', 'robots', 'num_robots', 'seed', 'map_frame', 'base_frame', 'resolution', 'n_beams',
            'max_range', 'range_noise', 'map_rate', 'update_rate', 'linear_speed', 'angular_speed', 'robot_radius',
            'speedup', 'publish_scan'} <= set(names)
    assert all(d.doc for d in describe())


@pytest.mark.parametrize('values, words', [
    ({'speedup': 0.0}, 'speedup'),
    ({'map_rate': -1.0}, 'map_rate'),
    ({'n_beams': 0}, 'n_beams'),
    ({'num_robots': 'three'}, 'num_robots'),
    ({'publish_scan': 1}, 'publish_scan'),
    ({'robots': [{'ns': 'a', 'x': 1.0}]}, 'robots[0].y'),
    ({'robots': [{'ns': 'a b', 'x': 1.0, 'y': 1.0}]}, 'namespace'),
    ({'robots': [{'ns': 'a', 'x': 1.0, 'y': 1.0}, {'ns': 'a', 'x': 2.0, 'y': 1.0}]}, 'unique'),
    ({'robots': [{'x': 1.0, 'y': 1.0, 'z': 0.0}]}, 'unknown keys'),
    ({'resolution': float('nan')}, 'finite'),
])
def test_bad_params_are_refused_with_their_name(values, words):
    with pytest.raises(ParamError, match=words.replace('[', r'\[').replace(']', r'\]')):
        FleetSimParams.from_mapping(values)


def test_robot_specs_default_namespaces():
    p = FleetSimParams.from_mapping({'robots': [{'x': 1, 'y': 2}, {'ns': '/scout', 'x': 3.0, 'y': 4.0, 'yaw': 1.0}]})
    specs = p.robot_specs(None)
    assert [s.ns for s in specs] == ['robot_1', 'scout']
    assert (specs[1].x, specs[1].y, specs[1].yaw) == (3.0, 4.0, 1.0)


def test_bad_world_and_start_pose_stop_the_simulator(tmp_path):
    with pytest.raises(ParamError, match='cannot load'):
        FleetSim(FleetSimParams.from_mapping({'world': str(tmp_path / 'missing.yaml')}))
    world = make_floor_plan(4, 14.0, 10.0)
    inside_wall = (0.5 * (world.extra['rooms'][0][0] + world.extra['rooms'][0][2]), world.extra['rooms'][0][1] - 0.02)
    with pytest.raises(ParamError, match='inside a wall'):
        FleetSim(FleetSimParams.from_mapping({'world_seed': 4, 'world_width': 14.0, 'world_height': 10.0,
                                              'robots': [{'x': inside_wall[0], 'y': inside_wall[1]}]}), world)
    with pytest.raises(ParamError, match='outside'):
        FleetSim(FleetSimParams.from_mapping({'robots': [{'x': -50.0, 'y': 0.0}]}), world)


# ---------------------------------------------------------------- planner

def path_clearance(values, origin, path):
    """Smallest distance (m) from path points to occupied cell centres."""
    rows, cols = np.nonzero(values >= 50)
    occ = np.c_[origin[0] + (cols + 0.5) * RES, origin[1] + (rows + 0.5) * RES]
    return min(np.hypot(*(occ - p).T).min() for p in path)


def test_plan_goes_around_a_wall_and_keeps_clear():
    v, o = box_map(walls=[(38, 0, 42, 45)])          # a wall from the bottom, gap at the top
    start, goal = cell_xy(o, 15, 15), cell_xy(o, 65, 15)
    res = plan_path(v, RES, o, start, goal)
    assert res.path is not None, res.reason
    p = res.path
    assert np.allclose(p[0], start) and np.allclose(p[-1], goal)
    assert p[:, 1].max() > o[1] + 45 * RES            # over the wall's end
    assert path_clearance(v, o, p[1:-1]) >= 0.2        # robot radius (lethal distance 0.25 at cell centres)
    # steps between consecutive points are short (a connected path)
    assert np.hypot(*np.diff(p, axis=0).T).max() < 0.2
    length = np.hypot(*np.diff(p, axis=0).T).sum()
    assert length < 1.3 * (2 * (45 * RES - 15 * RES) + 50 * RES)


def test_unknown_space_is_traversable_but_walls_are_not():
    v = np.full((60, 80), -1, np.int8)                # nothing known
    o = (-1.0, -1.0, 0.0)
    assert plan_path(v, RES, o, cell_xy(o, 10, 10), cell_xy(o, 70, 50)).path is not None
    v[:, 40] = 100                                     # a full-height wall, nothing around the map is known
    res = plan_path(v, RES, o, cell_xy(o, 10, 10), cell_xy(o, 70, 50))
    assert res.path is not None                        # around the map edge, through unknown space (pad)
    assert (res.path[:, 1] > o[1] + 60 * RES).any() or (res.path[:, 1] < o[1]).any()


def test_goal_in_wall_enclosed_or_too_close_is_refused():
    v, o = box_map(walls=[(45, 10, 75, 55)])
    v[17:48, 52:68] = 0                                 # a free pocket 0.8 m wide inside the block: enclosed
    start = cell_xy(o, 15, 15)
    r = plan_path(v, RES, o, start, cell_xy(o, 47, 30))
    assert r.path is None and 'obstacle' in r.reason
    r = plan_path(v, RES, o, start, cell_xy(o, 60, 32))
    assert r.path is None and 'no path' in r.reason, r.reason
    # 0.15 m from the block: the goal cell is lethal but free cells within goal_tolerance are reachable
    goal = cell_xy(o, 42, 30)
    r = plan_path(v, RES, o, start, goal)
    assert r.path is not None, r.reason
    assert 0.0 < math.hypot(*(r.path[-1] - goal)) <= PlannerConfig().goal_tolerance + 1e-9
    r = plan_path(v, RES, o, start, goal, PlannerConfig(goal_tolerance=0.0))
    assert r.path is None and 'too close' in r.reason


def test_robot_next_to_a_wall_can_leave():
    v, o = box_map()
    start = cell_xy(o, 4, 30)                           # 0.15-0.2 m from the left border wall: inside inflation
    r = plan_path(v, RES, o, start, cell_xy(o, 40, 30))
    assert r.path is not None, r.reason


# ---------------------------------------------------------------- motion

@pytest.fixture(scope='module')
def world():
    return make_floor_plan(4, 14.0, 10.0)


def test_clearance_and_collision(world):
    cl = Clearance(world)
    x0, y0, x1, y1 = world.extra['corridors'][0]
    yc = 0.5 * (y0 + y1)
    assert cl.free(3.0, yc, 0.2) and not cl.free(3.0, y0 - 0.02, 0.2) and not cl.free(-5.0, yc, 0.0)
    # driving into the corridor wall stops at the wall, turning still works
    pose, blocked_any = (3.0, yc, math.pi / 2), False
    for _ in range(200):
        pose, blocked = step_with_collision(pose, 0.5, 0.0, 0.05, cl, 0.2)
        blocked_any |= blocked
        assert cl.free(pose[0], pose[1], 0.2)
    assert blocked_any and y1 - pose[1] < 0.35
    turned, blocked = step_with_collision(pose, 0.0, 1.0, 0.05, cl, 0.2)
    assert not blocked and turned[2] == pytest.approx(pose[2] + 0.05)


def test_random_free_poses_are_free_apart_and_deterministic(world):
    cl = Clearance(world)
    a = cl.random_free_poses(np.random.default_rng(3), 5, 0.2)
    assert a == cl.random_free_poses(np.random.default_rng(3), 5, 0.2)
    assert all(cl.free(x, y, 0.4) for x, y, _ in a)
    assert min(math.hypot(p[0] - q[0], p[1] - q[1]) for i, p in enumerate(a) for q in a[i + 1:]) >= 1.0


def test_follower_reaches_the_end_of_a_path():
    path = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [2.0, 1.5]])
    f = PathFollower(np.vstack([np.linspace(path[i], path[i + 1], 20) for i in range(3)]), FollowerConfig())
    pose = (0.0, 0.0, math.pi)                          # facing away: turns first
    for _ in range(400):
        v, w = f.command(pose, 0.05)
        assert abs(v) <= 0.5 + 1e-9 and abs(w) <= 1.5 + 1e-9
        pose = integrate(pose, v, w, 0.05)
    assert math.hypot(pose[0] - 2.0, pose[1] - 1.5) < 0.05


def test_path_blocked_index():
    v, o = box_map()
    path = np.array([cell_xy(o, c, 30) for c in range(10, 70, 5)])
    assert path_blocked_index(values_occupied(v), RES, o, path, 0.2) is None
    v[28:33, 52] = 100                                   # a discovered wall across the path at column 52
    assert path_blocked_index(values_occupied(v), RES, o, path, 0.2) == 8      # point at column 50, 2 cells off


# ---------------------------------------------------------------- the move_base stand-in

def sim_with(world, robots, **extra):
    values = {'world_seed': 4, 'world_width': 14.0, 'world_height': 10.0, 'robots': robots, 'seed': 5}
    values.update(extra)
    return FleetSim(FleetSimParams.from_mapping(values), world)


def run_goal(sim, i, world_xy, limit=120.0):
    r = sim.robots[i]
    gx, gy, _ = relative_pose(r.start, (world_xy[0], world_xy[1], 0.0))
    out = sim.set_goal(i, gx, gy)
    while out is None and sim.t < limit:
        _, outcomes = sim.step()
        out = next((o for j, o in outcomes if j == i), None)
    return out


def test_goal_succeeds_through_a_door_and_the_map_is_built(world):
    sim = sim_with(world, [{'x': 3.0, 'y': 6.1, 'yaw': 2.0}])
    room = world.extra['rooms'][1]                          # a room off the corridor, behind a door
    cl = sim.clearance
    goal = next((x, y) for x in np.linspace(room[0] + 0.5, room[2] - 0.5, 20)
                for y in np.linspace(room[1] + 0.5, room[3] - 0.5, 20) if cl.free(x, y, 0.5))
    scans = sim.robots[0].mapper.n_scans
    out = run_goal(sim, 0, goal)
    assert out is not None and out.status == SUCCEEDED, out
    r = sim.robots[0]
    assert math.hypot(r.pose[0] - goal[0], r.pose[1] - goal[1]) <= 0.25
    assert r.mapper.n_scans > scans + 10 and r.state != ACTIVE
    # the map frame is the start pose: the robot's map-frame pose is its true pose seen from the start
    assert r.pose_map == pytest.approx(relative_pose(r.start, r.pose))


def test_goal_outside_the_building_and_in_a_wall_abort(world):
    sim = sim_with(world, [{'x': 8.325, 'y': 1.275, 'yaw': 0.3}])
    out = run_goal(sim, 0, (8.325, 2.575))                  # the centre of a furniture block: enclosed
    assert out.status == ABORTED and 'no path' in out.text
    m = sim.robots[0].mapper.to_grid()
    rows, cols = np.nonzero(m.data == 100)
    gx, gy = m.origin[0] + (cols[0] + 0.5) * m.resolution, m.origin[1] + (rows[0] + 0.5) * m.resolution
    out = sim.robots[0].set_goal(gx, gy, sim.t)             # a wall cell of its own map: refused at once
    assert out.status == ABORTED and 'obstacle' in out.text
    assert sim.robots[0].set_goal(float('nan'), 0.0, sim.t).status == ABORTED


def test_cancel_stops_the_robot(world):
    sim = sim_with(world, [{'x': 3.0, 'y': 6.1, 'yaw': 0.0}])
    r = sim.robots[0]
    assert sim.set_goal(0, 6.0, 0.0) is None and r.state == ACTIVE
    for _ in range(20):
        sim.step()
    r.cancel()
    pose = r.pose
    for _ in range(20):
        assert sim.step()[1] == []
    assert r.pose == pose and r.state != ACTIVE


def test_stuck_robot_aborts(world, monkeypatch):
    sim = sim_with(world, [{'x': 3.0, 'y': 6.1, 'yaw': 0.0}], stuck_timeout=1.0)
    assert sim.set_goal(0, 4.0, 0.0) is None
    # an invisible obstacle: every move is refused (as a wall the laser cannot see would)
    monkeypatch.setattr(sim.clearance, 'free', lambda x, y, radius: False)
    out = None
    while out is None and sim.t < 60.0:
        out = next((o for _, o in sim.step()[1]), None)
    assert out is not None and out.status == ABORTED and 'stuck' in out.text
    assert sim.t < 10.0                                      # ~ (3 re-plans + 1) x stuck_timeout


def test_simulation_is_deterministic(world):
    def run():
        sim = sim_with(world, [], num_robots=2)
        outs = [run_goal(sim, 0, (3.0, 6.1), limit=40.0)]
        return sim, outs
    a, oa = run()
    b, ob = run()
    assert [r.start for r in a.robots] == [r.start for r in b.robots]
    assert [r.pose for r in a.robots] == [r.pose for r in b.robots]
    for ra, rb in zip(a.robots, b.robots):
        np.testing.assert_array_equal(ra.mapper.values(), rb.mapper.values())
    assert [o.status for o in oa] == [o.status for o in ob]


def test_schedule_of_publications(world):
    sim = sim_with(world, [{'x': 3.0, 'y': 6.1}], map_rate=1.0, update_rate=5.0, tf_rate=10.0, scan_rate=5.0)
    counts = {'map': 0, 'update': 0, 'tf': 0}
    for _ in range(200):                                     # 10 s at 0.05 s steps
        due, _ = sim.step()
        counts['map'] += due.map
        counts['update'] += due.update
        counts['tf'] += due.tf
    # due at the first step, then every period up to and including t = 10 s
    assert counts == {'map': 11, 'update': 51, 'tf': 101}
    assert sim.t == pytest.approx(10.0)


# ---------------------------------------------------------------- laser: the fast cast equals the stepwise DDA

@pytest.mark.parametrize('seed', range(4))
def test_cast_equals_stepwise_dda(seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((60, 70)) < 0.06
    for _ in range(10):
        pose = (rng.uniform(-0.2, 3.7), rng.uniform(-0.2, 3.2), rng.uniform(-4, 4))
        mr = rng.uniform(0.5, 6.0)
        a, b = cast(occ, RES, pose, 181, mr), cast_stepwise(occ, RES, pose, 181, mr)
        np.testing.assert_array_equal(np.isinf(a), np.isinf(b))
        np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], atol=1e-9)


def test_cast_axis_and_diagonal_beams_from_cell_corners():
    occ = np.zeros((20, 20), bool)
    occ[:, 15] = True
    occ[2, :] = True
    occ[12, 3] = True
    for pose in [(0.25, 0.5, 0.0), (0.5, 0.5, math.pi / 4), (0.5, 0.5, -math.pi / 4), (0.25, 0.25, 0.0),
                 (0.275, 0.475, math.pi / 2)]:
        np.testing.assert_allclose(cast(occ, RES, pose, 16, 5.0), cast_stepwise(occ, RES, pose, 16, 5.0),
                                   atol=1e-9)


def test_line_sampling_maps_like_half_cell_sampling(world):
    from fleet_sim.world import obstacle_mask
    occ = obstacle_mask(world)
    poses = [(x, 6.1, 0.3 * x) for x in np.linspace(1.5, 12.5, 12)]
    maps = [LogOddsMap(RES), LogOddsMap(RES, line_sampling=True)]
    for p in poses:
        r = cast(occ, RES, p, 360, 5.0)
        for m in maps:
            m.integrate(relative_pose(poses[0], p), r, beam_angles(360), 5.0)
    a, b = (m.values() for m in maps)
    assert a.shape == b.shape
    walls_a, walls_b = a == 100, b == 100
    assert (walls_a & walls_b).sum() > 0.95 * (walls_a | walls_b).sum()     # nearly the same walls
    assert np.mean((a == 0) == (b == 0)) > 0.98                             # and free cells


# ---------------------------------------------------------------- messages

def test_array_messages_serialise_like_genpy():
    genpy = pytest.importorskip('genpy')
    from fleet_sim.messages import grid_msg, update_msg
    from multirobot_map_merge.ros.conversions import GridUpdate, grid_to_msg, update_to_msg
    v = np.random.default_rng(0).integers(-1, 101, (30, 40)).astype(np.int8)
    stamp = genpy.Time(5, 0)
    fast, slow = io.BytesIO(), io.BytesIO()
    grid_msg(v, RES, (1.0, -2.0, 0.3), 'r/map', stamp).serialize(fast)
    grid_to_msg(Grid(v, RES, (1.0, -2.0, 0.3), 'r/map'), stamp=stamp).serialize(slow)
    assert fast.getvalue() == slow.getvalue()
    fast, slow = io.BytesIO(), io.BytesIO()
    update_msg(v[3:9, 4:20], 4, 3, 'r/map', stamp).serialize(fast)
    update_to_msg(GridUpdate(4, 3, 16, 6, v[3:9, 4:20], 5.0, 'r/map')).serialize(slow)
    assert fast.getvalue() == slow.getvalue()
