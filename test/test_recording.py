"""The record of a node's estimations (multirobot_map_merge/recording.py) and scripts/replay_estimations.py, on the
chain3 sample maps estimated as the node does: robots arrive one by one, each estimation tracks the last one's
placements."""
import json
import re
import subprocess
import sys

import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.mapio import load_map
from multirobot_map_merge.pipeline import MergingPipeline
from multirobot_map_merge.recording import GRIDS, LINES, EstimationRecorder, read_estimations
from multirobot_map_merge.ros.params import MapMergeParams


def record_chain3(repo_root, directory):
    """Five estimations as a node makes them, 5 s apart (robot_2's map first absent; a new placement is published
    once a later one confirms it); returns what each was given."""
    sample = repo_root / 'data' / 'samples' / 'chain3'
    maps = [load_map(str(sample / f'map_0{k}.yaml')) for k in range(3)]
    names = ['/robot_0', '/robot_1', '/robot_2']
    pipeline = MergingPipeline(MapMergeParams().estimation_settings())
    recorder = EstimationRecorder(str(directory))
    given, placed, reference = [], {}, None
    for step, grids in enumerate([[maps[0], maps[1], None], maps, maps, maps, maps]):
        pipeline.feed(grids)
        previous = [placed.get(n) for n in names]
        preferred = names.index(reference) if reference in names else None
        result = pipeline.estimate(preferred_reference=preferred, previous=previous, names=names, now=10.0 + 5 * step)
        recorder.record(10.0 + 5 * step, names, grids, reference, previous, result, 0.1)
        given.append((list(grids), reference, previous, [t for t in result.transforms]))
        placed = {n: t for n, t in zip(names, result.transforms) if t is not None}
        reference = names[result.reference] if result.reference is not None else None
    recorder.close()
    return given, placed


def test_a_record_gives_back_each_estimation_as_it_was_given(repo_root, tmp_path):
    given, placed = record_chain3(repo_root, tmp_path)
    assert len(placed) == 3   # the sample's three maps merge: there is something to track
    records = list(read_estimations(str(tmp_path)))
    assert [r.index for r in records] == [0, 1, 2, 3, 4]
    for rec, (grids, reference, previous, transforms) in zip(records, given):
        assert rec.names == ['/robot_0', '/robot_1', '/robot_2']
        assert rec.reference == reference
        for a, b in zip(rec.grids, grids):
            assert (a is None) == (b is None)
            if a is not None:
                assert np.array_equal(a.data, b.data) and a.resolution == b.resolution and a.origin == b.origin
        for a, b in zip(rec.previous, previous):
            assert (a is None) == (b is None) and (a is None or np.allclose(a, b))
        assert sorted(rec.placed) == sorted(n for n, t in zip(rec.names, transforms) if t is not None)
    # each map content is written once, however many estimations use it
    assert len(list((tmp_path / GRIDS).iterdir())) == 3


def replay(repo_root, *args):
    proc = subprocess.run([sys.executable, str(repo_root / 'scripts' / 'replay_estimations.py'), *args],
                          capture_output=True, text=True, timeout=300)
    return proc


def test_the_replay_makes_the_recorded_placements_again_and_shows_a_difference(repo_root, tmp_path):
    record_chain3(repo_root, tmp_path)
    out = replay(repo_root, str(tmp_path))
    assert out.returncode == 0, out.stderr
    verdicts = re.findall(r'replay\s+(\d+) placed.*; (.*)$', out.stdout, re.M)
    assert len(verdicts) == 5 and all(v == 'same' for _, v in verdicts), out.stdout
    assert verdicts[-1][0] == '3'
    # the last estimation recorded robot_2 2 m further: the replay shows the move
    lines = (tmp_path / LINES).read_text().splitlines()
    last = json.loads(lines[-1])
    moved = np.asarray(last['placed']['/robot_2']) @ tf.rigid(2.0, 0.0, 0.0)
    last['placed']['/robot_2'] = moved.tolist()
    (tmp_path / LINES).write_text('\n'.join(lines[:-1] + [json.dumps(last)]) + '\n')
    out = replay(repo_root, str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert re.findall(r'; (.*)$', out.stdout, re.M)[-1] == 'moved /robot_2 2.00 m', out.stdout


def test_a_missing_record_is_one_line_and_a_non_zero_exit(repo_root, tmp_path):
    out = replay(repo_root, str(tmp_path / 'none'))
    assert out.returncode != 0
    assert out.stderr.strip().count('\n') == 0 and 'replay_estimations' in out.stderr


def test_exposure_matches_each_robot_left_out_onto_the_placed_ones_at_their_true_poses(repo_root, tmp_path):
    record_chain3(repo_root, tmp_path / 'record')
    truth = json.loads((repo_root / 'data' / 'samples' / 'chain3' / 'truth.json').read_text())
    poses = {f'robot_{k}': m['pose'] for k, m in enumerate(truth['maps'])}
    summary = tmp_path / 'summary.json'
    summary.write_text(json.dumps({'start_poses': poses}))
    out = replay(repo_root, str(tmp_path / 'record'), '--summary', str(summary), '--exposure')
    assert out.returncode == 0, out.stderr
    made, accepted, wrong = map(int, re.search(r'(\d+) matches .*, (\d+) accepted, (\d+) wrong', out.stdout).groups())
    assert accepted >= 1 and wrong == 0, out.stdout   # a robot held, not published yet: its true place fits
    # the same matches judged against a truth with robot_2 2 m away: each accepted one is off by those 2 m
    poses['robot_2'] = [poses['robot_2'][0] + 2.0] + poses['robot_2'][1:]
    summary.write_text(json.dumps({'start_poses': poses}))
    out = replay(repo_root, str(tmp_path / 'record'), '--summary', str(summary), '--exposure')
    offs = re.findall(r'/robot_2 onto \d placed: WRONG [\d.]+ deg, ([\d.]+) m off', out.stdout)
    assert offs and all(abs(float(o) - 2.0) < 0.1 for o in offs), out.stdout
    assert replay(repo_root, str(tmp_path / 'record'), '--exposure').returncode != 0   # no truth: one line, non-zero
