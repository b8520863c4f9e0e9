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
reads, solves and hands out the parts. A file of one part is read once and run as a whole.
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

from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import xarray as xr

from gnss_cli.config import ProcessingConfig
from gnss_cli.errors import NoSolutionError, RinexFormatError
from gnss_cli.gnss.observables import align_pseudoranges, codes_for, select_pseudoranges
from gnss_cli.io.obs_chunks import iter_obs_chunks
from gnss_cli.pipeline.epochs import (
    Coverage, EpochSetup, _systems_with_data, build_epochs, file_warnings, finish_epochs, signal_setup, used_systems,
)
from gnss_cli.pipeline.processing import process, with_velocity
from gnss_cli.pipeline.doppler_stream import DopplerStreamSmoother
from gnss_cli.pipeline.results import EpochData, EpochStatus, Progress, RunResult
from gnss_cli.pipeline.smoothing_stream import StreamSmoother
from gnss_cli.pipeline.snapshot import solve_methods, status_counts, status_summary

__all__ = ["ChunkedRun", "RESTART", "streamable"]

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


def release_memory() -> None:
    """Hand the heap's free pages back to the system (glibc ``malloc_trim``; elsewhere nothing).

    The parts' arrays are freed when a part is done, but the C heap keeps the pages of freed
    blocks below its top, so the resident size would creep up part after part."""
    global _TRIM
    if _TRIM is None:
        try:
            import ctypes

            _TRIM = ctypes.CDLL("libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _TRIM = False
    if _TRIM:
        _TRIM(0)


_TRIM = None
_M_MMAP_THRESHOLD = -3  # glibc mallopt parameter


def map_large_blocks() -> None:
    """Have glibc serve blocks of 256 KiB and more from their own mappings, returned to the
    system when freed, for the rest of the process (elsewhere than glibc: nothing). Its default
    threshold rises with the largest block freed, up to 32 MiB; the parts' arrays then come
    from the heap, whose freed pages stay resident and fragment, and the peak creeps up part
    after part. Set only when a file is run in parts: the mappings cost page faults (a whole
    24 h 30 s file ran 25 % slower with it)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").mallopt(_M_MMAP_THRESHOLD, 256 * 1024)
    except (OSError, AttributeError):
        pass


class _Survey:
    """What the whole observation file decides: satellites, systems, epoch times, parts."""

    def __init__(self) -> None:
        self.obs_sv: set[str] = set()
        self.pr_sv: set[str] = set()
        self.times: list[np.ndarray] = []

    def add(self, obs: xr.Dataset, setup: EpochSetup) -> None:
        self.obs_sv.update(np.asarray(obs["sv"].values).astype(str).tolist())
        prs = select_pseudoranges(obs, setup.systems, setup.priority)
        self.pr_sv.update(prs.sv.tolist())
        self.times.append(prs.time_gps_s)


class ChunkedRun:
    """``process(obs_path, nav_paths, config)`` in parts of at most ``chunk_epochs`` epochs;
    a file of at most ``whole_epochs`` epochs (default ``chunk_epochs``) is run whole.

    Iterate :meth:`parts`: each item is a :class:`RunResult` of consecutive epochs (the
    smoothing's window models finished with them in ``models``), or :data:`RESTART`. After
    the iteration :attr:`warnings` holds the run's warnings (the parts carry none).

    Raises (during the iteration) what :func:`~gnss_cli.pipeline.processing.process` raises.
    """

    def __init__(self, obs_path: str | Path, nav_paths: Sequence[str | Path], config: ProcessingConfig,
                 chunk_epochs: int, progress: Progress | None = None, whole_epochs: int | None = None) -> None:
        if not streamable(config):
            raise ValueError("ChunkedRun: this configuration needs the whole file (see streamable)")
        self.obs_path, self.nav_paths, self.config = obs_path, list(nav_paths), config
        self.chunk_epochs = int(chunk_epochs)
        self.whole_epochs = max(int(whole_epochs if whole_epochs is not None else chunk_epochs), 1)
        self.progress = progress
        self.warnings: tuple[str, ...] = ()

    def parts(self) -> Iterator[RunResult | _Restart]:
        setup = signal_setup(self.obs_path, self.nav_paths, self.config)
        chunks = iter_obs_chunks(self.obs_path, setup.systems, setup.codes, self.whole_epochs)
        if self.progress:
            self.progress("reading", 0.0)
        held = [next(chunks)]
        second = next(chunks, None)
        if second is None:  # one part: the whole file
            result = process(self.obs_path, self.nav_paths, self.config, self.progress, obs=held)
            self.warnings = result.warnings
            yield result
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
        yield from self._solve(setup, survey)

    def _axes(self, setup: EpochSetup, survey: _Survey) -> tuple[list[str], np.ndarray]:
        """The systems and the satellite axis of the whole file."""
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

    def _solve(self, setup: EpochSetup, survey: _Survey) -> Iterator[RunResult | _Restart]:
        systems, sv = self._axes(setup, survey)
        t = np.concatenate(survey.times)
        dt = np.diff(t)
        nominal = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
        sys_of = np.array([s[0] for s in sv])
        used = tuple(sy for sy in systems if (sys_of == sy).any() and setup.records(sy)[0] is not None)
        while True:
            factors = self._doppler_factors(setup, systems, sv, used, t.size)
            cov, counts = yield from self._pass(setup, systems, sv, used, nominal, t.size, factors)
            warnings = file_warnings(setup, sv, systems, cov)
            actual = used_systems(sv, systems, cov)
            if actual == used:
                break
            used = actual
            yield RESTART
        if not any(c.get(EpochStatus.OK.value, 0) for c in counts.values()):
            raise NoSolutionError(f"{Path(self.obs_path).name}: no epoch could be solved ({status_summary(counts)})")
        self.warnings = tuple(warnings)

    def _epochs(self, setup: EpochSetup, systems: list[str], sv: np.ndarray,
                used: tuple[str, ...]) -> Iterator[tuple[EpochData, Coverage]]:
        """The parts' epochs on the whole file's satellite axis, and each part's coverage."""
        for obs in iter_obs_chunks(self.obs_path, setup.systems, setup.codes, self.chunk_epochs):
            obs = obs.reindex(sv=np.union1d(np.asarray(obs["sv"].values).astype(str), sv))
            prs = align_pseudoranges(select_pseudoranges(obs, systems, setup.priority), sv)
            data, part_cov = build_epochs(obs, prs, setup, systems)
            del obs, prs
            yield finish_epochs(data, used), part_cov

    def _doppler_factors(self, setup: EpochSetup, systems: list[str], sv: np.ndarray,
                         used: tuple[str, ...], n_epochs: int) -> tuple[float, ...] | None:
        """The whole file's variance factors of the doppler smoothing model (a pass of WLS over the
        parts), so that every piece weighs as the whole file would; None for another model."""
        config = self.config
        if not config.smoothing.lag or config.smoothing.model not in ("auto", "doppler"):
            return None
        from gnss_cli.pipeline.doppler_smoothing import factors_from_totals, free_misfit_totals

        totals = np.zeros(6)  # misfit and degrees of freedom: pseudoranges, range rates, phase pairs
        done = 0
        wls_only = replace(config, methods=("wls",))
        for k, (data, _) in enumerate(self._epochs(setup, systems, sv, used)):
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
              n_epochs: int, factors: tuple[float, ...] | None = None):  # type: ignore[no-untyped-def]
        """One pass of reading, solving and handing out; returns the coverage and the status counts."""
        config = self.config
        lag = config.smoothing.lag
        others = tuple(m for m in config.methods if m != "stls") if lag else config.methods
        snapshot = replace(config, methods=others + (() if "wls" in others or not lag else ("wls",)))
        smoother: StreamSmoother | DopplerStreamSmoother | None = None
        cov: Coverage | None = None
        counts: dict[str, dict[str, int]] = {}
        done = 0
        for k, (data, part_cov) in enumerate(self._epochs(setup, systems, sv, used)):
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
                out = with_velocity(out, config)
                yield out
            del out  # before the next part is read: one part in memory at a time
            release_memory()
        out = smoother.push([], last=True) if smoother is not None else None  # the last segment ends
        if out is not None:
            yield with_velocity(out, config)
        assert cov is not None
        return cov, counts
