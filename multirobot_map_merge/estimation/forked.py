"""Matching work run in a forked child process, on the other core.

A match is mostly many small numpy steps that hold the GIL: two matches on two threads ran 1.2-1.3 times as fast
as one. A child forked from the estimating process sees every grid, union and cache as they are (copy-on-write:
nothing is shipped to it, only its result comes back, pickled through a pipe), and forking takes a few milliseconds.

Whatever goes wrong in a child (it raises, dies, is killed, or does not answer in time: a lock another thread of
the parent held when it forked, say inside OpenCV) only costs time: the parent then does that work itself, so the
result is always the one a single process would give. A child logs nothing (the parent's log handlers, rosout
among them, write to the parent's connections), leaves SIGINT and SIGTERM to their default (a Ctrl-C of the
terminal ends it too) and exits without running the parent's exit handlers.
"""
from __future__ import annotations

import logging
import os
import pickle
import select
import signal
import time
from typing import Callable, Generic, Optional, TypeVar

log = logging.getLogger('rosout.multirobot_map_merge.estimation.forked')

T = TypeVar('T')
_FAILED = object()
CAN_FORK = hasattr(os, 'fork')
SLACK_S = 2.0   # a child may take this long more than the parent took for its own share before it is given up


class Forked(Generic[T]):
    """fn() started in a forked child; result() returns its value (computed by the parent itself if the child
    fails), cancel() ends the child when its result is not needed."""

    def __init__(self, fn: Callable[[], T]):
        self.fn = fn
        self.pid: Optional[int] = None
        self.fd: Optional[int] = None
        self.started = time.perf_counter()
        if not CAN_FORK:
            return
        try:
            r, w = os.pipe()
        except OSError:
            return
        try:
            pid = os.fork()
        except OSError as e:
            os.close(r)
            os.close(w)
            log.debug('fork failed (%s): the work runs in this process', e)
            return
        if pid == 0:   # the child
            os.close(r)
            _child(fn, w)
        os.close(w)
        self.pid, self.fd = pid, r

    def result(self, deadline_s: Optional[float] = None) -> T:
        """The child's result, or fn() computed here if the child failed or gave no answer `deadline_s` seconds
        from now (default: SLACK_S plus the time since it started, so a child that hangs costs at most that)."""
        if self.pid is None:
            return self.fn()
        if deadline_s is None:
            deadline_s = SLACK_S + (time.perf_counter() - self.started)
        value = self._read(time.perf_counter() + deadline_s)
        if value is _FAILED:
            log.debug('a forked match gave no result: it runs in this process')
            return self.fn()
        return value

    def cancel(self) -> None:
        if self.pid is not None:
            self._end()

    def _read(self, until: float):
        chunks = []
        try:
            while True:
                left = until - time.perf_counter()
                if left <= 0 or not select.select([self.fd], [], [], left)[0]:
                    return _FAILED
                chunk = os.read(self.fd, 1 << 20)
                if not chunk:
                    break
                chunks.append(chunk)
            ok, value = pickle.loads(b''.join(chunks))
            return value if ok else _FAILED
        except Exception:   # a truncated or garbled answer: the child died while writing
            return _FAILED
        finally:
            self._end()

    def _end(self) -> None:
        try:
            os.kill(self.pid, signal.SIGKILL)
        except OSError:
            pass   # it has exited already
        try:
            os.waitpid(self.pid, 0)
        except OSError:
            pass
        os.close(self.fd)
        self.pid = self.fd = None


def _child(fn: Callable, w: int) -> None:
    status = 0
    try:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        logging.disable(logging.CRITICAL)
        try:
            payload = pickle.dumps((True, fn()), pickle.HIGHEST_PROTOCOL)
        except BaseException:
            payload = pickle.dumps((False, None))
        view = memoryview(payload)
        while view:
            view = view[os.write(w, view):]
    except BaseException:
        status = 1
    finally:
        os._exit(status)


def forked_map(fn: Callable, items: list, workers: int, cost: Optional[Callable] = None) -> list:
    """[fn(x) for x in items], the items shared among this process and workers - 1 forked children, balanced by
    cost(x) (largest first, each to the least loaded)."""
    if workers <= 1 or len(items) < 2 or not CAN_FORK:
        return [fn(x) for x in items]
    shares = [[] for _ in range(min(workers, len(items)))]
    loads = [0.0] * len(shares)
    order = sorted(range(len(items)), key=lambda i: -(cost(items[i]) if cost else 1.0))
    for i in order:
        s = loads.index(min(loads))
        shares[s].append(i)
        loads[s] += cost(items[i]) if cost else 1.0
    children = [Forked(lambda share=share: [fn(items[i]) for i in share]) for share in shares[1:]]
    out = [None] * len(items)
    try:
        for i in shares[0]:
            out[i] = fn(items[i])
        for share, child in zip(shares[1:], children):
            for i, value in zip(share, child.result()):
                out[i] = value
    finally:
        for child in children:
            child.cancel()
    return out
