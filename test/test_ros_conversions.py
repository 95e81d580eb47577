"""Grid <-> nav_msgs/OccupancyGrid and map_msgs/OccupancyGridUpdate conversion."""
import io
import math
import warnings

import genpy
import numpy as np
import pytest
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid

from multirobot_map_merge.grid import MAX_CELLS, Grid, GridError
from multirobot_map_merge.ros.conversions import (GridUpdate, grid_from_msg, grid_to_msg, restamped,
                                                  update_from_msg, update_to_msg, yaw_from_quaternion)


def random_grid(h=5, w=7, seed=0):
    data = np.random.default_rng(seed).integers(-1, 101, size=(h, w)).astype(np.int8)
    return Grid(data, 0.05, (1.5, -2.25, 0.8), frame_id='robot1/map', stamp=12.5)


def wire_round_trip(msg):
    buf = io.BytesIO()
    msg.serialize(buf)
    out = type(msg)()
    out.deserialize(buf.getvalue())
    return out


def raw_msg(w, h, data, res=0.05, q=(0.0, 0.0, 0.0, 1.0), pos=(0.0, 0.0)):
    m = OccupancyGrid()
    m.info.width, m.info.height, m.info.resolution = w, h, res
    m.info.origin.position.x, m.info.origin.position.y = pos
    (m.info.origin.orientation.x, m.info.origin.orientation.y,
     m.info.origin.orientation.z, m.info.origin.orientation.w) = q
    m.data = data
    return m


def test_round_trip_through_the_wire():
    g = random_grid()
    msg = grid_to_msg(g)
    assert msg.info.width == 7 and msg.info.height == 5
    back = grid_from_msg(wire_round_trip(msg))
    np.testing.assert_array_equal(back.data, g.data)
    assert back.resolution == pytest.approx(0.05)
    assert back.origin == pytest.approx(g.origin, abs=1e-9)
    assert back.frame_id == 'robot1/map'
    assert back.stamp == pytest.approx(12.5)


def test_packed_message_sends_the_same_bytes_and_keeps_its_own_copy():
    rospy_numpy_msg = pytest.importorskip('rospy.numpy_msg')
    packed = rospy_numpy_msg.numpy_msg(OccupancyGrid)
    g = random_grid(40, 30, seed=3)
    plain, fast = grid_to_msg(g, stamp=7.5, frame_id='world'), grid_to_msg(g, 7.5, 'world', packed_class=packed)
    assert isinstance(fast, packed) and isinstance(fast, OccupancyGrid)   # a publisher of OccupancyGrid takes it
    a, b = io.BytesIO(), io.BytesIO()
    plain.serialize(a)
    with warnings.catch_warnings():
        warnings.simplefilter('error')   # no deprecated numpy call (genpy's serializer asks for tostring)
        fast.serialize(b)
    assert a.getvalue() == b.getvalue()
    g.data[:] = 0   # the grid is changed later: the message (latched, re-sent) is not
    np.testing.assert_array_equal(grid_from_msg(wire_round_trip(fast)).data, grid_from_msg(plain).data)
    again = restamped(fast, genpy.Time(9, 0))
    assert type(again) is packed and again.header.stamp == genpy.Time(9, 0) and again.data is fast.data


def test_row_major_layout_row0_first():
    g = Grid(np.array([[1, 2, 3], [4, 5, 6]], np.int8), 1.0)
    assert list(grid_to_msg(g).data) == [1, 2, 3, 4, 5, 6]
    back = grid_from_msg(raw_msg(3, 2, (1, 2, 3, 4, 5, 6)))
    assert back.data[1, 0] == 4 and back.data[0, 2] == 3


def test_to_msg_header_stamp_frame_and_fresh_messages():
    g = random_grid()
    a = grid_to_msg(g, stamp=100.25, frame_id='world')
    b = grid_to_msg(g)
    assert a is not b and a.data is not b.data
    assert a.header.frame_id == 'world' and b.header.frame_id == 'robot1/map'
    assert a.header.stamp == genpy.Time(100, 250000000)
    assert a.info.map_load_time == a.header.stamp
    assert b.header.stamp.to_sec() == pytest.approx(12.5)
    t = genpy.Time(7, 5)
    c = grid_to_msg(g, stamp=t)
    assert c.header.stamp == t and c.info.map_load_time == t
    g.data[0, 0] = 7
    a, b = grid_to_msg(g), grid_to_msg(g)
    a.data[0] = 42                  # editing one message leaves the grid and the other message alone
    assert g.data[0, 0] == 7 and b.data[0] == 7


def test_to_msg_quaternion_is_yaw_about_z():
    g = Grid(np.zeros((1, 1), np.int8), 1.0, (0.0, 0.0, -2.5))
    q = grid_to_msg(g).info.origin.orientation
    assert (q.x, q.y) == (0.0, 0.0)
    assert q.z ** 2 + q.w ** 2 == pytest.approx(1.0)
    assert yaw_from_quaternion(q.x, q.y, q.z, q.w) == pytest.approx(-2.5)


def test_to_msg_rejects_bad_stamp():
    with pytest.raises(GridError):
        grid_to_msg(random_grid(), stamp=float('nan'))
    with pytest.raises(GridError):
        grid_to_msg(random_grid(), stamp=-1.0)


@pytest.mark.parametrize('q,yaw', [
    ((0.0, 0.0, 0.0, 0.0), 0.0),                                    # default-constructed message: identity
    ((0.0, 0.0, math.sin(0.3), math.cos(0.3)), 0.6),
    ((0.0, 0.0, 3 * math.sin(-1.0), 3 * math.cos(-1.0)), -2.0),     # not unit: normalised
    ((0.0, 0.0, 1.0, 0.0), math.pi),
])
def test_yaw_from_origin_quaternion(q, yaw):
    g = grid_from_msg(raw_msg(1, 1, [0], q=q))
    assert math.remainder(g.origin[2] - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-12)


def test_non_finite_quaternion_rejected():
    with pytest.raises(GridError, match='orientation'):
        grid_from_msg(raw_msg(1, 1, [0], q=(0.0, 0.0, float('nan'), 1.0)))


@pytest.mark.parametrize('res', [0.0, -0.05, float('nan'), float('inf')])
def test_bad_resolution_rejected(res):
    with pytest.raises(GridError, match='resolution'):
        grid_from_msg(raw_msg(2, 1, [0, 0], res=res))


def test_non_finite_origin_rejected():
    with pytest.raises(GridError, match='origin'):
        grid_from_msg(raw_msg(2, 1, [0, 0], pos=(float('inf'), 0.0)))


@pytest.mark.parametrize('n', [0, 5, 7])
def test_data_length_mismatch_rejected(n):
    with pytest.raises(GridError, match='expected 6'):
        grid_from_msg(raw_msg(3, 2, [0] * n))


def test_absurd_size_rejected_before_allocation():
    big = 1 << 16
    assert big * big > MAX_CELLS
    with pytest.raises(GridError, match='limit'):
        grid_from_msg(raw_msg(big, big, []))


def test_out_of_range_values_rejected():
    with pytest.raises(GridError, match='int8'):
        grid_from_msg(raw_msg(2, 1, [0, 300]))


def test_accepts_numpy_and_bytes_data():
    arr = np.array([-1, 0, 100, 50], np.int8)
    readonly = np.frombuffer(arr.tobytes(), np.int8)          # what numpy_msg deserialisation gives
    for data in (arr, readonly, arr.astype(np.int64), arr.tobytes(), list(arr), tuple(arr.tolist())):
        g = grid_from_msg(raw_msg(2, 2, data))
        np.testing.assert_array_equal(g.data.reshape(-1), arr)
        g.data[0, 0] = 7                                     # grids are edited in place (partial updates)
    with pytest.raises(GridError):
        grid_from_msg(raw_msg(2, 2, np.array([0, 0, 0, 200], np.int64)))


def test_empty_grid_round_trip():
    g = Grid(np.zeros((0, 0), np.int8), 0.1)
    back = grid_from_msg(wire_round_trip(grid_to_msg(g)))
    assert back.is_empty() and back.resolution == pytest.approx(0.1)


def test_large_grid_serialises():
    g = Grid(np.random.default_rng(1).integers(-1, 101, size=(300, 400)).astype(np.int8), 0.05)
    back = grid_from_msg(wire_round_trip(grid_to_msg(g)))
    np.testing.assert_array_equal(back.data, g.data)


# ---------------------------------------------------------------- partial updates

def update_msg(x, y, w, h, data, stamp=3.5):
    m = OccupancyGridUpdate()
    m.header.stamp = genpy.Time.from_sec(stamp)
    m.header.frame_id = 'robot2/map'
    m.x, m.y, m.width, m.height, m.data = x, y, w, h, data
    return m


def test_update_from_msg():
    u = update_from_msg(wire_round_trip(update_msg(4, 1, 3, 2, [0, 1, 2, 3, 4, -1])))
    assert (u.x, u.y, u.width, u.height) == (4, 1, 3, 2)
    assert u.data.dtype == np.int8 and u.data.shape == (2, 3)
    np.testing.assert_array_equal(u.data, [[0, 1, 2], [3, 4, -1]])
    assert u.stamp == pytest.approx(3.5) and u.frame_id == 'robot2/map'


@pytest.mark.parametrize('x,y', [(-1, 0), (0, -3)])
def test_update_negative_position_rejected(x, y):
    with pytest.raises(GridError, match='negative'):
        update_from_msg(update_msg(x, y, 1, 1, [0]))


def test_update_length_mismatch_rejected():
    with pytest.raises(GridError, match='expected 6'):
        update_from_msg(update_msg(0, 0, 3, 2, [0] * 5))


def test_update_to_msg_round_trip():
    u = GridUpdate(2, 5, 2, 3, np.arange(6, dtype=np.int8).reshape(3, 2), 9.0, 'm')
    back = update_from_msg(wire_round_trip(update_to_msg(u)))
    assert (back.x, back.y, back.width, back.height, back.frame_id) == (2, 5, 2, 3, 'm')
    np.testing.assert_array_equal(back.data, u.data)
    assert back.stamp == pytest.approx(9.0)
