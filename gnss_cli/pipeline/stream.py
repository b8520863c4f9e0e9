"""The run of a long observation file in parts of at most N epochs, in bounded memory.

:class:`ChunkedRun` gives the rows of :func:`~gnss_cli.pipeline.processing.process` part by
part, equal to the whole file's run: every part is solved on the whole file's satellite axis
and clock columns (the numbers of a least-squares solve depend, at the last bit, on the size
of its arrays), and the behavioral smoothing (``--lag``) runs over the parts with the whole
file's schedule (:class:`~gnss_cli.pipeline.smoothing_stream.StreamSmoother`); the doppler model
(the default ``auto`` on a file with Doppler) runs in overlapping pieces whose middles equal
the whole segment's solution to well below a millimetre, not bit for bit
(:class:`~gnss_cli.pipeline.doppler_stream.DopplerStreamSmoother`).

The file is read twice: a first pass collects what the whole file decides (its satellites
with a pseudorange, its systems, its epoch times for the segments' nominal step), the second
reads, solves and hands out the parts. A file of one part is read once and run as a whole,
or, with snapshot methods only and epochs enough (a day at 30 s), cut in one part per core:
the parts are read (:func:`~gnss_cli.io.obs_chunks.split_obs`) and solved at once in processes
forked from this one (:class:`~gnss_cli.parallel.Forked`), which send back their survey,
receive the whole file's axes, and hand back their parts' finished tables; the rows are those
of one process, bit for bit, as every part's are.
The clock columns are the systems with a usable observation; a system that has pseudoranges
and broadcast records but turns out unusable all through the file (every satellite excluded,
masked or unhealthy) is only known at the end: the parts are then handed out again from the
start (:data:`RESTART`), without it.

Methods that need the whole file at once are run as a whole: ``kf`` (the RTS smoother runs
backwards over the file), ``--model kinematic`` smoothing, windows of a whole segment
(``window = 0``) and windows chosen from the data (``window = "auto"`` with ``--model static``:
the ladder starts with the whole segment): :func:`streamable`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from gnss_cli.config import ProcessingConfig
from gnss_cli.errors import NoSolutionError, RinexFormatError
from gnss_cli.gnss.observables import codes_for, select_pseudoranges
from gnss_cli.io.obs_chunks import ObsRuns, iter_obs_chunks, split_obs
from gnss_cli.pipeline.epochs import (
    Coverage, EpochSetup, _systems_with_data, file_warnings, signal_setup, used_systems,
)
from gnss_cli.pipeline.processing import process, with_velocity
from gnss_cli.pipeline.doppler_stream import DopplerStreamSmoother
from gnss_cli.pipeline.memory import map_large_blocks, release_memory
from gnss_cli.pipeline.results import EpochData, EpochStatus, Progress, RunResult
from gnss_cli.pipeline.smoothing_stream import StreamSmoother
from gnss_cli.pipeline.parts import part_epochs, solve_part, split_epochs
from gnss_cli.pipeline.snapshot import solve_methods, status_counts, status_summary

__all__ = ["ChunkedRun", "PART_MIN_EPOCHS", "RESTART", "streamable"]

PART_MIN_EPOCHS = 500
"""A file of one part is split into one part per process only where every part keeps at least
this many epochs (a day at 30 s: two parts on two cores; an hour at 30 s: one process)."""

class _Restart:
    def __repr__(self) -> str:
        return "RESTART"


RESTART = _Restart()
"""Yielded by :meth:`ChunkedRun.parts` when the parts handed out so far are void and follow again from the start."""


def streamable(config: ProcessingConfig) -> bool:
    """Whether :class:`ChunkedRun` can run ``config`` part by part (else the run needs the whole file)."""
    if "kf" in config.methods:
        return False
    lag = config.smoothing
    return lag.lag == 0 or (lag.model != "kinematic" and not lag.window_ladder and lag.window_epochs > 0)


def _smoother(config: ProcessingConfig, has_doppler: bool, nominal_step_s: float,
              factors: tuple[float, ...] | None) -> StreamSmoother | DopplerStreamSmoother:
    """The smoother of the parts: the doppler model in overlapping pieces with the whole file's
    variance ``factors``, the window models exactly."""
    config = replace(config, smoothing=config.smoothing.resolved(has_doppler and config.kalman.doppler))
    if config.smoothing.model == "doppler":
        return DopplerStreamSmoother(config, factors=factors)
    return StreamSmoother(config, nominal_step_s)


class _Survey:
    """What the whole observation file decides: satellites, systems, epoch times, parts."""

    def __init__(self) -> None:
        self.obs_sv: set[str] = set()
        self.pr_sv: set[str] = set()
        self.times: list[np.ndarray] = []
        self.span: tuple[np.datetime64, np.datetime64] | None = None  # first and last epoch of the last dataset added

    def add(self, obs: xr.Dataset, setup: EpochSetup) -> None:
        self.obs_sv.update(np.asarray(obs["sv"].values).astype(str).tolist())
        prs = select_pseudoranges(obs, setup.systems, setup.priority)
        self.pr_sv.update(prs.sv.tolist())
        self.times.append(prs.time_gps_s)
        t = obs["time"].values
        self.span = (t[0], t[-1]) if t.size else None

    @classmethod
    def of(cls, obs: xr.Dataset | None, setup: EpochSetup) -> "_Survey | None":
        """The survey of one dataset (None for none)."""
        if obs is None:
            return None
        survey = cls()
        survey.add(obs, setup)
        return survey

    def merge(self, other: "_Survey | None") -> None:
        """Add the survey of the next part (None: a part without records)."""
        if other is not None:
            self.obs_sv |= other.obs_sv
            self.pr_sv |= other.pr_sv
            self.times += other.times


class ChunkedRun:
    """``process(obs_path, nav_paths, config)`` in parts of at most ``chunk_epochs`` epochs;
    a file of at most ``whole_epochs`` epochs (default ``chunk_epochs``) is run whole.

    Iterate :meth:`parts`: each item is a :class:`RunResult` of consecutive epochs (the
    smoothing's window models finished with them in ``models``), or :data:`RESTART`. After
    the iteration :attr:`warnings` holds the run's warnings (the parts carry none).

    Raises (during the iteration) what :func:`~gnss_cli.pipeline.processing.process` raises.
    """

    def __init__(self, obs_path: str | Path, nav_paths: Sequence[str | Path], config: ProcessingConfig,
                 chunk_epochs: int, progress: Progress | None = None, whole_epochs: int | None = None,
                 processes: int = 1) -> None:
        if not streamable(config):
            raise ValueError("ChunkedRun: this configuration needs the whole file (see streamable)")
        self.obs_path, self.nav_paths, self.config = obs_path, list(nav_paths), config
        self.chunk_epochs = int(chunk_epochs)
        self.whole_epochs = max(int(whole_epochs if whole_epochs is not None else chunk_epochs), 1)
        self.progress = progress
        self.processes = int(processes)
        self.warnings: tuple[str, ...] = ()
        self._notes: list[str] = []  # warnings of the run itself (a process refused)

    def parts(self, finish: Callable[[RunResult], Any] | None = None) -> Iterator[Any]:
        """The parts in order (each ``finish(part)`` when ``finish`` is given), or :data:`RESTART`.

        A file of one part whose epochs make at least two parts of :data:`PART_MIN_EPOCHS` is
        cut in ``processes`` parts (``0``: one per core; ``1``: never) when only snapshot methods
        run: the parts are solved and ``finish``-ed at once in forked processes
        (:class:`~gnss_cli.parallel.Forked`), the first in this one, and handed out in order.
        Their rows are those of the whole file at once, bit for bit, as every part's are.
        ``finish`` runs where the part is solved (its value, not the part, comes back from a
        forked process, pickled): it must return something that pickles.
        """
        finish = finish if finish is not None else _same
        setup = signal_setup(self.obs_path, self.nav_paths, self.config)
        workers = self._workers(self.whole_epochs)
        split = split_obs(self.obs_path, setup.systems, setup.codes, workers, self.whole_epochs,
                          PART_MIN_EPOCHS) if workers > 1 else None
        if split is not None:  # a day file in memory: its parts read at once too
            if self.progress:
                self.progress(f"reading in {len(split)} processes", 0.0)
            yield from self._run_split(split, setup, finish)
            return
        chunks = iter_obs_chunks(self.obs_path, setup.systems, setup.codes, self.whole_epochs)
        if self.progress:
            self.progress("reading", 0.0)
        held = [next(chunks)]
        second = next(chunks, None)
        if second is None:  # one part: the whole file
            workers = self._workers(held[0].sizes["time"])
            if workers > 1:
                pieces = split_epochs(held.pop(), workers)
                survey = _Survey()
                for piece in pieces:
                    survey.add(piece, setup)
                yield from self._solve(setup, survey, finish, pieces)
                return
            result = process(self.obs_path, self.nav_paths, self.config, self.progress, obs=held)
            self.warnings = result.warnings
            yield finish(result)
            return
        map_large_blocks()
        survey = _Survey()
        for obs in (held.pop(), second):
            survey.add(obs, setup)
        del second, obs
        for obs in chunks:
            survey.add(obs, setup)
            del obs
        release_memory()
        yield from self._solve(setup, survey, finish)

    def _run_split(self, split: ObsRuns, setup: EpochSetup, finish: Callable[[RunResult], Any]) -> Iterator[Any]:
        """The parts of a file in memory, each read, solved and ``finish``-ed in its own process:
        the first here, the others in forked processes that send back their survey and receive
        the whole file's axes (systems, satellites, clock columns) before they solve."""
        from gnss_cli.parallel import fork_all

        children = fork_all([partial(self._part_worker, split, k, setup, finish) for k in range(1, len(split))], talk=True)
        if isinstance(children, OSError):  # no process to be had: the parts one after the other, here
            self._refused(children)
            pieces = [split.parse(k) for k in range(len(split))]
            survey = _whole_survey(split, [_Survey.of(ds, setup) for ds in pieces])
            yield from self._solve(setup, survey, finish, [ds for ds in pieces if ds is not None])
            return
        try:
            first = split.parse(0)
            setup.read_navigation()
            survey = _whole_survey(split, [_Survey.of(first, setup)] + [child.recv() for child in children])

            def first_pass(systems: list[str], sv: np.ndarray, used: tuple[str, ...]):  # type: ignore[no-untyped-def]
                for child in children:
                    child.send((systems, sv, used))
                return (yield from self._gather(
                    [None if first is None else solve_part(first, setup, systems, sv, used, self.config, finish)]
                    + children))

            def reparse() -> list[xr.Dataset]:  # a restart (rare): every part read again, here
                return [ds for ds in [first] + [split.parse(k) for k in range(1, len(split))] if ds is not None]

            yield from self._solve(setup, survey, finish, first_pass=first_pass, reparse=reparse)
        finally:
            for child in children:
                child.cancel()

    def _part_worker(self, split: ObsRuns, k: int, setup: EpochSetup, finish: Callable[[RunResult], Any],
                     channel: Any) -> Any:
        """Part ``k`` of ``split`` in a forked process: read it, send its survey, read the navigation
        files, receive the axes, solve and finish it (None for a part without records)."""
        piece = split.parse(k)
        channel.send(_Survey.of(piece, setup))
        setup.read_navigation()
        systems, sv, used = channel.recv()
        return None if piece is None else solve_part(piece, setup, systems, sv, used, self.config, finish)

    def _gather(self, outcomes: list[Any]) -> Iterator[Any]:
        """Hand out the parts' outputs in order (a :class:`~gnss_cli.parallel.Forked` waited for);
        returns the merged coverage and status counts."""
        cov: Coverage | None = None
        counts: dict[str, dict[str, int]] = {}
        for k, outcome in enumerate(outcomes):
            if hasattr(outcome, "result"):  # a forked process
                outcome = outcome.result()
            elif callable(outcome):  # work left to this process
                outcome = outcome()
            if outcome is None:
                continue
            out, part_cov, part_counts = outcome
            cov = part_cov if cov is None else cov.merge(part_cov)
            for m, c in part_counts.items():
                for w, n in c.items():
                    counts.setdefault(m, {})[w] = counts.get(m, {}).get(w, 0) + n
            if self.progress:
                self.progress(f"part {k + 1} of {len(outcomes)} solved", (k + 1) / len(outcomes))
            yield out
            del out, outcome
        assert cov is not None
        return cov, counts

    def _refused(self, error: OSError) -> None:
        """No more processes from now on; the run's warnings say why."""
        self.processes = 1
        self._notes.append(f"--processes: no process could be started ({error}); solved in one process")

    def _workers(self, n_epochs: int) -> int:
        """Processes for a file of one part of ``n_epochs`` epochs (1: this one alone)."""
        from gnss_cli.parallel import can_fork, cores

        if self.processes == 1 or self.config.smoothing.lag or not can_fork():
            return 1
        wanted = self.processes if self.processes > 0 else cores()
        return max(1, min(wanted, n_epochs // PART_MIN_EPOCHS))

    def _axes(self, setup: EpochSetup, survey: _Survey) -> tuple[list[str], np.ndarray]:
        """The systems and the satellite axis of the whole file."""
        if setup.nav is None:
            setup.read_navigation()
        assert setup.nav is not None
        if setup.explicit:
            systems = setup.systems
        else:
            fake = xr.Dataset(coords={"sv": np.array(sorted(survey.obs_sv))})
            systems = _systems_with_data(fake, setup.nav, self.obs_path, setup.nav_name)
        sv = np.array(sorted(s for s in survey.pr_sv if s[0] in systems))
        if sv.size == 0:
            raise RinexFormatError(f"{self.obs_path}: no pseudoranges of {','.join(systems)} "
                                   f"(codes {', '.join(codes_for(systems, setup.priority))})")
        return systems, sv

    def _solve(self, setup: EpochSetup, survey: _Survey, finish: Callable[[RunResult], Any],
               pieces: list[xr.Dataset] | None = None, first_pass: Callable[..., Any] | None = None,
               reparse: Callable[[], list[xr.Dataset]] | None = None) -> Iterator[Any]:
        """Solve and hand out the parts on the whole file's axes, again from the start (after
        :data:`RESTART`) while the systems in use change. ``first_pass(systems, sv, used)``: the
        first pass when the parts are already being read elsewhere (:meth:`_run_split`), and
        ``reparse()`` their datasets for a second pass."""
        systems, sv = self._axes(setup, survey)
        t = np.concatenate(survey.times)
        dt = np.diff(t)
        nominal = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
        sys_of = np.array([s[0] for s in sv])
        used = tuple(sy for sy in systems if (sys_of == sy).any() and setup.records(sy)[0] is not None)
        while True:
            factors = self._doppler_factors(setup, systems, sv, used, t.size, pieces)
            if first_pass is not None:
                cov, counts = yield from first_pass(systems, sv, used)
                first_pass = None
            elif pieces is not None and len(pieces) > 1 and self.processes != 1:
                cov, counts = yield from self._pass_forked(setup, systems, sv, used, finish, pieces)
            else:
                cov, counts = yield from self._pass(setup, systems, sv, used, nominal, t.size, finish, factors, pieces)
            warnings = file_warnings(setup, sv, systems, cov)
            actual = used_systems(sv, systems, cov)
            if actual == used:
                break
            used = actual
            if pieces is None and reparse is not None:
                pieces = reparse()
            yield RESTART
        if not any(c.get(EpochStatus.OK.value, 0) for c in counts.values()):
            raise NoSolutionError(f"{Path(self.obs_path).name}: no epoch could be solved ({status_summary(counts)})")
        self.warnings = tuple(warnings) + tuple(self._notes)

    def _epochs(self, setup: EpochSetup, systems: list[str], sv: np.ndarray, used: tuple[str, ...],
                pieces: list[xr.Dataset] | None = None) -> Iterator[tuple[EpochData, Coverage]]:
        """The parts' epochs on the whole file's satellite axis, and each part's coverage (the
        parts read from the file, or ``pieces`` of it already read)."""
        source = pieces if pieces is not None else iter_obs_chunks(self.obs_path, setup.systems, setup.codes,
                                                                   self.chunk_epochs)
        for obs in source:
            yield part_epochs(obs, setup, systems, sv, used)
            del obs

    def _pass_forked(self, setup: EpochSetup, systems: list[str], sv: np.ndarray, used: tuple[str, ...],
                     finish: Callable[[RunResult], Any], pieces: list[xr.Dataset]):  # type: ignore[no-untyped-def]
        """:meth:`_pass` of snapshot methods with the ``pieces`` solved at once: every piece but the
        first in a forked process, the first here; returns the coverage and the status counts."""
        from gnss_cli.parallel import fork_all

        if self.progress:
            self.progress(f"solving in {len(pieces)} processes", 0.0)
        work = [partial(solve_part, obs, setup, systems, sv, used, self.config, finish) for obs in pieces[1:]]
        children = fork_all(work)
        if isinstance(children, OSError):  # no process to be had: the parts one after the other, here
            self._refused(children)
            children = work
        try:
            return (yield from self._gather([solve_part(pieces[0], setup, systems, sv, used, self.config, finish)]
                                            + children))
        finally:
            for child in children:
                if hasattr(child, "cancel"):
                    child.cancel()

    def _doppler_factors(self, setup: EpochSetup, systems: list[str], sv: np.ndarray, used: tuple[str, ...],
                         n_epochs: int, pieces: list[xr.Dataset] | None = None) -> tuple[float, ...] | None:
        """The whole file's variance factors of the doppler smoothing model (a pass of WLS over the
        parts), so that every piece weighs as the whole file would; None for another model."""
        config = self.config
        if not config.smoothing.lag or config.smoothing.model not in ("auto", "doppler"):
            return None
        from gnss_cli.pipeline.doppler_smoothing import factors_from_totals, free_misfit_totals

        totals = np.zeros(6)  # misfit and degrees of freedom: pseudoranges, range rates, phase pairs
        done = 0
        wls_only = replace(config, methods=("wls",))
        for k, (data, _) in enumerate(self._epochs(setup, systems, sv, used, pieces)):
            if k == 0 and config.smoothing.resolved(data.range_rate_m_s is not None and config.kalman.doppler).model != "doppler":
                return None
            if self.progress:
                self.progress(f"part {k + 1}: weighing pseudoranges and range rates", done / max(n_epochs, 1))
            totals += free_misfit_totals(data, solve_methods(data, wls_only)["wls"], config)
            done += data.time_gps_s.size
            del data
            release_memory()
        return factors_from_totals(tuple(float(v) for v in totals))  # type: ignore[arg-type]

    def _pass(self, setup: EpochSetup, systems: list[str], sv: np.ndarray, used: tuple[str, ...], nominal: float,
              n_epochs: int, finish: Callable[[RunResult], Any], factors: tuple[float, ...] | None = None,
              pieces: list[xr.Dataset] | None = None):  # type: ignore[no-untyped-def]
        """One pass of reading, solving and handing out; returns the coverage and the status counts."""
        config = self.config
        lag = config.smoothing.lag
        others = tuple(m for m in config.methods if m != "stls") if lag else config.methods
        snapshot = replace(config, methods=others + (() if "wls" in others or not lag else ("wls",)))
        smoother: StreamSmoother | DopplerStreamSmoother | None = None
        cov: Coverage | None = None
        counts: dict[str, dict[str, int]] = {}
        done = 0
        for k, (data, part_cov) in enumerate(self._epochs(setup, systems, sv, used, pieces)):
            cov = part_cov if cov is None else cov.merge(part_cov)
            if self.progress:
                self.progress(f"part {k + 1}: solving", done / max(n_epochs, 1))
            solutions = solve_methods(data, snapshot)
            for m, c in status_counts(solutions).items():
                for w, n in c.items():
                    counts.setdefault(m, {})[w] = counts.get(m, {}).get(w, 0) + n
            done += data.time_gps_s.size
            if lag and smoother is None:  # the model "auto" resolves on the file's Doppler
                smoother = _smoother(config, data.range_rate_m_s is not None, nominal, factors)
            parts = [RunResult(data, solutions)]
            del data, solutions
            out = smoother.push(parts) if smoother is not None else parts.pop()
            if out is not None:
                yield finish(with_velocity(out, config))
            del out  # before the next part is read: one part in memory at a time
            release_memory()
        out = smoother.push([], last=True) if smoother is not None else None  # the last segment ends
        if out is not None:
            yield finish(with_velocity(out, config))
        assert cov is not None
        return cov, counts


def _whole_survey(split: ObsRuns, surveys: list[_Survey | None]) -> _Survey:
    """The survey of the whole file from its runs' (None: a run without records), after the
    checks of their order."""
    split.check_order([None if sv is None else sv.span for sv in surveys])
    survey = _Survey()
    for part_survey in surveys:
        survey.merge(part_survey)
    return survey


def _same(part: RunResult) -> RunResult:
    return part
