"""Per-robot map storage: full maps replace, partial updates patch (clipped, checked), copy-on-write."""
import numpy as np
import pytest

from multirobot_map_merge.grid import Grid
from multirobot_map_merge.ros.conversions import GridUpdate
from multirobot_map_merge.ros.robot_maps import RobotMap


def grid(w=5, h=4, value=-1, stamp=1.0):
    return Grid(np.full((h, w), value, np.int8), 0.05, (0.0, 0.0, 0.0), 'map', stamp)


def update(x, y, w, h, data=None, stamp=2.0):
    if data is None:
        data = np.arange(w * h, dtype=np.int8).reshape(h, w)
    return GridUpdate(x, y, w, h, np.asarray(data, np.int8), stamp)


def test_inside_update_and_copy_on_write():
    m = RobotMap()
    m.set_full(grid())
    before = m.snapshot()
    res = m.apply_update(update(1, 2, 3, 2))
    assert res.applied and res.reason == ''
    after = m.snapshot()
    assert (before.data == -1).all()           # the earlier snapshot was not mutated
    np.testing.assert_array_equal(after.data[2:4, 1:4], np.arange(6).reshape(2, 3))
    assert after.stamp == 2.0 and after.resolution == before.resolution


def test_clipped_update_copies_the_right_cells():
    m = RobotMap()
    m.set_full(grid(5, 4))
    data = np.arange(12, dtype=np.int8).reshape(3, 4)   # 4 wide at x=3: only columns 0,1 fit; 3 high at y=2: 2 rows
    res = m.apply_update(update(3, 2, 4, 3, data))
    assert res.applied and 'only 2 x 2 cells' in res.reason
    g = m.snapshot().data
    np.testing.assert_array_equal(g[2:4, 3:5], [[0, 1], [4, 5]])   # stride of the update, not of the copied part
    assert (g[:2] == -1).all() and (g[:, :3] == -1).all()


def test_new_size_full_map_replaces_even_after_newer_update():
    m = RobotMap()
    m.set_full(grid(5, 4, stamp=1.0))
    assert m.apply_update(update(0, 0, 1, 1, stamp=10.0)).applied
    assert m.set_full(grid(8, 6, stamp=5.0))            # the original would drop it (§13.5)
    assert m.snapshot().data.shape == (6, 8)
    assert m.set_full(grid(8, 6, value=0, stamp=6.0))
    assert not m.set_full(grid(8, 6, value=100, stamp=5.5))  # out-of-order older copy of the same map
    assert (m.snapshot().data == 0).all()


@pytest.mark.parametrize('upd, why', [
    (update(-1, 0, 1, 1), 'negative'),
    (update(0, -2, 1, 1), 'negative'),
    (GridUpdate(0, 0, 2, 2, np.zeros(3, np.int8), 2.0), 'expected 2 x 2'),
    (GridUpdate(0, 0, 2, 2, np.zeros(5, np.int8), 2.0), 'expected 2 x 2'),
    (update(5, 0, 1, 1), 'outside'),
    (update(0, 4, 1, 1), 'outside'),
    (update(0, 0, 1, 1, stamp=0.5), 'older'),
])
def test_malformed_updates_rejected_and_map_unchanged(upd, why):
    m = RobotMap()
    m.set_full(grid())
    before = m.snapshot()
    res = m.apply_update(upd)
    assert not res.applied and why in res.reason
    assert m.snapshot() is before and (before.data == -1).all()


def test_update_before_full_map_rejected():
    m = RobotMap()
    res = m.apply_update(update(0, 0, 1, 1))
    assert not res.applied and 'no full map' in res.reason and m.snapshot() is None


def test_estimation_gate_estimates_unchanged_maps_twice_more_then_rests():
    """Changed maps are estimated; maps that stopped changing twice more (the estimation that checks the kept
    placements on the final maps, then the one that compares them with an estimate afresh), then not again until a
    map or the robots change."""
    from multirobot_map_merge.ros.robot_maps import EstimationGate
    gate = EstimationGate()
    first = (['a', 'b'], [grid(), grid(value=0)])
    same = (['a', 'b'], [grid(), grid(value=0)])   # new objects, the same content
    asked = []
    for inputs in (first, same, same, same, same):
        asked.append(gate.wanted(inputs))
        if asked[-1]:
            gate.estimated(inputs)
    assert asked == [True, True, True, False, False]
    changed = (['a', 'b'], [grid(), grid(value=100)])
    for _ in range(3):   # the new maps, then twice more on them as final maps
        assert gate.wanted(changed)
        gate.estimated(changed)
    assert not gate.wanted(changed)
    assert gate.wanted((['a'], [grid()]))   # a robot vanished


def test_estimation_gate_does_not_rest_while_the_search_budget_left_searches_undone():
    """An estimation whose search budget ran out (a loaded machine) left robots for a later one: unchanged maps are
    estimated again until one makes every search it wanted (estimator.estimate makes them then), so that a robot of
    static maps joins late, not never."""
    from multirobot_map_merge.ros.robot_maps import EstimationGate
    gate = EstimationGate()
    inputs = (['a', 'b'], [grid(), grid(value=0)])
    for _ in range(3):
        assert gate.wanted(inputs)
        gate.estimated(inputs)
    assert not gate.wanted(inputs)
    gate.estimated(inputs, complete=False)   # as if the last one had been cut short
    assert gate.wanted(inputs) and gate.wanted(inputs)
    gate.estimated(inputs, complete=True)
    assert not gate.wanted(inputs)
