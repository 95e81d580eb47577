"""Pacing of the node's loops on ROS time, as the original's ros::Rate, with a prompt stop."""
from __future__ import annotations

import math
import threading
import time
from typing import Optional

import rospy

SLICE = 0.1             # s (wall) between two checks of the stop flag while a loop waits on simulated time


class LoopPacer:
    """Paces one loop at a rate in ROS time, as ros::Rate does (so it follows /clock under use_sim_time).

    `wait()` returns when the period since `start_cycle()` has passed (and, with `rest_share`, at least that share
    of the wall time the cycle's work took), or at once when the loop's `kick` event is set (a stop request, or the
    estimation's wake-up). Under simulated time it waits on rospy's clock condition, which every /clock message
    notifies, in slices of at most SLICE wall seconds; until /clock has started it paces on the wall clock; when
    ROS time jumps back (bag loop, simulator reset) the period restarts instead of raising as rospy.Rate would.
    """

    def __init__(self, rate: float, kick: threading.Event, rest_share: float = 0.0) -> None:
        if not (math.isfinite(rate) and rate > 0.0):
            raise ValueError(f'loop rate {rate} is not a positive finite number')   # no zero-period loop
        self.period = 1.0 / rate
        self.kick = kick
        self.rest_share = rest_share   # after a cycle that took b seconds, rest at least rest_share * b
        self.sooner: Optional[float] = None   # a shorter period for the current cycle only (set during it)
        self._ros0 = 0.0
        self._wall0 = 0.0

    def start_cycle(self) -> None:
        self._ros0, self._wall0 = rospy.get_time(), time.monotonic()

    def _elapsed(self) -> float:
        """Seconds since start_cycle(): ROS time, or wall time while there is none; -1 if ROS time went back. When
        simulated time starts during a cycle, the period counts from its start: measured on the wall clock it would
        last `speedup` times longer (the demo's first estimations came 10 sim-s apart instead of 2)."""
        now = rospy.get_time()
        if self._ros0 <= 0.0 < now:
            self._ros0 = now
        if self._ros0 > 0.0 and now > 0.0:
            return now - self._ros0 if now >= self._ros0 else -1.0
        return time.monotonic() - self._wall0   # no ROS time yet (sim time, /clock not started)

    def wait(self) -> None:
        cond = rospy.rostime.get_rostime_cond()
        # the rest is in wall time: it keeps the CPU share down, whatever the simulated time's speed-up
        rest_until = time.monotonic() + (time.monotonic() - self._wall0) * self.rest_share
        while not self.kick.is_set():
            elapsed = self._elapsed()
            if elapsed < 0.0:
                break   # ROS time moved backwards (bag loop, simulator reset): start a new period now
            period = min(self.period, self.sooner) if self.sooner is not None else self.period
            remaining = max(period - elapsed, rest_until - time.monotonic())
            if remaining <= 0.0:
                break
            if rospy.rostime.is_wallclock():
                self.kick.wait(min(remaining, 1.0))
            else:
                with cond:   # kick() notifies under the same lock: no wake-up is lost
                    if not self.kick.is_set():
                        cond.wait(SLICE)
        self.kick.clear()
        self.sooner = None

    @staticmethod
    def wake(event: threading.Event) -> None:
        """Set a loop's kick event and wake it if it waits on simulated time."""
        event.set()
        cond = rospy.rostime.get_rostime_cond()
        with cond:
            cond.notify_all()
