"""``gnss-solve`` on a long observation file: solved and written part by part.

:func:`stream_tables` runs :class:`~gnss_cli.pipeline.stream.ChunkedRun` and writes the CSV
tables as the parts come: each table's rows go to an anonymous spool file per method (the
tables list one method after the other), and only when the run has succeeded are the spools
copied into the staged outputs (:class:`~gnss_cli.cli.output.OutputSet`: still all files or
none) or to stdout. ``summary.csv`` is computed at the end from the few per-epoch columns it
needs (positions, statuses, DOPs), kept for the whole file: about 100 bytes per epoch and
method. The bytes are those of the whole-file run.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Optional

import numpy as np

from gnss_cli.cli.exits import write_stdout

_SUMMARY_FIELDS = ("x_ecef_m", "status", "gdop", "pdop", "hdop", "vdop", "tdop", "tdops", "gdop_paper")
"""The per-epoch fields of a MethodSolution that :func:`gnss_cli.report.summary_table` reads."""
_TABLES = ("positions", "errors", "dop", "satellites")


def can_stream(cfg: Any, fmt: str, figures: bool) -> bool:
    """Whether the run can go part by part: CSV positions, no figures, a streamable configuration."""
    from gnss_cli.pipeline.stream import streamable

    return cfg.chunk_epochs > 0 and fmt == "csv" and not figures and streamable(cfg)


class _References:
    """The reference of each part: a fixed position, the SINEX station, or per-epoch rows."""

    def __init__(self, reference: Optional[str], sinex: Optional[Path], csv: Optional[Path], pos: Optional[Path]) -> None:
        from gnss_cli.io.reference import parse_reference, read_pos, read_reference_csv

        self.fixed = parse_reference(reference) if reference else None
        self.sinex = sinex
        self.rows = read_reference_csv(csv) if csv is not None else None
        self.pos = read_pos(pos) if pos is not None else None

    @property
    def given(self) -> bool:
        return self.fixed is not None or self.sinex is not None or self.rows is not None or self.pos is not None

    def of(self, part: Any, obs_name: str) -> Any:
        from gnss_cli.errors import ConfigError
        from gnss_cli.io.reference import match_reference, reference_from_sinex
        from gnss_cli.report import utc_offset_s

        if self.sinex is not None and self.fixed is None:
            if not part.epochs.marker_name:
                raise ConfigError(f"--reference-sinex: {obs_name} has no MARKER NAME to look up")
            self.fixed = reference_from_sinex(self.sinex, part.epochs.marker_name)
        if self.rows is not None:
            return match_reference(*self.rows, part.epochs.time_gps_s)
        if self.pos is not None:
            t_ref, xyz, scale = self.pos
            t = part.epochs.time_gps_s - (utc_offset_s(part) if scale == "UTC" else 0.0)
            return match_reference(t_ref, xyz, t)
        return self.fixed


class _Spools:
    """One anonymous temporary file per table and method; the CSV header written once."""

    def __init__(self) -> None:
        self.files: dict[tuple[str, str], IO[str]] = {}
        self.header: dict[str, str] = {}

    def write(self, table: str, method: str, text: str) -> None:
        head, _, body = text.partition("\n")
        self.header.setdefault(table, head + "\n")
        key = (table, method)
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

    def table(self, last: Any) -> Any:
        """``summary_table`` of the whole run (``last``: the last part, for the other fields)."""
        from dataclasses import replace

        from gnss_cli.report import summary_table

        solutions = {}
        for m, parts in self.parts.items():
            joined = {f: np.concatenate([p[f] for p in parts]) for f in parts[0]}
            solutions[m] = replace(last.solutions[m], **joined)
        ref = self.refs[0] if self.refs and (self.refs[0] is None or np.ndim(self.refs[0]) == 1) \
            else np.concatenate(self.refs)
        return summary_table(replace(last, solutions=solutions), ref)


@dataclass
class _PartOut:
    """What the tables need of one part: its CSV rows per table and method, its summary columns,
    its reference, its window models and the part without its epochs. Small, so that a part
    solved in a forked process comes back in milliseconds."""

    rows: list[tuple[str, str, str]]
    summary: dict[str, dict[str, Any]]
    ref: Any
    models: Any
    slim: Any


def _finisher(refs: _References, cfg: Any, targets: dict[str, Path], obs_name: str) -> Callable[[Any], _PartOut]:
    """The function that turns a solved part into its :class:`_PartOut` (where it was solved)."""
    from gnss_cli.report import dop_table, errors_table, positions_table, satellites_table, to_csv_text

    def finish(part: Any) -> _PartOut:
        ref = refs.of(part, obs_name)
        positions = positions_table(part, ref, cfg.time_system)
        tables = {"positions": positions, "dop": dop_table(positions)}
        if ref is not None:
            tables["errors"] = errors_table(positions)
        rows = [(name, m, to_csv_text(table[table["method"] == m]))
                for name, table in tables.items() if name == "positions" or name in targets for m in part.solutions]
        if "satellites" in targets:
            rows.append(("satellites", "", to_csv_text(satellites_table(part, cfg))))
        return _PartOut(rows, _Summary.fields(part), ref, part.models, _slim(part))

    return finish


def stream_tables(files: list[Path], cfg: Any, progress: Any, outputs: Any, targets: dict[str, Path],
                  references: tuple[Optional[str], Optional[Path], Optional[Path], Optional[Path]]
                  ) -> tuple[Any, list[str], bool]:
    """Run ``files`` part by part and stage (or print) the tables; returns the summary table, the
    warnings and whether there was a reference (the ``errors`` table)."""
    from gnss_cli.pipeline.stream import RESTART, ChunkedRun

    refs = _References(*references)
    spools, summary, models = _Spools(), _Summary(), _Models(cfg.smoothing, "models" in targets)
    run = ChunkedRun(files[0], files[1:], cfg, cfg.chunk_epochs, progress,
                     whole_epochs=max(cfg.stream_above_epochs, cfg.chunk_epochs), processes=cfg.processes)
    last = None
    try:
        for part in run.parts(_finisher(refs, cfg, targets, Path(files[0]).name)):
            if part is RESTART:
                spools.close()
                summary, last = _Summary(), None
                models.close()
                models = _Models(cfg.smoothing, "models" in targets)
                continue
            for name, method, text in part.rows:
                spools.write(name, method, text)
            summary.add(part.summary, part.ref)
            models.add(part.models)
            last = part.slim
            del part  # before the next part is computed
        assert last is not None
        summary_df = summary.table(last)
        _stage(outputs, targets, spools, tuple(last.solutions), summary_df, models)
    finally:
        spools.close()
        models.close()
    return summary_df, list(run.warnings), refs.given


class _Models:
    """The ``--model-out`` document written window by window into a spool: the text of
    :func:`gnss_cli.report.models_json` (``json.dumps(doc, indent=1)``) without holding the
    day's thousands of window records (only when ``wanted``)."""

    def __init__(self, smoothing: Any, wanted: bool) -> None:
        import json

        self.json, self.wanted, self.count, self.smoothing = json, wanted, 0, smoothing
        self.model = smoothing.model  # "auto": what the first record says it resolved to
        self.spool: IO[str] | None = tempfile.TemporaryFile("w+", encoding="utf-8", newline="") if wanted else None

    def add(self, models: Any) -> None:
        import textwrap

        if self.spool is None:
            return
        for m in models:
            if self.model == "auto":
                self.model = m.model
            self.spool.write((",\n" if self.count else "") + textwrap.indent(self.json.dumps(m.to_dict(), indent=1), "  "))
            self.count += 1

    def write(self, tmp: Path) -> None:
        sm = self.smoothing
        head = self.json.dumps({"lag": sm.lag, "model": self.model, "kernel": sm.kernel, "windows": []}, indent=1)
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


def _slim(part: Any) -> Any:
    """``part`` without its epochs (the systems, leap seconds, and one solution object per method remain)."""
    from gnss_cli.pipeline.smoothing_stream import take_result

    return take_result(part, slice(0, 0), copy=True)


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


def _stage(outputs: Any, targets: dict[str, Path], spools: _Spools, methods: tuple[str, ...], summary_df: Any,
           models: _Models) -> None:
    """Stage every target (committed together when the ``OutputSet`` closes), or print the positions."""
    from gnss_cli.report import to_csv_text

    for name, path in targets.items():
        if name == "models":
            _write_from(outputs, path, models.write)
        elif name == "summary":
            outputs.write_text(path, to_csv_text(summary_df))
        elif name in _TABLES and name in spools.header:  # errors: only with a reference
            order = methods if name != "satellites" else ("",)

            def write(tmp: Path, name: str = name, order: tuple[str, ...] = order) -> None:
                with open(tmp, "w", encoding="ascii", newline="") as f:
                    spools.copy(name, order, f)

            _write_from(outputs, path, write)
    if "positions" not in targets:
        spools.copy("positions", methods, write_stdout)


__all__ = ["can_stream", "stream_tables"]
