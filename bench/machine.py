"""What a benchmark's figures were measured on: CPUs, load, and the Python, OpenCV and numpy that ran the estimation.

The estimation's time depends on the OpenCV build: Debian's python3-opencv 4.6 (what a ROS user's /usr/bin/python3
imports) computes the correlation search's DFTs 3-4 times slower than the opencv-python-headless wheel of the
virtual environment, so a figure without its build cannot be compared with another.
"""
from __future__ import annotations

import os
import platform


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
