"""One ``gnss-batch`` task: one observation file, solved as ``gnss-solve`` would solve it.

:func:`run_file` runs in a worker process (a local process pool or a Dask worker): it
finds the navigation files whose records cover the observation file's time span
(:func:`gnss_cli.io.catalog.covering_navs`), calls
:func:`gnss_cli.cli.tables.solve_files` (the very function behind ``gnss-solve``) and
returns a :class:`FileResult`: the positions as a typed frame for the Parquet dataset,
the per-method summary and one row of ``files.csv``. It never raises for a problem of its
file: the error becomes a failed result with the exit code gnss-solve would have given,
so a failing file never stops the others. Everything here pickles (Dask ships it by value).
"""

from __future__ import annotations

import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from gnss_cli.config import ProcessingConfig
from gnss_cli.errors import GnssError

SECONDS_PER_WEEK = 604800


@dataclass(frozen=True)
class BatchSettings:
    """What every task shares: the configuration, the reference options and the navigation files.

    Attributes
    ----------
    config : the processing configuration (flags > ``--config`` > packaged defaults).
    reference, reference_sinex, reference_csv, reference_pos : the reference options of
        gnss-solve, applied to every file (a SINEX file gives each station its own position).
    navs : ``(path, first toc, last toc)`` of each navigation file, toc in s since the GPS epoch.
    """

    config: ProcessingConfig
    reference: Optional[str] = None
    reference_sinex: Optional[Path] = None
    reference_csv: Optional[Path] = None
    reference_pos: Optional[Path] = None
    navs: tuple[tuple[str, float, float], ...] = ()


@dataclass
class FileResult:
    """The outcome of one observation file (one row of ``files.csv``).

    ``positions`` (rows for the Parquet dataset, with ``station`` and ``day`` columns) and
    ``summary`` (gnss-solve's summary table) are None when the file failed.
    """

    index: int
    obs_path: str
    station: str
    status: str = "failed"
    exit_code: int = 1
    nav_paths: tuple[str, ...] = ()
    epochs: int = 0
    solved: int = 0
    method: str = ""
    rms_3d_m: float = float("nan")
    seconds: float = 0.0
    error: str = ""
    warnings: tuple[str, ...] = ()
    environment: str = ""
    """The environment the run took (``summary.csv``'s ``settings``: ``urban (auto: ...)``)."""
    positions: Any = field(default=None, repr=False)
    summary: Any = field(default=None, repr=False)

    def row(self) -> dict[str, object]:
        """The ``files.csv`` row."""
        return {"obs_path": self.obs_path, "nav_paths": ";".join(self.nav_paths), "station": self.station,
                "status": self.status, "exit_code": self.exit_code, "epochs": self.epochs, "solved": self.solved,
                "method": self.method, "rms_3d_m": self.rms_3d_m, "environment": self.environment, "seconds": self.seconds, "error": self.error,
                "warnings": " | ".join(self.warnings)}


SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""Environment of local worker processes: one BLAS thread each, the processes being the
parallelism (two processes of two BLAS threads on two cores took 23.5 s instead of 13.8 s for four 24 h files; Dask's
nanny sets the same)."""


def init_worker() -> None:
    """Start of a local worker process: Ctrl-C is for the parent, which ends the workers (with
    SIGTERM, whose default action a worker forked from the parent gets back here)."""
    from gnss_cli.io.navigation import keep_navigation

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    keep_navigation()  # the files of a network share their navigation files


def warm_up() -> None:
    """Import what a task needs (run in each new worker while the parent reads the navigation files)."""
    import gnss_cli.cli.tables  # noqa: F401
    import gnss_cli.formats  # noqa: F401
    import gnss_cli.io.catalog  # noqa: F401
    import gnss_cli.io.nav_checks  # noqa: F401
    import gnss_cli.io.rinex  # noqa: F401
    import gnss_cli.io.rinex3_nav  # noqa: F401
    import gnss_cli.io.rinex3_obs  # noqa: F401
    import gnss_cli.pipeline  # noqa: F401
    import gnss_cli.report  # noqa: F401


def failed(index: int, obs_path: str, exc: BaseException, seconds: float = 0.0) -> FileResult:
    """A failed result for ``exc``: its message and exit code (1 and the type for a bug)."""
    from gnss_cli.io.catalog import station_id

    if isinstance(exc, GnssError):
        code, message = exc.exit_code, str(exc)
    else:
        code, message = 1, f"internal error: {type(exc).__name__}: {exc}"
    return FileResult(index, obs_path, station_id(obs_path), exit_code=code, seconds=seconds,
                      error=" ".join(message.split()))


def _navs_for(obs_path: str, settings: BatchSettings) -> list[str]:
    """The navigation files whose toc span covers the observation file's epochs."""
    from gnss_cli.errors import InputError
    from gnss_cli.io.catalog import covering_navs, obs_time_span
    from gnss_cli.io.reference import GPS_EPOCH
    from gnss_cli.io.rinex import rinex_info

    if rinex_info(obs_path).kind != "obs":
        raise InputError(f"{obs_path}: is a RINEX navigation file, expected an observation file")
    span = obs_time_span(obs_path)
    chosen = covering_navs(span, [(a, b) for _, a, b in settings.navs])
    if not chosen:
        first, last = (np.datetime_as_string(GPS_EPOCH + np.timedelta64(round(t), "s"), unit="s").replace("T", " ")
                       for t in span)
        raise InputError(f"{obs_path}: no navigation file covers its epochs {first} to {last} GPST "
                         f"(given: {', '.join(Path(p).name for p, _, _ in settings.navs)})")
    return [settings.navs[i][0] for i in chosen]


def dataset_rows(positions: Any, time_system: str, obs_path: str, station: str) -> Any:
    """gnss-solve's positions table as Parquet-typed rows with ``obs_file``, ``station`` and ``day``.

    ``day`` is the GPS date of the epoch (``YYYY-MM-DD``), from ``gps_week`` and ``tow_s``
    whatever ``time_system`` the ``time`` column is in.
    """
    from gnss_cli.formats import parquet_table
    from gnss_cli.io.reference import GPS_EPOCH

    rows = parquet_table(positions, time_system)
    gps_s = rows["gps_week"].to_numpy(np.int64) * SECONDS_PER_WEEK + np.floor(rows["tow_s"].to_numpy(np.float64))
    days = np.datetime_as_string(GPS_EPOCH + gps_s.astype(np.int64).astype("timedelta64[s]"), unit="D")
    rows.insert(0, "obs_file", Path(obs_path).name)
    rows["station"] = station
    rows["day"] = days
    return rows


def run_file(index: int, obs_path: str, settings: BatchSettings) -> FileResult:
    """Solve one observation file; the result of its failure instead of an exception.

    Parameters
    ----------
    index : int
        Position of the file among the inputs (``files.csv`` keeps that order).
    obs_path : str
        The observation file, as the worker sees it.
    settings : BatchSettings
        Configuration, reference options and navigation files.

    Returns
    -------
    FileResult
        ``status`` ``ok`` with the positions and summary, or ``failed`` with the message and
        exit code of the error (SIGINT / SIGTERM still propagate).
    """
    from gnss_cli.cli.tables import solve_files
    from gnss_cli.io.catalog import station_id
    from gnss_cli.io.reference import Reference

    t0 = time.perf_counter()
    navs: list[str] = []
    try:
        navs = _navs_for(obs_path, settings)
        reference = Reference.from_options(settings.reference, settings.reference_sinex, settings.reference_csv,
                                           settings.reference_pos)
        run = solve_files([Path(obs_path), *map(Path, navs)], settings.config, None, reference, tables=(),
                          keep_positions=True)
        run.close()
    except Exception as exc:  # noqa: BLE001 - every failure of one file is reported, the others go on
        out = failed(index, obs_path, exc, time.perf_counter() - t0)
        out.nav_paths = tuple(navs)
        return out
    warnings = run.warnings
    station = station_id(obs_path, run.marker_name or "")
    summary = run.summary
    first = summary.iloc[0]
    out = FileResult(index, obs_path, station, "ok", 0, tuple(navs), int(first["epochs"]), int(first["epochs_solved"]),
                     str(first["method"]), float(first.get("rms_3d_m", float("nan"))), 0.0, "", tuple(warnings))
    out.environment = run.run_settings.get("environment", "")
    out.positions = dataset_rows(run.positions, settings.config.time_system, obs_path, station)
    summary.insert(0, "station", station)
    summary.insert(0, "obs_path", obs_path)
    out.summary = summary
    out.seconds = time.perf_counter() - t0
    return out
