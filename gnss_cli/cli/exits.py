"""Turning library failures into one stderr line and a documented exit code.

Every console script calls :func:`run_app`. A :class:`~gnss_cli.errors.GnssError` becomes
``<prog>: error: <message>`` on stderr and its ``exit_code``; any other exception is a bug:
exit 1 with a one-line message, and the traceback only when ``--debug`` is on the command
line (or ``GNSS_SOLVE_DEBUG=1``).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from typing import NoReturn

import click
import typer

from gnss_cli.errors import GnssError


def _debug_requested(argv: list[str]) -> bool:
    return "--debug" in argv or os.environ.get("GNSS_SOLVE_DEBUG", "") not in ("", "0")


def run_app(app: typer.Typer | Callable[..., object], prog_name: str, argv: list[str] | None = None) -> NoReturn:
    """Run a Typer app as a console script with gnss-solve's exit-code contract.

    Parameters
    ----------
    app
        The Typer application.
    prog_name
        Name used in messages (``gnss-solve``).
    argv
        Arguments (default: ``sys.argv[1:]``).
    """
    args = list(sys.argv[1:] if argv is None else argv)
    debug = _debug_requested(args)
    try:
        command = typer.main.get_command(app) if isinstance(app, typer.Typer) else app
        command.main(args=args, prog_name=prog_name, standalone_mode=False)  # type: ignore[union-attr]
    except GnssError as exc:
        if debug:
            raise
        sys.stderr.write(f"{prog_name}: error: {exc}\n")
        sys.exit(exc.exit_code)
    except click.exceptions.Abort:
        sys.stderr.write(f"{prog_name}: aborted\n")
        sys.exit(130)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except click.ClickException as exc:
        exc.show(file=sys.stderr)
        sys.exit(2)
    except BrokenPipeError:
        # Downstream of a pipe closed early (e.g. `| head`): not an error.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        sys.exit(0)
    except KeyboardInterrupt:
        sys.stderr.write(f"{prog_name}: interrupted\n")
        sys.exit(130)
    except Exception as exc:  # noqa: BLE001 - the bug path of the exit-code contract
        if debug:
            raise
        sys.stderr.write(
            f"{prog_name}: internal error: {type(exc).__name__}: {exc} (run with --debug for a traceback)\n"
        )
        sys.exit(1)
    sys.exit(0)
