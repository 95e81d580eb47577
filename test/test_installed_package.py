"""The package as a ROS user installs it: built and installed with catkin_make in a temporary workspace by
/usr/bin/python3, run in a clean environment (no venv on PATH or sys.path) on Debian's python3-numpy, -opencv,
-networkx and -yaml: merge_maps merges a sample as in the venv, and every module of the three packages (the nodes
included) imports from the install space.
"""
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

from multirobot_map_merge import transforms as tf

from test_merging_pipeline import placement_error

SYSTEM_PYTHON = '/usr/bin/python3'
PACKAGES = ('multirobot_map_merge', 'explore', 'fleet_sim')
NODE_MODULES = ('multirobot_map_merge.ros.node', 'explore.node', 'fleet_sim.node')
# the versions package.xml documents as the oldest that work (Debian 12)
DEBIAN_VERSIONS = {'numpy': '1.24', 'cv2': '4.6', 'networkx': '2.8'}


def clean_env(home: Path) -> dict:
    """What a fresh login shell on a ROS machine has: no venv, no workspace sourced, no ROS variables."""
    return {'PATH': '/usr/local/bin:/usr/bin:/bin', 'HOME': str(home), 'LANG': 'C.UTF-8',
            'ROS_HOME': str(home / 'ros_home'), 'PYTHONDONTWRITEBYTECODE': '1'}


def run(cmd: str, env: dict, timeout: float = 300.0) -> subprocess.CompletedProcess:
    return subprocess.run(['bash', '-c', cmd], env=env, capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


@pytest.fixture(scope='module')
def install_space(repo_root):
    """A catkin workspace holding the repository's top-level entries, built and installed by /usr/bin/python3
    (removed afterwards)."""
    if not os.path.exists('/usr/bin/catkin_make'):
        pytest.fail('catkin_make missing: run make setup (scripts/apt-packages.txt)')
    root = Path(tempfile.mkdtemp(prefix='mmm_installed_'))
    try:
        yield from _build(repo_root, root)
    finally:
        shutil.rmtree(root, ignore_errors=True)


def _build(repo_root: Path, root: Path):
    src = root / 'ws' / 'src' / 'multirobot_map_merge'
    src.mkdir(parents=True)
    # as bootstrap.sh: links to the visible entries, so the build never sees .ws/.venv/.git of the checkout
    for entry in repo_root.iterdir():
        if not entry.name.startswith('.'):
            (src / entry.name).symlink_to(entry)
    env = clean_env(root)
    done = run(f'catkin_make install -C {root / "ws"} -DPYTHON_EXECUTABLE={SYSTEM_PYTHON} '
               f'-DCATKIN_ENABLE_TESTING=OFF', env, timeout=600.0)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    yield root, env, f'source {root / "ws" / "install" / "setup.bash"} && '


def test_every_module_imports_from_the_install_space_on_debian_python(install_space):
    root, env, source = install_space
    script = (
        'import importlib, json, pkgutil, sys\n'
        f'packages = {PACKAGES!r}\n'
        'modules = {}\n'
        'for name in packages:\n'
        '    pkg = importlib.import_module(name)\n'
        '    modules[name] = pkg.__file__\n'
        '    for info in pkgutil.walk_packages(pkg.__path__, name + "."):\n'
        '        modules[info.name] = importlib.import_module(info.name).__file__\n'
        'import cv2, numpy, networkx, yaml\n'
        'print(json.dumps({"modules": modules, "path": sys.path, "executable": sys.executable,\n'
        '                  "versions": {"numpy": numpy.__version__, "cv2": cv2.__version__,\n'
        '                               "networkx": networkx.__version__, "yaml": yaml.__version__}}))\n')
    probe = root / 'probe.py'
    probe.write_text(script)
    done = run(source + f'python3 {probe}', env)
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout.strip().splitlines()[-1])
    print('installed package runs on', doc['executable'], doc['versions'])
    assert doc['executable'] == SYSTEM_PYTHON
    assert not any('.venv' in p for p in doc['path'])
    install = str(root / 'ws' / 'install')
    for node in NODE_MODULES:
        assert node in doc['modules'], sorted(doc['modules'])
    outside = {m: f for m, f in doc['modules'].items() if not f.startswith(install)}
    assert not outside, f'modules not imported from the install space: {outside}'
    for lib, version in DEBIAN_VERSIONS.items():
        assert doc['versions'][lib].startswith(version), (lib, doc['versions'][lib])


def test_rosrun_merge_maps_merges_a_sample(install_space, repo_root):
    root, env, source = install_space
    sample = repo_root / 'data' / 'samples' / 'three_robots'
    maps = sorted(str(p) for p in sample.glob('map_*.yaml'))
    out = root / 'out'
    done = run(source + f'rosrun multirobot_map_merge merge_maps --output {out / "merged"} '
               f'--transforms-json {out / "t.json"} ' + ' '.join(maps), env)
    assert done.returncode == 0, done.stdout + done.stderr
    doc = json.loads((out / 't.json').read_text())
    assert [m['file'] for m in doc['maps']] == maps and all(m['included'] for m in doc['maps'])
    truth = json.loads((sample / 'truth.json').read_text())
    est = [tf.rigid(m['transform']['x'], m['transform']['y'], m['transform']['yaw']) for m in doc['maps']]
    for k in range(1, len(maps)):
        rot, cells = placement_error(truth, est, 0, k)
        assert rot <= 1.5 and cells <= 3, (k, rot, cells)
    for name in ('merged.yaml', 'merged.pgm', 'merged.png', 'merged_overlay.png'):
        assert (out / name).stat().st_size > 0, name
