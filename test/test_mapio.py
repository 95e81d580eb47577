"""map_server-compatible map I/O: loading semantics, map_saver output, round trips and error paths."""
import json
import math
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from multirobot_map_merge.grid import Grid
from multirobot_map_merge.mapio import (MapFileError, data_to_image, image_to_data, load_map, save_map,
                                        save_png)


def write_yaml(path, image='m.pgm', **over):
    fields = {'image': image, 'resolution': 0.05, 'origin': '[0.0, 0.0, 0.0]', 'negate': 0,
              'occupied_thresh': 0.65, 'free_thresh': 0.196}
    fields.update(over)
    lines = [f"{k}: {v}" for k, v in fields.items() if v is not None]
    Path(path).write_text('\n'.join(lines) + '\n')
    return str(path)


def make_map(tmp_path, img, name='m.pgm', **over):
    cv2.imwrite(str(tmp_path / name), img)
    return write_yaml(tmp_path / 'm.yaml', image=name, **over)


def ref_value(v, mode, negate, occ_th, free_th, alpha=255):
    """Scalar re-statement of map_server's per-pixel rule, for cross-checking."""
    avg = 255.0 - v if negate else float(v)
    if mode == 'raw':
        b = math.trunc(avg)
        return b - 256 if b > 127 else b
    p = (255.0 - avg) / 255.0
    if p > occ_th:
        return 100
    if p < free_th:
        return 0
    if mode == 'trinary' or alpha == 0:
        return -1
    return math.trunc(1 + 98 * (p - free_th) / (occ_th - free_th))


# ---------------------------------------------------------------- round trips

def test_round_trip_values_odd_size_and_origin(tmp_path):
    rng = np.random.default_rng(3)
    data = rng.integers(-1, 101, size=(7, 13)).astype(np.int8)
    data[0, :4] = [0, 25, 26, 65]   # around both map_saver thresholds
    data[1, :3] = [64, 100, -1]
    grid = Grid(data, 0.1, (-3.25, 1.5, 0.7), frame_id='robot1')
    yaml_path, pgm_path = save_map(grid, str(tmp_path / 'out'))
    assert yaml_path.endswith('out.yaml') and pgm_path.endswith('out.pgm')
    back = load_map(yaml_path)
    expected = np.where(data < 0, -1, np.where(data <= 25, 0, np.where(data >= 65, 100, -1)))
    np.testing.assert_array_equal(back.data, expected)
    assert back.width == 13 and back.height == 7
    assert back.resolution == pytest.approx(0.1)
    assert back.origin == pytest.approx((-3.25, 1.5, 0.7), abs=1e-6)


def test_saved_pgm_bytes_are_map_saver_trinary(tmp_path):
    data = np.array([[0, 100, -1], [65, 50, 25]], dtype=np.int8)   # row 0 = bottom
    _, pgm = save_map(Grid(data, 0.05), str(tmp_path / 'a'))
    raw = Path(pgm).read_bytes()
    assert raw.startswith(b'P5\n')
    pixels = np.frombuffer(raw[-6:], dtype=np.uint8).reshape(2, 3)
    np.testing.assert_array_equal(pixels[0], [0, 205, 254])   # image top = grid row 1: 65 occ, 50 unknown, 25 free
    np.testing.assert_array_equal(pixels[1], [254, 0, 205])   # grid row 0: 0 free, 100 occ, -1 unknown
    assert cv2.imread(pgm, cv2.IMREAD_UNCHANGED).shape == (2, 3)


def test_saved_yaml_fields(tmp_path):
    import yaml
    yaml_path, _ = save_map(Grid(np.zeros((3, 4), np.int8), 0.025, (1.0, -2.0, -0.5)), str(tmp_path / 'sub_map'))
    meta = yaml.safe_load(Path(yaml_path).read_text())
    assert meta['image'] == 'sub_map.pgm'        # basename, so the pair can be moved together
    assert meta['resolution'] == pytest.approx(0.025)
    assert meta['origin'] == pytest.approx([1.0, -2.0, -0.5])
    assert meta['negate'] == 0
    assert meta['occupied_thresh'] == pytest.approx(0.65)
    assert meta['free_thresh'] == pytest.approx(0.196)


def test_custom_save_thresholds(tmp_path):
    data = np.array([[10, 40, 90]], dtype=np.int8)
    back = load_map(save_map(Grid(data, 1.0), str(tmp_path / 't'), occupied_thresh=90, free_thresh=5)[0])
    np.testing.assert_array_equal(back.data, [[-1, -1, 100]])


def test_205_loads_as_unknown_and_206_as_free(tmp_path):
    img = np.array([[205, 206, 254, 0, 1]], dtype=np.uint8)
    g = load_map(make_map(tmp_path, img))
    np.testing.assert_array_equal(g.data, [[-1, 0, 0, 100, 100]])


def test_row_flip(tmp_path):
    img = np.full((4, 3), 254, np.uint8)
    img[0, :] = 0                      # top image row: the highest y
    g = load_map(make_map(tmp_path, img))
    assert (g.data[3] == 100).all() and (g.data[:3] == 0).all()
    # and save_map puts it back on top
    _, pgm = save_map(g, str(tmp_path / 'again'))
    np.testing.assert_array_equal(cv2.imread(pgm, cv2.IMREAD_UNCHANGED), np.where(img == 0, 0, 254))


# ---------------------------------------------------------------- map_server pixel semantics

@pytest.mark.parametrize('mode', ['trinary', 'scale', 'raw'])
@pytest.mark.parametrize('negate', [0, 1])
def test_modes_match_scalar_rule(tmp_path, mode, negate):
    img = np.arange(256, dtype=np.uint8).reshape(16, 16)
    g = load_map(make_map(tmp_path, img, mode=mode, negate=negate))
    flipped = img[::-1]
    expected = np.vectorize(lambda v: ref_value(int(v), mode, negate, 0.65, 0.196))(flipped)
    np.testing.assert_array_equal(g.data, expected)
    # sanity of the rule itself on hand-picked pixels
    if mode == 'trinary' and not negate:
        assert g.data[15, 0] == 100 and g.data[0, 15] == 0       # black pixel occupied, white free
    if mode == 'raw':
        assert g.data[0, 15] == (0 if negate else -1)            # 255 wraps to -1 like map_server's int8


def test_scale_mid_values_are_in_1_99_and_monotonic(tmp_path):
    img = np.arange(256, dtype=np.uint8)[None, :]
    g = load_map(make_map(tmp_path, img, mode='scale'))
    mid = g.data[0][(g.data[0] > 0) & (g.data[0] < 100)]
    assert mid.size > 50 and mid.min() >= 1 and mid.max() <= 99
    assert np.all(np.diff(mid.astype(int)) <= 0)          # brighter pixel -> lower occupancy


def test_threshold_is_strict(tmp_path):
    # 204 -> p = 51/255 = 0.2 exactly, 153 -> p = 0.4 exactly
    img = np.array([[204, 205, 203, 153, 152]], dtype=np.uint8)
    g = load_map(make_map(tmp_path, img, occupied_thresh=0.4, free_thresh=0.2))
    np.testing.assert_array_equal(g.data, [[-1, 0, -1, -1, 100]])
    # equal thresholds: the one pixel exactly on them is neither free nor occupied
    g = load_map(make_map(tmp_path, img, occupied_thresh=0.2, free_thresh=0.2))
    np.testing.assert_array_equal(g.data, [[-1, 0, 100, 100, 100]])


def test_negate_swaps_black_and_white(tmp_path):
    img = np.array([[0, 255, 205]], dtype=np.uint8)
    a = load_map(make_map(tmp_path, img, negate=0)).data
    b = load_map(make_map(tmp_path, img, negate=1)).data
    np.testing.assert_array_equal(a, [[100, 0, -1]])
    np.testing.assert_array_equal(b, [[0, 100, 100]])    # 205 negated -> p = 205/255 > 0.65


def test_rgb_uses_channel_mean(tmp_path):
    img = np.zeros((1, 3, 3), np.uint8)
    img[0, 0] = (255, 255, 255)
    img[0, 1] = (0, 255, 255)       # mean 170 -> p 0.333: unknown
    img[0, 2] = (0, 0, 255)         # mean 85 -> p 0.667: occupied
    g = load_map(make_map(tmp_path, img, name='m.png'))
    np.testing.assert_array_equal(g.data, [[0, -1, 100]])


def test_rgba_alpha_handling(tmp_path):
    img = np.zeros((1, 3, 4), np.uint8)
    img[0, 0] = (255, 255, 255, 0)      # trinary averages alpha in: 191.25 -> p 0.25 -> unknown
    img[0, 1] = (255, 255, 255, 255)
    img[0, 2] = (128, 128, 128, 0)      # scale: mid value but transparent -> unknown
    tri = load_map(make_map(tmp_path, img, name='m.png')).data
    np.testing.assert_array_equal(tri, [[-1, 0, -1]])    # (128*3 + 0)/4 = 96 -> p 0.62: unknown
    sc = load_map(make_map(tmp_path, img, name='m.png', mode='scale')).data
    assert sc[0, 0] == 0 and sc[0, 1] == 0 and sc[0, 2] == -1
    img[0, 2, 3] = 255
    sc = load_map(make_map(tmp_path, img, name='m.png', mode='scale')).data
    assert sc[0, 2] == ref_value(128, 'scale', 0, 0.65, 0.196)


def test_png_gray_equals_pgm(tmp_path):
    img = np.random.default_rng(1).choice(np.array([0, 205, 254], np.uint8), size=(9, 11))
    a = load_map(make_map(tmp_path, img, name='m.pgm')).data
    b = load_map(make_map(tmp_path, img, name='m.png')).data
    np.testing.assert_array_equal(a, b)
    assert set(np.unique(a)) == {-1, 0, 100}


def test_absolute_image_path(tmp_path):
    other = tmp_path / 'elsewhere'
    other.mkdir()
    cv2.imwrite(str(other / 'x.pgm'), np.array([[0, 254]], np.uint8))
    g = load_map(write_yaml(tmp_path / 'm.yaml', image=str(other / 'x.pgm')))
    np.testing.assert_array_equal(g.data, [[100, 0]])


def test_mode_missing_means_trinary(tmp_path):
    img = np.array([[128]], np.uint8)
    assert load_map(make_map(tmp_path, img)).data[0, 0] == -1
    assert load_map(make_map(tmp_path, img, mode='scale')).data[0, 0] > 0


def test_save_png_preview(tmp_path):
    data = np.array([[0, 100], [-1, 30]], dtype=np.int8)
    path = save_png(Grid(data, 0.05), str(tmp_path / 'p.png'))
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(img, [[205, 205], [254, 0]])   # top row = grid row 1
    np.testing.assert_array_equal(img, data_to_image(data))


def test_image_to_data_rejects_bad_mode():
    with pytest.raises(ValueError):
        image_to_data(np.zeros((2, 2), np.uint8), mode='fancy')


# ---------------------------------------------------------------- errors

def assert_error(yaml_path, *words):
    with pytest.raises(MapFileError) as e:
        load_map(yaml_path)
    msg = str(e.value)
    assert os.path.basename(yaml_path) in msg or 'm.pgm' in msg or 'elsewhere' in msg, msg
    for w in words:
        assert w in msg, msg


def test_error_missing_yaml(tmp_path):
    assert_error(str(tmp_path / 'nope.yaml'), 'not found')


def test_error_bad_yaml(tmp_path):
    p = tmp_path / 'm.yaml'
    p.write_text('image: [unclosed\nresolution: 0.05\n')
    assert_error(str(p), 'invalid YAML')
    p.write_text('- just\n- a list\n')
    assert_error(str(p), 'mapping')


@pytest.mark.parametrize('field', ['image', 'resolution', 'origin', 'negate', 'occupied_thresh', 'free_thresh'])
def test_error_missing_field(tmp_path, field):
    cv2.imwrite(str(tmp_path / 'm.pgm'), np.zeros((2, 2), np.uint8))
    assert_error(write_yaml(tmp_path / 'm.yaml', **{field: None}), 'missing', field)


@pytest.mark.parametrize('field,value,word', [
    ('resolution', 0, 'resolution'), ('resolution', -0.05, 'resolution'), ('resolution', '.nan', 'resolution'),
    ('resolution', 'abc', 'resolution'), ('occupied_thresh', 'high', 'occupied_thresh'),
    ('free_thresh', '[0.1]', 'free_thresh'), ('negate', 'maybe', 'negate'), ('mode', 'fancy', 'mode'),
    ('origin', '[1.0, 2.0]', 'origin'), ('origin', '[1.0, .inf, 0.0]', 'origin'), ('origin', 'zero', 'origin'),
    ('image', '""', 'image'), ('image', '[a, b]', 'image')])
def test_error_bad_field(tmp_path, field, value, word):
    cv2.imwrite(str(tmp_path / 'm.pgm'), np.zeros((2, 2), np.uint8))
    assert_error(write_yaml(tmp_path / 'm.yaml', **{field: value}), word)


def test_error_missing_image(tmp_path):
    with pytest.raises(MapFileError) as e:
        load_map(write_yaml(tmp_path / 'm.yaml', image='gone.pgm'))
    assert 'gone.pgm' in str(e.value) and 'not found' in str(e.value)


def test_error_unreadable_image(tmp_path):
    (tmp_path / 'm.pgm').write_bytes(b'this is not an image at all')
    with pytest.raises(MapFileError) as e:
        load_map(write_yaml(tmp_path / 'm.yaml'))
    assert 'm.pgm' in str(e.value) and 'unreadable' in str(e.value)


def test_error_unwritable_destination(tmp_path):
    with pytest.raises(MapFileError) as e:
        save_map(Grid(np.zeros((2, 2), np.int8), 0.05), str(tmp_path / 'no_such_dir' / 'm'))
    assert 'no_such_dir' in str(e.value)


# ---------------------------------------------------------------- real data

@pytest.fixture
def dev_data(request):
    try:
        base = Path(request.getfixturevalue('shared_dir'))
    except pytest.FixtureLookupError:
        base = Path(__file__).resolve().parents[2] / 'shared'   # CI: ../shared beside the clone
    for cand in (base / 'data' / 'dev', base / 'dev', base):
        if (cand / 'index.json').is_file() or any(cand.glob('*/truth.json')):
            return cand
    pytest.skip('shared dev data not available')


def test_load_real_dev_map(dev_data, tmp_path):
    scen = sorted(p.parent for p in dev_data.glob('*/truth.json'))[0]
    truth = json.loads((scen / 'truth.json').read_text())
    m = truth['maps'][0]
    g = load_map(str(scen / m['file']))
    assert [g.width, g.height] == m['size']
    assert g.resolution == pytest.approx(m['resolution'])
    assert set(np.unique(g.data)) <= {-1, 0, 100}
    # the known-cell bounding box, through the yaml origin, is the one the truth gives (map frame metres)
    rows = np.flatnonzero(g.known_mask().any(axis=1))
    cols = np.flatnonzero(g.known_mask().any(axis=0))
    corners = np.array([[cols[0], rows[0]], [cols[-1] + 1, rows[0]], [cols[-1] + 1, rows[-1] + 1],
                        [cols[0], rows[-1] + 1], ], float)
    pts = (g.cell_to_map() @ np.c_[corners, np.ones(4)].T).T[:, :2]
    np.testing.assert_allclose(pts, np.asarray(m['known_bbox']), atol=1e-3)
    # saving and loading again changes nothing
    back = load_map(save_map(g, str(tmp_path / 'copy'))[0])
    np.testing.assert_array_equal(back.data, g.data)
