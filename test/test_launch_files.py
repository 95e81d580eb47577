"""Every launch file in launch/ passes the roslaunch check (as the original's roslaunch_add_file_check): it parses
with its default args, and every node's package and executable resolve. Files added later are picked up (glob).

Also: every `$(find multirobot_map_merge)/...` file a launch file names exists (e.g. the rviz config, whose node is
off by default and so not checked above), and the rviz config shows map_merge.launch's merged map in world.
Needs the ROS environment of scripts/env.sh (ROS_PACKAGE_PATH with this package), as under `make test`.
"""
import os
import re
import shutil
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parent.parent
LAUNCH_DIR = REPO / 'launch'
LAUNCH_FILES = sorted(LAUNCH_DIR.glob('*.launch'))
FIND_SELF = re.compile(r'\$\(find multirobot_map_merge\)(/[^\s"\'<>)]+)')


def _ros_env() -> bool:
    if shutil.which('roslaunch') is None:
        return False
    try:
        import rospkg
        # the workspace's package directory links to the repository's entries
        pkg = Path(rospkg.RosPack().get_path('multirobot_map_merge'))
        return (pkg / 'package.xml').resolve() == REPO / 'package.xml'
    except Exception:
        return False


needs_ros = pytest.mark.skipif(not _ros_env(), reason='ROS environment missing (run under scripts/env.sh)')


def test_launch_dir_has_the_original_files():
    names = {p.name for p in LAUNCH_FILES}
    assert {'map_merge.launch', 'from_map_server.launch'} <= names
    assert (LAUNCH_DIR / 'map_merge.rviz').is_file()


@needs_ros
@pytest.mark.parametrize('launch_file', LAUNCH_FILES, ids=[p.name for p in LAUNCH_FILES])
def test_roslaunch_check(launch_file: Path):
    from roslaunch.rlutil import check_roslaunch
    error = check_roslaunch(str(launch_file))
    assert error is None, f'{launch_file.name}: {error}'


@needs_ros
@pytest.mark.parametrize('launch_file', LAUNCH_FILES, ids=[p.name for p in LAUNCH_FILES])
def test_launch_file_nodes_load(launch_file: Path):
    """The launch file loads into a config (as `roslaunch --nodes` does) and starts at least one node."""
    import roslaunch.config
    config = roslaunch.config.load_config_default([str(launch_file)], 11311, verbose=False)
    assert config.nodes or config.tests, f'{launch_file.name} starts no node'


@pytest.mark.parametrize('launch_file', LAUNCH_FILES, ids=[p.name for p in LAUNCH_FILES])
def test_files_named_by_launch_files_exist(launch_file: Path):
    for rel in FIND_SELF.findall(launch_file.read_text()):
        assert (REPO / rel.lstrip('/')).is_file(), f'{launch_file.name} names missing {rel}'


def test_rviz_config_shows_the_merged_map():
    config = yaml.safe_load((LAUNCH_DIR / 'map_merge.rviz').read_text())
    manager = config['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == 'world'
    maps = [d for d in manager['Displays'] if d['Class'] == 'rviz/Map']
    assert [d['Topic'] for d in maps] == ['/map_merge/map']   # map_merge.launch: ns map_merge, merged_map_topic map
    assert {'/initialpose', '/move_base_simple/goal'} <= {t.get('Topic') for t in manager['Tools']}
    launch = (LAUNCH_DIR / 'map_merge.launch').read_text()
    assert '<group ns="map_merge">' in launch and re.search(r'name="merged_map_topic"\s+value="map"', launch)
    assert re.search(r'name="world_frame"\s+value="world"', launch)


@needs_ros
def test_from_map_server_args():
    """from_map_server.launch takes map1, map2 and rviz as the original, and rviz:=true adds the rviz node."""
    import roslaunch.config
    path = str(LAUNCH_DIR / 'from_map_server.launch')
    plain = roslaunch.config.load_config_default([path], 11311, verbose=False)
    names = {n.name for n in plain.nodes}
    assert {'robot1_publisher', 'robot2_publisher', 'map_merge'} <= names and 'rviz' not in names
    args = {n.name: n.args for n in plain.nodes}
    assert args['robot1_publisher'] == 'map1.yaml' and args['robot2_publisher'] == 'map2.yaml'
    with_rviz = roslaunch.config.load_config_default([(path, ['rviz:=true', 'map1:=a.yaml'])], 11311, verbose=False)
    rviz = [n for n in with_rviz.nodes if n.name == 'rviz']
    assert rviz and rviz[0].args.endswith('launch/map_merge.rviz')
    assert os.path.isfile(rviz[0].args.split('-d', 1)[1].strip())
