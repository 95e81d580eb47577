"""A record of a live node's estimations, exactly as each one started (a diagnostic; no ROS import).

The map_merge node writes one when the environment variable MAP_MERGE_RECORD_ESTIMATIONS names a directory (`make
demo DEMO_ARGS="... --record RUN.bag"` sets it to RUN.estimations): per estimation, one line of `estimations.jsonl`
(its ROS time, the robots in the node's order, the reference and the placements it started from, what it placed,
held and postponed, its wall time, its search budget's answers) and, once per map content, the map in
`grids/<digest>.npz`. A rosbag holds the maps as they came, not the snapshots each estimation took, and the search
budget is wall time on a loaded machine: `scripts/replay_estimations.py` estimates these again one by one with the
same inputs and the same budget answers (growth.SearchBudget), so that a placement the live node made is made again
offline.

The writing runs on a thread of its own (grids are never modified once stored, robot_maps.py), so that an
estimation waits only for the queue; a record that cannot be written is logged once and recording stops.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import queue
import threading
from dataclasses import dataclass
from typing import Dict, Iterator, List, Optional, Sequence

import numpy as np

from .grid import Grid

log = logging.getLogger('rosout.multirobot_map_merge.recording')

ENVIRONMENT = 'MAP_MERGE_RECORD_ESTIMATIONS'
LINES = 'estimations.jsonl'
GRIDS = 'grids'


@dataclass
class RecordedEstimation:
    index: int
    now: Optional[float]                       # ROS time the node passed to the estimation
    names: List[str]                           # robots, in the node's order
    grids: List[Optional[Grid]]                # the snapshots it estimated on
    reference: Optional[str]                   # the preferred reference robot
    previous: List[Optional[np.ndarray]]       # placements it started from (tracking), per robot
    placed: Dict[str, np.ndarray]              # what it placed (published, or about to be)
    held: int
    postponed: int
    seconds: float                             # its wall time
    budget_verdicts: List[bool]                # its search budget's answers (growth.SearchBudget)


def _matrix(t: Optional[np.ndarray]) -> Optional[list]:
    return None if t is None else np.asarray(t, float).tolist()


def _array(m: Optional[list]) -> Optional[np.ndarray]:
    return None if m is None else np.asarray(m, float)


class EstimationRecorder:
    """Appends estimations to a directory (see the module docstring); `close()` writes what is queued."""

    def __init__(self, directory: str) -> None:
        self.directory = directory
        os.makedirs(os.path.join(directory, GRIDS), exist_ok=True)
        self._queue: 'queue.Queue' = queue.Queue()
        self._count = 0
        self._written: Dict[int, str] = {}   # id of a grid object written -> its digest (grids are immutable)
        self._held_grids: Dict[int, Grid] = {}   # keeps those objects alive, so that an id is not reused
        self._thread = threading.Thread(target=self._write_loop, name='estimation_recorder', daemon=True)
        self._thread.start()

    @classmethod
    def from_environment(cls) -> Optional['EstimationRecorder']:
        directory = os.environ.get(ENVIRONMENT, '')
        if not directory:
            return None
        log.info('recording every estimation into %s (%s)', directory, ENVIRONMENT)
        return cls(directory)

    def record(self, now: Optional[float], names: Sequence[str], grids: Sequence[Optional[Grid]],
               reference: Optional[str], previous: Sequence[Optional[np.ndarray]], result, seconds: float) -> None:
        """Queue one estimation: its inputs and its result (an estimator.Estimate)."""
        placed = {n: t for n, t in zip(names, result.transforms) if t is not None}
        self._queue.put((self._count, now, list(names), list(grids), reference, list(previous), placed,
                         int(result.held), int(result.postponed), float(seconds), list(result.budget_verdicts)))
        self._count += 1

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=1.0)   # the node's exit watchdog waits 1.6 s

    def _write_loop(self) -> None:
        lines = open(os.path.join(self.directory, LINES), 'a')
        try:
            while True:
                item = self._queue.get()
                if item is None:
                    return
                index, now, names, grids, reference, previous, placed, held, postponed, seconds, verdicts = item
                line = {'index': index, 'now': now, 'names': names, 'grids': [self._write_grid(g) for g in grids],
                        'reference': reference, 'previous': [_matrix(t) for t in previous],
                        'placed': {n: _matrix(t) for n, t in placed.items()}, 'held': held,
                        'postponed': postponed, 'seconds': seconds,
                        'budget': ''.join('1' if v else '0' for v in verdicts)}
                lines.write(json.dumps(line) + '\n')
                lines.flush()
        except (OSError, ValueError) as e:   # a full disk: the node goes on without its record
            log.error('estimation record in %s stopped: %s', self.directory, e)
        finally:
            lines.close()

    def _write_grid(self, grid: Optional[Grid]) -> Optional[str]:
        if grid is None:
            return None
        digest = self._written.get(id(grid))
        if digest is not None:
            return digest
        h = hashlib.blake2b(digest_size=12)
        h.update(grid.data.tobytes())
        h.update(repr((grid.data.shape, grid.resolution, grid.origin, grid.frame_id)).encode())
        digest = h.hexdigest()
        path = os.path.join(self.directory, GRIDS, digest + '.npz')
        if not os.path.exists(path):
            np.savez_compressed(path, data=grid.data, resolution=grid.resolution, origin=np.asarray(grid.origin),
                                frame_id=grid.frame_id, stamp=grid.stamp)
        if len(self._held_grids) > 4096:   # bound the memory: forget the oldest (their ids may then be reused)
            self._written.clear()
            self._held_grids.clear()
        self._written[id(grid)] = digest
        self._held_grids[id(grid)] = grid
        return digest


def read_estimations(directory: str) -> Iterator[RecordedEstimation]:
    """The estimations of a record, in order (raises OSError or ValueError on a missing or broken record)."""
    cache: Dict[str, Grid] = {}

    def grid(digest: Optional[str]) -> Optional[Grid]:
        if digest is None:
            return None
        if digest not in cache:
            with np.load(os.path.join(directory, GRIDS, digest + '.npz')) as f:
                cache[digest] = Grid(f['data'], float(f['resolution']), tuple(f['origin']), str(f['frame_id']),
                                     float(f['stamp']))
        return cache[digest]

    with open(os.path.join(directory, LINES)) as lines:
        for text in lines:
            if not text.strip():
                continue
            d = json.loads(text)
            # live maps change between estimations: keep only the grids this one uses
            cache = {k: cache[k] for k in d['grids'] if k in cache}
            yield RecordedEstimation(d['index'], d['now'], d['names'], [grid(g) for g in d['grids']], d['reference'],
                                     [_array(t) for t in d['previous']],
                                     {n: _array(t) for n, t in d['placed'].items()}, d['held'], d['postponed'],
                                     d['seconds'], [c == '1' for c in d.get('budget', '')])
