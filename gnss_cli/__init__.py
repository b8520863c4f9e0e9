"""gnss-solve: batch GNSS positioning from RINEX with a family of least-squares solvers.

Layers (imports flow one way, left to right)::

    errors, constants -> io -> gnss, config -> solvers / behavior -> sim -> pipeline -> report -> api -> cli

The Python API is :func:`solve` (:mod:`gnss_cli.api`): ``gnss_cli.solve(obs, nav, **options)``
returns an ``xarray.Dataset``. It is imported on first use, so ``import gnss_cli`` (and the
command-line startup) does not load numpy, xarray or pandas.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"
__all__ = ["solve", "__version__"]

if TYPE_CHECKING:
    from gnss_cli.api import solve


def __getattr__(name: str) -> Any:
    if name == "solve":
        from gnss_cli.api import solve

        return solve
    raise AttributeError(f"module 'gnss_cli' has no attribute {name!r}")
