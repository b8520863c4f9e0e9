"""Where ``gnss-batch`` runs its tasks: local worker processes, or an existing Dask cluster.

Locally a :class:`concurrent.futures.ProcessPoolExecutor` (processes forked from this one
on Linux, spawned elsewhere; one task per observation file) is enough: the tasks are
independent and coarse (seconds to minutes each), so a scheduler with a task graph, a
dashboard and nanny processes buys nothing on one machine, the start is quick, and ``dask``
stays an optional dependency. Forked workers start with the numerical modules the parent
imported; spawned ones import them as soon as the runner is opened, while the parent still
reads the navigation files. With ``--scheduler tcp://HOST:PORT`` the same function
:func:`gnss_cli.cli.batch_task.run_file` is submitted to a ``dask.distributed`` cluster;
the workers must have gnss-solve installed and see the input files under the same paths.
Both yield results as the files finish; a task that dies with its worker process is
reported as a failed file. Leaving the runner early (an error, SIGINT, SIGTERM) cancels
what has not started and ends the local workers.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Iterator, Sequence
from typing import Any, Optional

from gnss_cli.cli.batch_task import SINGLE_THREAD_ENV, BatchSettings, FileResult, failed, init_worker, run_file, warm_up
from gnss_cli.errors import ConfigError

CLUSTER_HINT = "pip install 'gnss-solve[cluster]' (from a clone: pip install -e '.[cluster]')"
"""How to install the optional Dask dependency, for an installed package and for a clone."""
CONNECT_TIMEOUT_S = 5.0


def forks_workers() -> bool:
    """Whether the local workers are forked from this process (Linux), else spawned.

    Forked, they start with the modules and the navigation reader this process has loaded
    (eight 24 h files on two workers: 6.7 s instead of 7.6 s); the pool forks them all at its
    first task, before it starts its own threads, so no thread is copied half-way."""
    from gnss_cli.parallel import can_fork

    return can_fork()


class LocalRunner:
    """``jobs`` worker processes (none for one job or one file: then in this process).

    Parameters
    ----------
    jobs : int
        Worker processes.
    n_files : int
        Files to come (no more workers than files).
    """

    def __init__(self, jobs: int, n_files: int) -> None:
        from concurrent.futures import ProcessPoolExecutor

        self.pool: Any = None
        workers = min(jobs, n_files)
        self.parallel = workers > 1
        if workers > 1:
            for name, value in SINGLE_THREAD_ENV.items():
                os.environ.setdefault(name, value)  # inherited by the workers at their start
            if forks_workers():  # forked after the imports: the workers start with the modules loaded
                warm_up()
                self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"),
                                                initializer=init_worker)
            else:  # spawned: each imports the modules while the parent reads the navigation files
                self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                                initializer=init_worker)
                for _ in range(workers):
                    self.pool.submit(warm_up)

    def results(self, obs_paths: Sequence[str], settings: BatchSettings) -> Iterator[FileResult]:
        """Run the files; yield each result as it finishes."""
        from concurrent.futures import as_completed

        if self.pool is None:
            for i, obs in enumerate(obs_paths):
                yield run_file(i, obs, settings)
            return
        futures = {self.pool.submit(run_file, i, obs, settings): (i, obs) for i, obs in enumerate(obs_paths)}
        for future in as_completed(futures):
            i, obs = futures[future]
            try:
                yield future.result()
            except Exception as exc:  # noqa: BLE001 - a worker that died (BrokenProcessPool) fails its file only
                yield failed(i, obs, exc)

    def close(self, finished: bool) -> None:
        """Wait for the workers to exit (``finished``), else cancel the queue and end them now."""
        if self.pool is None:
            return
        if finished:
            self.pool.shutdown(wait=True)
            return
        terminate = getattr(self.pool, "terminate_workers", None)  # Python >= 3.14
        if terminate is not None:
            terminate()
            return
        processes = list((getattr(self.pool, "_processes", None) or {}).values())  # shutdown() forgets them
        for process in processes:
            process.terminate()
        self.pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.join(timeout=5.0)


class DaskRunner:
    """The tasks on the Dask cluster whose scheduler is at ``address``.

    Raises
    ------
    ConfigError
        ``dask.distributed`` is not installed (the ``cluster`` extra), or the scheduler
        cannot be reached within :data:`CONNECT_TIMEOUT_S`.
    """

    def __init__(self, address: str) -> None:
        try:
            from distributed import Client
        except ImportError:
            raise ConfigError(f"--scheduler: needs dask.distributed, which is not installed; install it with {CLUSTER_HINT}") from None
        try:
            self.client = Client(address, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise ConfigError(f"--scheduler: cannot connect to {address} ({str(exc).strip() or 'no answer'})") from None
        self.futures: list[Any] = []
        self.parallel = True

    def results(self, obs_paths: Sequence[str], settings: BatchSettings) -> Iterator[FileResult]:
        """Submit every file; yield each result as it finishes (a lost worker fails its file)."""
        from distributed import as_completed

        self.futures = [self.client.submit(run_file, i, obs, settings, pure=False) for i, obs in enumerate(obs_paths)]
        where = {f.key: (i, obs) for f, (i, obs) in zip(self.futures, enumerate(obs_paths))}
        for future in as_completed(self.futures):
            i, obs = where[future.key]
            try:
                yield future.result()
            except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: that file fails, the others go on
                yield failed(i, obs, exc)

    def close(self, finished: bool) -> None:
        """Cancel what is left (when not ``finished``) and disconnect."""
        if not finished and self.futures:
            self.client.cancel(self.futures)
        self.client.close()


def open_runner(jobs: int, scheduler: Optional[str], n_files: int) -> LocalRunner | DaskRunner:
    """A :class:`DaskRunner` for ``scheduler``, else a :class:`LocalRunner` of ``jobs`` processes."""
    return DaskRunner(scheduler) if scheduler is not None else LocalRunner(jobs, n_files)
