"""``--plots DIR`` and ``--report FILE.html`` of the commands: register the figure files with
the :class:`~gnss_cli.cli.output.OutputSet` before anything is computed (refusing the option
at once when matplotlib is missing), then draw them through :mod:`gnss_cli.plots` and stage
them with the other outputs (all files appear together or none does)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from gnss_cli.errors import OutputError


def register_figures(outputs: Any, plots_dir: Path | None, report: Path | None,
                     names: Sequence[str]) -> dict[str, Path]:
    """Register ``<plots_dir>/<name>.png`` for every name and the report; ``{}`` without either.

    Raises :class:`~gnss_cli.errors.ConfigError` (exit 3) when matplotlib is not installed.
    """
    from gnss_cli.plots import require_matplotlib

    targets: dict[str, Path] = {}
    if plots_dir is not None:
        require_matplotlib("--plots")
        if plots_dir.exists() and not plots_dir.is_dir():
            raise OutputError(f"{plots_dir}: cannot write output (not a folder)")
        for name in names:
            targets[name] = outputs.add(plots_dir / f"{name}.png", "--plots")
    if report is not None:
        require_matplotlib("--report")
        targets[REPORT] = outputs.add(report, "--report")
    return targets


REPORT = "report.html"
"""Key of the HTML report among the figure targets."""


def stage_figures(outputs: Any, targets: Mapping[str, Path], figures: Mapping[str, Any],
                  captions: Mapping[str, str], report_page: Any = None, progress: Any = None) -> list[tuple[Path, str]]:
    """Render every figure once (PNG bytes) and stage the PNG files and the HTML report.

    ``report_page(figures)`` builds the HTML text from ``{name: (caption, png bytes)}``;
    ``progress("figures", fraction)`` runs from 0.5 to 1 as the figures are rendered (the
    drawing was the first half). Returns ``(path, what)`` of every staged file.
    """
    from gnss_cli.plots.common import png_bytes

    pngs = {}
    for k, (name, fig) in enumerate(figures.items()):
        pngs[name] = png_bytes(fig)
        if progress is not None:
            progress("figures", 0.5 + 0.5 * (k + 1) / len(figures))
    written: list[tuple[Path, str]] = []
    for name, path in targets.items():
        if name in pngs:
            outputs.write_with(path, lambda tmp, data=pngs[name]: Path(tmp).write_bytes(data))
            written.append((path, "PNG figure"))
    if REPORT in targets and report_page is not None:
        page = report_page({name: (captions.get(name, name), png) for name, png in pngs.items()})
        outputs.write_text(targets[REPORT], page)
        written.append((targets[REPORT], f"HTML report, {len(pngs)} figures"))
    if progress is not None:
        progress("figures", 1.0)
    return written


def solve_settings(files: Sequence[Path], cfg: Any, result: Any, reference: str, command: str = "") -> dict[str, object]:
    """The settings of a ``gnss-solve`` run, as shown in the HTML report (the command line first)."""
    import numpy as np

    from gnss_cli import __version__
    from gnss_cli.gnss.time import gps_s2datetime

    t = result.epochs.time_gps_s
    span = np.datetime_as_string(gps_s2datetime(t[[0, -1]]), unit="s") if t.size else ["", ""]
    settings: dict[str, object] = {
        "command": command,
        "observation file": str(files[0]),
        "navigation files": ", ".join(str(f) for f in files[1:]),
        "epochs": f"{t.size} ({span[0]} to {span[1]} GPST)",
        "methods": ", ".join(cfg.methods),
        "systems": ", ".join(result.epochs.systems),
        "ionosphere": cfg.iono,
        "troposphere": cfg.tropo,
        "elevation mask": f"{cfg.elevation_mask_deg:g} deg",
        "weights": cfg.weights.describe(),
        "reference": reference,
    }
    for method, ran in result.settings.items():
        settings[f"method {method}"] = ran.line()
    settings["gnss-solve version"] = __version__
    return settings
