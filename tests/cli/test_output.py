"""All-or-nothing output files (:mod:`gnss_cli.cli.output`): failures and signals at any
step leave no file, finished sets appear whole, modes follow the umask."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from gnss_cli.cli import output as output_module
from gnss_cli.cli.exits import Interrupted
from gnss_cli.cli.signals import on_signal
from gnss_cli.cli.output import OutputSet
from gnss_cli.errors import ConfigError, OutputError


def _files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def test_a_set_appears_whole_and_overwrites_atomically(tmp_path: Path) -> None:
    (tmp_path / "a.csv").write_text("old\n")
    with OutputSet() as out:
        for name in ("a.csv", "sub/b.csv"):
            out.add(tmp_path / name, "-o")
            out.write_text(tmp_path / name, f"{name}\n")
        assert (tmp_path / "a.csv").read_text() == "old\n"  # nothing replaced before the commit
        assert not (tmp_path / "sub" / "b.csv").exists()
    assert (tmp_path / "a.csv").read_text() == "a.csv\n"
    assert (tmp_path / "sub" / "b.csv").read_text() == "sub/b.csv\n"
    assert _files(tmp_path) == {"a.csv", "sub", "sub/b.csv"}


@pytest.mark.parametrize("fail_at", [0, 1])
def test_failure_while_renaming_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fail_at: int) -> None:
    real_replace = os.replace
    calls = []

    def flaky(src: str, dst: str) -> None:
        calls.append(dst)
        if len(calls) > fail_at:
            raise OSError(28, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(output_module.os, "replace", flaky)
    with pytest.raises(OutputError, match="No space left on device"):
        with OutputSet() as out:
            for name in ("new/a.csv", "new/b.csv"):
                out.add(tmp_path / name, "--out-dir")
                out.write_text(tmp_path / name, "x\n")
    assert _files(tmp_path) == set()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_signal_after_staging_leaves_nothing(tmp_path: Path, signum: int) -> None:
    with pytest.raises(Interrupted):
        with OutputSet() as out:
            out.add(tmp_path / "d" / "a.csv", "--out-dir")
            out.write_text(tmp_path / "d" / "a.csv", "x\n")
            staging = out.staging_dir(tmp_path / "d")
            (staging / "obs.rnx").write_text("y\n")
            raise Interrupted(signum)
    assert _files(tmp_path) == set()


def test_signal_is_held_while_renaming(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A SIGINT during the commit is raised after it, with the set whole, even while another
    thread runs (the kernel may hand a process signal to any thread)."""
    import threading

    stop = threading.Event()
    worker = threading.Thread(target=stop.wait, daemon=True)
    worker.start()
    old = signal.signal(signal.SIGINT, on_signal)
    real_replace = os.replace
    seen = []

    def replace_and_signal(src: str, dst: str) -> None:
        os.kill(os.getpid(), signal.SIGINT)
        seen.append(dst)
        real_replace(src, dst)

    try:
        out = OutputSet()
        for name in ("a.csv", "b.csv"):
            out.add(tmp_path / name, "--out-dir")
            out.write_text(tmp_path / name, "x\n")
        monkeypatch.setattr(output_module.os, "replace", replace_and_signal)
        with pytest.raises(Interrupted):
            out.commit()
    finally:
        signal.signal(signal.SIGINT, old)
        stop.set()
    assert len(seen) == 2  # both renames ran although the first raised the signal
    assert _files(tmp_path) == {"a.csv", "b.csv"}


def test_outputs_that_name_inputs_or_repeat_are_refused(tmp_path: Path) -> None:
    src = tmp_path / "obs.rnx"
    src.write_text("data")
    out = OutputSet([src])
    with pytest.raises(ConfigError, match="one of the input files"):
        out.add(tmp_path / "." / "obs.rnx", "-o")
    os.symlink(src, tmp_path / "link.rnx")
    with pytest.raises(ConfigError, match="one of the input files"):
        out.add(tmp_path / "link.rnx", "-o")
    out.add(tmp_path / "a.csv", "-o")
    with pytest.raises(ConfigError, match="two outputs"):
        out.add(tmp_path / "a.csv", "--model-out")
    assert src.read_text() == "data"


def test_mode_follows_umask_and_existing_files_keep_theirs(tmp_path: Path) -> None:
    old_mask = os.umask(0o027)
    try:
        keep = tmp_path / "keep.csv"
        keep.write_text("old")
        keep.chmod(0o604)
        with OutputSet() as out:
            for name in ("new.csv", "keep.csv"):
                out.add(tmp_path / name, "-o")
                out.write_text(tmp_path / name, "x")
    finally:
        os.umask(old_mask)
    assert (tmp_path / "new.csv").stat().st_mode & 0o777 == 0o640
    assert keep.stat().st_mode & 0o777 == 0o604


def test_a_device_is_written_directly(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="/dev/full: cannot write output"):
        with OutputSet() as out:
            out.add(Path("/dev/full"), "-o")
            out.write_text(Path("/dev/full"), "x" * 100000)
    with OutputSet() as out:
        out.add(Path("/dev/null"), "-o")
        out.write_text(Path("/dev/null"), "x")
    assert Path("/dev/null").exists() and not Path("/dev/null").is_file()


def test_progress_off_a_terminal_is_one_line_per_stage_plus_heartbeats() -> None:
    import io
    import time

    from gnss_cli.cli.progress import Progress

    stream = io.StringIO()
    p = Progress("gnss-solve", interval_s=0.3, min_gap_s=0.0, start_delay_s=0.2, stream=stream)
    p("reading", 0.0)
    assert stream.getvalue() == ""  # nothing in the first start_delay_s
    time.sleep(0.5)  # the heartbeat writes the first line
    p("solving wls", 0.5)
    time.sleep(0.8)  # at least one more heartbeat
    p.done()
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("gnss-solve: [") and "reading" in lines[0]
    assert any("solving wls  50.0 %" in ln for ln in lines[1:])
    assert sum("solving wls" in ln for ln in lines) >= 2
    quiet = io.StringIO()
    q = Progress("gnss-solve", enabled=False, stream=quiet)
    q("reading", 0.0)
    q.done()
    assert quiet.getvalue() == ""


def test_a_staged_folder_replaces_the_old_one_with_the_files(tmp_path: Path) -> None:
    old = tmp_path / "out" / "positions" / "station=OLD"
    old.mkdir(parents=True)
    (old / "x.parquet").write_text("old")
    with OutputSet() as out:
        staged = out.stage_folder(tmp_path / "out" / "positions", "--out")
        (staged / "station=NEW").mkdir()
        (staged / "station=NEW" / "y.parquet").write_text("new")
        out.add(tmp_path / "out" / "files.csv", "--out")
        out.write_text(tmp_path / "out" / "files.csv", "f\n")
        assert (old / "x.parquet").exists()  # nothing replaced before the commit
    assert _files(tmp_path / "out") == {"positions", "positions/station=NEW", "positions/station=NEW/y.parquet",
                                        "files.csv"}


def test_a_failed_set_keeps_the_old_folder_and_leaves_no_staging(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "positions").mkdir()
    (tmp_path / "positions" / "x").write_text("old")
    real_replace = os.replace

    def replace(src, dst):  # type: ignore[no-untyped-def]
        if Path(dst).name == "files.csv":
            raise OSError(28, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(output_module.os, "replace", replace)
    with pytest.raises(OutputError, match="files.csv: cannot write output"):
        with OutputSet() as out:
            (out.stage_folder(tmp_path / "positions", "--out") / "y").write_text("new")
            out.add(tmp_path / "files.csv", "--out")
            out.write_text(tmp_path / "files.csv", "f\n")
    assert _files(tmp_path) == {"positions", "positions/x"}
    assert (tmp_path / "positions" / "x").read_text() == "old"


def test_a_folder_holding_an_input_or_that_is_a_file_is_refused(tmp_path: Path) -> None:
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "obs.rnx").write_text("x")
    (tmp_path / "f").write_text("x")
    with pytest.raises(ConfigError, match="holds the input"):
        with OutputSet([tmp_path / "d" / "obs.rnx"]) as out:
            out.stage_folder(tmp_path / "d", "--out")
    with pytest.raises(OutputError, match="not a folder"):
        with OutputSet() as out:
            out.stage_folder(tmp_path / "f", "--out")
    assert _files(tmp_path) == {"d", "d/obs.rnx", "f"}
