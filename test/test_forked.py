"""Work run in forked children (estimation/forked.py): the same results as in one process, whatever the child does."""
import os
import time

import numpy as np
import pytest

from multirobot_map_merge.estimation import forked
from multirobot_map_merge.estimation.forked import Forked, forked_map

pytestmark = pytest.mark.skipif(not forked.CAN_FORK, reason='no fork on this platform')


def test_forked_map_keeps_order_and_runs_in_children():
    pids = forked_map(lambda x: (x, os.getpid()), list(range(9)), workers=3, cost=lambda x: x)
    assert [x for x, _ in pids] == list(range(9))
    assert len({pid for _, pid in pids}) == 3 and os.getpid() in {pid for _, pid in pids}   # and two children


def test_forked_map_returns_numpy_results():
    out = forked_map(lambda x: np.full((3, 3), x), [1, 2, 3, 4], workers=2)
    assert [int(a[0, 0]) for a in out] == [1, 2, 3, 4]


def test_a_child_that_raises_is_replaced_by_the_parent():
    parent = os.getpid()

    def fails_in_child():
        if os.getpid() != parent:
            raise RuntimeError('only in the child')
        return 'computed here'

    assert Forked(fails_in_child).result() == 'computed here'


def test_a_child_that_dies_is_replaced_by_the_parent():
    parent = os.getpid()

    def dies_in_child():
        if os.getpid() != parent:
            os._exit(3)
        return 42

    assert Forked(dies_in_child).result() == 42


def test_a_child_that_hangs_is_given_up_after_the_deadline():
    parent = os.getpid()

    def hangs_in_child():
        if os.getpid() != parent:
            time.sleep(30)
        return 'late but right'

    job = Forked(hangs_in_child)
    pid = job.pid
    started = time.perf_counter()
    assert job.result(deadline_s=0.5) == 'late but right'
    assert time.perf_counter() - started < 5
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)   # killed and reaped


def test_cancel_ends_the_child():
    job = Forked(lambda: time.sleep(30))
    pid = job.pid
    job.cancel()
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)


def test_an_error_in_the_parent_share_ends_the_children():
    before = set(os.listdir('/proc'))

    def boom(x):
        if x == 0:
            raise ValueError('parent share')
        time.sleep(30)

    with pytest.raises(ValueError):
        forked_map(boom, [0, 1], workers=2, cost=lambda x: 1 - x)
    time.sleep(0.2)
    children = [p for p in set(os.listdir('/proc')) - before if p.isdigit()
                and os.path.exists(f'/proc/{p}/stat')
                and open(f'/proc/{p}/stat').read().split()[3] == str(os.getpid())]
    assert children == []
