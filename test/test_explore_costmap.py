"""explore costmap client: value translation, full maps, partial updates, geometry, probabilistic maps."""
import io

import numpy as np
import pytest

from explore.costmap import (FREE_SPACE, LETHAL_OBSTACLE, NO_INFORMATION, Costmap, CostmapError, InvalidMapError,
                             InvalidUpdateError, translate, translation_table)
from explore.frontier_search import FrontierSearch


def spec_cost(i: int) -> int:
    """explore.md §4.2, written independently: i is the occupancy byte reinterpreted as unsigned."""
    if i == 0:
        return 0
    if i == 99:
        return 253
    if i == 100:
        return 254
    if i == 255:
        return 255
    return (1 + (251 * (i - 1)) // 97) % 256


def test_table_matches_spec_for_every_byte():
    table = translation_table()
    assert table.dtype == np.uint8 and table.shape == (256,)
    assert [int(v) for v in table] == [spec_cost(i) for i in range(256)]


def test_table_examples_from_spec_and_ramp():
    t = translation_table()
    for occ, cost in [(1, 1), (2, 3), (10, 24), (50, 127), (98, 252), (101, 3), (127, 71), (128, 73), (254, 143)]:
        assert t[occ] == cost
    ramp = t[1:99].astype(int)
    assert ramp[0] == 1 and ramp[-1] == 252 and (np.diff(ramp) > 0).all()


def test_translate_reinterprets_int8():
    occ = np.array([-1, 0, 100, 99, 50, -2], dtype=np.int8)
    out = translate(occ)
    assert list(out[:4]) == [NO_INFORMATION, FREE_SPACE, LETHAL_OBSTACLE, 253]
    assert out[4] == spec_cost(50) and out[5] == spec_cost(254)
    # plain Python ints (what rospy gives for int8[]) translate the same
    assert (translate([int(v) for v in occ]) == out).all()


def make_map(width=4, height=3, data=None, res=0.5, origin=(-1.0, 2.0), frame='map', **kw):
    cm = Costmap(**kw)
    if data is None:
        data = [0] * (width * height)
    cm.update_full(width, height, res, origin[0], origin[1], data, frame)
    return cm


def test_full_map_layout_and_translation():
    occ = np.arange(12, dtype=np.int8) * 9 - 1  # -1, 8, 17, ... 98
    cm = make_map(data=occ)
    assert (cm.size_x, cm.size_y, cm.resolution, cm.origin_x, cm.origin_y, cm.frame_id) == (4, 3, 0.5, -1.0, 2.0, 'map')
    assert cm.data.shape == (3, 4)
    # row-major: flat index my*size_x + mx
    for my in range(3):
        for mx in range(4):
            assert cm.data[my, mx] == spec_cost(int(occ[my * 4 + mx]) & 0xFF)


def test_full_map_short_data_is_unknown_and_extra_ignored():
    cm = make_map(data=[0, 0, 100])
    assert list(cm.data.ravel()[:3]) == [0, 0, LETHAL_OBSTACLE]
    assert (cm.data.ravel()[3:] == NO_INFORMATION).all()
    cm = make_map(width=2, height=1, data=[0, 100, 0, 0, 0])
    assert list(cm.data.ravel()) == [0, LETHAL_OBSTACLE]


def test_full_map_resizes_every_time():
    cm = make_map()
    cm.update_full(2, 5, 0.1, 3.0, 4.0, [-1] * 10, 'other')
    assert cm.data.shape == (5, 2) and (cm.data == NO_INFORMATION).all()
    assert (cm.resolution, cm.origin_x, cm.origin_y, cm.frame_id) == (0.1, 3.0, 4.0, 'other')


@pytest.mark.parametrize('args', [
    dict(width=-1, height=2, resolution=0.1), dict(width=2, height=2, resolution=0.0),
    dict(width=2, height=2, resolution=float('nan')), dict(width=2, height=2, resolution=0.1, ox=float('inf')),
    dict(width=2, height=2, resolution=0.1, data=[0.5, 0.5, 0.5, 0.5])])
def test_bad_full_map_raises_and_leaves_map(args):
    cm = make_map(data=[100] * 12)
    before = cm.data.copy()
    with pytest.raises(InvalidMapError) as exc:
        cm.update_full(args['width'], args['height'], args['resolution'], args.get('ox', 0.0), 0.0,
                       args.get('data', [0] * 4), 'x')
    assert isinstance(exc.value, ValueError) and isinstance(exc.value, CostmapError)
    assert (cm.data == before).all() and cm.frame_id == 'map' and cm.resolution == 0.5


def test_partial_update_inside():
    cm = make_map(width=5, height=4, data=[-1] * 20)
    cm.update_partial(1, 2, 3, 2, [0, 100, 50, 0, 0, -1], 'map2')
    expect = np.full((4, 5), NO_INFORMATION, np.uint8)
    expect[2:4, 1:4] = [[0, LETHAL_OBSTACLE, spec_cost(50)], [0, 0, NO_INFORMATION]]
    assert (cm.data == expect).all()
    assert cm.frame_id == 'map2' and cm.data.shape == (4, 5) and cm.origin_x == -1.0


def test_partial_update_clipped_uses_patch_stride(caplog):
    cm = make_map(width=4, height=5, data=[-1] * 20)
    patch = np.array([[0, 100, 0], [100, 0, 100], [0, 0, 0]], dtype=np.int8)  # 3x3 at x=2, y=3: clipped right, top
    with caplog.at_level('WARNING'):
        cm.update_partial(2, 3, 3, 3, patch.ravel())
    assert "doesn't fully fit" in caplog.text
    # in-grid part: x 2..3, y 3..4; each grid row must come from the same patch row (the original's bug shifts row 2)
    assert (cm.data[3:5, 2:4] == translate(patch[:2, :2]).reshape(2, 2)).all()
    assert (cm.data[:3] == NO_INFORMATION).all() and (cm.data[3:, :2] == NO_INFORMATION).all()


def test_partial_update_fully_outside_changes_nothing():
    cm = make_map(width=3, height=3, data=[-1] * 9)
    cm.update_partial(5, 5, 2, 2, [0] * 4)
    assert (cm.data == NO_INFORMATION).all()


@pytest.mark.parametrize('x,y,w,h,n', [(-1, 0, 1, 1, 1), (0, -3, 1, 1, 1), (0, 0, 2, 2, 3)])
def test_bad_partial_update_raises_and_leaves_map(x, y, w, h, n):
    cm = make_map(width=3, height=3, data=[-1] * 9)
    with pytest.raises(InvalidUpdateError):
        cm.update_partial(x, y, w, h, [0] * n, 'new')
    assert (cm.data == NO_INFORMATION).all() and cm.frame_id == 'map'


def test_partial_update_before_full_map_raises():
    with pytest.raises(InvalidUpdateError):
        Costmap().update_partial(0, 0, 1, 1, [0])


def test_world_to_map_truncates_and_bounds():
    cm = make_map(width=4, height=3, res=0.5, origin=(-1.0, 2.0))
    assert cm.world_to_map(-1.0, 2.0) == (0, 0)
    assert cm.world_to_map(-0.51, 2.49) == (0, 0)
    assert cm.world_to_map(-0.5, 2.5) == (1, 1)
    assert cm.world_to_map(0.99, 3.49) == (3, 2)
    for p in [(-1.0001, 2.0), (-1.0, 1.999), (1.0, 2.0), (0.0, 3.5), (float('nan'), 2.0)]:
        assert cm.world_to_map(*p) is None
    assert Costmap().world_to_map(0.0, 0.0) is None


def test_map_to_world_is_cell_centre_and_round_trips():
    cm = make_map(width=4, height=3, res=0.5, origin=(-1.0, 2.0))
    assert cm.map_to_world(0, 0) == (-0.75, 2.25)
    for mx in range(4):
        for my in range(3):
            assert cm.world_to_map(*cm.map_to_world(mx, my)) == (mx, my)
            assert cm.index(mx, my) == my * 4 + mx


def test_probability_table_thresholds():
    t = translation_table(True, free_threshold=20, occupied_threshold=70)
    assert (t[:21] == FREE_SPACE).all() and (t[21:70] == NO_INFORMATION).all() and (t[70:101] == LETHAL_OBSTACLE).all()
    assert t[255] == NO_INFORMATION
    # invalid occupancies keep the original entries
    assert (t[101:255] == translation_table()[101:255]).all()
    with pytest.raises(ValueError):
        translation_table(True, free_threshold=70, occupied_threshold=70)


def test_probability_mode_leaves_ternary_maps_unchanged():
    rng = np.random.default_rng(3)
    occ = rng.choice(np.array([-1, 0, 100], np.int8), size=200)
    assert (translate(occ, translation_table(True)) == translate(occ)).all()


def cartographer_like(free_value=12, edge_value=45):
    """A 30x30 grid: unknown (-1) everywhere except an observed room with 'free' probabilities, an uncertain rim."""
    occ = np.full((30, 30), -1, np.int8)
    occ[5:20, 5:20] = free_value
    occ[5:20, 19] = edge_value
    occ[5, 5:20] = 90
    return occ


def test_probability_map_finds_frontiers_that_the_original_misses():
    occ = cartographer_like()
    found = {}
    for prob in (False, True):
        cm = Costmap(probability_map=prob)
        cm.update_full(30, 30, 0.1, 0.0, 0.0, occ.ravel(), 'map')
        found[prob] = FrontierSearch(cm, 1e-3, 1.0, 0.5).search_from(1.0, 1.0)
    assert found[False] == []
    assert len(found[True]) >= 1
    # the uncertain rim (value 45, between the thresholds) counts as unknown: the frontier runs along it
    xs = np.concatenate([f.points[:, 0] for f in found[True]])
    assert np.isclose(xs, 1.95).any()


def test_maps_received_as_numpy_msg_give_the_same_costmap_as_plain_ones():
    """The node subscribes with numpy_msg (cells as read-only int8 arrays, not tuples of ints): the costmap made
    from the same wire bytes must not differ, for full maps and for updates."""
    numpy_msg = pytest.importorskip('rospy.numpy_msg').numpy_msg
    OccupancyGrid = pytest.importorskip('nav_msgs.msg').OccupancyGrid
    OccupancyGridUpdate = pytest.importorskip('map_msgs.msg').OccupancyGridUpdate
    rng = np.random.default_rng(5)
    full = OccupancyGrid()
    full.info.width, full.info.height, full.info.resolution = 7, 5, 0.05
    full.data = rng.choice([-1, 0, 30, 100, 120], 35).astype(int).tolist()   # 120: invalid, read as unknown
    patch = OccupancyGridUpdate(x=2, y=1, width=3, height=2, data=[100, -1, 0, 55, 100, 0])

    def received(msg, cls):
        wire = io.BytesIO()
        msg.serialize(wire)
        return cls().deserialize(wire.getvalue())

    maps = []
    for grid_cls, update_cls in ((OccupancyGrid, OccupancyGridUpdate),
                                 (numpy_msg(OccupancyGrid), numpy_msg(OccupancyGridUpdate))):
        m, u = received(full, grid_cls), received(patch, update_cls)
        cm = Costmap()
        invalid = cm.update_full(m.info.width, m.info.height, m.info.resolution, 0.0, 0.0, m.data, 'map')
        invalid += cm.update_partial(u.x, u.y, u.width, u.height, u.data, 'map')
        maps.append((cm.data.copy(), invalid, type(m.data)))
    (plain, plain_invalid, plain_type), (fast, fast_invalid, fast_type) = maps
    assert fast_type is np.ndarray and plain_type is not np.ndarray
    np.testing.assert_array_equal(fast, plain)
    assert fast_invalid == plain_invalid == int(np.count_nonzero(np.array(full.data) == 120))
