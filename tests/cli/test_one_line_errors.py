"""Every error is one printable line naming the file, also when the file's own bytes (CR, line
feeds, escape sequences) end up in the message; damaged observation files exit 4, not 1."""

from __future__ import annotations

import gzip
from pathlib import Path

import pytest
import typer

from gnss_cli.cli.exits import one_line, run_app
from gnss_cli.cli.solve import app
from gnss_cli.errors import RinexFormatError

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


def _run(application: typer.Typer, args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    with pytest.raises(SystemExit) as exc:
        run_app(application, "prog", [str(a) for a in args])
    return int(exc.value.code), capsys.readouterr().err


def _raising(exc: Exception) -> typer.Typer:
    application = typer.Typer()

    @application.command()
    def main(x: int = 0) -> None:
        raise exc

    return application


def test_control_characters_from_a_file_are_escaped_on_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    code, err = _run(_raising(RinexFormatError("obs.rnx: bad epoch line 7:\r\n '> 20\x1b[2J\x00'")), [], capsys)
    assert code == 4
    assert err == "prog: error: obs.rnx: bad epoch line 7: '> 20\\x1b[2J\\x00'\n"


def test_an_internal_error_is_one_line_too(capsys: pytest.CaptureFixture[str]) -> None:
    code, err = _run(_raising(KeyError("a\rb\nc")), [], capsys)
    assert code == 1
    assert err.count("\n") == 1 and "\r" not in err and err.startswith("prog: internal error: KeyError: ")


def test_one_line_keeps_printable_text() -> None:
    assert one_line("  x.rnx:\tline 3:   ok  ") == "x.rnx: line 3: ok"
    assert one_line("süd.rnx: \u2028x") == "süd.rnx: x"  # a line separator is whitespace too


def _damaged(tmp_path: Path, name: str, transform) -> Path:  # type: ignore[no-untyped-def]
    text = (SAMPLE / "obs.rnx").read_text()
    path = tmp_path / name
    data = transform(text).encode()
    path.write_bytes(gzip.compress(data) if name.endswith(".gz") else data)
    return path


def _repeat_body(text: str) -> str:
    head, sep, body = text.partition("END OF HEADER\n")
    return head + sep + body * 3


def _restamp_second_epoch(text: str) -> str:
    lines = text.splitlines(keepends=True)
    epochs = [i for i, line in enumerate(lines) if line.startswith(">")]
    lines[epochs[1]] = lines[epochs[0]][:29] + lines[epochs[1]][29:]
    return "".join(lines)


@pytest.mark.parametrize(
    ("name", "transform", "pattern"),
    [
        ("twice.rnx.gz", _repeat_body, "is not later than the epoch"),
        ("restamped.rnx", _restamp_second_epoch, "is not later than the epoch"),
        ("cut.rnx", lambda t: t[: t.rindex(".", 0, len(t) - 20) - 3], "the file ends inside observation"),
    ],
    ids=["body-three-times", "restamped", "cut-in-a-value"],
)
def test_damaged_observation_files_exit_4_with_file_and_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                             name: str, transform, pattern: str) -> None:  # type: ignore[no-untyped-def]
    obs = _damaged(tmp_path, name, transform)
    out = tmp_path / "out"
    code, err = _run(app, [obs, SAMPLE / "nav.rnx", "--out-dir", out], capsys)
    assert code == 4
    assert err.startswith(f"prog: error: {name}: line ") and pattern in err and err.count("\n") == 1
    assert not out.exists()
