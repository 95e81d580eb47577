"""The matches in worker processes (estimation/workers.py): the same placements as on threads, a worker killed on
the way, the files removed, and no worker left behind when the estimating process is killed."""
import errno
import gc
import json
import logging
import math
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
import types
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import pytest

from multirobot_map_merge.estimation import search, workers
from multirobot_map_merge.estimation.estimator import estimate
from multirobot_map_merge.estimation.features import prepare
from multirobot_map_merge.estimation.neighbours import NeighbourCache
from multirobot_map_merge.estimation.pair import match_pair
from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.mapio import load_map
from multirobot_map_merge.throttle import Throttle


def _maps(repo_root, name='union_join'):
    folder = repo_root / 'data' / 'samples' / name
    truth = json.loads((folder / 'truth.json').read_text())
    return [load_map(str(folder / m['file'])) for m in truth['maps']]


def _same(a, b):
    assert [t is None for t in a.transforms] == [t is None for t in b.transforms]
    for s, t in zip(a.transforms, b.transforms):
        if s is not None:
            np.testing.assert_allclose(s, t, atol=1e-9)


def test_processes_place_the_maps_as_threads_do(repo_root):
    grids = _maps(repo_root)
    on_threads = estimate(grids, EstimationSettings(processes=False))
    on_processes = estimate(grids, EstimationSettings(processes=True))
    assert sum(t is not None for t in on_threads.transforms) >= 3   # the premise: batches of several matches
    _same(on_processes, on_threads)


def test_the_placements_do_not_depend_on_the_number_of_workers(repo_root):
    """merge_maps starts as many workers as the machine has cores (at most 4): a batch's matches land on other
    workers in another order, and each comes back to its place in the batch."""
    grids = _maps(repo_root)
    two = estimate(grids, EstimationSettings(processes=True, threads=2))
    three = estimate(grids, EstimationSettings(processes=True, threads=3))
    assert sum(t is not None for t in two.transforms) >= 3
    _same(three, two)


def test_a_prepared_grid_travels_whole(repo_root):
    grid = prepare(_maps(repo_root)[0], 0.05, 'akaze')
    copy = pickle.loads(pickle.dumps(grid))
    for name in ('work', 'px_to_map', 'keypoints', 'descriptors', 'walls', 'wall_distance', 'nearest_wall',
                 'free_side', 'wall_normals', 'known_depth'):
        np.testing.assert_array_equal(getattr(copy, name), getattr(grid, name))
    assert copy._lock is not grid._lock and copy._lock.acquire(blocking=False)


def test_a_worker_keeps_distances_by_content(repo_root):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)[:2]]
    a, b = grids[0].descriptors, grids[1].descriptors
    kept = workers.ContentNeighbourCache()
    first = kept.nearest(a, b)
    again = kept.nearest(a.copy(), b.copy())   # copies, as each file read gives them
    assert again[0] is first[0]
    np.testing.assert_array_equal(first[0], NeighbourCache().nearest(a, b)[0])


def test_the_processes_of_an_estimation_share_descriptor_distances_through_its_folder(repo_root, tmp_path,
                                                                                     monkeypatch):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)[:2]]
    a, b = grids[0].descriptors, grids[1].descriptors
    first = workers.ContentNeighbourCache(str(tmp_path)).nearest(a, b)
    computed = []
    batch_distance = cv2.batchDistance
    monkeypatch.setattr(cv2, 'batchDistance', lambda *args, **kw: computed.append(1) or batch_distance(*args, **kw))
    # another worker, with copies of the arrays as its files give them, and the estimating process (by their ids)
    for other, (q, t) in ((workers.ContentNeighbourCache(str(tmp_path)), (a.copy(), b.copy())),
                          (workers.SharedNeighbourCache(str(tmp_path)), (a, b))):
        again = other.nearest(q, t)
        assert not computed
        for x, y in zip(again, first):
            np.testing.assert_array_equal(x, y)
    # not the distances of other arrays, nor without a folder
    workers.ContentNeighbourCache(str(tmp_path)).nearest(b, a)
    workers.ContentNeighbourCache().nearest(a, b)
    assert len(computed) == 2


def test_what_a_search_derives_from_a_grid_is_derived_once_among_the_processes(repo_root, tmp_path, monkeypatch):
    path = str(tmp_path / '1.pickle')
    with open(path, 'wb') as f:
        pickle.dump(prepare(_maps(repo_root)[0], 0.05, 'akaze'), f)

    def loaded():
        with open(path, 'rb') as f:
            return pickle.load(f)
    one = loaded()
    shared = workers._take_derived(path, one)
    assert shared == frozenset()
    first = search.coarse(one, 4)
    shared = workers._give_derived(path, one, shared)
    assert {('coarse', 4), 'direction'} <= shared
    monkeypatch.setattr(search, '_coarse', lambda *args: pytest.fail('derived again'))
    other = loaded()
    assert workers._take_derived(path, other) == shared
    again = search.coarse(other, 4)
    for name in ('walls', 'open', 'factor', 'direction', 'strength'):
        np.testing.assert_array_equal(getattr(again, name), getattr(first, name))
    # what the other adds is kept with the first's
    other.derived['orientation'] = (0.5, 1.0)
    assert workers._give_derived(path, other, shared) == shared | {'orientation'}
    assert workers._take_derived(path, loaded()) == shared | {'orientation'}


def test_a_match_in_the_estimating_process_takes_and_gives_what_the_processes_derived(repo_root, monkeypatch):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    direction, derived_here = search.wall_direction, []
    monkeypatch.setattr(search, 'wall_direction', lambda work: derived_here.append(work is grids[0].work)
                        or direction(work))
    settings = EstimationSettings(processes=True)
    with ThreadPoolExecutor(2) as pool, workers.ParallelMatcher(settings, pool) as m:
        calls = _calls(grids)
        m.match_all(calls)   # the grids are sent: each has a file
        onto = m._files[id(grids[0])][1] + workers.DERIVED_SUFFIX
        theirs = {'direction': direction(grids[0].work)}   # as a worker derived it
        workers._write_shared(onto, theirs)
        grids[0].derived.clear()
        call = workers.MatchCall(calls[0].i, 0, calls[0].pi, grids[0], dict(descriptors=False))   # a search
        _same_matches([m.match_here(call)], [call], settings)
        assert grids[0].derived['direction'] == theirs['direction'] and not any(derived_here)
        assert ('coarse', settings.search_factor) in workers._read_shared(onto)


def test_what_was_derived_from_a_grid_goes_with_its_file(repo_root, monkeypatch):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    with ThreadPoolExecutor(2) as pool, workers.ParallelMatcher(EstimationSettings(processes=True), pool) as m:
        m.match_all(_calls(grids))
        paths = [sent[1] for sent in m._files.values()]
        for path in paths:
            workers._write_shared(path + workers.DERIVED_SUFFIX, {'direction': (0.0, 0.0)})
        monkeypatch.setattr(workers, 'FILES_KEPT_BYTES', 0)
        m._remove_unused({})
        assert not any(os.path.exists(p) or os.path.exists(p + workers.DERIVED_SUFFIX) for p in paths)


def _calls(grids):
    return [workers.MatchCall(k, 0, grids[k], grids[0], dict(search=False)) for k in range(1, len(grids))]


def _same_matches(matches, calls, settings):
    for c, m in zip(calls, matches):
        alone = match_pair(c.i, c.j, c.pi, c.pj, settings, **c.options)
        assert (m.accepted, m.reason) == (alone.accepted, alone.reason)
        if m.transform_m is not None:
            np.testing.assert_allclose(m.transform_m, alone.transform_m, atol=1e-9)


def test_a_killed_worker_leaves_its_batch_to_the_threads(repo_root, caplog):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    settings = EstimationSettings(processes=True)
    calls = _calls(grids)
    with ThreadPoolExecutor(2) as pool, workers.ParallelMatcher(settings, pool) as matcher:
        executor = workers._POOL.get(settings.threads)
        for pid in {executor.submit(os.getpid).result() for _ in range(4)}:
            os.kill(pid, signal.SIGKILL)
        with caplog.at_level(logging.WARNING, logger=workers.log.name):
            matches = matcher.match_all(calls)
        assert any('matching processes failed' in r.getMessage() for r in caplog.records)
        _same_matches(matches, calls, settings)
        # the next batch runs on a pool started again
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger=workers.log.name):
            _same_matches(matcher.match_all(calls), calls, settings)
        assert not caplog.records and workers._POOL.get(settings.threads) is not executor


def test_what_a_match_logs_in_a_worker_is_logged_in_the_estimating_process(repo_root, caplog):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    calls = [workers.MatchCall(i, j, grids[i], grids[j], dict(search=False))
             for i in range(len(grids)) for j in range(len(grids)) if i != j]
    pair_logger = 'rosout.multirobot_map_merge.estimation.pair'
    with ThreadPoolExecutor(2) as pool, workers.ParallelMatcher(EstimationSettings(processes=True), pool) as matcher:
        with caplog.at_level(logging.DEBUG, logger=workers.PACKAGE_LOGGER):
            matches = matcher.match_all(calls)
            here = [r for r in caplog.records if r.name == pair_logger]
        # each match made (one that reached its verdict) says so, from a worker, in the order of the calls
        said = [r.getMessage().split(':')[0] for r in here]
        assert said == [f'pair {m.i}-{m.j}' for m in matches if m.best is not None]
        assert said and os.getpid() not in {r.process for r in here}
        # at the level the estimating process logs at: nothing below it is made or sent
        caplog.clear()
        with caplog.at_level(logging.INFO, logger=workers.PACKAGE_LOGGER):
            matcher.match_all(calls)
        assert not [r for r in caplog.records if r.name == pair_logger]


def test_an_estimation_says_how_busy_its_batches_kept_the_workers(repo_root, caplog):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    calls = _calls(grids)
    with caplog.at_level(logging.DEBUG, logger=workers.log.name):
        with ThreadPoolExecutor(2) as pool, workers.ParallelMatcher(EstimationSettings(processes=True), pool) as m:
            m.match_all(calls)
            m.match_all(calls[:1])   # one match runs here, not on the workers
            stats = m.stats
    assert (stats.batches, stats.matches) == (1, len(calls))
    assert 0.0 < stats.matching_s <= 2 * stats.seconds and stats.reading_s > 0.0
    said = [r.getMessage() for r in caplog.records if 'worker processes' in r.getMessage()]
    assert len(said) == 1 and said[0].startswith(f'{len(calls)} matches in 1 batches on 2 worker processes')


def test_the_files_go_to_the_temporary_folder_when_dev_shm_has_too_little_room(repo_root, monkeypatch):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    settings = EstimationSettings(processes=True)
    calls = _calls(grids)
    monkeypatch.setattr(workers, 'SHARED_FREE_BYTES', 2 ** 62)   # as a container's 64 MB /dev/shm is for many maps
    with ThreadPoolExecutor(2) as pool, workers.ParallelMatcher(settings, pool) as matcher:
        _same_matches(matcher.match_all(calls), calls, settings)
        assert matcher.stats.batches == 1   # on the workers
        assert os.path.dirname(matcher._folder) == tempfile.gettempdir() != workers.SHARED_FOLDER


def test_grids_that_cannot_be_written_leave_the_estimation_on_threads_with_one_warning(repo_root, monkeypatch,
                                                                                        caplog):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    settings = EstimationSettings(processes=True)
    calls = _calls(grids)

    def full(self, grid):
        raise OSError(errno.ENOSPC, 'No space left on device')

    monkeypatch.setattr(workers, '_SAID', Throttle(math.inf))
    with ThreadPoolExecutor(2) as pool, workers.ParallelMatcher(settings, pool) as matcher:
        executor = workers._POOL.get(settings.threads)
        monkeypatch.setattr(workers.ParallelMatcher, '_path', full)
        with caplog.at_level(logging.WARNING, logger=workers.log.name):
            _same_matches(matcher.match_all(calls), calls, settings)
            _same_matches(matcher.match_all(calls), calls, settings)
        said = [r.getMessage() for r in caplog.records]
        assert len(said) == 1 and 'cannot be used' in said[0] and matcher.stats.batches == 0
        assert workers._POOL.get(settings.threads) is executor   # the pool was sound: not started again


def test_processes_that_cannot_start_leave_the_estimation_on_threads_with_one_warning(repo_root, monkeypatch,
                                                                                    caplog):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    settings = EstimationSettings(processes=True)
    calls = _calls(grids)

    def no_semaphores(*args, **kwargs):   # what multiprocessing raises where there are no POSIX semaphores
        raise OSError(errno.ENOSYS, 'Function not implemented')

    monkeypatch.setattr(workers, '_POOL', workers._Pool())
    monkeypatch.setattr(workers, '_SAID', Throttle(math.inf))
    monkeypatch.setattr(workers, 'ProcessPoolExecutor', no_semaphores)
    with caplog.at_level(logging.WARNING, logger=workers.log.name):
        for _ in range(2):   # two estimations (a node's): said once
            with ThreadPoolExecutor(2) as pool, workers.ParallelMatcher(settings, pool) as matcher:
                _same_matches(matcher.match_all(calls), calls, settings)
                _same_matches(matcher.match_all(calls), calls, settings)
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and 'cannot be used' in said[0] and matcher.stats.batches == 0


def test_the_files_of_an_estimation_are_removed(repo_root):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    settings = EstimationSettings(processes=True)
    calls = _calls(grids)
    with ThreadPoolExecutor(2) as pool, workers.ParallelMatcher(settings, pool) as matcher:
        _same_matches(matcher.match_all(calls), calls, settings)
        folder = matcher._folder
        # a file per grid, besides what the workers share (descriptor distances, what a search derives)
        sent = [n for n in os.listdir(folder) if not n.startswith(workers.NEIGHBOURS_PREFIX)
                and not n.endswith(workers.DERIVED_SUFFIX)]
        assert folder is not None and len(sent) == len(grids)
        assert os.path.basename(folder).startswith(f'{workers.FOLDER_PREFIX}{os.getpid()}_')
    assert not os.path.exists(folder)


def test_an_estimation_that_ends_while_a_grid_is_written_leaves_no_files(repo_root, monkeypatch):
    """merge_maps ended by SIGTERM while the estimation's threads wrote the grids of a batch: its folder was removed
    under a file being written, and a file created meanwhile kept the folder in /dev/shm. The end waits for the
    writes under way, and then removes the folder."""
    grid = prepare(_maps(repo_root)[0], 0.05, 'akaze')
    writing, folder_there = threading.Event(), []

    def slow_dump(obj, f, protocol=None):
        writing.set()
        time.sleep(0.5)
        pickle.dump(obj, f, protocol=protocol)
        folder_there.append(os.path.isdir(os.path.dirname(f.name)))
    monkeypatch.setattr(workers, 'pickle', types.SimpleNamespace(dump=slow_dump, load=pickle.load,
                                                                 HIGHEST_PROTOCOL=pickle.HIGHEST_PROTOCOL))
    with ThreadPoolExecutor(1) as pool:
        matcher = workers.ParallelMatcher(EstimationSettings(processes=False), pool)
        sent = pool.submit(matcher._path, grid)
        assert writing.wait(10)
        matcher.__exit__(None, None, None)   # the estimation ends, as an exception in its main thread ends it
        folder = matcher._folder
        sent.result(timeout=10)
    assert folder_there == [True]
    assert folder is not None and not os.path.exists(folder)


def test_the_folders_of_processes_that_have_gone_are_swept_once_untouched_for_a_while(tmp_path, monkeypatch):
    """A process killed with its workers at once leaves its folder (in /dev/shm, memory): the next estimation that
    writes files there removes it, once it has been untouched for STALE_S (a process of another PID namespace
    sharing the folder looks gone too); a live process's folder, a recent one and other files stay."""
    gone = subprocess.Popen(['true'])
    gone.wait()
    old = time.time() - 2 * workers.STALE_S
    names = {'stale': f'map_merge_{gone.pid}_a', 'recent': f'map_merge_{gone.pid}_b',
             'alive': f'map_merge_{os.getpid()}_c', 'other': f'map_merge_x{gone.pid}_d',
             'file': f'map_merge_{gone.pid}_e'}
    for key, name in names.items():
        path = tmp_path / name
        if key == 'file':
            path.write_text('')
        else:
            path.mkdir()
            (path / '1.pickle').write_bytes(b'')
        if key != 'recent':
            os.utime(path, (old, old))
    monkeypatch.setattr(workers, '_swept', set())
    workers._sweep_stale(str(tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(n for k, n in names.items() if k != 'stale')


def test_the_files_of_a_matcher_used_without_with_are_removed_once_it_is_collected(repo_root):
    grids = [prepare(g, 0.05, 'akaze') for g in _maps(repo_root)]
    with ThreadPoolExecutor(2) as pool:
        matcher = workers.ParallelMatcher(EstimationSettings(processes=True), pool)   # as a Grower makes its own
        matcher.match_all(_calls(grids))
        folder = matcher._folder
        assert os.path.isdir(folder)
        del matcher
        gc.collect()
    assert not os.path.exists(folder)


# a process that starts the workers, says their pids, and waits to be killed or interrupted
HOLDER = textwrap.dedent('''
    import os, sys, time
    from multirobot_map_merge.estimation import workers
    if __name__ == '__main__':
        executor = workers._POOL.get(2)
        print(sorted({executor.submit(os.getpid).result() for _ in range(6)}), flush=True)
        try:
            time.sleep(60)
        except KeyboardInterrupt:
            print('interrupted', flush=True)
''')


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f'/proc/{pid}/stat') as f:
        return f.read().split(')')[-1].split()[0] != 'Z'


def test_no_worker_outlives_a_killed_estimating_process(repo_root):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(repo_root), os.environ.get('PYTHONPATH')])))
    holder = subprocess.Popen([sys.executable, '-c', HOLDER], stdout=subprocess.PIPE, text=True, env=env)
    try:
        pids = json.loads(holder.stdout.readline())
        assert pids and all(_alive(p) for p in pids)
    finally:
        holder.kill()
        holder.wait()
    deadline = time.monotonic() + 10 * workers.WATCH_PERIOD_S
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(_alive(p) for p in pids)


WHICH_PACKAGE = """
import json, sys
sys.path.insert(0, sys.argv[1])
from multirobot_map_merge.estimation import workers
executor = workers._POOL.get(2)
found = executor.submit(eval, '__import__("multirobot_map_merge").__file__').result(timeout=60)
workers._POOL.shutdown()
print(json.dumps(found))
"""


UNGUARDED = """
import json, sys
sys.path.insert(0, {root!r})
from multirobot_map_merge.estimation.estimator import estimate
from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.mapio import load_map
folder = {folder!r}
grids = [load_map(folder + '/' + m['file']) for m in json.load(open(folder + '/truth.json'))['maps']]
found = [estimate(grids, EstimationSettings(processes=True, threads={threads})) for _ in range(3)]
print(json.dumps([[t is not None for t in r.transforms] for r in found]))
"""


def test_a_script_that_estimates_when_imported_ends_its_workers_at_once_and_then_matches_on_threads(repo_root,
                                                                                                      tmp_path):
    """A script without `if __name__ == '__main__':` around its estimation: multiprocessing runs the main module in
    each worker as it starts. A worker ends there at once, with one line (else it ran the estimation itself until it
    failed to start processes of its own, with a 40-line traceback, and every batch broke its pool: the generated
    office36 took 11.7 s, on threads 4.5 s); once FAILED_STARTS pools in a row ended so, the process matches on
    threads, with one warning that names the guard. Three estimations of a sample place the maps as threads do, the
    third starting no pool."""
    folder = repo_root / 'data' / 'samples' / 'union_join'
    threads = 2
    script = tmp_path / 'unguarded.py'
    script.write_text(UNGUARDED.format(root=str(repo_root), folder=str(folder), threads=threads))
    out = subprocess.run([sys.executable, str(script)], cwd=str(tmp_path), capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    on_threads = estimate(_maps(repo_root), EstimationSettings(processes=False))
    assert json.loads(out.stdout.strip().splitlines()[-1]) == [[t is not None for t in on_threads.transforms]] * 3
    lines = out.stderr.splitlines()
    assert 'Traceback' not in out.stderr, out.stderr
    # each pool that breaks so counts, whether its batch or its start found it broken
    assert sum('ended as it started' in line for line in lines) <= workers.FAILED_STARTS * threads, out.stderr
    assert sum('matching processes failed' in line for line in lines) <= workers.FAILED_STARTS, out.stderr
    assert sum('__name__ == "__main__"' in line and 'cannot be used' in line for line in lines) == 1, out.stderr


def test_the_workers_run_the_package_of_the_estimating_process_not_a_copy_in_its_working_folder(repo_root, tmp_path):
    """A user who runs merge_maps from a folder that holds another copy of the package (a source checkout of another
    version): the workers import the estimating process's copy, as the estimating process does."""
    copy = tmp_path / 'multirobot_map_merge'
    copy.mkdir()
    (copy / '__init__.py').write_text('')
    out = subprocess.run([sys.executable, '-c', WHICH_PACKAGE, str(repo_root)], cwd=str(tmp_path),
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == str(repo_root / 'multirobot_map_merge' / '__init__.py')


def _as_in_a_terminal():
    """A child started as from a terminal: SIGINT at its default whatever this process inherited (a suite started in
    the background by a shell ignores SIGINT, and so would the child's Python, never raising KeyboardInterrupt)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_leaves_the_workers_to_the_estimating_process(repo_root):
    """Ctrl-C reaches the whole process group: idle workers ignore it (each printed a traceback), the estimating
    process answers it."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(repo_root), os.environ.get('PYTHONPATH')])))
    holder = subprocess.Popen([sys.executable, '-c', HOLDER], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True, env=env, start_new_session=True, preexec_fn=_as_in_a_terminal)
    try:
        json.loads(holder.stdout.readline())
        time.sleep(0.5)   # the workers wait for work
        os.killpg(holder.pid, signal.SIGINT)
        out, _ = holder.communicate(timeout=30)
    finally:
        if holder.poll() is None:
            holder.kill()
    assert out.strip() == 'interrupted', out


def _process_group(pgid):
    pids = []
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            try:
                if os.getpgid(int(entry)) == pgid and _alive(int(entry)):
                    pids.append(int(entry))
            except (ProcessLookupError, PermissionError):
                pass
    return pids


def test_ctrl_c_ends_merge_maps_and_its_workers_with_one_line(repo_root, shared_dir, tmp_path):
    """Ctrl-C reaches the whole process group while merge_maps estimates: one line, exit 130, and no process of the
    group is left."""
    maps = sorted(str(p) for p in (shared_dir / 'data' / 'dev' / 'large30_hospital_section').glob('map_*.yaml'))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(repo_root), os.environ.get('PYTHONPATH')])))
    merge = subprocess.Popen([sys.executable, str(repo_root / 'nodes' / 'merge_maps'), '--output',
                              str(tmp_path / 'merged'), *maps], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                             text=True, env=env, start_new_session=True, preexec_fn=_as_in_a_terminal)
    try:
        for line in merge.stderr:   # bounded: merge_maps ends
            if 'estimating transforms' in line:
                break
        os.killpg(merge.pid, signal.SIGINT)
        rest = merge.stderr.read()
        assert merge.wait(timeout=30) == 130, rest
    finally:
        if merge.poll() is None:
            merge.kill()
    assert rest.strip() == 'merge_maps: interrupted', rest
    deadline = time.monotonic() + 10 * workers.WATCH_PERIOD_S
    while _process_group(merge.pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _process_group(merge.pid)


def _workers_cpu_ticks(executor) -> int:
    ticks = 0
    for pid in list(executor._processes):
        with open(f'/proc/{pid}/stat') as f:
            ticks += sum(int(v) for v in f.read().rsplit(')', 1)[1].split()[11:13])
    return ticks


def test_an_estimation_ended_in_a_batch_waits_for_the_matches_under_way(shared_dir):
    """merge_maps ended by SIGTERM in the middle of a batch: its workers went on matching, and shared what they
    computed in its folder while it was removed (a file written then kept the folder in /dev/shm). The batch ends
    with the matches under way; those not started are not made."""
    folder = shared_dir / 'data' / 'dev' / 'large30_hospital_section'
    grids = [prepare(load_map(str(folder / f'map_{k:02d}.yaml')), 0.05, 'akaze') for k in range(6)]
    calls = [workers.MatchCall(k, j, grids[k], grids[j], dict(descriptors=False))
             for j in range(2) for k in range(2, 6)]   # correlation searches: long enough to be ended in

    class Ended(Exception):
        pass

    def end(signum, frame):
        raise Ended()
    previous = signal.signal(signal.SIGUSR1, end)
    main = threading.get_ident()
    try:
        with ThreadPoolExecutor(2) as pool, \
                workers.ParallelMatcher(EstimationSettings(processes=True), pool) as matcher:
            executor = workers._POOL.get(2)
            idle = _workers_cpu_ticks(executor)
            done = threading.Event()

            def end_while_matching():   # once the workers have matched for a while (bounded)
                for _ in range(3000):
                    if done.is_set() or _workers_cpu_ticks(executor) - idle >= 20:
                        break
                    time.sleep(0.005)
                if not done.is_set():
                    signal.pthread_kill(main, signal.SIGUSR1)
            ender = threading.Thread(target=end_while_matching)
            ender.start()
            try:
                with pytest.raises(Ended):
                    matcher.match_all(calls)
            finally:
                done.set()
                ender.join(20)
            # no match runs on after the batch ended
            ended = _workers_cpu_ticks(executor)
            time.sleep(0.5)
            assert _workers_cpu_ticks(executor) - ended <= 5
    finally:
        signal.signal(signal.SIGUSR1, previous)
