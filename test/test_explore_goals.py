"""explore goal selection: same-goal predicate, blacklist, progress timeout, stop, return_to_init, team penalty,
parameters."""
import math
import re

import numpy as np
import pytest

from explore.frontier_search import Frontier
from explore.goal_logic import (ABORTED, DETOUR, PREEMPTED, SUCCEEDED, GoalLogic, PlanAction, apply_team_penalty,
                                on_blacklist, same_point)
from explore.params import ExploreParams, ParamError, describe

RES = 0.5  # binary-exact, so the ±5-cell blacklist edges can be tested exactly


def frontier(x, y, cost=0.0, min_distance=1.0, size=10):
    return Frontier(size=size, min_distance=min_distance, cost=cost, initial=(x, y), centroid=(x, y),
                    middle=(x, y), points=np.zeros((size - 1, 2)))


# ---- same goal (the ROS 2 port's testSameGoal) --------------------------------------------------------------------

def test_same_point():
    assert not same_point((1.0, 2.0, 3.0), (0.0, 0.0, 0.0))
    assert same_point((1.0, 2.0, 3.0), (1.0, 2.0, 3.0))
    assert same_point((1.0, 2.0, 0.0), (1.0, 2.0, 5.0))        # z is ignored
    assert same_point((0.0, 0.0), (0.006, 0.0079))              # 0.0099... m
    assert not same_point((0.0, 0.0), (0.006, 0.0081))          # > 1 cm
    assert not same_point((0.0, 0.0), (0.01, 0.0))              # strict


# ---- blacklist ----------------------------------------------------------------------------------------------------

def test_blacklist_square_is_five_cells_strict():
    bl = [(10.0, 10.0)]
    edge = 5 * RES
    assert on_blacklist((10.0 + edge - 0.01, 10.0 - edge + 0.01), bl, RES)
    assert not on_blacklist((10.0 + edge, 10.0), bl, RES)
    assert not on_blacklist((10.0, 10.0 - edge), bl, RES)
    assert not on_blacklist((10.0, 10.0), [], RES)


def test_aborted_goal_is_blacklisted_and_nearby_frontier_skipped():
    logic = GoalLogic(progress_timeout=30.0)
    fa, near, far = frontier(1.0, 1.0, -3.0), frontier(1.0 + 4 * RES, 1.0, -2.0), frontier(1.0 + 5 * RES, 1.0, -1.0)
    first = logic.plan([fa, near, far], RES, now=100.0)
    assert first.action is PlanAction.SEND_GOAL and first.target == fa.centroid
    assert logic.on_goal_done(ABORTED, first.target) is True
    assert logic.is_blacklisted(fa.centroid, RES)
    nxt = logic.plan([fa, near, far], RES, now=101.0)
    # 'near' is within 5 cells of the aborted goal, 'far' exactly 5 cells away is not
    assert nxt.action is PlanAction.SEND_GOAL and nxt.frontier is far


@pytest.mark.parametrize('status', [SUCCEEDED, PREEMPTED, 5, 8])
def test_other_results_replan_without_blacklisting(status):
    logic = GoalLogic(progress_timeout=30.0)
    assert logic.on_goal_done(status, (1.0, 1.0)) is True
    assert logic.blacklist == []


def test_all_blacklisted_stops():
    logic = GoalLogic(progress_timeout=30.0)
    for p in [(0.0, 0.0), (5.0, 5.0)]:
        logic.on_goal_done(ABORTED, p)
    res = logic.plan([frontier(0.1, 0.1), frontier(5.0, 5.2)], RES, now=10.0)
    assert res.action is PlanAction.STOP and res.reason == 'all_blacklisted' and res.return_target is None


def test_no_frontiers_stops():
    res = GoalLogic(progress_timeout=30.0).plan([], RES, now=10.0)
    assert res.action is PlanAction.STOP and res.reason == 'no_frontiers'


# ---- same goal and progress timeout -------------------------------------------------------------------------------

def test_same_goal_is_not_resent_until_timeout_then_blacklisted():
    timeout = 30.0
    logic = GoalLogic(progress_timeout=timeout)
    stuck, other = frontier(2.0, 2.0, -5.0, min_distance=3.0), frontier(8.0, 8.0, -1.0)
    t0 = 1000.0
    assert logic.plan([stuck, other], RES, t0).action is PlanAction.SEND_GOAL
    # the same frontier again, centroid moved by less than 1 cm, no progress: nothing is sent
    jiggled = frontier(2.005, 2.0, -5.0, min_distance=3.0)
    assert logic.plan([jiggled, other], RES, t0 + 10).action is PlanAction.KEEP_GOAL
    assert logic.plan([jiggled, other], RES, t0 + timeout).action is PlanAction.KEEP_GOAL  # not yet (strict >)
    res = logic.plan([jiggled, other], RES, t0 + timeout + 0.5)
    assert res.action is PlanAction.SEND_GOAL and res.frontier is other
    assert res.blacklisted == [jiggled.centroid] and logic.is_blacklisted(stuck.centroid, RES)


def test_progress_towards_the_goal_resets_the_timeout():
    logic = GoalLogic(progress_timeout=30.0)
    t = 0.0
    assert logic.plan([frontier(2.0, 2.0, min_distance=10.0)], RES, t).action is PlanAction.SEND_GOAL
    for step in range(1, 10):  # getting closer every 20 s: never blacklisted
        t += 20.0
        res = logic.plan([frontier(2.0, 2.0, min_distance=10.0 - step)], RES, t)
        assert res.action is PlanAction.KEEP_GOAL and res.blacklisted == []
    # stuck at the same distance: blacklisted after the timeout, then nothing else is left
    res = logic.plan([frontier(2.0, 2.0, min_distance=1.0)], RES, t + 31.0)
    assert res.action is PlanAction.STOP and res.blacklisted == [(2.0, 2.0)]


def test_a_different_goal_resets_the_timeout():
    logic = GoalLogic(progress_timeout=30.0)
    a, b = frontier(2.0, 2.0), frontier(9.0, 9.0)
    logic.plan([a], RES, 0.0)
    res = logic.plan([b], RES, 100.0)
    assert res.action is PlanAction.SEND_GOAL and res.blacklisted == []


def test_first_goal_near_origin_is_not_blacklisted_at_once():
    # the original compares the first target with (0,0,0) and would blacklist it immediately
    res = GoalLogic(progress_timeout=30.0).plan([frontier(0.001, 0.0)], RES, now=1e9)
    assert res.action is PlanAction.SEND_GOAL


def test_resume_skips_the_timeout_once():
    logic = GoalLogic(progress_timeout=30.0)
    f = frontier(2.0, 2.0)
    logic.plan([f], RES, 0.0)
    logic.resume()
    assert logic.plan([f], RES, 100.0).action is PlanAction.KEEP_GOAL
    assert logic.plan([f], RES, 101.0).action is PlanAction.STOP  # timed out, nothing else left


# ---- return to init ----------------------------------------------------------------------------------------------

def test_return_to_init_once_per_end_of_exploration():
    logic = GoalLogic(progress_timeout=30.0, return_to_init=True)
    home = ('pose', 1.0, 2.0)
    logic.set_initial_pose(home)
    logic.plan([frontier(3.0, 3.0)], RES, 0.0)
    end = logic.plan([], RES, 5.0)
    assert end.action is PlanAction.STOP and end.return_target is home and logic.returning_home
    assert logic.plan([], RES, 6.0).return_target is None  # e.g. the replan after the return goal completes
    assert logic.plan([frontier(7.0, 7.0)], RES, 7.0).action is PlanAction.SEND_GOAL  # new map: exploring again
    assert not logic.returning_home
    assert logic.plan([], RES, 8.0).return_target is home


def test_return_to_init_off_or_without_pose():
    off = GoalLogic(progress_timeout=30.0)
    off.set_initial_pose('home')
    assert off.plan([], RES, 0.0).return_target is None
    assert GoalLogic(progress_timeout=30.0, return_to_init=True).plan([], RES, 0.0).return_target is None


# ---- team coordination -------------------------------------------------------------------------------------------

def test_team_penalty_demotes_frontiers_near_team_goals():
    fs = [frontier(0.0, 0.0, -10.0), frontier(10.0, 0.0, -5.0), frontier(0.5, 0.5, -4.0), frontier(20.0, 0.0, 2.0)]
    out = apply_team_penalty(fs, [(0.0, 1.0)], team_radius=3.0)
    near = {id(fs[0]), id(fs[2])}
    # unpenalised frontiers keep their order and come first; penalised ones follow, in their own cost order
    assert [f.centroid for f in out] == [(10.0, 0.0), (20.0, 0.0), (0.0, 0.0), (0.5, 0.5)]
    assert out[0] is fs[1] and out[1] is fs[3] and not near & {id(f) for f in out}
    span = max(f.cost for f in fs) - min(f.cost for f in fs)
    assert out[2].cost == pytest.approx(fs[0].cost + span + 1.0) and out[2].cost > max(f.cost for f in out[:2])
    assert fs[0].cost == -10.0  # inputs are not modified


def test_team_penalty_radius_is_strict_and_off_without_goals():
    fs = [frontier(0.0, 0.0, -2.0), frontier(5.0, 0.0, -1.0)]
    assert [f.centroid for f in apply_team_penalty(fs, [(-3.0, 0.0)], 3.0)] == [(0.0, 0.0), (5.0, 0.0)]
    assert [f.centroid for f in apply_team_penalty(fs, [(-2.9, 0.0)], 3.0)] == [(5.0, 0.0), (0.0, 0.0)]
    assert apply_team_penalty(fs, [], 3.0) == fs


def test_team_penalty_keeps_tiers_with_infinite_costs():
    fs = [frontier(0.0, 0.0, -math.inf), frontier(9.0, 0.0, math.inf)]
    out = apply_team_penalty(fs, [(0.0, 0.0)], 1.0)
    assert [f.centroid for f in out] == [(9.0, 0.0), (0.0, 0.0)]


def test_frontier_nearer_to_a_teammates_goal_is_left_to_it():
    """With where the robot heads (its goal, or its position), a frontier nearer to a teammate's goal than to that is
    demoted, however far (the teammate will be there first); without it only team_radius counts."""
    robot = (0.0, 0.0)
    far_theirs, far_mine = frontier(30.0, 0.0, -10.0), frontier(-12.0, 0.0, -5.0)
    fs = [far_theirs, far_mine]
    goals = [(25.0, 0.0)]                                   # a teammate heads 5 m from the first one
    assert apply_team_penalty(fs, goals, 3.0) == fs        # beyond team_radius: unchanged
    assert [f.centroid for f in apply_team_penalty(fs, goals, 3.0, robot)] == [(-12.0, 0.0), (30.0, 0.0)]
    # nearer to this robot than to the goal: kept first; team_radius still applies near the robot
    assert apply_team_penalty(fs, [(60.0, 0.0)], 3.0, robot)[0] is far_theirs
    near_goal = frontier(1.0, 0.0, -10.0)
    assert apply_team_penalty([near_goal, far_mine], [(2.5, 0.0)], 3.0, robot)[0] is far_mine


def test_frontier_a_teammate_reaches_first_is_left_to_it_whatever_this_robot_chose():
    """With the teammates' remaining distances, a frontier is left to a teammate whose remaining distance plus the
    way from its goal is shorter than this robot's own distance to it, even when this robot's goal is right there
    (a robot that chose a far goal first must not keep it from a teammate next to it)."""
    heading = (40.0, 5.0)                                  # this robot chose a goal 38 m away
    far = frontier(40.0, 5.0, -10.0, min_distance=38.0)
    near = frontier(2.0, 0.0, -1.0, min_distance=2.0)
    teammate = [(39.0, 5.0)]                               # 5 m from its goal, 1 m from the far frontier
    out = apply_team_penalty([far, near], teammate, 0.5, heading, [5.0])
    assert [f.centroid for f in out] == [(2.0, 0.0), (40.0, 5.0)]
    # the goal-to-goal rule (no distances) keeps the far frontier first: it is nearer to this robot's goal
    assert apply_team_penalty([far, near], teammate, 0.5, heading)[0] is far
    # a teammate still 60 m from its goal would come later: the frontier stays this robot's
    assert apply_team_penalty([far, near], teammate, 0.5, heading, [60.0])[0] is far
    # an unknown distance (inf) falls back to the goal-to-goal rule; team_radius holds in any case
    assert apply_team_penalty([far, near], teammate, 0.5, heading, [math.inf])[0] is far
    assert apply_team_penalty([far, near], teammate, 3.0, heading, [60.0])[0] is near


def test_demoted_frontiers_nearest_first_and_a_teammates_goal_last():
    """Demoted frontiers come in two tiers after the robot's own: those a teammate only reaches first, then those
    within team_radius of a teammate's goal; each tier nearest first (min_distance), whatever the gain."""
    mine = frontier(-5.0, 0.0, 5.0, min_distance=5.0)
    at_goal_near = frontier(10.0, 0.0, -20.0, min_distance=10.0)
    left_far_big = frontier(30.0, 0.0, -30.0, min_distance=30.0)      # large, cheapest by cost
    left_near = frontier(20.0, 0.0, -1.0, min_distance=20.0)
    teammate = [(10.5, 0.0)]                                            # 1 m from its goal
    out = apply_team_penalty([left_far_big, at_goal_near, left_near, mine], teammate, 3.0, (-5.0, 0.0), [1.0])
    assert [f.centroid for f in out] == [(-5.0, 0.0), (20.0, 0.0), (30.0, 0.0), (10.0, 0.0)]
    assert all(f.cost > 5.0 for f in out[1:])                            # penalised above every own cost


def test_teammates_way_from_its_goal_counts_with_a_detour():
    """The straight line from a teammate's goal is stretched by DETOUR before it is compared with this robot's
    distance along the map: a frontier the teammate is only slightly nearer to by a straight line stays this
    robot's."""
    f = frontier(10.0, 0.0, -1.0, min_distance=10.0)
    other = frontier(-20.0, 0.0, 0.0, min_distance=20.0)
    goal = [(18.0, 0.0)]                                                # 8 m straight from the frontier
    # 1 + 8 < 10 but 1 + 1.4 * 8 > 10: kept
    assert apply_team_penalty([f, other], goal, 0.5, (0.0, 0.0), [1.0])[0] is f
    # 1 + 1.4 * 5 < 10: left to the teammate
    assert apply_team_penalty([f, other], [(15.0, 0.0)], 0.5, (0.0, 0.0), [1.0])[0] is other
    assert DETOUR == pytest.approx(1.4)


def test_penalised_frontier_chosen_when_others_blacklisted():
    logic = GoalLogic(progress_timeout=30.0)
    fs = apply_team_penalty([frontier(0.0, 0.0, -10.0), frontier(10.0, 0.0, -1.0)], [(0.0, 0.5)], 3.0)
    assert logic.plan(fs, RES, 0.0).target == (10.0, 0.0)
    logic.on_goal_done(ABORTED, (10.0, 0.0))
    assert logic.plan(fs, RES, 1.0).target == (0.0, 0.0)


# ---- parameters --------------------------------------------------------------------------------------------------

def test_params_match_the_specification_table(shared_dir):
    text = (shared_dir / 'reference' / 'explore.md').read_text()
    section = text[text.index('### 2.1 Parameters'):text.index('### 2.2')]
    rows = re.findall(r'^\| `~(\w+)` \| (\w+)[^|]*\| `([^`]+)` \|', section, re.M)
    assert len(rows) == 11
    defaults = ExploreParams()
    types = {'string': str, 'double': float, 'bool': bool}
    for name, typ, default in rows:
        value = getattr(defaults, name)
        assert type(value) is types[typ], name
        expect = {'true': True, 'false': False}.get(default, default)
        assert value == (types[typ](expect) if typ == 'double' else expect), name


def test_params_from_mapping_coerces_like_roscpp(caplog):
    p = ExploreParams.from_mapping({'planner_frequency': 2, 'visualize': 1, 'potential_scale': 3.0,
                                    'robot_base_frame': 5, 'unknown_param': 'x', 'return_to_init': True})
    assert p.planner_frequency == 2.0 and isinstance(p.planner_frequency, float)
    assert p.visualize is False and p.robot_base_frame == 'base_link'  # wrong types: defaults, with a warning
    assert p.potential_scale == 3.0 and p.return_to_init is True
    assert 'visualize' in caplog.text and 'robot_base_frame' in caplog.text


@pytest.mark.parametrize('bad', [{'planner_frequency': 0.0}, {'planner_frequency': -1.0},
                                 {'progress_timeout': float('nan')}, {'team_radius': -1.0},
                                 {'probability_map': True, 'free_threshold': 70, 'occupied_threshold': 60},
                                 {'occupied_threshold': 101}])
def test_params_validation(bad):
    with pytest.raises(ParamError):
        ExploreParams.from_mapping(bad)


def test_every_param_is_documented():
    docs = describe()
    assert [d.name for d in docs][:11] == ['robot_base_frame', 'costmap_topic', 'costmap_updates_topic',
                                           'transform_tolerance', 'visualize', 'planner_frequency',
                                           'progress_timeout', 'potential_scale', 'orientation_scale',
                                           'gain_scale', 'min_frontier_size']
    assert all(d.doc for d in docs) and not any(d.extension for d in docs[:11]) and all(d.extension for d in docs[11:])


def test_forget_goal_resends_the_same_goal():
    """After a pause or stop cancelled the goal, the same frontier must be sent again, not kept."""
    logic = GoalLogic(progress_timeout=30.0)
    fa = frontier(1.0, 1.0, -3.0)
    assert logic.plan([fa], RES, now=1.0).action is PlanAction.SEND_GOAL
    assert logic.plan([fa], RES, now=2.0).action is PlanAction.KEEP_GOAL
    logic.forget_goal()
    assert logic.plan([fa], RES, now=3.0).action is PlanAction.SEND_GOAL


def test_centroid_jitter_does_not_restart_the_timeout():
    """Map noise moving the frontier's centroid by a few cm each plan must not keep an unreachable goal alive
    forever (the original restarts the timeout for every goal more than 1 cm away from the last one)."""
    logic = GoalLogic(progress_timeout=30.0)
    other = frontier(8.0, 8.0, -1.0)
    t = 0.0
    first = logic.plan([frontier(2.0, 2.0, -5.0, min_distance=3.0), other], RES, t)
    assert first.action is PlanAction.SEND_GOAL
    for k in range(1, 20):
        t += 2.0
        jittered = frontier(2.0 + 0.05 * (k % 3), 2.0 - 0.04 * (k % 2), -5.0, min_distance=3.0)
        res = logic.plan([jittered, other], RES, t)
        if res.frontier is other:
            break
        assert res.action is PlanAction.SEND_GOAL   # a new point: re-sent, but the timeout keeps running
    assert res.frontier is other and 30.0 < t <= 32.0 and len(res.blacklisted) == 1


def test_two_robots_agree_whom_a_frontier_is_left_to():
    fs = [frontier(x, y, -1.0) for x, y in ((0.0, 0.0), (4.0, 1.0), (9.0, -2.0), (20.0, 5.0))]
    goal_a, goal_b = (1.0, 0.0), (12.0, 0.0)
    left_to_b_by_a = {f.centroid for f in apply_team_penalty(fs, [goal_b], 0.5, goal_a) if f.cost > -1.0}
    left_to_a_by_b = {f.centroid for f in apply_team_penalty(fs, [goal_a], 0.5, goal_b) if f.cost > -1.0}
    assert left_to_b_by_a and left_to_a_by_b
    assert left_to_b_by_a | left_to_a_by_b == {f.centroid for f in fs} and not left_to_b_by_a & left_to_a_by_b


def test_all_blacklisted_waits_while_the_team_is_busy():
    """A team member with every frontier blacklisted waits (and plans on) while a teammate still has a goal; it
    stops when none has, and a new frontier after waiting is sent even if it is where the old goal was."""
    logic = GoalLogic(progress_timeout=30.0, return_to_init=True)
    logic.set_initial_pose('home')
    f = frontier(1.0, 1.0)
    assert logic.plan([f], RES, 0.0).action is PlanAction.SEND_GOAL
    logic.on_goal_done(ABORTED, f.centroid)
    res = logic.plan([f], RES, 1.0, team_busy=True)
    assert res.action is PlanAction.WAIT and res.return_target is None and not logic.returning_home
    fresh = frontier(7.0, 7.0)
    assert logic.plan([f, fresh], RES, 2.0, team_busy=True).action is PlanAction.SEND_GOAL
    logic.on_goal_done(ABORTED, fresh.centroid)
    res = logic.plan([f, fresh], RES, 3.0, team_busy=False)
    assert res.action is PlanAction.STOP and res.reason == 'all_blacklisted' and res.return_target == 'home'
    assert logic.plan([], RES, 4.0, team_busy=True).action is PlanAction.STOP    # nothing at all: stop
