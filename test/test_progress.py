"""merge_maps' terminal progress: the estimation hook on the settings, and the throttled one-line printer."""
import io
import re
import time

from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.progress import TerminalProgress, attach, no_progress, progress_of


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


class Tty(io.StringIO):
    def isatty(self):
        return True


def test_hook_defaults_to_a_no_op_and_carries_the_attached_callback():
    settings = EstimationSettings()
    assert progress_of(settings) is no_progress
    seen = []
    attach(settings, lambda done, total: seen.append((done, total)))
    progress_of(settings)(3, 10)
    assert seen == [(3, 10)]
    attach(settings, None)
    assert progress_of(settings) is no_progress


def test_nothing_is_shown_before_the_delay_then_counts_and_time_on_one_line():
    clock, out = FakeClock(), Tty()
    progress = TerminalProgress('estimating', unit='pairs', stream=out, delay=1.0, clock=clock)
    progress(2, 10)
    clock.now += 0.5
    progress.redraw()
    assert out.getvalue() == ''
    clock.now += 1.0
    progress.redraw()
    assert out.getvalue() == '\restimating: 2/10 pairs, 2 s'
    progress(10, 10)
    progress.redraw()
    assert out.getvalue().endswith('\restimating: 10/10 pairs, 2 s') and '\n' not in out.getvalue()
    progress.clear()
    assert out.getvalue().endswith('\r' + ' ' * len('estimating: 10/10 pairs, 2 s') + '\r')


def test_without_counts_it_shows_the_elapsed_time():
    clock, out = FakeClock(), Tty()
    progress = TerminalProgress('estimating', stream=out, delay=0.0, clock=clock)
    clock.now += 3.2
    progress.redraw()
    assert out.getvalue() == '\restimating: 3 s'


def test_quiet_when_the_stream_is_not_a_terminal():
    out = io.StringIO()
    progress = TerminalProgress('estimating', stream=out, delay=0.0, interval=0.01)
    assert not progress.enabled
    with progress:
        progress(1, 2)
        time.sleep(0.05)
    assert out.getvalue() == ''


def test_the_ticker_redraws_during_long_work_and_erases_the_line_at_the_end():
    out = Tty()
    with TerminalProgress('estimating', stream=out, delay=0.0, interval=0.01) as progress:
        progress(1, 3)
        deadline = time.monotonic() + 5.0
        while 'estimating: 1/3 pairs' not in out.getvalue() and time.monotonic() < deadline:
            time.sleep(0.01)
    text = out.getvalue()
    assert 'estimating: 1/3 pairs' in text
    assert text.endswith('\r') and text.rstrip('\r ').count('\r') >= 1
    assert '\n' not in text


def test_merge_maps_passes_a_terminal_printer_that_the_estimation_reaches(repo_root, tmp_path, monkeypatch):
    """The estimation calls progress_of(settings)(done, total) (here slowed down); on a terminal merge_maps shows it."""
    from multirobot_map_merge import cli
    from multirobot_map_merge.pipeline import MergingPipeline

    real_estimate = MergingPipeline.estimate

    def reporting_estimate(self, *args, **kwargs):
        report = progress_of(self.settings)
        for done in range(3):
            report(done, 3)
            time.sleep(0.6)
        return real_estimate(self, *args, **kwargs)

    monkeypatch.setattr(MergingPipeline, 'estimate', reporting_estimate)
    err = Tty()
    monkeypatch.setattr('sys.stderr', err)
    maps = sorted(str(p) for p in (repo_root / 'data' / 'samples' / 'chain3').glob('map_*.yaml'))
    assert cli.main(['--output', str(tmp_path / 'm'), *maps]) == 0
    text = err.getvalue()
    assert re.search(r'\rmerge_maps: estimating: [12]/3 maps placed or set aside, \d+ s', text), repr(text)
    # the line is erased before the next message
    assert re.search(r'\r +\rmerge_maps: 3 of 3 maps placed', text)
