"""Size limit of the package: functions up to 100 lines (benchmarks/code_size.py); modules are cut by
job, not by size, and have no line limit."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _code_size():
    spec = importlib.util.spec_from_file_location("code_size", ROOT / "benchmarks" / "code_size.py")
    assert spec is not None and spec.loader is not None
    module = sys.modules.get("code_size")
    if module is None:
        module = importlib.util.module_from_spec(spec)
        sys.modules["code_size"] = module  # dataclasses look their module up while it runs
        spec.loader.exec_module(module)
    return module


def test_functions_within_limit():
    bad = _code_size().offenders()
    assert not bad, "over the size limit:\n" + "\n".join(bad)


def test_limits_catch_a_long_function(tmp_path):
    code_size = _code_size()
    pkg = tmp_path / "gnss_cli"
    pkg.mkdir()
    body = "".join(f"    x{i} = {i}\n" for i in range(code_size.FUNCTION_MAX_LINES))
    (pkg / "long.py").write_text("def f():\n" + body + "\n\ndef g():\n    return 1\n")
    (pkg / "big.py").write_text("x = 1\n" * 2000)  # a long module is no offence
    bad = code_size.offenders(pkg)
    assert bad == [
        f"function gnss_cli/long.py:1 f: {code_size.FUNCTION_MAX_LINES + 1} lines > {code_size.FUNCTION_MAX_LINES}",
    ]
