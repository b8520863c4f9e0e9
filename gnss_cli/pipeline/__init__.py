"""Files -> epochs -> solutions (no terminal I/O).

Modules, one job each::

    results     EpochData, MethodSolution, RunResult, WindowModel, EpochStatus (the status vocabulary)
    epochs      load_epochs: RINEX files -> validated epochs with satellite states
    snapshot    solve_method, solve_methods: the single-epoch solution of every method, DOPs
    integrity   monitor: chi-square test, fault detection and exclusion, protection levels
    velocity    solve_velocity, with_velocity: receiver velocity and clock drift from Doppler
    methods     method_settings, solve_multi_epoch: what each method computes (the one vocabulary)
    smoothing   smooth: stls with lag >= 1, the identified Hankel STLS of the WLS fixes in windows
    doppler_smoothing  doppler_smooth: the smoother method (fixed motion model, measurement domain)
    phase_rows  phase_pair_rows: time-differenced carrier phase rows of the multi-epoch methods
    kinematic   kinematic_smooth: fixes tied to Doppler velocities (position domain)
    kalman      run_kalman: the kf method, extended Kalman filter with an RTS smoother
    run         Run, process: the one run of a file, part by part, every method (forked processes
                for the parts of a day file)
    parts       part_epochs, solve_part: one part of a file on the whole file's axes, solved
    memory      release_memory, map_large_blocks: the C heap of a run in parts
    ephemerides system_records: broadcast ephemerides of one system behind one interface
    identification  identify_trajectory: kernel identification and prediction of a trajectory
    window_solve  (see module)
    integrity_table  (see module)

The CLI and :func:`gnss_cli.solve` both run :class:`~gnss_cli.pipeline.run.Run`.
"""

from gnss_cli.pipeline.epochs import load_epochs
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
from gnss_cli.pipeline.run import Run, process
from gnss_cli.pipeline.behavioral import smooth
from gnss_cli.pipeline.snapshot import ITERATED_METHODS, WEIGHTED_METHODS, solve_method, solve_methods

__all__ = [
    "load_epochs", "process", "Run", "solve_method", "solve_methods", "smooth",
    "EpochData", "EpochStatus", "MethodSolution", "Progress", "RunResult", "WindowModel",
    "solver_epoch_status", "window_epoch_status", "ITERATED_METHODS", "WEIGHTED_METHODS",
]
