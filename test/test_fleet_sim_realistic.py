"""fleet_sim's realistic profile, each part on a small world: field of view, range and range noise, beams with no
return, glass, people, doors, and the SLAM's pose drift with its loop closures."""
import math

import numpy as np
import pytest

from fleet_sim.drift import SlamDrift
from fleet_sim.laser import add_noise, beam_angles, cast, glass_no_return
from fleet_sim.mapping import relative_pose
from fleet_sim.motion import Clearance
from fleet_sim.params import REALISTIC, FleetSimParams, ParamError, describe
from fleet_sim.robot import SUCCEEDED, RobotConfig, SimRobot
from fleet_sim.scenery import Doors, door_leaves, glass_mask, wall_runs
from fleet_sim.sim import FleetSim
from fleet_sim.world import make_floor_plan, obstacle_mask
from multirobot_map_merge.grid import Grid

RES = 0.05


def hall(length_m=40.0, width_m=3.0):
    """A walled hall along x (1-cell walls), origin (0, 0)."""
    w, h = int(round(length_m / RES)), int(round(width_m / RES))
    data = np.zeros((h, w), np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    return Grid(data, RES, (0.0, 0.0, 0.0), frame_id='world')


def sim_in(world, robots, **values):
    params = FleetSimParams.from_mapping({'robots': robots, 'seed': 3, **values})
    return FleetSim(params, world)


@pytest.fixture(scope='module')
def plan():
    return make_floor_plan(4, 14.0, 10.0)


# ---------------------------------------------------------------- the profile

def test_realistic_profile_sets_its_values_and_explicit_values_win():
    p = FleetSimParams.from_mapping({'profile': 'realistic', 'max_range': 20.0})
    assert p.max_range == 20.0                               # explicit
    for name, value in REALISTIC.items():
        if name != 'max_range':
            assert getattr(p, name) == value, name
    assert p.drift and p.fov == 270.0 and not p.clear_no_return
    default = FleetSimParams.from_mapping({})
    assert not default.drift and default.fov == 360.0 and default.people == 0 and default.clear_no_return
    with pytest.raises(ParamError, match='profile'):
        FleetSimParams.from_mapping({'profile': 'fancy'})
    with pytest.raises(ParamError, match='fov'):
        FleetSimParams.from_mapping({'fov': 400.0})
    # the docs (table and docstring) say the profile's value, from the same field
    docs = {d.name: d.doc for d in describe()}
    for name, value in REALISTIC.items():
        assert '*realistic*' in docs[name], name


# ---------------------------------------------------------------- field of view and range

@pytest.mark.parametrize('fov', [180.0, 270.0])
def test_field_of_view_limits_the_beams_and_the_map(fov):
    world = hall(10.0, 10.0)
    sim = sim_in(world, [{'x': 5.0, 'y': 5.0, 'yaw': 0.0}], fov=fov, n_beams=360, max_range=10.0)
    r = sim.robots[0]
    assert len(r.angles) == pytest.approx(360 * fov / 360.0, abs=1)
    assert np.abs(r.angles).max() <= math.radians(fov / 2) + 1e-9
    assert np.isfinite(r.ranges).all()                        # walls all round within 10 m
    # the map after the first scan: known cells ahead, none behind the scanner's blind sector
    g = r.mapper.to_grid()
    rows, cols = np.nonzero(g.data >= 0)
    x = g.origin[0] + (cols + 0.5) * RES
    y = g.origin[1] + (rows + 0.5) * RES
    bearing = np.degrees(np.arctan2(y, x))
    far = np.hypot(x, y) > 0.3
    assert (np.abs(bearing[far]) <= fov / 2 + 2.0).all()
    assert (np.abs(bearing[far]) >= fov / 2 - 5.0).any()      # and the whole field of view is used


def test_range_limit_and_no_return_beams():
    world = hall(40.0, 3.0)
    # the far wall: 37.9 m ahead (beyond 30 m) for robot_1, 27.9 m for robot_2
    sim = sim_in(world, [{'ns': 'robot_1', 'x': 2.0, 'y': 1.5}, {'ns': 'robot_2', 'x': 12.0, 'y': 1.5}],
                 profile='realistic', glass_panes=0, people=0, drift_yaw=0.0, drift_xy=0.0)
    near, far = sim.robots[1], sim.robots[0]
    ahead = int(np.argmin(np.abs(near.angles)))
    assert near.ranges[ahead] == pytest.approx(27.9, abs=0.3)
    assert np.isposinf(far.ranges[ahead])
    # no return clears nothing: robot_1's map stays unknown beyond its last wall hits straight ahead
    g = far.mapper.to_grid()
    row = int((0.0 - g.origin[1]) / RES)
    ahead_cells = g.data[row, int((31.0 - g.origin[0]) / RES):]
    assert (ahead_cells == -1).all()
    # with the default (clear_no_return true) the same beam clears free space to max_range
    sim2 = sim_in(world, [{'x': 2.0, 'y': 1.5}], max_range=30.0)
    g2 = sim2.robots[0].mapper.to_grid()
    assert (g2.data[row, int((25.0 - g2.origin[0]) / RES):int((29.0 - g2.origin[0]) / RES)] == 0).all()


def test_range_noise_grows_with_distance():
    world = hall(40.0, 3.0)
    occ = obstacle_mask(world)
    rng = np.random.default_rng(7)
    angles = np.zeros(2000)
    for x in (36.0, 12.0):          # the far wall about 4 m and 28 m ahead
        exact = cast(occ, RES, (x, 1.5, 0.0), 1, 30.0, angles=angles)
        noisy = add_noise(exact.copy(), rng, 0.01, sigma_per_m=0.0015)
        assert np.std(noisy - exact) == pytest.approx(0.01 + 0.0015 * exact[0], rel=0.1)


# ---------------------------------------------------------------- glass

def test_glass_returns_only_head_on_and_stops_robots():
    world = hall(10.0, 10.0)
    occ = obstacle_mask(world)
    glass = np.zeros_like(occ)
    glass[:, -1] = True                                       # the east wall (x = 9.95..10) is one pane
    angles = np.radians(np.arange(-60.0, 61.0, 1.0))
    pose = (5.0, 5.0, 0.0)                                    # facing the glass
    ranges = cast(occ, RES, pose, 1, 30.0, angles=angles)
    assert np.isfinite(ranges).all()
    glass_no_return(ranges, angles, pose, glass, RES)
    head_on = np.abs(np.degrees(angles)) < 10.0 - 1e-6
    assert np.isfinite(ranges[head_on]).all()
    assert ranges[head_on][len(ranges[head_on]) // 2] == pytest.approx(4.95, abs=0.01)
    oblique = np.abs(np.degrees(angles)) > 10.0 + 1e-6
    # oblique beams that reach the east wall give no return; the ones hitting the north/south walls do
    to_east = np.abs(np.tan(angles)) * 4.95 < 4.95
    assert np.isposinf(ranges[oblique & to_east]).all()
    assert np.isfinite(ranges[oblique & ~to_east]).all()
    # glass is a wall for robots
    assert not Clearance(world).free(9.97, 5.0, 0.01)


def test_glass_panes_lie_in_interior_walls(plan):
    occ = obstacle_mask(plan)
    glass = glass_mask(plan, occ, np.random.default_rng(1), 4)
    assert glass.any() and (occ[glass]).all()
    assert not (glass & ~wall_runs(occ)).any()                # never the outer walls (unknown outside)
    assert glass.sum() * RES <= 4 * 2.1 * 3 * RES / RES       # at most 4 panes of <= 2 m, <= 3 cells thick


def test_a_robot_facing_glass_obliquely_maps_nothing_behind_it(plan):
    sim = sim_in(plan, [{'x': 3.0, 'y': 6.1, 'yaw': 0.0}], profile='realistic', people=0, door_changes=0.0,
                 drift_yaw=0.0, drift_xy=0.0, glass_panes=12)
    r = sim.robots[0]
    plain = cast(sim.occ, RES, r.pose, 1, 30.0, angles=r.angles)
    on_glass = np.isposinf(r.ranges) & np.isfinite(plain)
    assert on_glass.any()                                     # some beams hit glass and returned nothing


# ---------------------------------------------------------------- people

def test_people_walk_are_seen_and_do_not_block_robots(plan):
    sim = sim_in(plan, [{'x': 3.0, 'y': 6.1, 'yaw': 0.0}], people=6, seed=2)
    start = sim.people.pos.copy()
    r = sim.robots[0]
    shorter = 0
    for _ in range(400):                                      # 20 s
        sim.step()
        r.scan(force=True)
        static = cast(obstacle_mask(plan), RES, r.pose, r.cfg.n_beams, r.cfg.max_range, angles=r.angles)
        shorter += int(np.sum(r.ranges < static - 0.15))
        assert sim.clearance.free(*r.pose[:2], r.cfg.robot_radius)
        for x, y in sim.people.pos:                           # people stay in free space
            assert sim.clearance.free(x, y, 0.2)
    assert np.hypot(*(sim.people.pos - start).T).max() > 3.0  # they walk
    assert shorter > 0                                        # the laser saw them
    # robots ignore them: the clearance is the world's
    np.testing.assert_array_equal(sim.clearance.blocked, obstacle_mask(plan))


# ---------------------------------------------------------------- doors

def test_door_leaves_close_the_gaps(plan):
    occ = obstacle_mask(plan)
    leaves = door_leaves(plan, occ, plan.extra['doors'])
    assert len(leaves) >= len(plan.extra['doors']) - 1
    for leaf in leaves:
        assert not occ[leaf[0], leaf[1]].any()                # in the free gap
        assert 0.8 / RES * 2 <= leaf.shape[1] <= 1.3 / RES * 2   # two cells thick, door-wide


def test_doors_open_and_shut_block_beams_and_robots_never_on_a_robot(plan):
    sim = sim_in(plan, [{'x': 3.0, 'y': 6.1, 'yaw': 0.0}], door_changes=1.0, door_period=5.0)
    doors = sim.doors
    assert len(doors.leaves) >= 4 and not any(doors.shut)
    seen_shut = False
    for _ in range(800):                                      # 40 s, doors change every ~5 s
        sim.step()
        for leaf, shut in zip(doors.leaves, doors.shut):
            assert bool(sim.occ[leaf[0], leaf[1]].all()) == shut
            assert bool(sim.clearance.blocked[leaf[0], leaf[1]].all()) == shut
            seen_shut |= shut
        assert sim.clearance.free(*sim.robots[0].pose[:2], 0.2)   # never shut on the robot
    assert seen_shut and doors.changes >= 8


def test_a_door_does_not_shut_next_to_a_robot(plan):
    occ = obstacle_mask(plan)
    doors = Doors(plan, occ, np.random.default_rng(0), 1.0, 1.0)
    leaf = doors.leaves[0]
    x = plan.origin[0] + (leaf[1].mean() + 0.5) * RES
    y = plan.origin[1] + (leaf[0].mean() + 0.5) * RES
    for t in np.arange(0.0, 30.0, 0.2):
        doors.update(float(t), [(x, y)])
        assert not doors.shut[0]


# ---------------------------------------------------------------- drift

def drive(sim, i, waypoints):
    r = sim.robots[i]
    for wx, wy in waypoints:
        goal = relative_pose(r.start, (wx, wy, 0.0))
        gx, gy, _ = r.drift.believed(goal) if r.drift else goal     # goals are given in the believed map
        out = sim.set_goal(i, gx, gy)
        while out is None and sim.t < 600.0:
            _, outcomes = sim.step()
            out = next((o for j, o in outcomes if j == i), None)
        assert out is not None and out.status == SUCCEEDED, out


def belief_offset(r):
    b, t = r.pose_map, r.true_pose_map
    return b[0] - t[0], b[1] - t[1], math.remainder(b[2] - t[2], 2 * math.pi)


def pose_error(r):
    b, t = r.pose_map, r.true_pose_map
    return math.hypot(b[0] - t[0], b[1] - t[1]), abs(math.remainder(b[2] - t[2], 2 * math.pi))


def test_drift_grows_with_distance_and_a_loop_closure_jumps_back(plan):
    x0, y0, x1, y1 = plan.extra['corridors'][0]
    yc = 0.5 * (y0 + y1)
    sim = sim_in(plan, [{'x': x0 + 1.0, 'y': yc, 'yaw': 0.0}], drift_yaw=0.5, drift_xy=0.02,
                 loop_closure_path=5.0, seed=11)
    r = sim.robots[0]
    assert pose_error(r) == (0.0, 0.0)                        # the map frame is the start pose: no error there
    drive(sim, 0, [(x0 + 3.0, yc)])
    offset_a = belief_offset(r)                               # the SLAM's error at place A, on the way out
    drive(sim, 0, [(x1 - 1.0, yc)])
    far = pose_error(r)
    assert far[0] > 0.02 or far[1] > math.radians(0.3)       # it grew on the way
    assert not r.drift.closures                               # no place revisited yet
    # TF carries the belief, and the map is drawn at it
    assert r.pose_map != pytest.approx(r.true_pose_map)
    grid = r.mapper.to_grid()
    drive(sim, 0, [(x0 + 3.0, yc)])                           # back at A: the loop closes
    assert len(r.drift.closures) == 1
    jump = r.drift.closures[0]
    assert jump.jump_m > 0.01 or jump.jump_deg > 0.3         # a visible jump
    # the belief at A is A's belief of the way out again (up to the difference between neighbouring places)
    offset = belief_offset(r)
    assert offset[:2] == pytest.approx(offset_a[:2], abs=0.03)
    assert offset[2] == pytest.approx(offset_a[2], abs=math.radians(1.0))
    assert grid.data.shape[1] >= int(8.0 / RES)               # the map of the long corridor was drawn meanwhile


def test_drift_is_deterministic_and_off_by_default(plan):
    x0, y0, x1, y1 = plan.extra['corridors'][0]
    yc = 0.5 * (y0 + y1)
    errors = []
    for _ in range(2):
        sim = sim_in(plan, [{'x': x0 + 1.0, 'y': yc}], drift_yaw=0.5, drift_xy=0.01)
        drive(sim, 0, [(x1 - 1.0, yc)])
        errors.append(sim.robots[0].drift.error)
    assert errors[0] == errors[1] and errors[0] != (0.0, 0.0, 0.0)
    sim = sim_in(plan, [{'x': x0 + 1.0, 'y': yc}])
    assert sim.robots[0].drift is None
    drive(sim, 0, [(x1 - 1.0, yc)])
    assert pose_error(sim.robots[0]) == (0.0, 0.0)


def test_slam_drift_turns_about_the_believed_position():
    d = SlamDrift(np.random.default_rng(0), 2.0, 0.0, 10.0)
    before = d.believed((5.0, 0.0, 0.0))
    d.moved((4.9, 0.0, 0.0), (5.0, 0.0, 0.0))
    after = d.believed((5.0, 0.0, 0.0))
    assert after[:2] == pytest.approx(before[:2], abs=1e-9)   # no jump in position, only the heading drifts
    assert after[2] != 0.0
