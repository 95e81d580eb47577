"""Each node of nodes/ resolves to exactly one executable, so `rosrun multirobot_map_merge NODE` runs it without
asking which copy (the workspace holds the package as links to the repository's entries, not one link to the
repository, which contains the workspace itself)."""
import shutil
import subprocess
from pathlib import Path

import pytest

NODES = sorted(p.name for p in (Path(__file__).resolve().parents[1] / 'nodes').iterdir())
needs_ros = pytest.mark.skipif(shutil.which('rosrun') is None, reason='rosrun not on PATH (use scripts/env.sh)')


@needs_ros
@pytest.mark.parametrize('node', NODES)
def test_node_resolves_to_one_executable(node):
    import roslib.packages
    assert len(roslib.packages.find_node('multirobot_map_merge', node)) == 1


@needs_ros
def test_rosrun_runs_merge_maps_without_a_master():
    done = subprocess.run(['rosrun', 'multirobot_map_merge', 'merge_maps', '--help'], capture_output=True,
                          text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'usage: merge_maps' in done.stdout
    assert 'non-unique' not in done.stdout + done.stderr and 'loop' not in done.stderr
