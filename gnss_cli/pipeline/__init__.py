"""Files -> epochs -> solutions (no terminal I/O).

Modules, one job each::

    results     EpochData, MethodSolution, RunResult, WindowModel, EpochStatus (the status vocabulary)
    epochs      load_epochs: RINEX files -> validated epochs with satellite states
    snapshot    solve_method, run: the single-epoch solution of every method, DOPs
    smoothing   smooth: behavioral multi-epoch smoothing of the WLS fixes (window scheduling)
    processing  process: the whole run (snapshot, then the smoothing when configured)
    stream      ChunkedRun: a long file's run in parts of N epochs, equal to the whole run; a day
                file's parts read and solved at once in forked processes
    parts       part_epochs, solve_part: one part of a file on the whole file's axes, solved
    memory      release_memory, map_large_blocks: the C heap of a run in parts
    smoothing_stream  StreamSmoother: the smoothing of parts with the whole file's schedule
    identification  identify_trajectory: kernel identification and prediction of a trajectory

The CLI calls :func:`process`.
"""

from gnss_cli.pipeline.epochs import load_epochs
from gnss_cli.pipeline.processing import process
from gnss_cli.pipeline.results import (
    EpochData,
    EpochStatus,
    MethodSolution,
    Progress,
    RunResult,
    WindowModel,
    solver_epoch_status,
    window_epoch_status,
)
from gnss_cli.pipeline.smoothing import smooth
from gnss_cli.pipeline.snapshot import ITERATED_METHODS, WEIGHTED_METHODS, run, solve_method

__all__ = [
    "load_epochs", "process", "run", "solve_method", "smooth",
    "EpochData", "EpochStatus", "MethodSolution", "Progress", "RunResult", "WindowModel",
    "solver_epoch_status", "window_epoch_status", "ITERATED_METHODS", "WEIGHTED_METHODS",
]
