"""Matches of pairs in parallel: on worker processes, which the GIL does not hold back, or on threads.

A match is mostly short numpy and OpenCV calls between Python steps, so two threads hold the GIL in turn: on the
generated 36-map buildings a second thread added 0.14 of a core's work, a second process a whole core's.
`ParallelMatcher.match_all` runs a batch of `match_pair` calls (the growth's descriptor matches, the searches of
the maps left out, the pair evidence, the group matches made ahead) on a pool of worker processes started by the
`forkserver`: a forked child of a process whose OpenCV threads have run can deadlock, and the server forks before
any has. The grids of a batch reach the workers through files (in /dev/shm when it has room), each written once
(again only if it was removed to keep the files within FILES_KEPT_BYTES) and read once by each worker that needs
it; a worker keeps the last LOADED_KEPT it read, with what its matches derive from them, and the descriptor
distances it used (neighbours.py), known by the descriptors' content. What one process computes of that, another
takes from the estimation's folder instead of computing it again: the descriptor distances of two arrays, and what
a search derives from a grid (in a file beside the grid's). The largest grids go first, so that a batch ends on
short matches. A batch the pool cannot run (a worker killed) runs on the threads instead, and the pool is started
again for the next one; a worker ends itself when the estimating process has gone, and removes its files. What a
match logs in a worker (at the level the estimating process logs this package at) is logged again in the estimating
process, with the match's result, in the order of the calls.

A program that uses the estimation with processes must guard its main code with `if __name__ == '__main__':`, as
multiprocessing requires: a worker runs the main module as it starts. A worker that finds itself running an
estimation there ends at once with one line (UNGUARDED_EXIT), and after FAILED_STARTS pools in a row broke before
any batch ran on them the estimating process runs its matches on threads, with one warning that names the cause.
"""
from __future__ import annotations

import atexit
import hashlib
import logging
import logging.handlers
import math
import multiprocessing
import os
import pickle
import shutil
import signal
import sys
import tempfile
import threading
import time
import weakref
from collections import OrderedDict
from concurrent.futures import Executor, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..throttle import Throttle
from .features import PreparedGrid
from .match_memo import MatchMemo
from .neighbours import NeighbourCache
from .pair import PairMatch, match_pair
from .settings import EstimationSettings

log = logging.getLogger('rosout.multirobot_map_merge.estimation.workers')
PACKAGE_LOGGER = 'rosout.multirobot_map_merge'   # the core's loggers: a worker's records are sent back

WATCH_PERIOD_S = 1.0   # how often a worker checks that the estimating process is still there
STARTED_TOGETHER_S = 0.05   # a task this long on each worker makes the pool start them all at once
# pools in a row that broke before a batch ran on them: the processes are not used again in this process (a worker
# killed on the way breaks a pool that worked: the next batch starts one again)
FAILED_STARTS = 2
# why the processes are not used after that, for the warning
UNUSABLE = (f'{FAILED_STARTS} pools in a row ended before they matched; a main module that runs the estimation when '
            f'imported, outside if __name__ == "__main__":, makes every worker end so')
UNGUARDED_EXIT = 3   # a worker's exit status when it ends as it starts, running an estimation (_end_if_starting)
LOADED_KEPT = 8   # grids a worker keeps loaded (a batch needs one union and its grids, one at a time each)
# the files of an estimation kept (in RAM, in /dev/shm) for later batches: a grid's file is about 21 bytes a pixel at
# the working resolution (its fields), 3.5 MB for the median map of the generated 36-map buildings, 14 MB for a
# large union; an estimation there writes 200-400 MB in all
FILES_KEPT_BYTES = 256 * 2 ** 20
SHARED_FOLDER = '/dev/shm'
SHARED_FREE_BYTES = 2 * FILES_KEPT_BYTES   # free in /dev/shm for the files to go there: those kept and a batch's
FOLDER_PREFIX = 'map_merge_'   # an estimation's folder: map_merge_<pid of the estimating process>_<random>
WRITE_WAIT_S = 10.0   # at the end of an estimation, for grids being written to its folder and the matches under way
STALE_S = 600.0   # a folder of a process that has gone, untouched this long, is removed by the next estimation
# what the workers' server imports once, before it forks them. Not this package: Python 3.11's server looks in its
# working folder first, not in this process's sys.path, and a copy of the package in the folder merge_maps ran from
# ran in the workers. Each worker imports the package itself, by this process's sys.path (multiprocessing passes it).
SERVER_PRELOAD = ['numpy', 'cv2']
# what the processes of an estimation share through its folder, each computed once and read by the others: the
# descriptor distances of two arrays (a file each: NEIGHBOURS_PREFIX and a digest of both), and what a search derives
# from a grid (SHARED_DERIVED, in a file beside the grid's: DERIVED_SUFFIX). Unshared, each worker computed its own:
# the generated hospital36's distances of 866 pairs of arrays were computed 1626 times (1.83 s of CPU; shared, 866
# times, 0.89 s) and its 107 coarse grids 244 times (0.92 s; shared, 139 times, 0.53 s)
NEIGHBOURS_PREFIX = 'nn_'
DERIVED_SUFFIX = '.derived'
SHARED_DERIVED = ('coarse', 'direction', 'orientation', 'families')


@dataclass
class MatchCall:
    """match_pair(i, j, pi, pj, settings, **options): what one match of a batch needs."""
    i: int
    j: int
    pi: PreparedGrid
    pj: PreparedGrid
    options: Dict[str, object] = field(default_factory=dict)


@dataclass
class BatchStats:
    """What the batches of one estimation took on the worker processes: how busy they kept the workers."""
    batches: int = 0
    matches: int = 0
    seconds: float = 0.0          # the batches' wall time, as the estimating process waited for them
    reading_s: float = 0.0        # the workers' time reading grids from their files
    matching_s: float = 0.0       # and matching them

    def add(self, seconds: float, times: Sequence[Tuple[float, float]]) -> None:
        """A batch that took `seconds`, and (reading, matching) seconds of each of its matches."""
        self.batches += 1
        self.matches += len(times)
        self.seconds += seconds
        self.reading_s += sum(t[0] for t in times)
        self.matching_s += sum(t[1] for t in times)

    def summary(self, workers: int) -> str:
        busy = (self.reading_s + self.matching_s) / max(workers * self.seconds, 1e-9)
        return (f'{self.matches} matches in {self.batches} batches on {workers} worker processes, '
                f'{self.seconds:.2f} s: the workers busy {100 * busy:.0f} % of it, reading grids '
                f'{self.reading_s:.2f} s and matching {self.matching_s:.2f} s')


class SharedNeighbourCache(NeighbourCache):
    """Descriptor distances shared with the other processes of an estimation through its folder (None: not
    shared): each pair's in a file, known by the arrays' content; those computed here are written there."""

    def __init__(self, folder: Optional[str] = None) -> None:
        super().__init__()
        self.folder = folder

    def digests(self, key: tuple, query: np.ndarray, train: np.ndarray) -> tuple:
        """The arrays' digests (_digest)."""
        return _digest(query), _digest(train)

    def computed(self, key: tuple, query: np.ndarray, train: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        if self.folder is None:
            return super().computed(key, query, train)
        name = hashlib.blake2b(b''.join(self.digests(key, query, train)), digest_size=16).hexdigest()
        path = os.path.join(self.folder, f'{NEIGHBOURS_PREFIX}{name}.pickle')
        found = _read_shared(path)
        if found is None:
            found = super().computed(key, query, train)
            _write_shared(path, found)
        return found


class ContentNeighbourCache(SharedNeighbourCache):
    """A worker's descriptor distances: the arrays arrive as copies, so they are known by their content."""

    def key(self, query: np.ndarray, train: np.ndarray) -> tuple:
        return _digest(query), _digest(train)

    def digests(self, key: tuple, query: np.ndarray, train: np.ndarray) -> tuple:
        return key   # computed for the key already


def _digest(a: np.ndarray) -> bytes:
    return hashlib.blake2b(np.ascontiguousarray(a).data, digest_size=16).digest() + repr(a.shape).encode()


def _read_shared(path: str) -> Optional[object]:
    """What another process shared in `path` (_write_shared), or None."""
    try:
        with open(path, 'rb') as f:
            return pickle.load(f)
    except (OSError, EOFError, pickle.UnpicklingError):
        return None


def _write_shared(path: str, value: object) -> None:
    """Share `value` in `path`, whole or not at all (a reader sees no half-written file); a failure (the estimation
    has ended and its folder gone, a full disk) only leaves it unshared."""
    temporary = f'{path}.{os.getpid()}.part'
    try:
        with open(temporary, 'wb') as f:
            pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(temporary, path)
    except OSError:
        try:
            os.remove(temporary)
        except OSError:
            pass


def _take_derived(path: str, grid: PreparedGrid) -> frozenset:
    """Take into the grid (its file `path`) what other processes derived from it and shared (SHARED_DERIVED);
    returns the keys shared."""
    shared = _read_shared(path + DERIVED_SUFFIX) or {}
    for key, value in shared.items():
        grid.derived.setdefault(key, value)
    return frozenset(shared)


def _give_derived(path: str, grid: PreparedGrid, shared: frozenset) -> frozenset:
    """Share what was derived here from the grid (its file `path`) beyond the keys `shared` already, with what other
    processes added meanwhile (two that write at once can lose each other's: it is then derived again); returns the
    keys shared now."""
    mine = {key: value for key, value in grid.derived.items()
            if (key[0] if isinstance(key, tuple) else key) in SHARED_DERIVED}
    if not mine.keys() - shared:
        return shared
    value = {**(_read_shared(path + DERIVED_SUFFIX) or {}), **mine}
    _write_shared(path + DERIVED_SUFFIX, value)
    return frozenset(value)


# --- in a worker process ---------------------------------------------------------------------------------------

_worker_estimation: Optional[str] = None
_worker_grids: 'OrderedDict[str, PreparedGrid]' = OrderedDict()
_worker_neighbours = ContentNeighbourCache()
_worker_shared: Dict[str, frozenset] = {}   # a grid's file -> the keys of its derived file as last read or written


def _start_worker(estimating: int) -> None:
    cv2.setNumThreads(1)   # one core each: the pool has a worker per core it may use
    # Ctrl-C reaches the whole process group: the estimating process answers it, and its workers end with it
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch, args=(estimating,), name='watch', daemon=True).start()


def _watch(estimating: int) -> None:
    """End this worker when the estimating process has gone (killed: nothing told the pool), and remove the files
    of its estimation."""
    while True:
        time.sleep(WATCH_PERIOD_S)
        try:
            os.kill(estimating, 0)
        except ProcessLookupError:
            if _worker_estimation is not None:
                shutil.rmtree(_worker_estimation, ignore_errors=True)
            os._exit(0)
        except OSError:
            pass   # alive, another user's


def _load(path: str) -> PreparedGrid:
    grid = _worker_grids.get(path)
    if grid is None:
        with open(path, 'rb') as f:
            grid = pickle.load(f)
        _worker_shared[path] = _take_derived(path, grid)
        _worker_grids[path] = grid
        while len(_worker_grids) > LOADED_KEPT:
            _worker_grids.popitem(last=False)
    else:
        _worker_grids.move_to_end(path)
    return grid


class _Kept(list):
    """A worker's log records of one match, as a QueueHandler prepares them (picklable), to be sent back."""
    put_nowait = list.append


def _match_in_worker(estimation: str, i: int, j: int, path_i: str, path_j: str, settings: EstimationSettings,
                     options: dict, log_level: int) -> Tuple[PairMatch, List[logging.LogRecord], float, float]:
    """The match, what it logged, and the seconds spent reading its grids and matching them."""
    global _worker_estimation, _worker_neighbours
    if estimation != _worker_estimation:
        _worker_estimation = estimation
        _worker_grids.clear()
        _worker_shared.clear()
        _worker_neighbours = ContentNeighbourCache(estimation)
    package, kept = logging.getLogger(PACKAGE_LOGGER), _Kept()
    handler = logging.handlers.QueueHandler(kept)
    package.setLevel(log_level)
    package.propagate = False   # kept for the estimating process, not printed here
    package.addHandler(handler)
    try:
        started = time.perf_counter()
        pi, pj = _load(path_i), _load(path_j)
        loaded = time.perf_counter()
        m = match_pair(i, j, pi, pj, settings, neighbours=_worker_neighbours, **options)
        for path, grid in ((path_i, pi), (path_j, pj)):
            _worker_shared[path] = _give_derived(path, grid, _worker_shared.get(path, frozenset()))
        return m, kept, loaded - started, time.perf_counter() - loaded
    finally:
        package.removeHandler(handler)


def _end_if_starting() -> None:
    """End this process at once, with one line, if it is a worker that has not finished starting: it runs the main
    module of the estimating process (as multiprocessing starts a worker), and that module runs an estimation when
    imported, outside `if __name__ == '__main__':`. Else it would run the whole estimation, fail to start processes
    of its own and end with a traceback of 40 lines. multiprocessing marks a process that is starting so
    (`_inheriting`, which its own check of the same mistake reads)."""
    if getattr(multiprocessing.current_process(), '_inheriting', False):
        sys.stderr.write('multirobot_map_merge: a matching process ended as it started: the main module runs an '
                         'estimation when imported (guard it with if __name__ == "__main__":)\n')
        sys.stderr.flush()
        os._exit(UNGUARDED_EXIT)


# --- in the estimating process ---------------------------------------------------------------------------------

class _Pool:
    """The worker processes, started on first use and kept for the process's later estimations."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._executor: Optional[ProcessPoolExecutor] = None
        self._workers = 0
        self._worked = False      # a batch has run on the pool now started
        self._failed_starts = 0   # pools in a row that broke before a batch ran on them
        self.unusable = False     # FAILED_STARTS of them: this process matches on threads from now on
        atexit.register(self.shutdown)

    def get(self, workers: int) -> ProcessPoolExecutor:
        with self._lock:
            if self._executor is None or self._workers != workers:
                self._stop(wait=False)
                context = multiprocessing.get_context('forkserver')
                context.set_forkserver_preload(SERVER_PRELOAD)
                self._executor = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                                     initializer=_start_worker, initargs=(os.getpid(),))
                self._workers, self._worked = workers, False
            return self._executor

    def start(self, workers: int) -> None:
        """Start every worker now (the pool starts one only when the others are busy), a broken pool afresh."""
        _end_if_starting()
        if self.unusable:
            return
        for _ in range(2):
            executor = self.get(workers)
            try:
                for _ in range(workers):
                    executor.submit(time.sleep, STARTED_TOGETHER_S)
                return
            except (BrokenProcessPool, RuntimeError):
                self.broken(executor)

    def worked(self, executor: ProcessPoolExecutor) -> None:
        """A batch ran on `executor`."""
        with self._lock:
            if self._executor is executor:
                self._worked, self._failed_starts = True, 0

    def broken(self, executor: ProcessPoolExecutor) -> None:
        """`executor` broke (a worker ended): it is stopped, and the next batch starts a pool afresh, unless
        FAILED_STARTS pools in a row broke before a batch ran on them (`unusable`): every worker ended as it started,
        and so would the next pool's (a main module that runs the estimation when imported, _end_if_starting)."""
        with self._lock:
            if self._executor is executor:
                self._failed_starts = 0 if self._worked else self._failed_starts + 1
                self.unusable = self.unusable or self._failed_starts >= FAILED_STARTS
                self._stop(wait=False)

    def shutdown(self) -> None:
        with self._lock:
            self._stop(wait=True)

    def _stop(self, wait: bool) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=wait, cancel_futures=True)
            self._executor = None


_POOL = _Pool()
_SAID = Throttle(math.inf)   # the warnings of _without_processes: once per process and cause


def _files_folder() -> Optional[str]:
    """Where an estimation's files go: /dev/shm (memory) when it has room for them, else the temporary folder (None:
    tempfile's default). A container's /dev/shm is often 64 MB, less than one batch of the generated 36-map
    buildings writes."""
    try:
        if os.access(SHARED_FOLDER, os.W_OK) and shutil.disk_usage(SHARED_FOLDER).free >= SHARED_FREE_BYTES:
            return SHARED_FOLDER
    except OSError:
        pass
    return None


_swept: set = set()   # the folders this process has swept (once each)


def _sweep_stale(folder: Optional[str]) -> None:
    """Remove the estimation folders in `folder` (None: the temporary folder) of processes that have gone: a process
    killed with its workers at once (SIGKILL to its process group, the OOM killer) leaves its files there, and
    /dev/shm is memory. Only this user's, untouched for STALE_S: a process of another PID namespace that shares the
    folder looks gone."""
    folder = folder or tempfile.gettempdir()
    if folder in _swept:
        return
    _swept.add(folder)
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for entry in entries:
        pid = entry.name[len(FOLDER_PREFIX):].split('_', 1)[0]
        if not (entry.name.startswith(FOLDER_PREFIX) and pid.isdigit()):
            continue
        try:
            stat = entry.stat(follow_symlinks=False)
            if not entry.is_dir(follow_symlinks=False) or stat.st_uid != os.getuid() \
                    or time.time() - stat.st_mtime < STALE_S:
                continue
            os.kill(int(pid), 0)
        except ProcessLookupError:
            log.info('removing %s: the files of an estimation whose process has gone', entry.path)
            shutil.rmtree(entry.path, ignore_errors=True)
        except OSError:
            pass   # alive (another user's), or gone meanwhile


class ParallelMatcher:
    """One estimation's parallel matches: on `settings.threads` worker processes (settings.processes), else on the
    estimation's thread pool. A context manager: its files are removed at its end (or once it is collected, for one
    used without `with`)."""

    def __init__(self, settings: EstimationSettings, threads: Executor, memo: Optional[MatchMemo] = None) -> None:
        self.s, self.threads = settings, threads
        self.memo = memo   # the matches kept for an estimation made again (match_memo.py)
        # the descriptor distances of the matches made in this process, shared with the workers once there is a folder
        self.neighbours = SharedNeighbourCache()
        self.processes = settings.processes and settings.threads > 1
        if self.processes:
            try:
                _POOL.start(settings.threads)   # while the grids are prepared
            except OSError as e:
                self._without_processes(e)
            if _POOL.unusable:
                self._without_processes(UNUSABLE)
        self._folder: Optional[str] = None
        self._remove_folder: Optional[weakref.finalize] = None
        # id of a grid sent -> (it, its file, the file's size), least recently used first
        self._files: 'OrderedDict[int, Tuple[PreparedGrid, str, int]]' = OrderedDict()
        self._bytes = 0
        self._lock = threading.Condition()
        self._writing = 0     # files being written on the estimation's threads, outside the lock
        self._closed = False  # the estimation has ended: no file is written any more
        self._written = 0
        self._worker_settings = settings.replace(threads=1)   # a worker's search runs on its own core
        self.stats = BatchStats()

    def __enter__(self) -> 'ParallelMatcher':
        return self

    def __exit__(self, *exc) -> bool:
        if self.stats.batches:
            log.debug('%s', self.stats.summary(self.s.threads))
        with self._lock:
            # an estimation ended by an exception (SIGTERM, merge_maps) can leave threads writing grids: a file
            # created while the folder was removed kept it in /dev/shm (a fresh-clone test run)
            self._closed = True
            self._lock.wait_for(lambda: self._writing == 0, timeout=WRITE_WAIT_S)
        if self._remove_folder is not None:
            self._remove_folder()
        self._files.clear()
        return False

    def match_all(self, calls: Sequence[MatchCall]) -> List[PairMatch]:
        """The matches of `calls`, in their order."""
        if self.memo is None:
            return self._match_all(calls)
        found = [self.memo.get(c.i, c.j, c.pi, c.pj, c.options) for c in calls]
        made = iter(self._match_all([c for c, m in zip(calls, found) if m is None]))
        out = []
        for c, m in zip(calls, found):
            if m is None:
                m = next(made)
                self.memo.put(c.i, c.j, c.pi, c.pj, c.options, m)
            out.append(m)
        return out

    def _match_all(self, calls: Sequence[MatchCall]) -> List[PairMatch]:
        if not calls:
            return []
        if len(calls) > 1 and self.processes:
            try:
                executor = _POOL.get(self.s.threads)
                return self._on_processes(executor, calls)
            except BrokenProcessPool as e:
                log.warning('the matching processes failed (%s): this batch runs on threads', e)
                _POOL.broken(executor)
                if _POOL.unusable:
                    self._without_processes(UNUSABLE)
            except OSError as e:
                self._without_processes(e)
        return list(self.threads.map(self._match_here, calls))

    def _without_processes(self, why: object) -> None:
        """The rest of this estimation's matches run on threads: processes cannot start (no POSIX semaphores, as
        in some sandboxes), the grids cannot be written (a full disk), or the workers end as they start (UNUSABLE);
        every batch would fail the same way, and a pool that runs is sound."""
        said = f'the matching processes cannot be used ({why}): the matches of this estimation run on threads'
        (log.warning if _SAID(said) else log.debug)('%s', said)   # a node would say it at every estimation
        self.processes = False

    def match_here(self, call: MatchCall) -> PairMatch:
        """One match, in this process."""
        if self.memo is None:
            return self._match_here(call)
        m = self.memo.get(call.i, call.j, call.pi, call.pj, call.options)
        if m is None:
            m = self._match_here(call)
            self.memo.put(call.i, call.j, call.pi, call.pj, call.options, m)
        return m

    def _match_here(self, call: MatchCall) -> PairMatch:
        files = self._sent(call.pi, call.pj)
        known = [_take_derived(path, grid) for path, grid in files]
        m = match_pair(call.i, call.j, call.pi, call.pj, self.s, neighbours=self.neighbours, **call.options)
        for (path, grid), keys in zip(files, known):
            _give_derived(path, grid, keys)
        return m

    def _sent(self, *grids: PreparedGrid) -> List[Tuple[str, PreparedGrid]]:
        """(its file, it) of those of the grids sent to the workers (whose file is still there)."""
        with self._lock:
            sent = [(self._files.get(id(g)), g) for g in grids]
        return [(s[1], g) for s, g in sent if s is not None and s[0] is g]

    def _on_processes(self, executor: ProcessPoolExecutor, calls: Sequence[MatchCall]) -> List[PairMatch]:
        grids = {id(g): g for c in calls for g in (c.pi, c.pj)}
        # detection and wall fields left for later (features.prepare(lazy=True)) are done here, once, not in each
        # worker
        list(self.threads.map(lambda g: g.describe().wall_fields(), grids.values()))
        paths = dict(zip(grids, self.threads.map(self._path, grids.values())))
        # the largest first: the batch ends on short matches, not on a long one alone on the pool
        order = sorted(range(len(calls)), key=lambda n: -len(calls[n].pi.walls))
        level = logging.getLogger(PACKAGE_LOGGER).getEffectiveLevel()
        started = time.perf_counter()
        futures = {n: executor.submit(_match_in_worker, self._folder, calls[n].i, calls[n].j,
                                      paths[id(calls[n].pi)], paths[id(calls[n].pj)], self._worker_settings,
                                      calls[n].options, level) for n in order}
        try:
            results = [futures[n].result() for n in range(len(calls))]
        except BaseException:
            # the estimation ends in the middle of a batch (SIGTERM, Ctrl-C): the matches under way end before it
            # removes its folder, where they share what they computed (a file written while the folder was removed
            # kept it in /dev/shm); those not started are not made
            for future in futures.values():
                future.cancel()
            wait(futures.values(), timeout=WRITE_WAIT_S)
            raise
        finally:
            self._remove_unused(grids)
        _POOL.worked(executor)
        self.stats.add(time.perf_counter() - started, [r[2:] for r in results])
        for _, records, _, _ in results:
            for record in records:
                logging.getLogger(record.name).handle(record)
        return [r[0] for r in results]

    def _path(self, grid: PreparedGrid) -> str:
        with self._lock:
            sent = self._files.get(id(grid))
            if sent is not None and sent[0] is grid:
                self._files.move_to_end(id(grid))
                return sent[1]
            if self._closed:
                raise RuntimeError('the estimation has ended: no more grids are sent to its workers')
            if self._folder is None:
                folder = _files_folder()
                _sweep_stale(folder)
                self._folder = tempfile.mkdtemp(prefix=f'{FOLDER_PREFIX}{os.getpid()}_', dir=folder)
                self.neighbours.folder = self._folder
                self._remove_folder = weakref.finalize(self, shutil.rmtree, self._folder, ignore_errors=True)
            self._written += 1
            self._writing += 1
            path = os.path.join(self._folder, f'{self._written}.pickle')
        try:
            with open(path, 'wb') as f:
                pickle.dump(grid, f, protocol=pickle.HIGHEST_PROTOCOL)
                size = f.tell()
        finally:
            with self._lock:
                self._writing -= 1
                self._lock.notify_all()
        with self._lock:
            # kept with its file: its id is not reused while the file is
            self._files[id(grid)] = (grid, path, size)
            self._bytes += size
        return path

    def _remove_unused(self, used: Dict[int, PreparedGrid]) -> None:
        """Remove the files least recently used beyond FILES_KEPT_BYTES (the unions of earlier batches, mostly): a
        grid whose file is removed is written again if a later batch needs it."""
        with self._lock:
            for key in list(self._files):
                if self._bytes <= FILES_KEPT_BYTES:
                    break
                if key not in used:
                    _, path, size = self._files.pop(key)
                    self._bytes -= size
                    for name in (path, path + DERIVED_SUFFIX):
                        try:
                            os.remove(name)
                        except OSError:
                            pass
