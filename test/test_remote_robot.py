"""Robots on another host: roscore + map_merge in one network namespace, a robot in another, joined by a veth pair.

The test creates two namespaces and a veth pair with addresses 10.213.<n>.1/.2 that exist only inside them (no
route leaves the machine), and always deletes them (finally; deleting a namespace deletes its veth end). The
checker (test/ros/mm_link_outage.py) runs in the core's namespace: the robot must reach the merged map over the
link; then the link goes down for 15 s and up: the node keeps publishing, and the robot's maps and updates
published after the outage reach the merged map within 10 s. Needs root and `ip`; every wait is bounded.
"""
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
HELPER = REPO / 'test' / 'ros' / 'mm_link_outage.py'
OUTAGE, WITHIN = 15.0, 10.0

pytestmark = [
    pytest.mark.skipif(os.geteuid() != 0, reason='needs root to create network namespaces'),
    pytest.mark.skipif(shutil.which('ip') is None, reason='needs the ip tool (iproute2)'),
    pytest.mark.skipif(shutil.which('roscore') is None, reason='roscore not on PATH (use scripts/env.sh)'),
]


def ip(*args: str) -> None:
    subprocess.run(['ip', *args], check=True, capture_output=True, timeout=10)


def node_executable() -> str:
    import roslib.packages
    found = roslib.packages.find_node('multirobot_map_merge', 'map_merge')
    if not found:
        pytest.skip('map_merge executable not found (make setup)')
    return found[0]


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    except ProcessLookupError:
        pass


def test_robot_on_another_host_survives_a_link_outage(tmp_path):
    tag = os.getpid() % 100000
    subnet = 10 + os.getpid() % 240
    core, robot = f'mm14core{tag}', f'mm14robot{tag}'
    core_dev, robot_dev = f'mmc{tag}', f'mmr{tag}'
    core_ip, robot_ip = f'10.213.{subnet}.1', f'10.213.{subnet}.2'
    master = f'http://{core_ip}:11311'
    procs, logs = [], []

    def spawn(ns: str, own_ip: str, name: str, cmd: list) -> subprocess.Popen:
        env = dict(os.environ, ROS_MASTER_URI=master, ROS_IP=own_ip, ROS_LOG_DIR=str(tmp_path / 'ros'))
        env.pop('ROS_HOSTNAME', None)
        log = open(tmp_path / f'{name}.log', 'w')
        logs.append(log)
        proc = subprocess.Popen(['ip', 'netns', 'exec', ns, *cmd], env=env, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        procs.append(proc)
        return proc

    try:
        ip('netns', 'add', core)
        ip('netns', 'add', robot)
        ip('link', 'add', core_dev, 'type', 'veth', 'peer', 'name', robot_dev)
        ip('link', 'set', core_dev, 'netns', core)
        ip('link', 'set', robot_dev, 'netns', robot)
        for ns, dev, addr in ((core, core_dev, core_ip), (robot, robot_dev, robot_ip)):
            ip('-n', ns, 'addr', 'add', f'{addr}/24', 'dev', dev)
            ip('-n', ns, 'link', 'set', dev, 'up')
            ip('-n', ns, 'link', 'set', 'lo', 'up')

        t0 = time.time()
        spawn(core, core_ip, 'roscore', ['roscore', '-p', '11311'])
        probe = f"import rosgraph, sys; sys.exit(0 if rosgraph.Master('/probe', master_uri='{master}').is_online() " \
                "else 1)"
        deadline = time.monotonic() + 30.0
        while subprocess.run(['ip', 'netns', 'exec', core, sys.executable, '-c', probe], capture_output=True,
                             timeout=20).returncode != 0:
            assert time.monotonic() < deadline, 'roscore did not start in the core namespace within 30 s'
            time.sleep(0.5)
        spawn(core, core_ip, 'map_merge', [node_executable(), '__name:=map_merge', '__ns:=/map_merge',
                                           '_known_init_poses:=true', '_discovery_rate:=1.0', '_merging_rate:=4.0',
                                           '_origin_mode:=world'])
        spawn(robot, robot_ip, 'robot', [sys.executable, str(HELPER), 'robot', '--t0', str(t0)])
        checker = spawn(core, core_ip, 'checker', [sys.executable, str(HELPER), 'check', '--t0', str(t0),
                                                   '--link', core_dev, '--outage', str(OUTAGE),
                                                   '--within', str(WITHIN)])
        try:
            code = checker.wait(timeout=90.0 + OUTAGE + WITHIN + 30.0)
        except subprocess.TimeoutExpired:
            code = None
        for log in logs:
            log.flush()
        out = (tmp_path / 'checker.log').read_text()
        lines = [line for line in out.splitlines() if line.startswith('{')]
        figures = json.loads(lines[-1]) if lines else {}
        print(f'remote robot figures: {figures}')
        node_log = (tmp_path / 'map_merge.log').read_text()
        assert code == 0, f'checker exit {code}: {figures}\n--- checker ---\n{out[-3000:]}\n--- node ---\n' \
                          f'{node_log[-3000:]}'
        assert procs[1].poll() is None, 'map_merge died'
        assert 'Traceback' not in node_log, node_log[-3000:]
    finally:
        for proc in reversed(procs):
            stop(proc)
        for log in logs:
            log.close()
        for ns in (core, robot):
            subprocess.run(['ip', 'netns', 'del', ns], capture_output=True, timeout=10)
        subprocess.run(['ip', 'link', 'del', core_dev], capture_output=True, timeout=10)   # if never moved
        assert not any(ns in subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True,
                                            timeout=10).stdout for ns in (core, robot)), 'namespaces left behind'
