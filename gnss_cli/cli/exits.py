"""The exit-code contract of every console script (the README's table).

Every console script calls :func:`run_app`, which works with the Click that Typer brings
(the separate ``click`` package for older Typer, Typer's own copy for newer ones):

- usage mistakes (missing argument, unknown option, a value of the wrong type): Click's
  usual message with its "did you mean", exit 2;
- a :class:`~gnss_cli.errors.GnssError`: ``<prog>: error: <message>`` and its
  ``exit_code`` (3 bad configuration or out-of-range value, 4 bad input, 5 nothing solved,
  6 output not writable);
- SIGINT (Ctrl-C) and SIGTERM: one line, exit 130 and 143; output files are not left
  behind (:mod:`gnss_cli.cli.output` removes what was staged);
- a closed stdout pipe (``| head``): exit 0, quietly;
- anything else is a bug: exit 1 with a one-line message, and the traceback only with
  ``--debug`` on the command line (or ``GNSS_SOLVE_DEBUG=1``).
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from types import ModuleType
from typing import NoReturn

import typer

from gnss_cli.cli.signals import Interrupted, on_signal
from gnss_cli.errors import GnssError

EXIT_INTERRUPTED = 128 + signal.SIGINT
EXIT_TERMINATED = 128 + signal.SIGTERM


class PipeClosed(BaseException):
    """stdout's reader went away (``gnss-solve ... | head``)."""


HELP_OPTIONS = {"help_option_names": ["-h", "--help"]}

_COMMAND: list[str] = []
"""The program name and arguments of the command :func:`run_app` is running."""


def command_line() -> str:
    """The running command as a shell would take it back (``gnss-solve obs.rnx nav.rnx -o 'a b.csv'``),
    for the outputs that record how they were made."""
    import shlex

    return shlex.join(_COMMAND) if _COMMAND else shlex.join([os.path.basename(sys.argv[0]), *sys.argv[1:]])
"""Typer ``context_settings`` of every command: ``-h`` as well as ``--help``."""


def version_callback(prog_name: str) -> Callable[[bool], None]:
    """The callback of an eager ``--version`` flag: print ``<prog> <version>`` and exit 0."""

    def show(value: bool) -> None:
        if value:
            from gnss_cli import __version__

            sys.stdout.write(f"{prog_name} {__version__}\n")
            raise typer.Exit()

    return show


def _click_exceptions() -> ModuleType:
    """The ``exceptions`` module of the Click that this Typer uses."""
    return sys.modules[typer.BadParameter.__module__]


def _debug_requested(argv: list[str]) -> bool:
    return "--debug" in argv or os.environ.get("GNSS_SOLVE_DEBUG", "") not in ("", "0")


def write_stdout(text: str) -> None:
    """Write ``text`` to stdout; a closed pipe ends the run quietly (:class:`PipeClosed`)."""
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except BrokenPipeError:
        raise PipeClosed() from None


def one_line(text: str) -> str:
    """``text`` as one printable line: runs of whitespace (line ends and raw CRs included)
    become one space, other control characters their ``\\xNN`` escape.

    A message can quote bytes of a damaged input file; printed raw, a CR or an escape
    sequence would overwrite the terminal line, a line feed split the message.

    >>> one_line("obs.rnx: bad line\\r\\n  'G01\\x1b[2J'\\x00")
    "obs.rnx: bad line 'G01\\\\x1b[2J'\\\\x00"
    """
    joined = " ".join(text.split())
    return "".join(c if c.isprintable() else f"\\x{ord(c):02x}" if ord(c) < 256 else f"\\u{ord(c):04x}"
                   for c in joined)


def _exit_code_of(exc: BaseException) -> int | None:
    """The exit code carried by a Click/Typer ``Exit``, or None."""
    code = getattr(exc, "exit_code", None)
    return int(code) if isinstance(code, int) else None


def run_app(app: typer.Typer, prog_name: str, argv: list[str] | None = None) -> NoReturn:
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
    _COMMAND[:] = [prog_name, *args]
    debug = _debug_requested(args)
    click_exc = _click_exceptions()
    exits = tuple({click_exc.Exit, typer.Exit} if hasattr(click_exc, "Exit") else {typer.Exit})
    aborts = tuple({click_exc.Abort, typer.Abort} if hasattr(click_exc, "Abort") else {typer.Abort})
    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        command = typer.main.get_command(app)
        rv = command.main(args=args, prog_name=prog_name, standalone_mode=False)
        code = rv if isinstance(rv, int) and not isinstance(rv, bool) else 0
    except Interrupted as exc:
        word = "interrupted" if exc.signum == signal.SIGINT else "terminated"
        newline = "\n" if sys.stderr.isatty() else ""  # end a progress line redrawn in place
        sys.stderr.write(f"{newline}{prog_name}: {word} ({signal.Signals(exc.signum).name}); no output written\n")
        code = 128 + exc.signum
    except PipeClosed:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        code = 0
    except GnssError as exc:
        if debug:
            raise
        sys.stderr.write(f"{prog_name}: error: {one_line(str(exc))}\n")
        code = exc.exit_code
    except exits as exc:
        code = _exit_code_of(exc) or 0
    except aborts:
        sys.stderr.write(f"{prog_name}: aborted\n")
        code = EXIT_INTERRUPTED
    except click_exc.ClickException as exc:
        exc.show(file=sys.stderr)
        code = exc.exit_code if exc.exit_code else 2
    except Exception as exc:  # noqa: BLE001 - the bug path of the exit-code contract
        if debug:
            raise
        sys.stderr.write(f"{prog_name}: internal error: {type(exc).__name__}: {one_line(str(exc))} "
                         "(run with --debug for a traceback)\n")
        code = 1
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    sys.exit(code)


def single_blas_thread() -> None:
    """One BLAS thread per process unless the user set one (before numpy is imported): millions
    of 8x8 to 113x8 factorizations, where BLAS threads only synchronise (a 24 h run took
    1.1-1.4x the wall time with OpenBLAS's default threads on 2 cores), and the processes
    (forked parts, batch workers) are the parallelism."""
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")


def without_dask() -> None:
    """Mark dask as not installed in this process.

    One ``gnss-solve`` run never uses dask, nor ``gnss-batch`` without ``--scheduler`` (nor its
    local workers, forked from it), but xarray imports ``dask`` and ``dask.array`` when they are installed (the
    ``cluster`` extra), only to recognise dask arrays: 0.1-0.2 s of every run.
    """
    mark_missing("dask")


def mark_missing(module: str) -> None:
    """Make ``module`` look not installed to this process, unless it, pandas or xarray is already
    imported (they note at import what they found). A ``None`` entry in :data:`sys.modules`
    makes ``importlib.util.find_spec`` report it missing and ``import`` raise ImportError."""
    if not {module, "pandas", "xarray"} & set(sys.modules):
        sys.modules[module] = None  # type: ignore[assignment]
