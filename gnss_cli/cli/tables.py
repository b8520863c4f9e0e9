"""The outputs of a ``gnss-solve`` run, built as its parts come (one writer for every run).

:func:`solve_files` runs :class:`~gnss_cli.pipeline.run.Run` and turns each part into its
table rows where the part is solved (:class:`_PartOut`): the CSV rows of each table go to an
anonymous spool file per table and method (the tables list one method after the other), so
that a long file's tables never sit in memory. ``summary.csv`` is computed at the end from the
few per-epoch columns it needs, kept for the whole file (about 100 bytes per epoch and
method). Positions in another format than CSV (and ``gnss-batch``) keep the positions table of
every part; ``--plots`` and ``--report`` keep the parts themselves. :func:`stage` then hands
everything to the :class:`~gnss_cli.cli.output.OutputSet` (all files or none) or to stdout.
"""

from __future__ import annotations

import json
import tempfile
import textwrap
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Any, Optional

import numpy as np

from gnss_cli.cli.exits import write_stdout

__all__ = ["RunOutput", "solve_files", "stage", "TABLES"]

_SUMMARY_FIELDS = ("x_ecef_m", "status", "gdop", "pdop", "hdop", "vdop", "tdop", "tdops", "gdop_paper", "hpl_m", "vpl_m")
"""The per-epoch fields of a MethodSolution that :func:`gnss_cli.report.summary_table` reads."""
TABLES = ("positions", "errors", "dop", "satellites")
"""The tables written row by row (``summary.csv`` is computed at the end)."""


class _Spools:
    """One anonymous temporary file per table and method; the CSV header written once."""

    def __init__(self) -> None:
        self.files: dict[tuple[str, str], IO[str]] = {}
        self.header: dict[str, str] = {}
        self.rows: dict[tuple[str, str], int] = {}

    def write(self, table: str, method: str, text: str) -> None:
        head, _, body = text.partition("\n")
        self.header.setdefault(table, head + "\n")
        key = (table, method)
        self.rows[key] = self.rows.get(key, 0) + body.count("\n")
        if key not in self.files:
            self.files[key] = tempfile.TemporaryFile("w+", encoding="ascii", newline="")
        self.files[key].write(body)

    def copy(self, table: str, methods: tuple[str, ...], out: Any) -> None:
        """The table into ``out`` (a text file, or ``write_stdout``): header, then every method's rows."""
        write = out.write if hasattr(out, "write") else out
        write(self.header.get(table, ""))
        for m in methods:
            f = self.files.get((table, m))
            if f is None:
                continue
            f.seek(0)
            while block := f.read(1 << 20):
                write(block)

    def close(self) -> None:
        for f in self.files.values():
            f.close()
        self.files.clear()
        self.header.clear()
        self.rows.clear()


class _Models:
    """The ``--model-out`` document written record by record into a spool, without holding a day's
    thousands of window records: the methods' settings, then one record per window."""

    def __init__(self, wanted: bool) -> None:
        self.count = 0
        self.spool: IO[str] | None = tempfile.TemporaryFile("w+", encoding="utf-8", newline="") if wanted else None

    def add(self, models: Any) -> None:
        if self.spool is None:
            return
        for m in models:
            self.spool.write((",\n" if self.count else "") + textwrap.indent(json.dumps(m.to_dict(), indent=1), "  "))
            self.count += 1

    def write(self, tmp: Path, settings: dict[str, Any]) -> None:
        """The document into ``tmp``: ``{"methods": {method: settings}, "windows": [...]}``."""
        head = json.dumps({"methods": {m: s.to_dict() for m, s in settings.items()}, "windows": []}, indent=1)
        assert self.spool is not None and head.endswith("[]\n}")
        with open(tmp, "w", encoding="utf-8", newline="") as f:
            if not self.count:
                f.write(head + "\n")
                return
            f.write(head[: -len("]\n}")] + "\n")
            self.spool.seek(0)
            while block := self.spool.read(1 << 20):
                f.write(block)
            f.write("\n ]\n}\n")

    def close(self) -> None:
        if self.spool is not None:
            self.spool.close()
            self.spool = None


@dataclass
class _PartOut:
    """What the outputs need of one part: its CSV rows per table and method, its summary columns,
    its reference, its window models, the part without its epochs, and (when kept) its positions
    table and the part itself. Small unless kept, so that a part solved in a forked process comes
    back in milliseconds."""

    rows: list[tuple[str, str, str]]
    summary: dict[str, dict[str, Any]]
    ref: Any
    models: Any
    slim: Any
    positions: Any = None
    part: Any = None


@dataclass
class RunOutput:
    """A run's outputs, before they are staged (:func:`stage`).

    ``positions``, ``result`` and ``reference_ecef_m`` are None unless they were asked to be kept.
    """

    spools: _Spools
    models: _Models
    summary: Any
    methods: tuple[str, ...]
    settings: dict[str, Any]
    warnings: list[str]
    with_errors: bool
    systems: tuple[str, ...]
    marker_name: str = ""
    positions: Any = None
    result: Any = None
    reference_ecef_m: Any = None
    files: list[Path] = field(default_factory=list)
    command: str = ""
    """The command line of the run (the first column of ``summary.csv``)."""
    run_settings: dict[str, str] = field(default_factory=dict)
    """The run's resolved settings (:func:`run_settings`; the second column of ``summary.csv``)."""

    def close(self) -> None:
        self.spools.close()
        self.models.close()


def solve_files(files: list[Path], cfg: Any, progress: Any, reference: Any, *, tables: tuple[str, ...] = TABLES,
                models: bool = False, keep_positions: bool = False, keep_result: bool = False,
                command: str = "") -> RunOutput:
    """Run OBS NAV... (``files``) part by part with ``cfg`` and build the outputs of the run.

    Parameters
    ----------
    reference : Reference
        The run's reference (:class:`~gnss_cli.io.reference.Reference`).
    tables : tuple of str
        The tables of :data:`TABLES` to spool (the positions always are).
    models : bool
        Spool the window models (``--model-out``).
    keep_positions, keep_result : bool
        Keep the whole positions table (another format than CSV, ``gnss-batch``) / the whole
        run and its reference (figures).
    command : str
        The command line, recorded in ``summary.csv`` and the report.

    Raises what :class:`~gnss_cli.pipeline.run.Run` raises. The caller closes the result.
    """
    from gnss_cli.pipeline.run import RESTART, Run

    obs_name = Path(files[0]).name
    run = Run(files[0], files[1:], cfg, progress)
    out = _fresh(models)
    last: Any = None
    kept: list[Any] = []
    finish = _finisher(reference, cfg, tables, obs_name, keep_positions, keep_result)
    try:
        for part in run.parts(finish):
            if part is RESTART:
                out.close()
                out, last, kept = _fresh(models), None, []
                continue
            for name, method, text in part.rows:
                out.spools.write(name, method, text)
            out.summary.add(part.summary, part.ref)
            out.models.add(part.models)
            last = part.slim
            if keep_positions or keep_result:
                kept.append(part)
            del part  # before the next part is computed
    except BaseException:
        out.close()
        raise
    assert last is not None
    from gnss_cli.io.reference import coverage_warning

    warnings = list(run.warnings)
    if reference.moving:
        note = coverage_warning(*out.summary.coverage(), reference.source)
        if note is not None:
            warnings.append(note)
    result = RunOutput(out.spools, out.models, out.summary.table(last), tuple(last.solutions), dict(last.settings),
                       warnings, reference.given, tuple(last.epochs.systems), last.epochs.marker_name,
                       files=list(files), command=command,
                       run_settings=run_settings(run.config, reference_text(reference), tuple(last.epochs.systems)))
    if keep_positions:
        import pandas as pd

        frame = pd.concat([p.positions for p in kept], ignore_index=True)
        order = {m: k for k, m in enumerate(result.methods)}  # the tables list one method after the other
        result.positions = frame.iloc[np.argsort(frame["method"].map(order).to_numpy(), kind="stable")].reset_index(drop=True)
    if keep_result:
        from gnss_cli.pipeline.results import concat_results

        whole = concat_results([p.part for p in kept])
        result.result = replace(whole, epochs=replace(whole.epochs, warnings=run.warnings))
        refs = [p.ref for p in kept]
        result.reference_ecef_m = refs[0] if refs[0] is None or np.ndim(refs[0]) == 1 else np.concatenate(refs)
    return result


@dataclass
class _Open:
    spools: _Spools
    models: _Models
    summary: "_Summary"

    def close(self) -> None:
        self.spools.close()
        self.models.close()


def _fresh(models: bool) -> _Open:
    return _Open(_Spools(), _Models(models), _Summary())


class _Summary:
    """The per-epoch columns of ``summary.csv``, collected over the parts."""

    def __init__(self) -> None:
        self.parts: dict[str, list[dict[str, Any]]] = {}
        self.refs: list[Any] = []

    @staticmethod
    def fields(part: Any) -> dict[str, dict[str, Any]]:
        """The part's columns that the summary needs, per method (copies: a view would keep the
        part's arrays alive)."""
        return {m: {f: getattr(s, f).copy() for f in _SUMMARY_FIELDS if getattr(s, f) is not None}
                for m, s in part.solutions.items()}

    def add(self, fields: dict[str, dict[str, Any]], ref: Any) -> None:
        for m, columns in fields.items():
            self.parts.setdefault(m, []).append(columns)
        self.refs.append(ref if ref is None or np.ndim(ref) == 1 else ref.copy())

    def coverage(self) -> tuple[int, int]:
        """``(matched, solved)``: the epochs solved by some method that have a reference, and
        the epochs solved by some method."""
        from gnss_cli.pipeline.results import EpochStatus

        solved = None
        for parts in self.parts.values():
            ok = np.concatenate([p["status"] for p in parts]) == EpochStatus.OK
            solved = ok if solved is None else solved | ok
        if solved is None:
            return 0, 0
        refs = [np.broadcast_to(r, (n, 3)) if r is not None else np.full((n, 3), np.nan)
                for r, n in zip(self.refs, (p["status"].size for p in next(iter(self.parts.values()))))]
        have = np.isfinite(np.concatenate(refs)).all(axis=1) if refs else np.zeros(solved.size, dtype=bool)
        return int((have & solved).sum()), int(solved.sum())

    def table(self, last: Any) -> Any:
        """``summary_table`` of the whole run (``last``: the last part, for the other fields)."""
        from gnss_cli.report import summary_table

        solutions = {}
        for m, parts in self.parts.items():
            joined = {f: np.concatenate([p[f] for p in parts]) for f in parts[0]}
            solutions[m] = replace(last.solutions[m], **joined)
        ref = self.refs[0] if self.refs and (self.refs[0] is None or np.ndim(self.refs[0]) == 1) \
            else np.concatenate(self.refs)
        return summary_table(replace(last, solutions=solutions), ref)


def _finisher(reference: Any, cfg: Any, tables: tuple[str, ...], obs_name: str, keep_positions: bool,
              keep_result: bool) -> Callable[[Any], _PartOut]:
    """The function that turns a solved part into its :class:`_PartOut` (where it was solved)."""
    from gnss_cli.pipeline.results import take_result
    from gnss_cli.report import dop_table, errors_table, positions_table, satellites_table, to_csv_text, utc_offset_s

    def finish(part: Any) -> _PartOut:
        ref = reference.of(part.epochs.time_gps_s, part.epochs.marker_name, utc_offset_s(part), obs_name)
        positions = positions_table(part, ref, cfg.time_system)
        built = {"positions": positions, "dop": dop_table(positions)}
        if ref is not None:
            built["errors"] = errors_table(positions)
        rows = [(name, m, to_csv_text(table[table["method"] == m]))
                for name, table in built.items() if name == "positions" or name in tables for m in part.solutions]
        if "satellites" in tables:
            rows.append(("satellites", "", to_csv_text(satellites_table(part, cfg))))
        return _PartOut(rows, _Summary.fields(part), ref, part.models, take_result(part, slice(0, 0), copy=True),
                        positions if keep_positions else None, part if keep_result else None)

    return finish


def _write_from(outputs: Any, path: Path, writer: Any) -> None:
    """Stage ``path`` by ``writer(temporary path)``; a device or a pipe (``/dev/stdout``,
    ``/dev/full``) cannot be renamed over and gets the text written into it, as
    :meth:`~gnss_cli.cli.output.OutputSet.write_text` does."""
    if path.exists() and not path.is_file() and not path.is_dir():
        with tempfile.TemporaryDirectory() as tmp:
            writer(Path(tmp) / "text")
            outputs.write_text(path, (Path(tmp) / "text").read_text(encoding="utf-8"))
        return
    outputs.write_with(path, writer)


def stage(outputs: Any, targets: dict[str, Path], run: RunOutput, fmt: str = "csv", time_system: str = "gpst",
          pos_options: tuple[str, ...] = ()) -> list[tuple[Path, str]]:
    """Stage every target (committed together when the ``OutputSet`` closes), or print the positions.

    ``targets``: ``positions`` (or ``positions:<method>`` per method for pos / nmea with several
    methods), the tables of :data:`TABLES`, ``summary``, ``models``. Positions in ``fmt`` other
    than CSV need ``run.positions`` (``solve_files(..., keep_positions=True)``).

    Returns ``(path, what it holds)`` of every file staged (:func:`written_lines`)."""
    from gnss_cli.formats import render
    from gnss_cli.report import to_csv_text

    inputs = [str(f) for f in run.files]
    written: list[tuple[Path, str]] = []
    for name, path in targets.items():
        if name == "models":
            _write_from(outputs, path, lambda tmp: run.models.write(tmp, run.settings))
            written.append((path, count(run.models.count, "window record")))
        elif name == "summary":
            outputs.write_text(path, to_csv_text(with_run_columns(run.summary, run.command, run.run_settings)))
            written.append((path, count(len(run.summary), "row") + ", one per method"))
        elif name.startswith("positions") and fmt != "csv":
            _, _, method = name.partition(":")
            table = run.positions[run.positions["method"] == method] if method else run.positions
            written.append((path, count(len(table), "epoch") + (f" of {method}" if method else _of_methods(run.methods))))
            data = render(fmt, table, time_system, inputs, pos_options)
            if isinstance(data, bytes):
                outputs.write_with(path, lambda tmp, data=data: tmp.write_bytes(data))
            else:
                outputs.write_text(path, data)
        elif name.startswith("positions") or name in run.spools.header:  # errors: only with a reference
            table = name.partition(":")[0]
            order = (name.partition(":")[2],) if ":" in name else run.methods if table != "satellites" else ("",)

            def write(tmp: Path, table: str = table, order: tuple[str, ...] = order) -> None:
                with open(tmp, "w", encoding="ascii", newline="") as f:
                    run.spools.copy(table, order, f)

            _write_from(outputs, path, write)
            rows = sum(run.spools.rows.get((table, m), 0) for m in order)
            written.append((path, count(rows, "row") + (f" of {order[0]}" if ":" in name else
                                                         _of_methods(run.methods) if table != "satellites" else "")))
    if not any(name.startswith("positions") for name in targets):
        if fmt == "csv":
            run.spools.copy("positions", run.methods, write_stdout)
        else:
            text = render(fmt, run.positions, time_system, inputs, pos_options)
            write_stdout(text if isinstance(text, str) else text.decode())
    return written


def count(n: int, noun: str) -> str:
    """``n`` and the noun, singular for one (``1 row``, ``2 rows``)."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _of_methods(methods: tuple[str, ...]) -> str:
    return f": {', '.join(methods)}" if methods else ""


def written_lines(written: list[tuple[Path, str]], program: str = "gnss-solve") -> list[str]:
    """The closing stderr lines that list the files a run wrote: ``<program>: wrote PATH (what)``."""
    return [f"{program}: wrote {path} ({what})" for path, what in written]


def run_settings(cfg: Any, reference: str, systems: tuple[str, ...] = ()) -> dict[str, str]:
    """The resolved settings of a run that every method shares (``summary.csv``'s ``settings``
    column; each method's own settings have columns of their own)."""
    from gnss_cli import __version__
    from gnss_cli.pipeline.environment import describe

    levels = "none" if cfg.integrity == "off" else (
        f"risk {cfg.integrity_risk:g}, prior satellite {cfg.prior_fault_satellite:g}, prior constellation "
        f"{cfg.prior_fault_constellation:g}, faults at once {cfg.max_simultaneous_faults}, nominal bias "
        f"{cfg.nominal_bias_cn0_sigmas:g} C/N0 sigmas, alert limits {cfg.alert_limit_h_m:g}/{cfg.alert_limit_v_m:g} m")
    nlos = cfg.nlos.detector if cfg.nlos.detector == "off" or cfg.integrity == "off" else (
        f"{cfg.nlos.detector}, kept spans variance x{cfg.nlos.variance_factor:g}"
        + (f", min direct dof {cfg.nlos.min_direct_dof}" if cfg.nlos.min_direct_dof > 0 else ""))
    if cfg.nlos.multi_epoch != "off" and cfg.multi_epoch_methods:
        nlos += (f", multi-epoch spans {cfg.nlos.multi_epoch} k {cfg.nlos.multi_epoch_k:g} h {cfg.nlos.multi_epoch_h:g}"
                 f" x{cfg.nlos.multi_epoch_rounds}")
    return {"methods": ",".join(cfg.methods), "systems": ",".join(systems or cfg.systems), "iono": cfg.iono,
            "tropo": cfg.tropo, "elevation_mask_deg": f"{cfg.elevation_mask_deg:g}", "weights": cfg.weights.describe(),
            "integrity": cfg.integrity, "environment": describe(cfg), "levels": levels, "nlos": "off" if cfg.integrity == "off" else nlos,
            "robust": cfg.robust, "time_system": cfg.time_system, "reference": reference, "version": __version__}


RUN_COLUMNS = ("command", "settings")
"""The first columns of ``summary.csv``: the same value on every row."""


def with_run_columns(summary: Any, command: str, settings: dict[str, str]) -> Any:
    """``summary`` with :data:`RUN_COLUMNS` first: the command line and ``key=value; ...`` of
    the settings (one value for every row, so that ``pandas.read_csv`` needs no option)."""
    out = summary.copy()
    out.insert(0, "settings", "; ".join(f"{k}={v}" for k, v in settings.items()))
    out.insert(0, "command", command)
    return out


def closing_lines(run: RunOutput, program: str = "gnss-solve") -> list[str]:
    """The closing stderr lines: the environment the run took, then per method what ran and its
    epochs, errors and DOP."""
    environment = run.run_settings.get("environment")
    lines = [f"{program}: environment {environment}"] if environment else []
    for _, row in run.summary.iterrows():
        m = row["method"]
        line = f"{program}: {m}: {row['epochs_solved']}/{row['epochs']} epochs solved"
        if row["epochs_solved"] == 0:  # no ok epoch: no statistics of ok epochs to quote
            line += " (none ok: see the status column)"
        elif run.with_errors:
            line += f", 3D RMS {row['rms_3d_m']:.3f} m (E {row['rms_e_m']:.3f} N {row['rms_n_m']:.3f} U {row['rms_u_m']:.3f})"
        if row["epochs_solved"] > 0:
            line += f", mean GDOP {row['mean_gdop']:.2f}"
        if m in run.settings:
            line += f"; {run.settings[m].line()}"
        lines.append(line)
    return lines


def reference_text(reference: Optional[Any]) -> str:
    """What the reference was, for the settings of the outputs."""
    return "none" if reference is None or not reference.given else reference.source
