"""scripts/replay_bag_estimation.py on a small recorded run (the chain3 sample maps as three robots' topics, the
demo's summary.json written from their ground truth): the node's cadence (--pace) and the earliest time the rules
could place each robot (--evidence)."""
import json
import math
import re
import subprocess
import sys

import pytest

pytest.importorskip('rosbag')
from test_bag_input import T0, sample_bag  # noqa: E402


def summary_of(repo_root, tmp_path):
    truth = json.loads((repo_root / 'data' / 'samples' / 'chain3' / 'truth.json').read_text())
    robots = [f'robot_{k}' for k in range(len(truth['maps']))]
    doc = {'start_poses': {r: m['pose'] for r, m in zip(robots, truth['maps'])},
           'placement': [{'robot': r, 'joinable_sim_s': T0} for r in robots]}
    path = tmp_path / 'summary.json'
    path.write_text(json.dumps(doc))
    return str(path)


def replay(repo_root, *args):
    proc = subprocess.run([sys.executable, str(repo_root / 'scripts' / 'replay_bag_estimation.py'), *args],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def robot_rows(out):
    """robot -> {joinable, placed, evidence} of the closing rows."""
    rows = {}
    for line in out.splitlines():
        m = re.match(r'(/robot_\d): (.*)', line)
        if m:
            rows[m.group(1)] = dict(re.findall(r'(joinable|placed|evidence) ([-\d.]+|None)', m.group(2)))
    return rows


def test_evidence_is_when_the_true_placement_first_passes_the_rules(repo_root, tmp_path):
    bag, summary = sample_bag(repo_root, tmp_path), summary_of(repo_root, tmp_path)
    rows = robot_rows(replay(repo_root, bag, '--summary', summary, '--every', '0.5', '--evidence'))
    assert sorted(rows) == ['/robot_0', '/robot_1', '/robot_2']
    # robot_1's map is whole only after its update (T0 + 1.5); robot_2's comes at T0 + 2: none can pass before
    # the maps it overlaps are there, and each passes once they are
    evidence = {r: float(v['evidence']) for r, v in rows.items() if v['evidence'] != '-'}
    assert set(evidence) == {'/robot_0', '/robot_1', '/robot_2'}
    assert all(t >= T0 + 1 for t in evidence.values())
    assert evidence['/robot_2'] >= T0 + 2


def test_pace_counts_a_placement_when_the_estimation_ends(repo_root, tmp_path):
    bag, summary = sample_bag(repo_root, tmp_path), summary_of(repo_root, tmp_path)
    # one estimation after the bag: the node's next one, which confirms the last new placements
    out = replay(repo_root, bag, '--summary', summary, '--pace', '5', '--contention', '3', '--more', '1')
    spans = [(float(a), float(b)) for a, b in re.findall(r'^t\s+([\d.]+)-([\d.]+)', out, re.M)]
    assert spans, out
    # one at a time: the next starts when the last has ended (at once only for a new robot's first map)
    assert all(later[0] >= earlier[1] - 0.01 for earlier, later in zip(spans, spans[1:]))
    rows = robot_rows(out)
    assert all(v['placed'] not in ('None', '-') for v in rows.values()), out
    # a placement counts from the end of the estimation that made it, not from its start
    assert all(any(abs(float(v['placed']) - b) < 0.006 for _, b in spans) for v in rows.values())
    assert max(float(v['placed']) for v in rows.values()) > max(a for a, _ in spans if a < T0 + 2.5)


def test_status_errors_count_the_time_a_published_placement_is_off(repo_root, tmp_path):
    """scripts/status_errors.py scores every ~status of a recorded run against the start poses: here the truth at
    T0 + 3 and T0 + 4, robot_2 turned by 2 degrees at T0 + 5 and the truth again at T0 + 9, so it is off for 4 s of
    the 6 s with robots placed."""
    import genpy
    import rosbag
    from geometry_msgs.msg import Quaternion, Vector3
    from multirobot_map_merge.msg import MergeStatus, RobotMergeStatus
    from test_bag_input import write_bag
    truth = json.loads((repo_root / 'data' / 'samples' / 'chain3' / 'truth.json').read_text())
    poses = [m['pose'] for m in truth['maps']]

    def status(dt, turn_deg):
        msg = MergeStatus()
        msg.header.stamp = genpy.Time.from_sec(T0 + dt)
        for k, (x, y, yaw) in enumerate(poses):
            r = RobotMergeStatus(robot_namespace=f'/robot_{k}', included=True)
            yaw += math.radians(turn_deg) if k == 2 else 0.0
            r.transform.translation = Vector3(x, y, 0.0)
            r.transform.rotation = Quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
            msg.robots.append(r)
        return msg

    bag = tmp_path / 'run.bag'
    sample_bag(repo_root, tmp_path)   # chain3.bag: the robots' maps
    entries = [(t.to_sec() - T0, topic, msg) for topic, msg, t in rosbag.Bag(str(tmp_path / 'chain3.bag'))]
    entries += [(3, '/map_merge/status', status(3, 0.0)), (4, '/map_merge/status', status(4, 0.0)),
                (5, '/map_merge/status', status(5, 2.0)), (9, '/map_merge/status', status(9, 0.0))]
    write_bag(bag, sorted(entries, key=lambda e: e[0]))
    proc = subprocess.run([sys.executable, str(repo_root / 'scripts' / 'status_errors.py'), str(bag),
                           '--summary', summary_of(repo_root, tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    off = re.findall(r'^t\s+([\d.]+)\s+worst (\S+): ([\d.]+) deg', proc.stdout, re.M)
    assert [(float(t), robot) for t, robot, _ in off] == [(T0 + 5, '/robot_2')] and abs(float(off[0][2]) - 2) < 0.01
    assert re.search(r'^6\.0 sim s with two robots or more placed: 4\.0 s \(66\.7 %\)', proc.stdout, re.M), \
        proc.stdout
