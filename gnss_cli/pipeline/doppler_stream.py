"""The ``smoother`` (:func:`~gnss_cli.pipeline.smoother.smooth_segments`) of a file that arrives in
parts, in overlapping pieces.

The smoother solves whole segments; a long file is instead solved piece by piece: each
piece is the epochs not yet handed out plus :data:`MARGIN_EPOCHS` epochs on either side (those
before it already handed out, those after it still to come), and only its middle is handed
out. The motion model ties an epoch to its neighbours, and the pull of an observation
fades with its distance in epochs; carrier-phase differences (when the file has phase) tie
the epochs of a piece rigidly, so there a piece's pseudoranges are averaged over the piece
instead of the whole segment (tst2 in parts of 300 epochs: up to 0.56 m from the whole run). The variance factors are the whole file's, summed over a
pass of WLS through the parts before the first piece is smoothed
(:meth:`~gnss_cli.pipeline.stream.ChunkedRun`); each piece applies its own residual gate. The
result is therefore close to, not bit for bit, the whole file's (measured in
``tests/cli/test_solve_stream.py``), and ``--model-out`` holds one record per segment of each piece. Memory is one piece: a
part plus two margins.
"""

from __future__ import annotations

from dataclasses import replace

from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.results import RunResult
from gnss_cli.pipeline.smoothing_stream import concat_results, take_result, take_solution

__all__ = ["DopplerStreamSmoother", "MARGIN_EPOCHS"]

MARGIN_EPOCHS = 300
"""Epochs solved on either side of the epochs a piece hands out (5 min at 1 Hz)."""


class DopplerStreamSmoother:
    """The smoother over parts: :meth:`push` as :class:`~gnss_cli.pipeline.smoothing_stream.StreamSmoother`.

    ``motion``, ``measurements``: as :func:`~gnss_cli.pipeline.smoother.smooth_segments` (default: the
    quadrature rule of ``config.smoothing.lag`` and every kind of measurement the file has)."""

    def __init__(self, config: ProcessingConfig, margin_epochs: int = MARGIN_EPOCHS,
                 factors: tuple[float, ...] | None = None, motion: str = "quadrature",
                 measurements: frozenset[str] | None = None) -> None:
        self.config = config
        self.factors = factors
        self.motion = motion
        self.measurements = measurements
        self.margin = int(margin_epochs)
        self.kept: RunResult | None = None
        self.pending = 0  # index in ``kept`` of the first epoch not yet handed out

    def push(self, parts: list[RunResult], last: bool = False) -> RunResult | None:
        """Add the next part (snapshot solutions with ``wls``), taken out of the one-element list
        ``parts``; returns the epochs now final, with the smoothed ``stls`` solution, or None.
        ``last``: the file ends here (``parts`` may then be empty)."""
        from gnss_cli.pipeline.smoother import default_measurements, smooth_segments  # scipy: imported when it runs

        part = parts.pop() if parts else None
        if part is None and self.kept is None:
            return None
        buf = self.kept if part is None else part if self.kept is None else concat_results(self.kept, part)
        del part
        T = buf.epochs.time_gps_s.size
        end = T if last else T - self.margin  # epochs [pending, end) are handed out now
        if end <= self.pending:
            self.kept = buf
            return None
        kinds = default_measurements(buf.epochs, self.config) if self.measurements is None else self.measurements
        sol, models = smooth_segments(buf.epochs, buf.solutions["wls"], self.config, motion=self.motion,
                                      lag=self.config.smoothing.lag, measurements=kinds, factors=self.factors)
        start = self.pending
        out = take_result(buf, slice(start, end))
        out = replace(out, solutions={m: (take_solution(sol, slice(start, end)) if m == "stls" else out.solutions[m])
                                      for m in self.config.methods}, models=models)
        keep_from = max(0, end - self.margin)
        self.kept = None if last else take_result(buf, slice(keep_from, None), copy=True)
        self.pending = end - keep_from
        return out
