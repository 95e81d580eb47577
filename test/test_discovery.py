"""Discovery helpers: roscpp name semantics (map_merge.md §3.1) and the robot-map-topic filter (§3.2)."""
import pytest

from multirobot_map_merge.ros.discovery import (append, clean, init_pose_param_names, parent_namespace,
                                            robot_map_topics, robot_topics)
from multirobot_map_merge.ros.params import MapMergeParams

GRID = 'nav_msgs/OccupancyGrid'


@pytest.mark.parametrize('name, expected', [('/', ''), ('//a//b/', '/a/b'), ('/robot1', '/robot1'), ('', ''),
                                            ('a/', 'a')])
def test_clean(name, expected):
    assert clean(name) == expected


@pytest.mark.parametrize('a, b, expected', [('/robot1', 'map', '/robot1/map'), ('/', 'map', '/map'),
                                            ('/robot1', '/map', '/robot1/map'), ('/robot1/', 'map/', '/robot1/map')])
def test_append(a, b, expected):
    assert append(a, b) == expected


@pytest.mark.parametrize('name, expected', [('', ''), ('/', '/'), ('/robot1/map', '/robot1'), ('/map', '/'),
                                            ('/a/b/map', '/a/b'), ('map', ''), ('/a/b/', '/a')])
def test_parent_namespace(name, expected):
    assert parent_namespace(name) == expected


def test_robot_map_topics_filter():
    topics = [['/robot1/map', GRID], ['/robot2/map', GRID], ['/robot2/map_updates', 'map_msgs/OccupancyGridUpdate'],
              ['/robot3/map', 'std_msgs/String'], ['/map_merge/map', GRID], ['/map', GRID],
              ['/a/b/map', GRID], ['/robot4/costmap', GRID], ['/robot1/map', GRID]]
    got = robot_map_topics(topics, MapMergeParams(), own_topic='/map_merge/map')
    assert got == ['/robot1', '/robot2', '/', '/a/b']


def test_root_map_is_own_output():
    got = robot_map_topics([['/map', GRID], ['/r1/map', GRID]], MapMergeParams(), own_topic='/map')
    assert got == ['/r1']


def test_robot_namespace_is_plain_substring():
    params = MapMergeParams(robot_namespace='bot')
    topics = [['/robot1/map', GRID], ['/tb3/map', GRID], ['/x/bottle/map', GRID]]
    assert robot_map_topics(topics, params, '/map_merge/map') == ['/robot1', '/x/bottle']


def test_robot_map_topic_with_inner_slash_never_matches_and_slashes_are_harmless():
    topics = [['/r1/a/map', GRID]]
    assert robot_map_topics(topics, MapMergeParams(robot_map_topic='a/map'), '/m') == []
    assert robot_map_topics([['/r1/map', GRID]], MapMergeParams(robot_map_topic='/map/'), '/m') == ['/r1']


def test_robot_topics_and_init_pose_names():
    assert robot_topics('/robot1', MapMergeParams()) == ('/robot1/map', '/robot1/map_updates')
    assert robot_topics('/', MapMergeParams()) == ('/map', '/map_updates')
    assert init_pose_param_names('/robot1') == ['/robot1/map_merge/init_pose_' + k for k in ('x', 'y', 'z', 'yaw')]
    assert init_pose_param_names('/')[0] == '/map_merge/init_pose_x'


def test_params_read_types():
    warnings = []
    values = {'~merging_rate': 2, '~known_init_poses': 'yes', '~estimation_confidence': float('nan'),
              '~world_frame': 5, '~origin_mode': 'world', '~discovery_rate': 0.0}
    p = MapMergeParams.read(lambda n, d: values.get(n, d), warn=warnings.append)
    assert p.merging_rate == 2.0 and isinstance(p.merging_rate, float)
    assert p.known_init_poses is True and p.estimation_confidence == 1.0 and p.world_frame == 'world'
    assert p.origin_mode == 'world' and p.discovery_rate == 0.05
    assert len(warnings) == 4 and all('using the default' in w for w in warnings)
    assert MapMergeParams.read(lambda n, d: d) == MapMergeParams()


def test_param_table_lists_every_parameter_from_the_dataclass():
    """scripts/param_table.py (the table in doc/map_merge.md) and the node docstring come from MapMergeParams'
    fields."""
    import dataclasses
    import importlib.util
    from pathlib import Path

    script = Path(__file__).resolve().parent.parent / 'scripts' / 'param_table.py'
    spec = importlib.util.spec_from_file_location('param_table', script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    table = module.table().splitlines()
    fields = dataclasses.fields(MapMergeParams)
    for f in fields:
        assert f.metadata.get('doc'), f'{f.name} has no meaning documented'
        row = [r for r in table if r.startswith(f'| `~{f.name}` |')]
        assert len(row) == 1, f.name
        default = {True: 'true', False: 'false'}.get(f.default, f.default) if isinstance(f.default, bool) \
            else f.default
        assert f'`{default}`' in row[0] or f'`"{default}"`' in row[0], row[0]
    assert MapMergeParams().merging_rate == 4.0 and MapMergeParams().known_init_poses is True
    assert [r for r in table if 'init_pose' in r and r.startswith('| `<robot_ns>')]
