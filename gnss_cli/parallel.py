"""Work of one run on the machine's other cores: a function run in a forked child process.

A forked child starts with the parent's memory (the imported modules, the file already read,
the navigation records), so a piece of work needs no start-up and no input sent to it; only
its result comes back, pickled (through an anonymous temporary file; a :class:`Channel` of two
pipes carries the small messages of work that needs some on the way). This is what lets ``gnss-solve`` solve the
halves of a day file on two cores at once (:class:`~gnss_cli.pipeline.run.Run`).

Only on Linux (``os.fork``; macOS's system libraries are not safe to use after a fork, and
Windows has none): elsewhere :func:`can_fork` is False and the callers run the work in turn.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import tempfile
import warnings
from collections.abc import Callable
from functools import partial
from typing import Any

__all__ = ["Channel", "Forked", "WorkerError", "can_fork", "cores", "fork_all"]


def can_fork() -> bool:
    """Whether work can go to forked children here (Linux)."""
    return sys.platform.startswith("linux") and hasattr(os, "fork")


def cores() -> int:
    """The cores this process may run on (its CPU affinity, else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def fork_all(fns: list[Callable[..., Any]], talk: bool = False) -> "list[Forked] | OSError":
    """A :class:`Forked` child for each of ``fns``, or, when the system refuses a process (a
    limit on processes or memory: ``OSError``), that error, with the children already made ended."""
    children: list[Forked] = []
    try:
        for fn in fns:
            children.append(Forked(fn, talk))
    except OSError as exc:
        for child in children:
            child.cancel()
        return exc
    return children


class WorkerError(RuntimeError):
    """A child process ended without handing back a result (killed, or out of memory)."""


class Forked:
    """``fn()`` running in a forked child; :meth:`result` waits and returns its value. With
    ``talk`` the child runs ``fn(channel)``, a :class:`Channel` to this process's :meth:`send`
    and :meth:`recv`, for work that needs something only known once both have begun.

    The value comes back pickled through an anonymous temporary file that both processes hold
    (a day file's half of observations is 28 MB: through a pipe's 64 KiB at a time it took
    0.1 s, through the page cache 10 ms). An exception raised by ``fn`` is raised again by
    :meth:`result` (the same type and message; one that cannot be pickled becomes a
    :class:`RuntimeError` with its text). The child never returns into the caller's code: it
    ends with ``os._exit`` (no ``atexit`` handlers, no flushing of the parent's buffered
    output), and dies of Ctrl-C (SIGINT) and SIGTERM at once, without a traceback, while the
    parent reports the interruption. :meth:`cancel` ends a child whose result is no longer wanted.
    """

    def __init__(self, fn: Callable[..., Any], talk: bool = False) -> None:
        self._file = tempfile.TemporaryFile()
        pipes = (os.pipe(), os.pipe()) if talk else None  # (to the child, to the parent)
        sys.stderr.flush()  # nothing buffered is written twice
        with warnings.catch_warnings():
            # Python 3.12 warns about fork() in a process with threads: the only other threads
            # here are the prefetch readers (files, zlib, crx2rnx), which hold no lock the child takes
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()
        if pid == 0:  # the child
            if pipes is None:
                _child(fn, self._file.fileno())
            (down_r, down_w), (up_r, up_w) = pipes
            os.close(down_w)
            os.close(up_r)
            _child(partial(fn, Channel(down_r, up_w)), self._file.fileno())
        self.pid: int | None = pid
        self._outcome: tuple[bool, Any] | None = None
        self._channel: Channel | None = None
        if pipes is not None:
            (down_r, down_w), (up_r, up_w) = pipes
            os.close(down_r)
            os.close(up_w)
            self._channel = Channel(up_r, down_w)

    def send(self, obj: Any) -> None:
        """Hand ``obj`` to the child's :meth:`Channel.recv` (``talk=True``)."""
        assert self._channel is not None
        self._channel.send(obj)

    def recv(self) -> Any:
        """What the child sent with :meth:`Channel.send` (``talk=True``); when it ended instead,
        raises what ``fn`` raised (or :class:`WorkerError`)."""
        assert self._channel is not None
        try:
            return self._channel.recv()
        except EOFError:
            self.result()
            raise WorkerError("a worker process ended before it sent what was expected") from None

    def result(self) -> Any:
        """The value of ``fn()`` (waits for the child); raises what ``fn`` raised."""
        if self._outcome is None:
            status = self._reap()
            with self._file:
                self._file.seek(0)
                payload = self._file.read()
            if self._channel is not None:
                self._channel.close()
            if not payload or not (os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0):
                self._outcome = (False, WorkerError(f"a worker process ended without a result ({_status_text(status)})"))
            else:
                self._outcome = pickle.loads(payload)
        ok, value = self._outcome
        if not ok:
            raise value
        return value

    def cancel(self) -> None:
        """End the child (SIGKILL) if it still runs, and reap it."""
        if self._outcome is not None:
            return
        self._outcome = (False, WorkerError("cancelled"))
        if self.pid is not None:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self._reap()
        self._file.close()
        if self._channel is not None:
            self._channel.close()

    def _reap(self) -> int:
        pid, self.pid = self.pid, None
        if pid is None:
            return 0
        while True:
            try:
                return os.waitpid(pid, 0)[1]
            except InterruptedError:
                continue
            except ChildProcessError:
                return 0


class Channel:
    """One end of the two pipes between a parent and a child of :class:`Forked` (``talk=True``):
    objects pickled, each after its length."""

    def __init__(self, read_fd: int, write_fd: int) -> None:
        self._read, self._write = read_fd, write_fd

    def send(self, obj: Any) -> None:
        payload = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        view = memoryview(len(payload).to_bytes(8, "little") + payload)
        while view:
            view = view[os.write(self._write, view):]

    def recv(self) -> Any:
        """The next object; EOFError when the other end has closed."""
        size = int.from_bytes(self._read_exactly(8), "little")
        return pickle.loads(self._read_exactly(size))

    def _read_exactly(self, n: int) -> bytes:
        chunks, left = [], n
        while left:
            block = os.read(self._read, min(left, 1 << 20))
            if not block:
                raise EOFError("the other process closed the channel")
            chunks.append(block)
            left -= len(block)
        return b"".join(chunks)

    def close(self) -> None:
        for fd in (self._read, self._write):
            try:
                os.close(fd)
            except OSError:
                pass
        self._read = self._write = -1


def _status_text(status: int) -> str:
    if os.WIFSIGNALED(status):
        return f"killed by signal {os.WTERMSIG(status)}"
    return f"exit status {os.waitstatus_to_exitcode(status)}"


def _child(fn: Callable[[], Any], fd: int) -> None:
    """The child's whole life: run ``fn``, write the pickled outcome to ``fd``, exit."""
    code = 0
    try:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        try:
            outcome: tuple[bool, Any] = (True, fn())
        except BaseException as exc:  # noqa: BLE001 - handed to the parent, which raises it
            outcome = (False, exc)
        try:
            payload = pickle.dumps(outcome, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # noqa: BLE001 - an exception or value that cannot be pickled
            error = outcome[1] if not outcome[0] else exc
            payload = pickle.dumps((False, RuntimeError(f"{type(error).__name__}: {error}")))
        view = memoryview(payload)
        while view:
            view = view[os.write(fd, view):]
    except BaseException:  # noqa: BLE001 - the parent sees no result and says so
        code = 1
    finally:
        os._exit(code)
