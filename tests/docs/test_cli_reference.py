"""The CLI reference pages are made from the Typer apps: every option of every command is on its
page with its help, panels become sections, and the Markdown tables stay tables."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest
import typer

REPO = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("cli_reference", REPO / "tools" / "cli_reference.py")
assert _spec is not None and _spec.loader is not None
cli_reference = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cli_reference)

SCRIPTS = cli_reference.console_scripts()


def test_every_console_script_has_a_page() -> None:
    assert set(SCRIPTS) == {"gnss-solve", "gnss-batch", "gnss-simulate", "gnss-identify"}
    assert set(cli_reference.pages()) == set(SCRIPTS)


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_the_page_has_every_visible_option_of_the_command(name: str) -> None:
    app = importlib.import_module(SCRIPTS[name]).app
    page = cli_reference.command_page(name, app)
    command = typer.main.get_command(app)
    ctx = command.context_class(command, info_name=name, **command.context_settings)
    rows = [line for line in page.splitlines() if line.startswith("| `")]
    for param in command.get_params(ctx):
        if getattr(param, "hidden", False) or param.get_help_record(ctx) is None:
            continue
        spelled = param.get_help_record(ctx)[0]
        assert any(row.startswith(f"| `{spelled}` |") for row in rows), (name, spelled)
    assert all(len(re.findall(r"(?<!\\)\|", row)) == 3 for row in rows), "a help text broke its table row"
    assert page.startswith(f"# {name}\n") and f"Usage: {name}" in page


def test_panels_epilog_and_markdown_characters() -> None:
    app = typer.Typer(add_completion=False, rich_markup_mode=None)

    @app.command(epilog="See the manual.")
    def run(
        path: Path = typer.Argument(..., help="Input file."),
        iono: str = typer.Option("klobuchar", help="klobuchar | none; x_m *not* emphasis.", rich_help_panel="Models"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress <stderr>.", rich_help_panel="Output"),
        secret: int = typer.Option(0, hidden=True),
    ) -> None:
        """Do a thing.

        Second paragraph."""

    page = cli_reference.command_page("toy", app)
    headings = re.findall(r"^## (.+)$", page, flags=re.M)
    assert headings == ["Arguments", "Models", "Output", "Options"]  # declaration order; --help last
    assert r"klobuchar \| none; x\_m \*not\* emphasis." in page
    assert "No progress &lt;stderr&gt;." in page
    assert "--secret" not in page
    assert "Do a thing.\n\nSecond paragraph." in page and "See the manual." in page
