"""Progress of a long estimation: the hook the estimation calls, and a terminal printer for merge_maps.

The hook travels on the settings object, so no signature changes: the caller attaches a callback, the
estimation reads it with `progress_of(settings)` (a no-op when none is attached) and calls
`report(done, total)` after each unit of work (a matched pair, or a prepared map). It may be called from worker
threads; a callback must be cheap and thread safe.

    attach(settings, TerminalProgress('estimating'))     # merge_maps on a terminal
    report = progress_of(settings)                         # in the estimation
    report(done, total)
"""
from __future__ import annotations

import sys
import threading
import time
from typing import Callable, Optional, TextIO

ProgressCallback = Callable[[int, int], None]

_ATTRIBUTE = 'progress'


def no_progress(done: int, total: int) -> None:
    """The default hook: does nothing."""


def attach(settings: object, callback: Optional[ProgressCallback]) -> None:
    """Give `settings` (an EstimationSettings) a progress callback; None removes it. Not copied by
    settings.replace(): a copy reports nothing."""
    setattr(settings, _ATTRIBUTE, callback)


def progress_of(settings: object) -> ProgressCallback:
    """The callback attached to `settings`, or the no-op."""
    return getattr(settings, _ATTRIBUTE, None) or no_progress


def is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):   # closed or not a real stream
        return False


class TerminalProgress:
    """A one-line progress display on a terminal, shown only once the work has taken `delay` seconds.

    Use as a context manager around the work and pass the object as the progress callback. A ticker thread
    redraws the line (`label: 12/45 pairs, 3 s`) at most every `interval` seconds with `\\r`, so the elapsed time
    moves even while no unit completes; the line is erased at the end. Does nothing when `stream` is not a
    terminal (unless `enabled` says otherwise), so piped output and logs stay clean.
    """

    def __init__(self, label: str, unit: str = 'pairs', stream: Optional[TextIO] = None, delay: float = 1.0,
                 interval: float = 0.25, enabled: Optional[bool] = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.label, self.unit = label, unit
        self.stream = stream if stream is not None else sys.stderr
        self.delay, self.interval = delay, interval
        self.enabled = is_terminal(self.stream) if enabled is None else enabled
        self._clock = clock
        self._lock = threading.Lock()     # owns the counts, _shown and the writes to the stream
        self._done: Optional[int] = None
        self._total: Optional[int] = None
        self._start = clock()
        self._shown = 0                   # length of the line on screen (0: nothing shown)
        self._text = ''                   # the line on screen
        self._stop = threading.Event()
        self._ticker: Optional[threading.Thread] = None

    def __call__(self, done: int, total: int) -> None:
        with self._lock:
            self._done, self._total = int(done), int(total)

    def line(self) -> str:
        """The text shown now."""
        with self._lock:
            done, total = self._done, self._total
        elapsed = self._clock() - self._start
        counts = f'{done}/{total} {self.unit}, ' if done is not None and total else ''
        return f'{self.label}: {counts}{elapsed:.0f} s'

    def redraw(self) -> None:
        """Write the line if the work has run `delay` seconds (the ticker calls this)."""
        if not self.enabled or self._clock() - self._start < self.delay:
            return
        text = self.line()
        with self._lock:
            if text == self._text:
                return
            self._text = text
            pad = max(self._shown - len(text), 0)
            self.stream.write('\r' + text + ' ' * pad)
            self.stream.flush()
            self._shown = len(text)

    def clear(self) -> None:
        """Erase the line, if one was shown."""
        with self._lock:
            if self._shown:
                self.stream.write('\r' + ' ' * self._shown + '\r')
                self.stream.flush()
                self._shown, self._text = 0, ''

    def _tick(self) -> None:
        while not self._stop.wait(self.interval):
            self.redraw()

    def __enter__(self) -> 'TerminalProgress':
        self._start = self._clock()
        if self.enabled:
            self._ticker = threading.Thread(target=self._tick, name='progress', daemon=True)
            self._ticker.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        self.clear()
