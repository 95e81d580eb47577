"""merge_maps --bag: robot maps read from a rosbag (written here with the rosbag Python API), as the node would
hold them: full maps replace, updates patch, in bag order, cut at --at; bad bags give one-line errors."""
import json
import subprocess
import sys

import numpy as np
import pytest

rosbag = pytest.importorskip('rosbag')
import genpy  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from multirobot_map_merge import transforms as tf  # noqa: E402
from multirobot_map_merge.grid import Grid  # noqa: E402
from multirobot_map_merge.mapio import load_map  # noqa: E402
from multirobot_map_merge.ros.bag_input import BagError, find_robots, read_bag_maps  # noqa: E402
from multirobot_map_merge.ros.conversions import GridUpdate, grid_to_msg, update_to_msg  # noqa: E402

T0 = 1000.0


def write_bag(path, entries):
    """entries: (seconds after T0, topic, message)."""
    with rosbag.Bag(str(path), 'w') as bag:
        for dt, topic, msg in entries:
            bag.write(topic, msg, genpy.Time.from_sec(T0 + dt))
    return str(path)


def grid(value=0, shape=(6, 8), stamp=0.0):
    return Grid(np.full(shape, value, np.int8), 0.1, (1.0, 2.0, 0.0), 'a_robot/with_a_long/map_frame', stamp)


def update(x, y, data, stamp):
    data = np.asarray(data, np.int8)
    return update_to_msg(GridUpdate(x, y, data.shape[1], data.shape[0], data, stamp))


def test_maps_and_updates_in_bag_order_and_cut_at(tmp_path):
    path = write_bag(tmp_path / 'a.bag', [
        (0.0, '/robot_1/map', grid_to_msg(grid(-1, stamp=T0))),
        (0.5, '/chatter', String('not a map')),
        (1.0, '/robot_1/map_updates', update_to_msg(GridUpdate(2, 1, 2, 1, np.array([[100, 100]], np.int8),
                                                               T0 + 1))),
        (1.5, '/robot_2/map', grid_to_msg(grid(0, shape=(3, 3), stamp=T0 + 1.5))),
        (3.0, '/robot_1/map_updates', update(0, 0, [[0]], T0 + 3)),
        (4.0, '/robot_2/map', grid_to_msg(grid(100, shape=(4, 5), stamp=T0 + 4))),   # resized: replaces
    ])
    robots = read_bag_maps(path)
    assert [r.name for r in robots] == ['/robot_1', '/robot_2']
    r1, r2 = robots
    assert r1.updates_topic == '/robot_1/map_updates' and r2.updates_topic is None
    assert (r1.maps, r1.updates, r2.maps) == (1, 2, 2)
    assert r1.grid.data[1, 2:4].tolist() == [100, 100] and r1.grid.data[0, 0] == 0
    assert int((r1.grid.data != -1).sum()) == 3
    assert r1.grid.origin == (1.0, 2.0, 0.0) and r1.grid.resolution == pytest.approx(0.1)
    assert r2.grid.data.shape == (4, 5) and (r2.grid.data == 100).all()

    early = {r.name: r for r in read_bag_maps(path, at=2.0)}
    assert early['/robot_1'].updates == 1 and early['/robot_1'].grid.data[0, 0] == -1
    assert early['/robot_2'].grid.data.shape == (3, 3)
    assert read_bag_maps(path, at=0.2)[1].grid is None      # robot_2's first map comes later


def test_only_the_full_map_the_node_keeps_counts_with_the_updates_after_it(tmp_path):
    path = write_bag(tmp_path / 'o.bag', [
        (0.0, '/r/map', grid_to_msg(grid(0, stamp=T0))),
        (1.0, '/r/map_updates', update(0, 0, [[100]], T0 + 1)),
        (2.0, '/r/map', grid_to_msg(grid(-1, stamp=T0 + 2))),
        (3.0, '/r/map_updates', update(1, 0, [[100]], T0 + 3)),
        (4.0, '/r/map', grid_to_msg(grid(0, stamp=T0 + 1.5))),          # older stamp, same size: dropped
        (5.0, '/r/map_updates', update(2, 0, [[100]], T0 + 5)),
        (6.0, '/r/chatter', String('x')),
    ])
    (robot,) = read_bag_maps(path)
    assert (robot.maps, robot.updates) == (3, 3)
    assert robot.grid.data[0, :4].tolist() == [-1, 100, 100, -1] and int((robot.grid.data != -1).sum()) == 2
    resized = write_bag(tmp_path / 'r.bag', [
        (0.0, '/r/map', grid_to_msg(grid(0, stamp=T0 + 9))),
        (1.0, '/r/map', grid_to_msg(grid(100, shape=(2, 3), stamp=T0))),   # older but resized: replaces
    ])
    assert read_bag_maps(resized)[0].grid.data.shape == (2, 3)


def test_topic_suffix_and_discovery_rules():
    topics = {'/a/map': 'nav_msgs/OccupancyGrid', '/b/grid': 'nav_msgs/OccupancyGrid',
              '/b/grid_updates': 'map_msgs/OccupancyGridUpdate', '/c/map': 'std_msgs/String',
              '/map': 'nav_msgs/OccupancyGrid', '/d/map_updates': 'nav_msgs/OccupancyGrid'}
    assert [r.name for r in find_robots(topics)] == ['/a', '/']
    robots = find_robots(topics, 'grid')
    assert [(r.name, r.updates_topic) for r in robots] == [('/b', '/b/grid_updates')]


def test_malformed_messages_are_refused_per_robot_and_the_rest_kept(tmp_path, caplog):
    bad = grid_to_msg(grid(0))
    bad.data = bad.data[:-1]
    path = write_bag(tmp_path / 'b.bag', [
        (0.0, '/r1/map', grid_to_msg(grid(0, stamp=T0))),
        (1.0, '/r1/map', bad),
        (2.0, '/r1/map_updates', update(50, 50, [[100]], T0 + 2)),       # outside the map
        (3.0, '/r2/map_updates', update(0, 0, [[100]], T0 + 3)),         # before any map of r2
        (4.0, '/r2/map', grid_to_msg(grid(-1, stamp=T0 + 4))),
    ])
    r1, r2 = read_bag_maps(path)
    assert (r1.grid.data == 0).all() and r1.refused == 2
    # r2's early update would be refused, but it comes before the full map that counts: never read
    assert (r2.grid.data == -1).all() and (r2.maps, r2.updates, r2.refused) == (1, 1, 0)
    warnings = [r.getMessage() for r in caplog.records if r.levelname == 'WARNING']
    assert warnings == ['/r1: 2 of 3 messages refused, the first: malformed map: map of 8 x 6 cells: data has 47 '
                        'cells, expected 48']


def test_bad_bags_raise_one_line_errors(tmp_path):
    with pytest.raises(BagError, match='not found'):
        read_bag_maps(str(tmp_path / 'missing.bag'))
    text = tmp_path / 'text.bag'
    text.write_text('not a bag\n' * 10)
    with pytest.raises(BagError, match='not a readable bag'):
        read_bag_maps(str(text))
    only_chatter = write_bag(tmp_path / 'c.bag', [(0.0, '/chatter', String('x')),
                                                  (0.1, '/robot/grid', grid_to_msg(grid()))])
    with pytest.raises(BagError, match=r'no nav_msgs/OccupancyGrid topic named <ns>/map .*/robot/grid'):
        read_bag_maps(only_chatter)
    with pytest.raises(BagError, match='--at'):
        read_bag_maps(only_chatter, at=-1.0)
    good = tmp_path / 'g.bag'
    write_bag(good, [(dt, '/r/map', grid_to_msg(grid(0, shape=(200, 200), stamp=T0 + dt))) for dt in range(5)])
    truncated = tmp_path / 't.bag'
    truncated.write_bytes(good.read_bytes()[:len(good.read_bytes()) // 2])
    corrupt = tmp_path / 'x.bag'
    raw = bytearray(good.read_bytes())
    raw[4096:4196] = b'\xff' * 100   # the first chunk's header, after the 4 KiB file header
    corrupt.write_bytes(bytes(raw))
    for path in (truncated, corrupt):
        with pytest.raises(BagError) as err:
            read_bag_maps(str(path))
        assert '\n' not in str(err.value) and str(path) in str(err.value)


def run_merge_maps(repo_root, *args):
    return subprocess.run([sys.executable, str(repo_root / 'nodes' / 'merge_maps'), *args],
                          capture_output=True, text=True, timeout=120)


def sample_bag(repo_root, tmp_path):
    """The chain3 sample maps as three robots' topics: full maps, with half of map_01 sent as an update."""
    entries = []
    for k in range(3):
        g = load_map(str(repo_root / 'data' / 'samples' / 'chain3' / f'map_0{k}.yaml'))
        g.stamp = T0 + k
        if k == 1:
            half = g.copy()
            rows = g.height // 2
            half.data[rows:] = -1
            entries.append((k, f'/robot_{k}/map', grid_to_msg(half)))
            entries.append((k + 0.5, f'/robot_{k}/map_updates', update(0, rows, g.data[rows:], T0 + k + 0.5)))
        else:
            entries.append((k, f'/robot_{k}/map', grid_to_msg(g)))
    return write_bag(tmp_path / 'chain3.bag', entries)


def test_merge_maps_bag_places_the_robots_as_their_map_files(repo_root, tmp_path):
    path = sample_bag(repo_root, tmp_path)
    proc = run_merge_maps(repo_root, '--bag', path, '--output', str(tmp_path / 'm'),
                          '--transforms-json', str(tmp_path / 't.json'))
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / 't.json').read_text())
    assert [m['robot'] for m in doc['maps']] == ['/robot_0', '/robot_1', '/robot_2']
    assert all(m['included'] for m in doc['maps'])
    files = sorted(str(p) for p in (repo_root / 'data' / 'samples' / 'chain3').glob('map_*.yaml'))
    assert run_merge_maps(repo_root, '--output', str(tmp_path / 'f'), '--transforms-json',
                          str(tmp_path / 'f.json'), *files).returncode == 0
    from_files = json.loads((tmp_path / 'f.json').read_text())['maps']
    for a, b in zip(doc['maps'], from_files):
        ta, tb = (tf.rigid(m['transform']['x'], m['transform']['y'], m['transform']['yaw']) for m in (a, b))
        assert np.allclose(ta, tb, atol=1e-6)   # the update restored map_01 exactly
    assert (tmp_path / 'm_overlay.png').stat().st_size > 0 and (tmp_path / 'm.yaml').exists()

    early = run_merge_maps(repo_root, '--bag', path, '--at', '0.5', '--output', str(tmp_path / 'e'),
                           '--transforms-json', str(tmp_path / 'e.json'))
    assert early.returncode == 0, early.stderr
    assert [m['included'] for m in json.loads((tmp_path / 'e.json').read_text())['maps']] == [True, False, False]


@pytest.mark.parametrize('args, reason', [
    (['--bag', '/nonexistent.bag'], 'bag file not found'),
    (['--bag', 'BAG', 'MAP'], 'not both'),
    (['--at', '3', 'MAP'], 'need --bag'),
    (['--bag', 'BAG', '--topic-suffix', 'grid'], 'no nav_msgs/OccupancyGrid topic named <ns>/grid'),
    (['--bag', 'BAG', '--at', '-1'], 'non-negative'),
    (['--bag', 'TEXT'], 'not a readable bag'),
])
def test_merge_maps_bad_bag_exits_2_with_one_line(repo_root, tmp_path, args, reason):
    bag = write_bag(tmp_path / 'one.bag', [(0.0, '/r/map', grid_to_msg(grid(0)))])
    (tmp_path / 'text.bag').write_text('hello')
    sample = str(repo_root / 'data' / 'samples' / 'chain3' / 'map_00.yaml')
    args = [{'BAG': bag, 'MAP': sample, 'TEXT': str(tmp_path / 'text.bag')}.get(a, a) for a in args]
    proc = run_merge_maps(repo_root, *args)
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if 'error' in line]
    assert len(lines) == 1 and reason in lines[0], proc.stderr
