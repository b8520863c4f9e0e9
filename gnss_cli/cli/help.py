"""The ``--help`` page of every command: options in panels, plain metavars, examples kept as written.

Each option names its panel with Typer's ``rich_help_panel``. Typer draws panels only through
Rich, which costs about 0.3 s of every ``--help`` (importing and rendering it; the target is
``gnss-solve --help`` <= 0.3 s in all, ``benchmarks/bench_startup.py``), so the commands keep
Click's plain-text formatter and :class:`PanelCommand` writes the panels with it:

- one section per panel, in the order of :data:`PANELS`, the options in the order declared;
  ``-h, --help`` in the last panel;
- an option's value is its ``metavar`` (``FILE``, ``LIST``, ``METHOD[,METHOD...]``), never a
  type name (``<str>``, ``<list[Path]>``); the usage line shows the arguments' metavars as
  they are (``OBS NAV...``, not ``[OBS NAV [NAV]...]...``);
- defaults read ``[default: wls]`` (the packaged value as written on the command line);
- the epilog (the examples) is printed line for line, not re-wrapped, so an example can be
  copied as it stands;
- a misspelt flag is answered with the close matches among the shown options only: a hidden
  option (a retired spelling such as ``--model``, which exits 2 itself) is never suggested.
"""

from __future__ import annotations

import sys
from typing import Any

import typer.core

PANELS = ("Inputs", "Scenario", "Errors", "Processing", "Model", "Multi-epoch", "Integrity", "Reference", "Output",
          "Run")
"""Panel titles in the order they are printed (a command shows the ones its options name)."""
NAME_COLUMN = 24
"""Width of the names column of every panel; a longer name (``-m, --method METHOD[,METHOD...]``)
has its help text start on the next line."""


class PanelCommand(typer.core.TyperCommand):
    """A Typer command whose plain-text help groups the options by their ``rich_help_panel``.

    Use as ``@app.command(cls=PanelCommand, epilog=...)``.
    """

    def collect_usage_pieces(self, ctx: Any) -> list[str]:
        """``[OPTIONS]`` and each argument's metavar as declared (``OBS NAV...``)."""
        pieces = [self.options_metavar] if self.options_metavar else []
        for param in self.get_params(ctx):
            if param.param_type_name == "argument" and not getattr(param, "hidden", False):
                pieces.append(param.metavar or param.name.upper())
        return pieces

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        """Click's parsing, with hidden options left out of a misspelt flag's suggestions."""
        no_such_option = sys.modules[typer.BadParameter.__module__].NoSuchOption  # (the Click this Typer uses)
        try:
            return super().parse_args(ctx, args)
        except no_such_option as exc:
            hidden = {o for p in self.get_params(ctx) if getattr(p, "hidden", False)
                      for o in (*p.opts, *p.secondary_opts)}
            if not hidden & set(exc.possibilities or ()):
                raise
            shown = [o for o in exc.possibilities or () if o not in hidden]
            raise no_such_option(exc.option_name, exc.message, shown or None, exc.ctx) from None

    def format_options(self, ctx: Any, formatter: Any) -> None:
        """One section per panel (:data:`PANELS` order; an unnamed panel: ``Arguments`` / ``Options``)."""
        help_option = self.get_help_option(ctx)
        panels: dict[str, list[tuple[str, str]]] = {}
        for param in self.get_params(ctx):
            if getattr(param, "hidden", False) or param is help_option:
                continue
            default = "Arguments" if param.param_type_name == "argument" else "Options"
            panels.setdefault(getattr(param, "rich_help_panel", None) or default, []).append(help_record(param))
        order = sorted(panels, key=lambda p: PANELS.index(p) if p in PANELS else -1 if p == "Arguments" else len(PANELS))
        if help_option is not None:
            panels.setdefault(order[-1] if order else "Options", []).append(help_record(help_option))
            order = order or ["Options"]
        # one column for the help texts of every panel; a longer name puts its text on the next line
        width = min(max(len(name) for rows in panels.values() for name, _ in rows), NAME_COLUMN)
        for title in order:
            with formatter.section(title):
                formatter.write_dl([(name.ljust(width), text) for name, text in panels[title]], col_max=width)

    def format_epilog(self, ctx: Any, formatter: Any) -> None:
        """The epilog line for line (examples are not re-wrapped), indented like a section."""
        if not self.epilog:
            return
        formatter.write_paragraph()
        for line in self.epilog.strip("\n").splitlines():
            formatter.write(f"{'':>{formatter.current_indent}}{line}".rstrip() + "\n")


def help_record(param: Any) -> tuple[str, str]:
    """``(names, help)`` of one parameter: ``-m, --method METHOD[,METHOD...]`` and its help text
    with ``[default: wls]`` (or ``[required]``).

    >>> import typer.main
    >>> from gnss_cli.cli.solve import app
    >>> lag = next(p for p in typer.main.get_command(app).params if p.name == "lag")
    >>> help_record(lag)[0]
    '--lag L'
    >>> help_record(lag)[1].endswith("[default: stls 0, smoother 3]")
    True
    """
    metavar = param.metavar or param.name.upper()
    if param.param_type_name == "argument":
        names = metavar
    else:
        names = ", ".join(sorted(param.opts, key=lambda opt: opt.startswith("--")))
        if param.secondary_opts:
            names += " / " + ", ".join(param.secondary_opts)
        if not param.is_flag:
            names += f" {metavar}"
    extra = []
    if isinstance(param.show_default, str):
        extra.append(f"default: {param.show_default}")
    elif param.show_default and param.default is not None and not getattr(param, "is_flag", False):
        extra.append(f"default: {param.default}")
    if param.required:
        extra.append("required")
    text = param.help or ""
    if extra:
        text = f"{text}  [{'; '.join(extra)}]" if text else f"[{'; '.join(extra)}]"
    return names, text
