"""What the package declares is what it needs, and a built wheel works on its own.

* Every third-party module imported anywhere in ``gnss_cli/`` (also inside functions) comes
  from a distribution listed in ``[project.dependencies]`` of ``pyproject.toml``, except
  modules imported only by ``gnss_cli/plots/``, which may come from the optional ``plot``
  extra (matplotlib), and by ``gnss_cli/cli/batch_runner.py`` (the ``cluster`` extra, dask
  and distributed); the ``test`` extra includes both so that their tests run.
* A wheel built from the source tree, installed (without the editable checkout) into a new
  virtual environment, runs ``gnss-solve`` from an unrelated folder and uses the packaged
  default configuration.
"""

from __future__ import annotations

import ast
import csv
import io
import json
import os
import re
import shutil
import site
import subprocess
import sys
import sysconfig
import venv
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "gnss_cli"


def normalize(name: str) -> str:
    """PEP 503 normalized distribution name."""
    return re.sub(r"[-_.]+", "-", name).lower()


def requirement_name(requirement: str) -> str:
    return normalize(re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", requirement).group(1))  # type: ignore[union-attr]


def declared_dependencies() -> set[str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    return {requirement_name(r) for r in project["dependencies"]}


def declared_extra(name: str) -> set[str]:
    """Distributions of the optional extra ``name`` of ``pyproject.toml``."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    return {requirement_name(r) for r in project["optional-dependencies"][name]}


OPTIONAL_FOLDERS = {"plots": "plot", "cli/batch_runner.py": "cluster"}
"""Sub-packages (folders) or single modules of gnss_cli whose imports may come from an
optional extra (path -> extra): matplotlib for the figures, dask.distributed for
``gnss-batch --scheduler``."""


def imported_top_level_modules(package_dir: Path) -> dict[str, list[str]]:
    """Top-level module name -> the files (relative to the repository) that import it.

    Every ``import x.y`` and ``from x.y import z`` with level 0 counts, at any depth of the
    syntax tree (imports inside functions, ``try`` and ``if`` blocks included)."""
    found: dict[str, list[str]] = {}
    for path in sorted(package_dir.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                found.setdefault(name.split(".")[0], []).append(str(path.relative_to(package_dir.parent)))
    return found


def undeclared_imports(package_dir: Path, declared: set[str],
                       optional: dict[str, set[str]] | None = None) -> dict[str, str]:
    """Third-party modules imported under ``package_dir`` that no declared distribution provides.

    ``optional`` maps a sub-package folder (``plots``) to the distributions of its extra: a
    module imported only from files in that folder may come from them.
    """
    providers = packages_distributions()
    problems = {}
    for module, files in imported_top_level_modules(package_dir).items():
        if module in sys.stdlib_module_names or module == "gnss_cli" or module == "__future__":
            continue
        dists = {normalize(d) for d in providers.get(module, [module])}
        allowed = set(declared)
        for folder, extra in (optional or {}).items():
            prefix = f"{package_dir.name}/{folder}"
            if all(f.replace(os.sep, "/") == prefix or f.replace(os.sep, "/").startswith(prefix + "/") for f in files):
                allowed |= extra
        if not dists & allowed:
            problems[module] = f"imported by {sorted(set(files))}, provided by {sorted(dists)}, not in [project.dependencies]"
    return problems


def test_package_imports_are_declared_dependencies() -> None:
    modules = imported_top_level_modules(PACKAGE)
    assert {"numpy", "scipy", "typer", "hatanaka"} <= set(modules)  # the scan sees nested imports
    optional = {folder: declared_extra(extra) for folder, extra in OPTIONAL_FOLDERS.items()}
    assert undeclared_imports(PACKAGE, declared_dependencies(), optional) == {}
    assert "matplotlib" in modules and "matplotlib" in declared_extra("test")  # the figure tests can run
    assert "distributed" in modules and declared_extra("cluster") <= declared_extra("test")  # and the Dask ones


def test_an_extra_import_outside_its_folder_is_found(tmp_path: Path) -> None:
    """matplotlib is allowed in gnss_cli/plots/ (the plot extra), not in the always-installed code."""
    pkg = tmp_path / "gnss_cli"
    (pkg / "plots").mkdir(parents=True)
    (pkg / "plots" / "fig.py").write_text("from matplotlib.figure import Figure\n")
    optional = {"plots": declared_extra("plot")}
    assert undeclared_imports(pkg, declared_dependencies(), optional) == {}
    (pkg / "report.py").write_text("def f():\n    import matplotlib\n")
    assert set(undeclared_imports(pkg, declared_dependencies(), optional)) == {"matplotlib"}


def test_an_undeclared_import_is_found(tmp_path: Path) -> None:
    """The check above would catch e.g. ``import click`` in a function (Typer no longer needs it)."""
    pkg = tmp_path / "gnss_cli"
    pkg.mkdir()
    (pkg / "mod.py").write_text("import numpy as np\n\ndef f():\n    from click.exceptions import Abort\n    return Abort\n")
    problems = undeclared_imports(pkg, declared_dependencies())
    assert set(problems) == {"click"}


# --- a wheel in a fresh environment ---------------------------------------------------------


def _can_build_without_isolation() -> bool:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return int(version("setuptools").split(".")[0]) >= 68 and bool(version("wheel"))
    except PackageNotFoundError:
        return False


def _build_wheel(out_dir: Path, tmp_path: Path) -> Path:
    """Build from a copy of the sources (the checkout gets no build/ or egg-info)."""
    src = tmp_path / "src"
    shutil.copytree(PACKAGE, src / "gnss_cli", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out_dir), str(src)]
    if _can_build_without_isolation():  # the test extra brings setuptools>=68 and wheel
        cmd.insert(4, "--no-build-isolation")
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    (wheel,) = out_dir.glob("gnss_solve-*.whl")
    return wheel


def _venv_python(env_dir: Path) -> Path:
    return env_dir / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def _venv_purelib(python: Path, env: dict[str, str]) -> Path:
    out = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                         env=env, capture_output=True, text=True, check=True)
    return Path(out.stdout.strip())


def test_wheel_in_a_fresh_venv_runs_with_packaged_defaults(tmp_path: Path) -> None:
    env_dir = tmp_path / "venv"
    try:
        venv.create(env_dir, with_pip=True, symlinks=os.name != "nt")
    except Exception as exc:  # noqa: BLE001 - e.g. no venv support in this Python
        pytest.skip(f"cannot create a virtual environment here: {type(exc).__name__}: {exc}")
    python = _venv_python(env_dir)
    if not python.exists():
        pytest.skip(f"cannot create a virtual environment here: no {python}")
    # The new environment sees nothing of this one's search path (PYTHONPATH may name the checkout).
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    env["PYTHONNOUSERSITE"] = "1"

    wheel = _build_wheel(tmp_path / "wheel", tmp_path)
    proc = subprocess.run(
        [str(python), "-m", "pip", "install", "--no-deps", "--no-index", "--quiet", str(wheel)],
        env=env, capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr

    # The dependencies come from this environment's site-packages, added as plain path lines:
    # such paths are not site dirs, so their .pth files (an editable gnss_cli) stay inactive.
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"], *site.getsitepackages()}
    (_venv_purelib(python, env) / "zz_test_dependencies.pth").write_text("\n".join(sorted(ours)) + "\n")

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    probe = (
        "import json, gnss_cli, gnss_cli.config as c; cfg = c.load_config(); "
        "print(json.dumps({'module': gnss_cli.__file__, 'defaults': str(c.DEFAULT_CONFIG_PATH), "
        "'methods': list(cfg.methods), 'elevation_mask_deg': cfg.elevation_mask_deg, 'iono': cfg.iono, "
        "'signals_G': list(cfg.signals['G']), 'second_E': list(cfg.signals_second['E']), "
        "'orbit_sigma_m': cfg.orbit_sigma_m, 'weights_model': cfg.weights.model}))"
    )
    out = subprocess.run([str(python), "-c", probe], cwd=run_dir, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    env_root = env_dir.resolve()
    assert Path(info["module"]).resolve().is_relative_to(env_root), info["module"]
    defaults = Path(info["defaults"]).resolve()
    assert defaults.is_relative_to(env_root) and defaults.name == "default.toml", info["defaults"]
    assert defaults.read_bytes() == (PACKAGE / "configs" / "default.toml").read_bytes()
    assert (defaults.parent / "simulate.toml").read_bytes() == (PACKAGE / "configs" / "simulate.toml").read_bytes()
    data = tomllib.loads(defaults.read_text(encoding="utf-8"))
    assert info["methods"] == data["processing"]["methods"]
    assert info["elevation_mask_deg"] == data["processing"]["elevation_mask_deg"]
    assert info["iono"] == data["processing"]["iono"]
    assert info["signals_G"] == data["signals"]["G"]
    assert info["second_E"] == data["signals"]["second"]["E"]
    assert info["orbit_sigma_m"] == data["stls"]["orbit_sigma_m"]
    assert info["weights_model"] == data["weights"]["model"]

    script = env_dir / ("Scripts/gnss-solve.exe" if os.name == "nt" else "bin/gnss-solve")
    sample = ROOT / "sample_rinex" / "static"
    proc = subprocess.run(
        [str(script), str(sample / "obs.rnx"), str(sample / "nav.rnx"), "--method", "ls,wls",
         "--reference-csv", str(sample / "truth.csv")],
        cwd=run_dir, env=env, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader(io.StringIO(proc.stdout)))
    n_epochs = sum(1 for _ in open(sample / "truth.csv")) - 1
    assert len(rows) == 2 * n_epochs
    assert {r["method"] for r in rows} == {"ls", "wls"}
    assert list(run_dir.iterdir()) == []  # data went to stdout only
