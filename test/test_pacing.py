"""The node's loop pacing on simulated time (no ROS master: rospy's clock is set as its /clock callback sets it)."""
import threading

import pytest

rospy = pytest.importorskip('rospy')

from multirobot_map_merge.ros.pacing import LoopPacer  # noqa: E402


@pytest.fixture
def sim_clock():
    """rospy's time as under use_sim_time, before /clock has started (0); restored afterwards."""
    rostime = rospy.rostime
    saved = (rostime._rostime_initialized, rostime._rostime_current)
    rostime.set_rostime_initialized(True)
    rostime._set_rostime(rospy.Time(0))
    yield lambda seconds: rostime._set_rostime(rospy.Time.from_sec(seconds))
    rostime._rostime_initialized, rostime._rostime_current = saved


def _wait_in_thread(pacer: LoopPacer) -> threading.Event:
    done = threading.Event()

    def run():
        pacer.wait()
        done.set()

    threading.Thread(target=run, daemon=True).start()
    return done


def test_a_cycle_started_before_the_clock_waits_its_period_in_simulated_time(sim_clock):
    """The demo's first estimation starts before /clock does: its period (2 s at 0.5 Hz) must pass in simulated
    time from when the clock starts, not on the wall clock (at a speed-up of 5, 10 simulated seconds)."""
    pacer = LoopPacer(0.5, threading.Event())
    pacer.start_cycle()            # ROS time 0: the simulator has not published /clock yet
    sim_clock(100.0)               # the clock starts
    done = _wait_in_thread(pacer)
    returned_at = None
    for second in range(1, 11):    # 1 simulated second per 0.1 wall seconds, up to 10
        returned_at = 100.0 + second - 1 if done.wait(0.1) else None
        if returned_at is not None:
            break
        sim_clock(100.0 + second)
    assert returned_at == 102.0, f'returned at simulated time {returned_at}, not after its period (102)'


def test_a_kick_ends_the_wait_at_once(sim_clock):
    sim_clock(5.0)
    kick = threading.Event()
    pacer = LoopPacer(0.5, kick)
    pacer.start_cycle()
    done = _wait_in_thread(pacer)
    assert not done.wait(0.3)      # simulated time stands still: the period does not pass
    LoopPacer.wake(kick)
    assert done.wait(1.0)


def test_a_sooner_period_holds_for_the_current_cycle_only(sim_clock):
    """An estimation that held a new placement asks for the next one sooner (node CONFIRM_S): at 0.1 Hz the cycle
    ends after 2 simulated seconds instead of 10, and the next cycle waits its full period again."""
    def wait_until_returned(start: float) -> float:
        done = _wait_in_thread(pacer)
        for second in range(1, 13):
            if done.wait(0.1):
                return start + second - 1
            sim_clock(start + second)
        return float('inf')

    sim_clock(50.0)
    pacer = LoopPacer(0.1, threading.Event())
    pacer.start_cycle()
    pacer.sooner = 2.0
    assert wait_until_returned(50.0) == 52.0
    assert pacer.sooner is None
    sim_clock(60.0)
    pacer.start_cycle()
    assert wait_until_returned(60.0) == 70.0
