"""What a benchmark's figures were measured on: CPUs, load, and the Python, OpenCV and numpy that ran the estimation;
and the CPU a process used with the processes under it (the estimation's worker processes and their server).

The estimation's time depends on the OpenCV build: Debian's python3-opencv 4.6 (what a ROS user's /usr/bin/python3
imports) computes the correlation search's DFTs 3-4 times slower than the opencv-python-headless wheel of the
virtual environment, so a figure without its build cannot be compared with another.
"""
from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Dict, List

CLK_TCK = os.sysconf('SC_CLK_TCK')


def cpus() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else (os.cpu_count() or 1)


def software() -> str:
    """'Python 3.11.2, OpenCV 4.12.0 (wheel), numpy 2.2.6' for this interpreter."""
    import cv2
    import numpy as np
    # the wheel is a package (cv2/__init__.py), Debian's python3-opencv a single extension module
    origin = 'wheel' if os.path.basename(cv2.__file__) == '__init__.py' else 'system'
    return f'Python {platform.python_version()}, OpenCV {cv2.__version__} ({origin}), numpy {np.__version__}'


def describe() -> str:
    """'2 CPUs, load average 0.52; Python ..., OpenCV ... (...), numpy ...'."""
    return f'{cpus()} CPUs, load average {os.getloadavg()[0]:.2f}; {software()}'


def _stat(pid: int) -> List[str]:
    return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()


def process_tree(pid: int) -> List[int]:
    """The process and every process under it (the estimation's worker processes and their server)."""
    children: Dict[int, List[int]] = {}
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                children.setdefault(int(_stat(int(entry.name))[1]), []).append(int(entry.name))   # ppid
            except (OSError, IndexError, ValueError):
                pass   # ended meanwhile
    tree, todo = [], [pid]
    while todo:
        tree.append(todo.pop())
        todo += children.get(tree[-1], [])
    return tree


def proc_cpu_seconds(pid: int) -> float:
    """CPU of the process and of the processes under it, the children they have waited for included."""
    ticks = 0
    for p in process_tree(pid):
        try:
            fields = _stat(p)
        except OSError:
            continue   # ended meanwhile
        ticks += sum(int(f) for f in fields[11:15])   # utime, stime, cutime, cstime (fields 14-17 of stat)
    return ticks / CLK_TCK
