"""The run of ``gnss-solve``: one path for every observation file and every method.

:class:`Run` hands out the rows of a run part by part; :func:`process` joins them into one
:class:`~gnss_cli.pipeline.results.RunResult` (the Python API). A file of at most
``stream_above_epochs`` epochs is one part; a longer one is read and solved in parts of
``chunk_epochs`` epochs, so that memory stays that of a part whatever the file's length.

Every part is solved on the whole file's satellite axis and clock columns (the numbers of a
least-squares solve depend, at the last bit, on the size of its arrays), so the single-epoch
rows of a part are those of the whole file at once, bit for bit. The file is then read twice:
a first pass collects what the whole file decides (its satellites with a pseudorange, its
systems, its epoch times), the second reads, solves and hands out the parts. The clock columns
are the systems with a usable observation; a system that has pseudoranges and broadcast
records but turns out unusable all through the file (every satellite excluded, masked or
unhealthy) is only known at the end: the parts are then handed out again from the start
(:data:`RESTART`), without it.

Before anything is solved the run's environment is resolved
(:func:`~gnss_cli.pipeline.environment.judged`): with ``environment = "auto"`` from the file's
first :data:`~gnss_cli.pipeline.environment.HEAD_EPOCHS` epochs, whatever its parts, so that a file
in parts or in several processes takes the settings of the whole file. A file cut over processes
before it was judged a street canyon is joined again and solved in this one (the NLOS detector
estimates its C/N0 template from the whole file).

The multi-epoch methods (``stls`` with ``lag >= 1``, ``smoother``, ``kf``) run on the parts'
WLS solutions in overlapping pieces (:class:`MultiEpoch`): each piece is the epochs not yet
handed out plus :data:`MARGIN_EPOCHS` epochs on either side, and only its middle is handed out.
A file of one part is one piece: the whole file at once. In a longer file an epoch's estimate
differs from the whole file's only through observations more than a margin away, whose pull
fades with the distance (carrier-phase differences tie a piece rigidly: there the pseudoranges
of a piece are averaged over the piece instead of the whole segment; tst2 in parts of 300
epochs: up to 0.56 m from the whole run); the variance factors of the measurement kinds are the
whole file's, from a pass of WLS through the parts before the first piece.

A file of one part with single-epoch methods only and epochs enough (a day at 30 s) is cut in
one part per core: the parts are read (:func:`~gnss_cli.io.obs_chunks.split_obs`) and solved
at once in processes forked from this one (:class:`~gnss_cli.parallel.Forked`), which send
back their survey, receive the whole file's axes and hand back their parts' finished tables;
the rows are those of one process, bit for bit.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Iterator, Sequence
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
    Coverage, EpochSetup, _systems_with_data, file_warnings, signal_setup, system_warnings, used_systems,
)
from gnss_cli.pipeline.environment import HEAD_EPOCHS, describe, judged
from gnss_cli.pipeline.memory import map_large_blocks
from gnss_cli.pipeline.methods import (
    measurement_warnings, settings_warnings, snapshot_config, solve_multi_epoch, with_settings,
)
from gnss_cli.pipeline.parts import part_epochs, solve_part, split_epochs
from gnss_cli.pipeline.results import (
    PASSED_FIX, EpochData, EpochStatus, Progress, RunResult, concat_results, take_result, take_solution,
)
from gnss_cli.pipeline.snapshot import solve_methods, status_counts, status_summary
from gnss_cli.pipeline.velocity import with_velocity

__all__ = ["Run", "MultiEpoch", "process", "PART_MIN_EPOCHS", "MARGIN_EPOCHS", "RESTART"]

PART_MIN_EPOCHS = 500
"""A file of one part is split into one part per process only where every part keeps at least
this many epochs (a day at 30 s: two parts on two cores; an hour at 30 s: one process)."""
MARGIN_EPOCHS = 300
"""Epochs a piece of the multi-epoch methods solves on either side of those it hands out (5 min at 1 Hz)."""


class _Restart:
    def __repr__(self) -> str:
        return "RESTART"


RESTART = _Restart()
"""Yielded by :meth:`Run.parts` when the parts handed out so far are void and follow again from the start."""
_FIXED = PASSED_FIX + (EpochStatus.UNTESTED.value,)
"""Statuses of a fix that did not fail: a run without any epoch of these is an error (no epoch solved)."""


def process(obs_path: str | Path, nav_paths: Sequence[str | Path], config: ProcessingConfig,
            progress: Progress | None = None) -> RunResult:
    """Read, validate and solve every epoch with every configured method: :class:`Run`'s parts joined.

    Returns
    -------
    RunResult
        Every epoch of the file, one solution per method of ``config.methods`` (in that order),
        the window models of the multi-epoch methods, each method's resolved settings, the
        environment it took (``RunResult.environment``) and the run's warnings (``RunResult.warnings``).

    Raises
    ------
    InputError
        Bad input files.
    NoSolutionError
        No epoch could be solved by any method.
    """
    run = Run(obs_path, nav_paths, config, progress)
    parts: list[RunResult] = []
    for part in run.parts():
        if part is RESTART:
            parts.clear()
        else:
            parts.append(part)
    result = concat_results(parts)
    return replace(result, epochs=replace(result.epochs, warnings=run.warnings), environment=describe(run.config))


class MultiEpoch:
    """The multi-epoch methods of ``config`` over the parts of a file, in overlapping pieces.

    :meth:`push` takes the next part (its single-epoch solutions, WLS among them) and returns
    the epochs now final with every method of ``config.methods``, or None while a piece is
    still incomplete. ``factors``: the whole file's variance factors of the measurement kinds
    (None: each piece estimates its own, which for a file of one piece is the whole file's).
    """

    def __init__(self, config: ProcessingConfig, factors: tuple[float, ...] | None = None,
                 margin_epochs: int = MARGIN_EPOCHS) -> None:
        self.config = config
        self.factors = factors
        self.margin = int(margin_epochs)
        self.kept: RunResult | None = None
        self.pending = 0  # index in ``kept`` of the first epoch not yet handed out

    def push(self, part: RunResult | None, last: bool = False,
             report: Callable[[str, float], None] | None = None) -> RunResult | None:
        """Add ``part`` (None: nothing more) and return the epochs now final, or None.
        ``last``: the file ends with this part. ``report(method, epochs)`` is called as each
        method starts and once after the last one, with the epochs of this call's output done
        so far (each method counts for an equal share of them: ``0`` at the first method, all
        of them at the end)."""
        if part is None and self.kept is None:
            return None
        buf = self.kept if part is None else part if self.kept is None else concat_results([self.kept, part])
        del part
        T = buf.epochs.time_gps_s.size
        end = T if last else T - self.margin  # epochs [pending, end) are handed out now
        if end <= self.pending:
            self.kept = buf
            return None
        start = self.pending
        out = take_result(buf, slice(start, end))
        solutions = dict(out.solutions)
        models = []
        t = buf.epochs.time_gps_s
        first, final = (t[start], t[end - 1]) if end > start else (np.inf, -np.inf)
        methods = self.config.multi_epoch_methods
        for i, m in enumerate(methods):
            if report is not None:
                report(m, (end - start) * i / len(methods))
            sol, found = solve_multi_epoch(m, buf.epochs, buf.solutions["wls"], self.config, self.factors)
            solutions[m] = take_solution(sol, slice(start, end))
            models += [w for w in found if first <= w.start_time_gps_s <= final]  # each window once
        if report is not None:
            report(methods[-1], float(end - start))
        keep_from = max(0, end - self.margin)
        self.kept = None if last else take_result(buf, slice(keep_from, None), copy=True)
        self.pending = end - keep_from
        return replace(out, solutions={m: solutions[m] for m in self.config.methods}, models=tuple(models))


class _Survey:
    """What the whole observation file decides: satellites, systems, epoch times."""

    def __init__(self) -> None:
        self.obs_sv: set[str] = set()
        self.pr_sv: set[str] = set()
        self.obs_types: dict[str, list[str]] | None = None  # the header's, per system (RINEX 3/4)
        self.unlisted = ""  # systems with records but no observation types in the header
        self.times: list[np.ndarray] = []
        self.span: tuple[np.datetime64, np.datetime64] | None = None  # first and last epoch of the last dataset added

    def add(self, obs: xr.Dataset, setup: EpochSetup) -> None:
        self.obs_sv.update(np.asarray(obs["sv"].values).astype(str).tolist())
        prs = select_pseudoranges(obs, setup.systems, setup.priority)
        self.pr_sv.update(prs.sv.tolist())
        self.obs_types = obs.attrs.get("obs_types", self.obs_types)
        self.unlisted = "".join(sorted(set(self.unlisted) | set(obs.attrs.get("unlisted_systems", ""))))
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
            self.obs_types = self.obs_types if self.obs_types is not None else other.obs_types
            self.unlisted = "".join(sorted(set(self.unlisted) | set(other.unlisted)))
            self.times += other.times


class Run:
    """The run of one observation file with ``config``, handed out part by part (module docstring).

    Iterate :meth:`parts`: each item is a :class:`~gnss_cli.pipeline.results.RunResult` of
    consecutive epochs with every method of ``config.methods`` (the window models finished
    with them in ``models``, each method's settings in ``settings``), or :data:`RESTART`.
    After the iteration :attr:`warnings` holds the run's warnings (the parts carry none).

    ``config.chunk_epochs`` (0: the whole file at once) and ``config.stream_above_epochs`` set the
    parts; ``config.processes`` the processes of a file of one part (single-epoch methods).

    Raises (during the iteration) :class:`~gnss_cli.errors.InputError` for bad input files and
    :class:`~gnss_cli.errors.NoSolutionError` when no epoch could be solved by any method.
    """

    def __init__(self, obs_path: str | Path, nav_paths: Sequence[str | Path], config: ProcessingConfig,
                 progress: Progress | None = None) -> None:
        # an environment given (open, urban) is set now: a judged one (auto) once the file is read
        self.obs_path, self.nav_paths = obs_path, list(nav_paths)
        self.config = config if config.environment == "auto" else judged(config, None)
        whole = 1 << 62 if config.chunk_epochs == 0 else max(config.stream_above_epochs, config.chunk_epochs)
        self.chunk_epochs = config.chunk_epochs or whole
        self.whole_epochs = max(whole, 1)
        self.progress = progress
        self.processes = int(config.processes)
        self.warnings: tuple[str, ...] = ()
        self._notes: list[str] = settings_warnings(config)  # warnings of the run itself (settings, a process refused)

    def parts(self, finish: Callable[[RunResult], Any] | None = None) -> Iterator[Any]:
        """The parts in order (each ``finish(part)`` when ``finish`` is given), or :data:`RESTART`.

        ``finish`` runs where the part is solved (in a forked process its value, not the part,
        comes back, pickled): it must return something that pickles.
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
            survey = _Survey()
            survey.add(held[0], setup)
            self._judge(_head(held), setup, survey)
            workers = self._workers(held[0].sizes["time"])
            pieces = split_epochs(held.pop(), workers) if workers > 1 else held
            if workers > 1:  # the survey of the pieces, as each process makes its own
                survey = _Survey()
                for piece in pieces:
                    survey.add(piece, setup)

            def reread() -> list[xr.Dataset]:  # a restart (rare): the file read again
                whole = next(iter_obs_chunks(self.obs_path, setup.systems, setup.codes, self.whole_epochs))
                return split_epochs(whole, workers) if workers > 1 else [whole]

            yield from self._solve(setup, survey, finish, pieces, reparse=reread)
            return
        map_large_blocks()
        survey = _Survey()
        head: list[xr.Dataset] = []  # the first HEAD_EPOCHS epochs, whatever the parts: what judges the environment
        for obs in itertools.chain((held.pop(), second), chunks):
            survey.add(obs, setup)
            if sum(h.sizes["time"] for h in head) < HEAD_EPOCHS:
                head.append(obs.isel(time=slice(0, HEAD_EPOCHS)))
            del obs
        del second
        self._judge(_head(head), setup, survey)
        del head
        yield from self._solve(setup, survey, finish)

    def _run_split(self, split: ObsRuns, setup: EpochSetup, finish: Callable[[RunResult], Any]) -> Iterator[Any]:
        """The parts of a file in memory, each read, solved and ``finish``-ed in its own process:
        the first here, the others in forked processes that send back their survey and receive
        the whole file's axes (systems, satellites, clock columns) before they solve."""
        from gnss_cli.parallel import fork_all

        children = fork_all([partial(self._part_worker, split, k, setup, finish) for k in range(1, len(split))], talk=True)
        if isinstance(children, OSError):  # no process to be had: the parts one after the other, here
            self._refused(children)
            parsed = [split.parse(k) for k in range(len(split))]
            survey = _whole_survey(split, [_Survey.of(ds, setup) for ds in parsed])
            self._judge(_head(parsed), setup, survey)
            yield from self._solve(setup, survey, finish, [ds for ds in parsed if ds is not None],
                                   reparse=lambda: [ds for ds in map(split.parse, range(len(split))) if ds is not None])
            return
        try:
            first = split.parse(0)
            setup.read_navigation()
            survey = _whole_survey(split, [_Survey.of(first, setup)] + [child.recv() for child in children])
            # a part holds HEAD_EPOCHS epochs (PART_MIN_EPOCHS) unless set shorter: then the next are parsed here too
            self._judge(_head(itertools.chain([first], (split.parse(k) for k in range(1, len(split))))), setup, survey)
            if self._workers(self.whole_epochs) == 1:  # judged a canyon: the NLOS detector wants the whole file
                for child in children:
                    child.cancel()
                whole = xr.concat([ds for ds in [first] + [split.parse(k) for k in range(1, len(split))]
                                   if ds is not None], dim="time", join="outer")
                yield from self._solve(setup, survey, finish, [whole], reparse=lambda: [whole])
                return

            def first_pass(systems: list[str], sv: np.ndarray, used: tuple[str, ...]):  # type: ignore[no-untyped-def]
                for child in children:
                    child.send((systems, sv, used, self.config))
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
        systems, sv, used, config = channel.recv()  # the config with its environment judged
        return None if piece is None else solve_part(piece, setup, systems, sv, used, config, finish)

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
            _add_counts(counts, part_counts)
            if self.progress:
                self.progress(f"part {k + 1} of {len(outcomes)} solved", (k + 1) / len(outcomes))
            yield out
            del out, outcome
        assert cov is not None
        return cov, counts

    def _judge(self, head: xr.Dataset | None, setup: EpochSetup, survey: _Survey) -> None:
        """Resolve the run's environment (:func:`~gnss_cli.pipeline.environment.judged`) from the
        file's first :data:`~gnss_cli.pipeline.environment.HEAD_EPOCHS` epochs, ``head``
        (:func:`_head`; None: no records, judged open), on the axes of ``survey``."""
        if self.config.environment != "auto":  # given: set when the run was made
            return
        data = None
        if head is not None and self.config.integrity != "off":
            systems, sv = self._axes(setup, survey)
            used = _clock_systems(setup, systems, sv)
            if self.progress:
                self.progress("judging the environment", 0.0)
            data, _ = part_epochs(head, setup, systems, sv, used)
        self.config = judged(self.config, data)

    def _refused(self, error: OSError) -> None:
        """No more processes from now on; the run's warnings say why."""
        self.processes = 1
        self._notes.append(f"--processes: no process could be started ({error}); solved in one process")

    def _workers(self, n_epochs: int) -> int:
        """Processes for a file of one part of ``n_epochs`` epochs (1: this one alone)."""
        from gnss_cli.parallel import can_fork, cores

        if self.processes == 1 or self.config.multi_epoch_methods or not can_fork():
            return 1
        wanted = self.processes if self.processes > 0 else cores()
        workers = max(1, min(wanted, n_epochs // PART_MIN_EPOCHS))
        if workers > 1 and self.config.integrity != "off" and self.config.nlos.detector != "off":
            # the detector's line-of-sight C/N0 template is estimated from the epochs it is given: cut
            # in parts, each would have its own and flag other spans than the whole file's
            if self.processes > 1 and not any("NLOS detector" in n for n in self._notes):
                self._notes.append("--processes: solved in one process: the NLOS detector estimates its "
                                   "C/N0 template from the whole file")
            return 1
        return workers

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
        :data:`RESTART`) while the systems in use change. ``pieces``: the file's datasets already
        read (else the parts are read from the file), taken out of the list as they are solved
        in this process; ``first_pass(systems, sv, used)``: the first pass when the parts are
        already being read elsewhere (:meth:`_run_split`); ``reparse()``: the datasets again for
        another pass."""
        systems, sv = self._axes(setup, survey)
        used = _clock_systems(setup, systems, sv)
        n_epochs = int(sum(t.size for t in survey.times))
        while True:
            if first_pass is not None:
                cov, counts = yield from first_pass(systems, sv, used)
                first_pass = None
            elif pieces is not None and len(pieces) > 1 and self.processes != 1:
                cov, counts = yield from self._pass_forked(setup, systems, sv, used, finish, pieces)
            else:
                factors = self._variance_factors(setup, systems, sv, used, n_epochs) if pieces is None else None
                cov, counts = yield from self._pass(setup, systems, sv, used, n_epochs, finish, factors, pieces)
            warnings = system_warnings(setup, survey.obs_types, survey.unlisted, survey.obs_sv, survey.pr_sv)
            warnings += file_warnings(setup, sv, systems, cov)
            warnings += measurement_warnings(self.config, cov.has_doppler, cov.has_phase)
            actual = used_systems(sv, systems, cov)
            if actual == used:
                break
            used = actual
            if reparse is not None:
                pieces = reparse()
            yield RESTART
        if not any(sum(c.get(w, 0) for w in _FIXED) for c in counts.values()):
            raise NoSolutionError(f"{Path(self.obs_path).name}: no epoch could be solved ({status_summary(counts)})")
        self.warnings = tuple(warnings) + tuple(self._notes)

    def _epochs(self, setup: EpochSetup, systems: list[str], sv: np.ndarray, used: tuple[str, ...],
                pieces: list[xr.Dataset] | None = None) -> Iterator[tuple[EpochData, Coverage, bool]]:
        """The parts' epochs on the whole file's satellite axis, each part's coverage, and whether
        it is the last part (the parts read from the file, or ``pieces`` of it already read, taken
        out of that list so that each dataset is freed once its epochs are built)."""
        source = _taken(pieces) if pieces is not None else \
            iter_obs_chunks(self.obs_path, setup.systems, setup.codes, self.chunk_epochs)
        obs = next(source, None)
        while obs is not None:
            after = next(source, None)  # a dataset ahead (not yet its epochs): is this part the last?
            data, part_cov = part_epochs(obs, setup, systems, sv, used)
            del obs
            yield data, part_cov, after is None
            obs = after

    def _pass_forked(self, setup: EpochSetup, systems: list[str], sv: np.ndarray, used: tuple[str, ...],
                     finish: Callable[[RunResult], Any], pieces: list[xr.Dataset]):  # type: ignore[no-untyped-def]
        """:meth:`_pass` of single-epoch methods with the ``pieces`` solved at once: every piece but
        the first in a forked process, the first here; returns the coverage and the status counts."""
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

    def _variance_factors(self, setup: EpochSetup, systems: list[str], sv: np.ndarray, used: tuple[str, ...],
                          n_epochs: int) -> tuple[float, ...] | None:
        """The whole file's variance factors of the measurement kinds (a pass of WLS over the
        parts), so that every piece of ``smoother``, ``kf`` and ``stls --lag L`` weighs as the whole file would; None
        when no method needs them."""
        config = self.config
        stls_measurements = "stls" in config.multi_epoch_methods and config.stls.kernel == "shared"
        if not ({"smoother", "kf"} & set(config.multi_epoch_methods) or stls_measurements):
            return None
        from gnss_cli.pipeline.measurements import factors_from_totals, free_misfit_totals

        totals = np.zeros(6)  # misfit and degrees of freedom: pseudoranges, range rates, phase pairs
        done = 0
        wls_only = replace(config, methods=("wls",))
        for k, (data, _, _) in enumerate(self._epochs(setup, systems, sv, used)):
            if self.progress:
                self.progress(f"part {k + 1}: weighing the measurements", done / max(n_epochs, 1))
            wls = solve_methods(data, wls_only)["wls"]
            totals += free_misfit_totals(data, wls, config)  # as WLS used them (its exclusions and weights)
            done += data.time_gps_s.size
            del data
        return factors_from_totals(tuple(float(v) for v in totals))  # type: ignore[arg-type]

    def _pass(self, setup: EpochSetup, systems: list[str], sv: np.ndarray, used: tuple[str, ...], n_epochs: int,
              finish: Callable[[RunResult], Any], factors: tuple[float, ...] | None = None,
              pieces: list[xr.Dataset] | None = None):  # type: ignore[no-untyped-def]
        """One pass of reading, solving and handing out; returns the coverage and the status counts."""
        config = self.config
        snapshot = snapshot_config(config)
        multi = MultiEpoch(config, factors) if config.multi_epoch_methods else None
        cov: Coverage | None = None
        counts: dict[str, dict[str, int]] = {}
        done = 0
        handed = 0  # epochs the multi-epoch methods have finished
        total = max(n_epochs, 1)

        def report(method: str, epochs: float) -> None:
            """A multi-epoch method's progress: the epochs it and those before it have finished."""
            if self.progress:
                self.progress(f"{method}: solving", (handed + epochs) / total)
        for k, (data, part_cov, last) in enumerate(self._epochs(setup, systems, sv, used, pieces)):
            cov = part_cov if cov is None else cov.merge(part_cov)
            if self.progress:
                self.progress(f"part {k + 1}: solving" if pieces is None else "solving", done / total)
            solutions = solve_methods(data, snapshot)
            _add_counts(counts, status_counts(solutions))
            done += data.time_gps_s.size
            part = RunResult(data, solutions)
            del data, solutions
            out = multi.push(part, last, report) if multi is not None else part
            del part
            if out is not None:
                handed += out.epochs.time_gps_s.size
                yield finish(with_velocity(with_settings(out, config), config))
            del out  # before the next part is read: one part in memory at a time
        assert cov is not None
        return cov, counts


def _head(datasets: Iterable[xr.Dataset | None]) -> xr.Dataset | None:
    """The first :data:`~gnss_cli.pipeline.environment.HEAD_EPOCHS` epochs of consecutive
    ``datasets`` (None: a part without records), taking no more of them than it needs; None
    when none has records."""
    head: list[xr.Dataset] = []
    for ds in datasets:
        if sum(h.sizes["time"] for h in head) >= HEAD_EPOCHS:
            break
        if ds is not None:
            head.append(ds)
    if not head:
        return None
    return (xr.concat(head, dim="time", join="outer") if len(head) > 1 else head[0]).isel(time=slice(0, HEAD_EPOCHS))


def _clock_systems(setup: EpochSetup, systems: list[str], sv: np.ndarray) -> tuple[str, ...]:
    """The systems of ``systems`` with a satellite on the axis ``sv`` and broadcast records: the
    clock columns, until a pass finds one unusable all through the file."""
    sys_of = np.array([s[0] for s in sv])
    return tuple(sy for sy in systems if (sys_of == sy).any() and setup.records(sy)[0] is not None)


def _add_counts(counts: dict[str, dict[str, int]], more: dict[str, dict[str, int]]) -> None:
    for m, c in more.items():
        for w, n in c.items():
            counts.setdefault(m, {})[w] = counts.get(m, {}).get(w, 0) + n


def _whole_survey(split: ObsRuns, surveys: list[_Survey | None]) -> _Survey:
    """The survey of the whole file from its runs' (None: a run without records), after the
    checks of their order."""
    split.check_order([None if sv is None else sv.span for sv in surveys])
    survey = _Survey()
    for part_survey in surveys:
        survey.merge(part_survey)
    return survey


def _taken(items: list[Any]) -> Iterator[Any]:
    """The items of ``items``, each taken out of the list as it is handed out."""
    while items:
        yield items.pop(0)


def _same(part: RunResult) -> RunResult:
    return part
