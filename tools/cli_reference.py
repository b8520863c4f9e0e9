"""Markdown reference pages of the command-line tools, written from their Typer apps.

Each console script of ``pyproject.toml`` (``[project.scripts]``) names a module whose ``app``
is a Typer app; :func:`typer.main.get_command` turns it into the Click command that
``--help`` prints, and every page here is made from that command: its help text, usage, every
argument and option (grouped by their ``rich_help_panel``, in declaration order) with the help
record ``--help`` shows, and the epilog. Nothing is copied by hand, so a new option, a new help
text or a new panel appears on the next build.

Usage: ``python tools/cli_reference.py [gnss-solve]`` prints the page(s) to stdout; the MkDocs
hook (``tools/mkdocs_hooks.py``) writes them into the site.
"""

from __future__ import annotations

import html
import importlib
import re
import sys
from pathlib import Path

import typer

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
_MARKDOWN_SPECIAL = re.compile(r"([\\`*_\[\]|])")


def console_scripts(pyproject: Path = ROOT / "pyproject.toml") -> dict[str, str]:
    """Script name -> module of its Typer app (``gnss-solve`` -> ``gnss_cli.cli.solve``)."""
    scripts = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["scripts"]
    return {name: target.split(":")[0] for name, target in sorted(scripts.items())}


def _cell(text: str) -> str:
    """``text`` as one Markdown table cell: escaped, on one line."""
    text = html.escape(" ".join(text.split()), quote=False)
    return _MARKDOWN_SPECIAL.sub(r"\\\1", text)


def _paragraphs(text: str | None) -> str:
    """A Click help text (paragraphs, ``\\b`` no-rewrap markers) as Markdown paragraphs."""
    if not text:
        return ""
    out = []
    for block in re.split(r"\n\s*\n", text.strip()):
        if block.lstrip().startswith("\b"):
            out.append("```text\n" + block.lstrip()[1:].strip("\n") + "\n```")
        elif block.startswith("    ") or "::" in block.splitlines()[-1]:
            out.append("```text\n" + block.rstrip() + "\n```")
        else:
            out.append(_MARKDOWN_SPECIAL.sub(r"\\\1", html.escape(" ".join(block.split()), quote=False)))
    return "\n\n".join(out)


def command_page(name: str, app: typer.Typer) -> str:
    """The Markdown reference page of the command ``name`` whose Typer app is ``app``."""
    command = typer.main.get_command(app)
    ctx = command.context_class(command, info_name=name, **command.context_settings)
    groups: dict[str, list[tuple[str, str]]] = {}
    for param in command.get_params(ctx):
        record = param.get_help_record(ctx)
        if record is None or getattr(param, "hidden", False):
            continue
        default_panel = "Arguments" if param.param_type_name == "argument" else "Options"
        panel = getattr(param, "rich_help_panel", None) or default_panel
        groups.setdefault(panel, []).append(record)
    lines = [f"# {name}", "", _paragraphs(command.help), "", "```text", command.get_usage(ctx), "```", ""]
    for panel, records in groups.items():
        lines += [f"## {panel}", "", "| argument or option | description |", "|---|---|"]
        lines += [f"| `{opts}` | {_cell(help_text)} |" for opts, help_text in records]
        lines.append("")
    epilog = _paragraphs(command.epilog)
    if epilog:
        lines += [epilog, ""]
    lines += [f"*Generated from `{name} --help` when the documentation was built.*", ""]
    return "\n".join(lines)


def pages() -> dict[str, str]:
    """Script name -> its reference page, for every console script."""
    return {name: command_page(name, importlib.import_module(module).app)
            for name, module in console_scripts().items()}


def main(argv: list[str]) -> int:
    for name, text in pages().items():
        if not argv or name in argv:
            print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
