"""SIGINT and SIGTERM as an exception, with sections that hold them back.

The console scripts install :func:`on_signal` for SIGINT and SIGTERM (see
:func:`gnss_cli.cli.exits.run_app`): a signal raises :class:`Interrupted` in the main thread.
Inside :func:`deferred` a signal is only recorded and raised when the outermost section
ends, so that creating a temporary file and recording it, or renaming a set of finished
files, is never cut in half. The deferral is a Python-level flag, not a thread signal mask:
the kernel may deliver a process signal to any thread (BLAS workers, the progress
heartbeat), but Python runs the handler in the main thread, where the flag is read.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from types import FrameType

_depth = 0
_pending: int | None = None


class Interrupted(BaseException):
    """Raised in the main thread by SIGINT or SIGTERM; not an ``Exception``, so nothing in
    the libraries below swallows it, while their ``finally`` blocks still run."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def on_signal(signum: int, frame: FrameType | None) -> None:
    """Signal handler: raise :class:`Interrupted`, or record it inside a deferred section."""
    global _pending
    if _depth:
        if _pending is None:
            _pending = signum
        return
    raise Interrupted(signum)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM until the outermost deferred section ends, then raise."""
    global _depth, _pending
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0 and _pending is not None:
            signum, _pending = _pending, None
            raise Interrupted(signum)
