"""The exit-code table of docs/outputs.md, row by row, as a user meets it: each case runs a console
script in its own process (so signals and the real Click/Typer error paths are exercised)
from an empty working folder, and checks the exit code, the message on stderr and that no
file was left behind — temporary ones included.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_rinex" / "static"
OBS, NAV, TRUTH = SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", SAMPLE / "truth.csv"
MODULES = {"solve": "gnss_cli.cli.solve", "simulate": "gnss_cli.cli.simulate", "identify": "gnss_cli.cli.identify",
           "batch": "gnss_cli.cli.batch"}

# (id, command, arguments, exit code, regular expression the stderr must match)
# Arguments: "{obs}", "{nav}", "{truth}" are the sample files, "{here}/" the working folder.
CASES = [
    ("no arguments", "solve", [], 2, r"expected OBS NAV"),
    ("only OBS", "solve", ["{obs}"], 2, r"expected OBS NAV"),
    ("unknown option, did you mean", "solve", ["{obs}", "{nav}", "--metod", "ls"], 2, r"No such option: --metod.*--method"),
    ("--lag not a number", "solve", ["{obs}", "{nav}", "--lag", "abc"], 2, r"Invalid value for '--lag'"),
    ("two references", "solve", ["{obs}", "{nav}", "--reference", "1,2,3", "--reference-csv", "{truth}"], 2, r"give one of --reference"),
    ("-o and --out-dir", "solve", ["{obs}", "{nav}", "-o", "a.csv", "--out-dir", "d"], 2, r"not both"),
    ("unknown format", "solve", ["{obs}", "{nav}", "--format", "gpx"], 2, r"--format: expected one of csv, pos"),
    ("parquet to stdout", "solve", ["{obs}", "{nav}", "--format", "parquet"], 2, r"--format parquet: binary output needs -o FILE"),
    ("pos to stdout, several methods", "solve", ["{obs}", "{nav}", "--format", "pos", "--method", "ls,wls"], 2, r"--format pos: one method per file"),
    ("--window without --lag", "solve", ["{obs}", "{nav}", "--window", "30"], 2, r"--window: only with --method stls --lag L"),
    ("--model, a retired spelling", "solve", ["{obs}", "{nav}", "--model", "pva"], 2, r"--model pva was replaced: use --method smoother --motion ca"),
    ("--smoother, a retired spelling", "solve", ["{obs}", "{nav}", "--smoother", "none"], 2, r"--smoother none was replaced: use --kf-output filtered"),
    ("--motion without smoother", "solve", ["{obs}", "{nav}", "--motion", "cv"], 2, r"--motion: only with --method smoother"),
    ("--measurements with single-epoch methods", "solve", ["{obs}", "{nav}", "--measurements", "pseudorange"], 2, r"--measurements: only with a multi-epoch method"),
    ("full kernel order too high", "solve", ["{obs}", "{nav}", "--method", "stls", "--lag", "3", "--kernel", "full", "--order", "20"], 3, r"stls.order: expected 1 <= order < 3 \(lag \+ 1\) = 12"),
    ("--lag without stls", "solve", ["{obs}", "{nav}", "--lag", "3", "--method", "wls"], 2, r"--lag: only with --method stls or smoother"),
    ("smoother lag above 3", "solve", ["{obs}", "{nav}", "--lag", "4", "--method", "smoother"], 3, r"smoother.lag: expected 1, 2 or 3"),
    ("measurements without pseudorange", "solve", ["{obs}", "{nav}", "--method", "kf", "--measurements", "doppler"], 3, r"add pseudorange"),
    ("unknown method", "solve", ["{obs}", "{nav}", "--method", "foo"], 3, r"unknown method 'foo'"),
    ("bad time system", "solve", ["{obs}", "{nav}", "--time-system", "tai"], 3, r"time_system: expected one of gpst, utc"),
    ("elevation mask out of range", "solve", ["{obs}", "{nav}", "--elevation-mask", "95"], 3, r"elevation_mask_deg: expected 0 <= value < 90"),
    ("negative lag", "solve", ["{obs}", "{nav}", "--method", "stls", "--lag", "-1"], 3, r"stls.lag: expected an integer >= 0"),
    ("bad reference", "solve", ["{obs}", "{nav}", "--reference", "1,2"], 3, r"--reference: expected"),
    ("geodetic reference without its prefix", "solve", ["{obs}", "{nav}", "--reference", "22.3,114.2,4.9"], 3, r"--reference: .*write geodetic:LAT,LON,H"),
    ("bad TOML", "solve", ["{obs}", "{nav}", "--config", "{here}/bad.toml"], 3, r"bad.toml: invalid TOML"),
    ("-o names an input", "solve", ["{here}/obs.rnx", "{nav}", "-o", "{here}/obs.rnx"], 3, r"is one of the input files"),
    ("--plots without matplotlib", "solve", ["{obs}", "{nav}", "--plots", "{here}/figs"], 3, r"--plots: needs matplotlib.*pip install 'gnss-solve\[plot\]' \(from a clone: pip install -e '\.\[plot\]'\)$"),
    ("missing OBS", "solve", ["{here}/nothere.rnx", "{nav}"], 4, r"nothere.rnx: no such file"),
    ("folder as NAV", "solve", ["{obs}", "{here}/"], 4, r"not a regular file"),
    ("OBS and NAV swapped", "solve", ["{nav}", "{obs}"], 4, r"OBS and NAV swapped"),
    ("not RINEX", "solve", ["{truth}", "{nav}"], 4, r"truth.csv"),
    ("missing --config file", "solve", ["{obs}", "{nav}", "--config", "{here}/nothere.toml"], 4, r"configuration file not found"),
    ("-o inside a file", "solve", ["{obs}", "{nav}", "-o", "{here}/obs.rnx/x.csv"], 6, r"obs.rnx is not a folder"),
    ("--out-dir is a file", "solve", ["{obs}", "{nav}", "--out-dir", "{here}/obs.rnx"], 6, r"not a folder"),
    ("disk full", "solve", ["{obs}", "{nav}", "-o", "/dev/full"], 6, r"/dev/full: cannot write output \(No space left on device\)"),
    ("simulate without --out-dir", "simulate", [], 2, r"Missing option '--out-dir'"),
    ("simulate unknown option", "simulate", ["--out-dir", "s", "--duraton", "5"], 2, r"No such option: --duraton"),
    ("simulate negative duration", "simulate", ["--out-dir", "s", "--duration", "-5"], 3, r"duration >= 0"),
    ("simulate unknown system", "simulate", ["--out-dir", "s", "--systems", "Q"], 3, r"--systems: expected"),
    ("simulate bad config", "simulate", ["--out-dir", "s", "--config", "{here}/bad.toml"], 3, r"bad.toml"),
    ("identify no arguments", "identify", [], 2, r"Missing argument"),
    ("identify missing file", "identify", ["{here}/nothere.csv"], 4, r"nothere.csv: no such file"),
    ("identify lag 0", "identify", ["{truth}", "--lag", "0"], 3, r"--lag: expected an integer >= 1"),
    ("batch without --out", "batch", ["{obs}", "--nav", "{nav}"], 2, r"--out DIR: the output folder is required"),
    ("batch without navigation files", "batch", ["{obs}", "--out", "{here}/out"], 2, r"expected navigation files"),
    ("batch --jobs and --scheduler", "batch", ["{obs}", "--nav", "{nav}", "--out", "{here}/out", "--jobs", "2", "--scheduler", "tcp://127.0.0.1:9"], 2, r"give --jobs or --scheduler, not both"),
    ("batch --jobs 0", "batch", ["{obs}", "--nav", "{nav}", "--out", "{here}/out", "--jobs", "0"], 3, r"--jobs: expected an integer >= 1; received 0"),
    ("batch --scheduler without dask", "batch", ["{obs}", "--nav", "{nav}", "--out", "{here}/out", "--scheduler", "tcp://127.0.0.1:9"], 3, r"--scheduler: needs dask.distributed.*pip install 'gnss-solve\[cluster\]' \(from a clone: pip install -e '\.\[cluster\]'\)$"),
    ("batch scheduler unreachable", "batch", ["{obs}", "--nav", "{nav}", "--out", "{here}/out", "--scheduler", "tcp://127.0.0.1:9"], 3, r"--scheduler: cannot connect to tcp://127.0.0.1:9"),
    ("batch pattern matches nothing", "batch", ["{here}/none*.rnx", "--nav", "{nav}", "--out", "{here}/out"], 4, r"none\*.rnx: no observation file matches this pattern"),
    ("batch missing --nav file", "batch", ["{obs}", "--nav", "{here}/nothere.rnx", "--out", "{here}/out"], 4, r"--nav: .*nothere.rnx: no such file"),
    ("batch --out is a file", "batch", ["{obs}", "--nav", "{nav}", "--out", "{here}/obs.rnx"], 6, r"obs.rnx: cannot write output \(not a folder\)"),
    ("batch, a file fails", "batch", ["{truth}", "{obs}", "--nav", "{nav}", "--out", "{here}/out"], 4, r"truth.csv: failed \(exit 4\): \S*truth.csv: .*1 of 2 files solved, 1 failed"),
]

WRITES = {"batch, a file fails": {"out", "out/files.csv", "out/summary.csv", "out/positions", "out/positions/SIM",
                                  "out/positions/SIM/day=2024-03-01",
                                  "out/positions/SIM/day=2024-03-01/00001-obs.rnx-0.parquet"}}
"""Cases that write their outputs (the other files are solved): what they leave."""


def _prepare(here: Path) -> set[str]:
    shutil.copy(OBS, here / "obs.rnx")
    (here / "bad.toml").write_text("[processing\nmethods = \n")
    return {"obs.rnx", "bad.toml"}


WITHOUT = {"--plots without matplotlib": "matplotlib", "batch --scheduler without dask": "distributed"}
"""Cases run with a package of that name that cannot be imported ahead on the path."""
NEEDS = {"batch scheduler unreachable": "distributed"}
"""Cases that need an optional package (skipped without it)."""


@pytest.fixture(scope="session")
def hidden_packages_path(tmp_path_factory: pytest.TempPathFactory) -> str:
    folder = tmp_path_factory.mktemp("hidden-packages")
    for name in set(WITHOUT.values()):
        (folder / name).mkdir()
        (folder / name / "__init__.py").write_text(f"raise ImportError(\"No module named '{name}'\")\n")
    return str(folder)


def _run(command: str, args: list[str], cwd: Path, pythonpath: str | None = None,
         **kw: object) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    if pythonpath is not None:
        env["PYTHONPATH"] = os.pathsep.join([pythonpath, *filter(None, [env.get("PYTHONPATH")])])
    return subprocess.run([sys.executable, "-m", MODULES[command], *args], cwd=cwd, capture_output=True, text=True,
                          timeout=120, env=env, **kw)  # type: ignore[call-overload]


def _fill(args: list[str], here: Path) -> list[str]:
    return [a.format(obs=OBS, nav=NAV, truth=TRUTH, here=here) for a in args]


def _all_files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


@pytest.mark.parametrize(("command", "args", "code", "pattern"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_exit_code_and_message(request: pytest.FixtureRequest, tmp_path: Path, command: str, args: list[str], code: int,
                               pattern: str) -> None:
    case = request.node.callspec.id
    if case in NEEDS:
        pytest.importorskip(NEEDS[case])
    before = _prepare(tmp_path)
    hidden = request.getfixturevalue("hidden_packages_path") if case in WITHOUT else None
    proc = _run(command, _fill(args, tmp_path), tmp_path, pythonpath=hidden)
    assert proc.returncode == code, proc.stderr
    assert re.search(pattern, proc.stderr, re.S), proc.stderr
    assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr
    assert proc.stdout == ""
    assert _all_files(tmp_path) == before | WRITES.get(case, set())  # nothing else written, no temporary file left
    assert (tmp_path / "obs.rnx").read_bytes() == OBS.read_bytes()


def test_help_version_and_short_help_show_every_default(tmp_path: Path) -> None:
    for command in MODULES:
        long, short = _run(command, ["--help"], tmp_path), _run(command, ["-h"], tmp_path)
        assert long.returncode == short.returncode == 0
        assert long.stdout == short.stdout
        version = _run(command, ["--version"], tmp_path)
        assert version.returncode == 0 and re.fullmatch(rf"gnss-{command} \d+\.\d+\.\d+\n", version.stdout)
    text = " ".join(_run("solve", ["--help"], tmp_path).stdout.split())
    for flag, default in [("--method", "wls"), ("--systems", "all"), ("--iono", "klobuchar"),
                          ("--tropo", "saastamoinen"), ("--elevation-mask", "10.0")]:
        assert re.search(rf"{flag} .*?\[default: \(?{re.escape(default)}\)?\]", text), (flag, text)


def _simulated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("long")
    proc = _run("simulate", ["--out-dir", str(folder), "--duration", "3600", "--interval", "1", "--systems", "G,E",
                             "--quiet"], folder)
    assert proc.returncode == 0, proc.stderr
    return folder


@pytest.fixture(scope="module")
def long_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated 1 h, 1 Hz GPS+Galileo data set: a run long enough to interrupt."""
    return _simulated(tmp_path_factory)


@pytest.mark.parametrize(("signum", "code", "word"), [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")])
def test_signal_exits_with_one_line_and_no_file(long_run: Path, tmp_path: Path, signum: int, code: int, word: str) -> None:
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", MODULES["solve"], str(long_run / "obs.rnx"), str(long_run / "nav.rnx"),
           "--method", "all", "--out-dir", str(out)]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    first = proc.stderr.readline()  # the first progress line: the run has lasted a second
    assert re.match(r"gnss-solve: \[ *\d+\.\d s\] ", first), first
    time.sleep(0.2)
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code, stderr
    lines = [ln for ln in stderr.splitlines() if not re.match(r"gnss-solve: \[ *\d+\.\d s\] ", ln)]
    assert len(lines) == 1 and re.fullmatch(rf"gnss-solve: {word} \(SIG(INT|TERM)\); no output written", lines[0]), stderr
    assert "Traceback" not in stderr and stdout == ""
    assert not out.exists() and _all_files(tmp_path) == set()


def test_progress_lines_when_stderr_is_a_file(long_run: Path, tmp_path: Path) -> None:
    proc = _run("solve", [str(long_run / "obs.rnx"), str(long_run / "nav.rnx"), "--method", "all", "-o", "p.csv"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if re.match(r"gnss-solve: \[ *\d+\.\d s\] ", ln)]
    assert lines, proc.stderr
    quiet = _run("solve", [str(long_run / "obs.rnx"), str(long_run / "nav.rnx"), "--method", "all", "-q", "-o", "q.csv"], tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == ""
    # --quiet changes stderr only. Compared on the LS/WLS rows: the TLS-family DOP of a nearly
    # degenerate epoch can differ in its last printed digit between identical runs.
    loud = [ln for ln in (tmp_path / "p.csv").read_text().splitlines() if ",ls," in ln or ",wls," in ln]
    silent = [ln for ln in (tmp_path / "q.csv").read_text().splitlines() if ",ls," in ln or ",wls," in ln]
    assert loud and loud == silent


def test_files_get_the_umask(tmp_path: Path) -> None:
    for mask, mode in ((0o022, 0o644), (0o077, 0o600), (0o002, 0o664)):
        out = tmp_path / f"out{mask:o}"
        proc = _run("solve", [str(OBS), str(NAV), "--out-dir", str(out), "-q"], tmp_path,
                    preexec_fn=lambda m=mask: os.umask(m))
        assert proc.returncode == 0, proc.stderr
        for f in out.iterdir():
            assert f.stat().st_mode & 0o777 == mode, (f, oct(f.stat().st_mode))


def test_docs_table_lists_every_case_with_its_exit_code() -> None:
    """The table of docs/outputs.md and the cases run above are the same list."""
    text = (REPO / "docs" / "outputs.md").read_text()
    section = text[text.index("## Exit codes"):]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[2].isdigit():
            rows[cells[0]] = int(cells[2])
    expected = {case[0]: case[3] for case in CASES}
    expected.update({"Ctrl-C during a run": 130, "SIGTERM during a run": 143})
    assert rows == expected
    assert len(rows) >= 15


def test_interrupted_batch_ends_its_workers_and_writes_nothing(long_run: Path, tmp_path: Path) -> None:
    """Ctrl-C after the first two of four files (two workers): exit 130, one line, no output
    folder, and the run ends at once instead of finishing the two files being solved."""
    data = tmp_path / "data"
    data.mkdir()
    for name in "ABCD":
        shutil.copy(long_run / "obs.rnx", data / f"{name * 4}00DNK_R_20240610000_01H_01S_MO.rnx")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", MODULES["batch"], str(data / "*.rnx"), "--nav", str(long_run / "nav.rnx"),
           "--out", str(out), "--jobs", "2", "--method", "all"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    done = [proc.stderr.readline(), proc.stderr.readline()]  # the first two files finished: the last two just started
    assert all(re.match(r"gnss-batch: \[ *\d+\.\d s\] [12]/4 .*, (\d+\.\d) s$", ln) for ln in done), done
    file_s = min(float(ln.rsplit(", ", 1)[1][:-2]) for ln in done)
    sent = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)  # returns when every holder of the pipes (the workers) is gone
    assert time.perf_counter() - sent < 0.5 * file_s + 0.5  # not after the running files finish
    assert proc.returncode == 130, stderr
    assert stderr.splitlines() == ["gnss-batch: interrupted (SIGINT); no output written"], stderr
    assert "Traceback" not in stderr and stdout == ""
    assert not out.exists() and _all_files(tmp_path) == {"data", *(f"data/{p.name}" for p in data.iterdir())}
