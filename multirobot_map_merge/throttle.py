"""Per-key log throttling shared by the nodes (no rospy import).

rospy's *_throttle helpers key on the call site, which would let one robot's (or one kind of) problem hide
another's; here every key (e.g. robot and kind of problem) has its own period.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Dict, Hashable


class Throttle:
    """Call with a key: True at most once per `period` seconds (monotonic clock) for that key. Thread safe."""

    def __init__(self, period: float) -> None:
        self._period = period
        self._last: Dict[Hashable, float] = {}
        self._lock = threading.Lock()

    def __call__(self, key: Hashable) -> bool:
        now = time.monotonic()
        with self._lock:
            if now - self._last.get(key, -math.inf) < self._period:
                return False
            self._last[key] = now
            return True
