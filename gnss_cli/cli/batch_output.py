"""The outputs of ``gnss-batch``: a Parquet dataset of positions, ``files.csv`` and ``summary.csv``.

``OUT/positions/`` is a Parquet dataset, ``<station>/day=<GPS date>/``, one file per
observation file and day (``<n>-<obs file>-0.parquet``), holding gnss-solve's positions
columns (typed as by ``--format parquet``) plus ``obs_file`` and ``station`` (a string
column). The station folder is a plain folder, not a Hive key ``station=<id>``: readers infer
a Hive key's type from the folder names, so ``station=0759`` came back as the integer 759 (and a
column of the same name in the files clashes with it); ``day=`` stays a Hive key (a date is never
read as a number). Each
file's rows are written as soon as it finishes, into a staged folder of the run's
:class:`~gnss_cli.cli.output.OutputSet`; if the files disagree on their columns (one file
with several systems has ``tdop_<letter>`` columns, another has not), every file is rewritten
at the end with the union of the columns, missing ones null, so that a reader that takes the
schema from one file (``pandas.read_parquet``) sees every column. ``files.csv`` has one row
per input in the order given, ``summary.csv`` gnss-solve's summary per file and method.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gnss_cli.cli.batch_task import FileResult

PARTITIONS = ("day",)
"""The Hive keys of the positions dataset (below the station folder)."""
FILES_COLUMNS = ["obs_path", "nav_paths", "station", "status", "exit_code", "epochs", "solved", "method", "rms_3d_m",
                 "environment", "seconds", "error", "warnings"]
"""``files.csv`` columns (README: gnss-batch)."""


def _write_options() -> Any:
    """Parquet format 2.6, the first with nanosecond timestamps (as ``--format parquet``)."""
    import pyarrow.dataset as ds

    return ds.ParquetFileFormat().make_write_options(version="2.6")


class PositionsDataset:
    """The positions of finished files, appended to a partitioned dataset in ``folder``.

    Parameters
    ----------
    folder : Path
        The (staged) dataset folder.
    """

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.files: list[tuple[int, Path]] = []
        self.schemas: list[Any] = []
        self.rows = 0
        self.stations: set[str] = set()

    def description(self) -> str:
        """What the dataset holds, for the closing lines of gnss-batch."""
        from gnss_cli.cli.tables import count

        return f"Parquet dataset: {count(self.rows, 'row')} in {count(len(self.files), 'file')}, {count(len(self.stations), 'station')}"

    def add(self, result: FileResult) -> None:
        """Write the rows of a finished file (nothing for a failed one) and forget them."""
        if result.positions is None:
            return
        import pyarrow as pa
        import pyarrow.dataset as ds

        table = pa.Table.from_pandas(result.positions, preserve_index=False).replace_schema_metadata(None)
        name = "".join(c if c.isalnum() or c in "-_." else "_" for c in Path(result.obs_path).name)
        written: list[Path] = []
        ds.write_dataset(table, self.folder / station_folder(str(result.station)), format="parquet",
                         partitioning=list(PARTITIONS), partitioning_flavor="hive",
                         basename_template=f"{result.index:05d}-{name}-{{i}}.parquet", file_options=_write_options(),
                         existing_data_behavior="overwrite_or_ignore",
                         file_visitor=lambda f: written.append(Path(f.path)))
        self.files += [(result.index, p) for p in written]
        self.rows += table.num_rows
        self.stations.add(str(result.station))
        self.schemas += [pa.schema([f for f in table.schema if f.name not in PARTITIONS])] * len(written)
        result.positions = None

    def finish(self) -> None:
        """Give every file the union of the columns when they differ (missing columns null).

        The union's column order is that of the inputs' order (not the order they finished in)."""
        if len({str(s) for s in self.schemas}) <= 1:
            return
        import pyarrow as pa
        import pyarrow.parquet as pq

        order = sorted(range(len(self.files)), key=lambda k: self.files[k][0])
        union = pa.unify_schemas([self.schemas[k] for k in order])
        for (_, path), schema in zip(self.files, self.schemas):
            if schema.equals(union):
                continue
            table = pq.read_table(path, partitioning=None)
            columns = [table[f.name] if f.name in schema.names else pa.nulls(table.num_rows, f.type) for f in union]
            pq.write_table(pa.Table.from_arrays(columns, schema=union), path, version="2.6")


def station_folder(station: str) -> str:
    """The folder of a station in the positions dataset: its name, with an ``s`` before a name
    that readers would skip (``_`` or ``.`` first). The ``station`` column keeps the name as is.

    >>> station_folder("0759"), station_folder("_X1")
    ('0759', 's_X1')
    """
    return "s" + station if station.startswith(("_", ".")) else station


def files_table(results: list[FileResult]) -> Any:
    """``files.csv``: one row per input, in input order."""
    import pandas as pd

    rows = [r.row() for r in sorted(results, key=lambda r: r.index)]
    return pd.DataFrame(rows, columns=FILES_COLUMNS)


def summary_table(results: list[FileResult]) -> Any:
    """``summary.csv``: gnss-solve's summary rows of every finished file (``obs_path``, ``station`` first)."""
    import pandas as pd

    frames = [r.summary for r in sorted(results, key=lambda r: r.index) if r.summary is not None]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=["obs_path", "station", "method"])


NETWORK_COLUMNS = ["station", "method", "files", "epochs", "ok_%", "rms_3d_m", "rms_horizontal_m", "rms_vertical_m",
                   "mean_gdop", "mean_lat_deg", "mean_lon_deg", "mean_height_m"]
"""The network page's table (``gnss-batch --report``): one row per station (and method)."""


def network_table(summary: Any) -> Any:
    """One row per station and method from gnss-batch's ``summary.csv`` rows (one per file and method).

    ``epochs`` and ``ok_%`` (epochs solved, per cent) are over the station's files; the RMS
    errors (m) pool the files' squared errors over their epochs with a reference
    (``√(Σ nᵢ rmsᵢ² / Σ nᵢ)``; horizontal ``√(rms_e² + rms_n²)``, vertical ``rms_u``), empty
    without a reference; ``mean_gdop`` and the mean position are weighted by the solved epochs.
    """
    import numpy as np
    import pandas as pd

    rows = []
    if summary is None or not len(summary):
        return pd.DataFrame(columns=NETWORK_COLUMNS)

    def col(df: Any, name: str) -> Any:
        return df[name].to_numpy(dtype=np.float64) if name in df.columns else np.full(len(df), np.nan)

    for (station, method), df in summary.groupby(["station", "method"], sort=False):
        epochs, solved = col(df, "epochs"), col(df, "epochs_solved")
        n_ref = np.nan_to_num(col(df, "epochs_with_reference"))

        def pooled(name: str) -> float:
            v = col(df, name)
            use = np.isfinite(v) & (n_ref > 0)
            return float(np.sqrt(np.sum(n_ref[use] * v[use] ** 2) / np.sum(n_ref[use]))) if use.any() else float("nan")

        def weighted(name: str) -> float:
            v = col(df, name)
            use = np.isfinite(v) & (solved > 0)
            return float(np.sum(solved[use] * v[use]) / np.sum(solved[use])) if use.any() else float("nan")

        rms_e, rms_n = pooled("rms_e_m"), pooled("rms_n_m")
        rows.append({"station": str(station), "method": method, "files": len(df), "epochs": int(epochs.sum()),
                     "ok_%": 100.0 * solved.sum() / epochs.sum() if epochs.sum() else float("nan"),
                     "rms_3d_m": pooled("rms_3d_m"), "rms_horizontal_m": float(np.hypot(rms_e, rms_n)),
                     "rms_vertical_m": pooled("rms_u_m"), "mean_gdop": weighted("mean_gdop"),
                     "mean_lat_deg": weighted("mean_lat_deg"), "mean_lon_deg": weighted("mean_lon_deg"),
                     "mean_height_m": weighted("mean_height_m")})
    return pd.DataFrame(rows, columns=NETWORK_COLUMNS)
