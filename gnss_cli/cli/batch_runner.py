"""Where ``gnss-batch`` runs its tasks: local worker processes, or an existing Dask cluster.

Locally a :class:`concurrent.futures.ProcessPoolExecutor` (spawned processes, one task
per observation file) is enough: the tasks are independent and coarse (seconds to minutes
each), so a scheduler with a task graph, a dashboard and nanny processes buys nothing on
one machine, the start is quick, and ``dask`` stays an optional dependency. With
``--scheduler tcp://HOST:PORT`` the same function :func:`gnss_cli.cli.batch_task.run_file`
is submitted to a ``dask.distributed`` cluster; the workers must have gnss-solve installed
and see the input files under the same paths. Both yield results as the files finish; a
task that dies with its worker process is reported as a failed file.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Iterator, Sequence

from gnss_cli.cli.batch_task import BatchSettings, FileResult, failed, init_worker, run_file
from gnss_cli.errors import ConfigError

CLUSTER_HINT = "pip install 'gnss-solve[cluster]'"
CONNECT_TIMEOUT_S = 5.0


def run_in_process(obs_paths: Sequence[str], settings: BatchSettings) -> Iterator[FileResult]:
    """One file after the other in this process (``--jobs 1``)."""
    for i, obs in enumerate(obs_paths):
        yield run_file(i, obs, settings)


def run_local(obs_paths: Sequence[str], settings: BatchSettings, jobs: int) -> Iterator[FileResult]:
    """Run the files in ``jobs`` local worker processes; yield each result as it finishes.

    An interruption of the consumer (SIGINT, SIGTERM, closing the generator) cancels what
    has not started and terminates the workers.
    """
    from concurrent.futures import ProcessPoolExecutor, as_completed

    if jobs <= 1 or len(obs_paths) <= 1:
        yield from run_in_process(obs_paths, settings)
        return
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(obs_paths)), mp_context=multiprocessing.get_context("spawn"),
                               initializer=init_worker)
    try:
        futures = {pool.submit(run_file, i, obs, settings): (i, obs) for i, obs in enumerate(obs_paths)}
        for future in as_completed(futures):
            i, obs = futures[future]
            try:
                yield future.result()
            except Exception as exc:  # noqa: BLE001 - a worker that died (BrokenProcessPool) fails its file only
                yield failed(i, obs, exc)
    except BaseException:
        _stop(pool)
        raise
    pool.shutdown(wait=True)


def _stop(pool: object) -> None:
    """Cancel the queued tasks and end the worker processes now."""
    pool.shutdown(wait=False, cancel_futures=True)  # type: ignore[attr-defined]
    terminate = getattr(pool, "terminate_workers", None)  # Python >= 3.14
    if terminate is not None:
        terminate()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()


def run_dask(obs_paths: Sequence[str], settings: BatchSettings, address: str) -> Iterator[FileResult]:
    """Run the files on the Dask cluster whose scheduler is at ``address``; yield results as they finish.

    Raises
    ------
    ConfigError
        ``dask.distributed`` is not installed (the ``cluster`` extra), or the scheduler
        cannot be reached within :data:`CONNECT_TIMEOUT_S`.
    """
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ConfigError(f"--scheduler: needs dask.distributed, which is not installed; install it with {CLUSTER_HINT}") from None
    try:
        client = Client(address, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise ConfigError(f"--scheduler: cannot connect to {address} ({type(exc).__name__}: {exc})") from None
    with client:
        futures = [client.submit(run_file, i, obs, settings, pure=False) for i, obs in enumerate(obs_paths)]
        where = {f.key: (i, obs) for f, (i, obs) in zip(futures, enumerate(obs_paths))}
        try:
            for future in as_completed(futures):
                i, obs = where[future.key]
                try:
                    yield future.result()
                except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: that file fails, the others go on
                    yield failed(i, obs, exc)
        except BaseException:
            client.cancel(futures)
            raise
