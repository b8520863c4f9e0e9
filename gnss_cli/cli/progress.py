"""Progress on stderr, for a terminal and for a log file alike.

On a terminal one status line is redrawn in place. When stderr is not a terminal (a log
file, CI, ``2> run.log``) one line is written per stage once the run has lasted a second,
and a heartbeat line every ``interval_s`` seconds while a stage runs (a background thread, so long numerical stages
such as the smoothing report too without calling back). ``--quiet`` turns it all off.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import TextIO


class Progress:
    """Callable ``progress(stage, fraction)`` used by the library's long-running functions.

    Parameters
    ----------
    prog
        Program name at the start of each line.
    enabled
        False for ``--quiet``.
    interval_s
        Seconds between heartbeat lines when stderr is not a terminal.
    min_gap_s
        Stages that follow each other faster than this share one line (not on a terminal).
    start_delay_s
        Nothing is written before the run has lasted this long (not on a terminal), so a
        quick run or an early error prints no progress at all.
    stream
        Where to write (default ``sys.stderr``).
    """

    def __init__(self, prog: str, enabled: bool = True, interval_s: float = 5.0, min_gap_s: float = 1.0, start_delay_s: float = 1.0,
                 stream: TextIO | None = None) -> None:
        self.prog = prog
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval_s = interval_s
        self.min_gap_s = min_gap_s
        self.start_delay_s = start_delay_s
        self.t0 = time.perf_counter()
        self.stage = ""
        self.fraction = 0.0
        self._last_line_s = -1.0
        self._shown: tuple[str, bool] = ("", False)
        """The stage of the last line written, and whether it was unfinished (below 100 %)."""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if enabled and not self.tty:
            self._thread = threading.Thread(target=self._heartbeat, name="progress", daemon=True)
            self._thread.start()

    def _elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def _line(self) -> str:
        return f"{self.prog}: [{self._elapsed():6.1f} s] {self.stage} {100 * self.fraction:5.1f} %"

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        with self._lock:
            new_stage = stage != self.stage
            self.stage, self.fraction = stage, float(fraction)
            if self.tty:
                self.stream.write(f"\r{self._line():<78}")
                self.stream.flush()
            elif new_stage and self._elapsed() >= self.start_delay_s and self._elapsed() - self._last_line_s >= self.min_gap_s:
                self._write_line()
            elif not new_stage and self.fraction >= 1.0 and self._shown == (stage, True):
                self._write_line()  # a stage shown unfinished gets its closing line (no "figures 0.0 %" left last)

    def _heartbeat(self) -> None:
        while not self._stop.wait(0.25):
            with self._lock:
                now = self._elapsed()
                first = self._last_line_s < 0 and now >= self.start_delay_s
                if self.stage and (first or now - max(self._last_line_s, 0.0) >= self.interval_s):
                    self._write_line()

    def _write_line(self) -> None:
        self._last_line_s = self._elapsed()
        self._shown = (self.stage, self.fraction < 1.0)
        self.stream.write(self._line() + "\n")
        self.stream.flush()

    def done(self) -> None:
        """Stop the heartbeat and end the terminal status line."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        if self.enabled and self.tty and self.stage:
            self.stream.write("\n")
            self.stream.flush()
        self.enabled = False  # done once: later calls (a second done, a late stage) write nothing
