"""One continuous trajectory through the identified windows of ``stls --lag L``: neighbours tied.

After the spans are chosen (:mod:`gnss_cli.pipeline.spans`), each window's trajectory was solved
from its own measurements only: two neighbouring windows do not know of each other, so a window
holds its position only from the pseudoranges of its own 15 or so epochs, whatever the range
rates or phase say about how the receiver moved between them. The path is continuous, so the
windows of a run are solved together, each in its identified behavior:

* window ``k`` keeps its epochs ``a_k:b_k`` and its kernel; its trajectory is ``x_t = o + Y_k(t)
  c_k`` (the bases of :func:`~gnss_cli.behavior.behavior_solve.shared_modes`, velocities from
  the modes);
* tie: at the first epoch ``h`` the next window supplies, both give the same position,
  ``Y_k(h) c_k = Y_{k+1}(h) c_{k+1}`` (a window that ends before ``h`` is extended to it);
* cost: the weighted measurement misfit of every window over its epochs, each row's weight
  divided by the number of windows holding its epoch (so every measurement counts once), with
  the variance factors and the gate (and robust) multipliers of the window that supplied the
  epoch, clocks and drifts eliminated per epoch;
* a tie is made only where the two windows agree: the jump between their own solutions at ``h``
  against its covariance, chi-square with 3 degrees of freedom at ``[stls] behavior_pfa``
  (a manoeuvre between two windows that their kernels do not share keeps them apart).

The equality-constrained least squares of a run is solved by its sparse KKT system, linearized
at the current trajectory and solved again until no position moves by more than
:data:`STEP_TOL_M` (at most :data:`MAX_PASSES`); each epoch takes the position of the window
that supplied it. The kernels stay those identified in the windows. A run breaks where an epoch
kept its WLS fix, where a window stayed in the position domain, where the measurement kinds of
two windows differ (:mod:`gnss_cli.pipeline.spans` drops range rates and phase where they reject
the behavior) and where a window's kernel has no velocity for the range rates. With
pseudoranges alone the tie lends each window its neighbours' fixes; with range rates it carries
the pseudoranges of the whole run to every epoch, as a fixed-model smoother does.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import spsolve
from scipy.stats import chi2

from gnss_cli.behavior.behavior_solve import behavior_normals, shared_modes
from gnss_cli.behavior.window_solve import reduce_epochs
from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.behavioral import Fit, Segment, WindowJob
from gnss_cli.pipeline.integrity import take_epochs
from gnss_cli.pipeline.measurements import measurement_rows
from gnss_cli.pipeline.phase_rows import phase_pair_rows
from gnss_cli.pipeline.results import EpochData

__all__ = ["tie_spans", "chains", "STEP_TOL_M", "MAX_PASSES"]

F64 = NDArray[np.float64]

#: The linearization is repeated until no position moves by more than this, m.
STEP_TOL_M = 1e-3
#: Linearizations at most.
MAX_PASSES = 6


def chains(jobs: list[WindowJob], fits: list[Fit]) -> list[list[int]]:
    """Runs of windows (indices into ``jobs``) whose supplied epochs follow each other in one segment
    and whose results are measurement-domain trajectories with a shared kernel from the same
    measurement kinds; only runs of two or more."""
    usable = [k for k, (job, fit) in enumerate(zip(jobs, fits))
              if job.hi > job.lo and fit.w_hat is not None and fit.domain == "measurement"
              and fit.kernel is not None and fit.kernel.shared_coefficients is not None]
    usable.sort(key=lambda k: (jobs[k].segment, jobs[k].lo))
    out: list[list[int]] = []
    for k in usable:
        prev = out[-1][-1] if out else None
        if prev is not None and jobs[prev].segment == jobs[k].segment and jobs[prev].hi == jobs[k].lo \
                and fits[prev].kinds == fits[k].kinds:
            out[-1].append(k)
        else:
            out.append([k])
    return [c for c in out if len(c) > 1]


def _window_ranges(chain: list[int], jobs: list[WindowJob]) -> list[tuple[int, int]]:
    """Each window's epochs (segment-local ``a:e``): its own range, reaching the next window's first
    supplied epoch (where the two are tied) when it does not already."""
    out = []
    for i, k in enumerate(chain):
        job = jobs[k]
        e = max(job.b, jobs[chain[i + 1]].lo + 1) if i + 1 < len(chain) else job.b
        out.append((job.a, e))
    return out


def tie_spans(data: EpochData, config: ProcessingConfig, factors: tuple[float, ...], mult: F64, segs: list[Segment],
              jobs: list[WindowJob], fits: list[Fit]) -> list[Fit]:
    """``fits`` with the supplied epochs of every chain of windows solved together (module docstring).

    Parameters
    ----------
    data, config : the prepared epochs (WLS exclusions applied) and the configuration.
    factors : the variance factors of the kinds (pseudoranges, range rates, pairs); each chain uses
        the kinds its windows were solved with.
    mult : ``(3, T, n)`` gate (and robust) multipliers of the window that supplied each epoch.
    segs, jobs, fits : the segments, windows and fits of :func:`~gnss_cli.pipeline.spans.tested_windows`.

    Returns
    -------
    fits : the tied windows with the supplied rows of ``w_hat`` replaced; their messages say how
        many windows were tied and after how many linearizations.
    """
    factors = (*factors, 1.0, 1.0, 1.0)[:3]
    out = list(fits)
    for chain in chains(jobs, fits):
        kinds = fits[chain[0]].kinds
        doppler = "doppler" in kinds
        seg = segs[jobs[chain[0]].segment]
        ranges = _window_ranges(chain, jobs)
        dt = float(np.median(np.diff(data.time_gps_s[seg.epochs]))) if seg.epochs.size > 1 else 1.0
        kernels = np.stack([np.asarray(fits[k].kernel.shared_coefficients, dtype=np.float64)  # type: ignore[union-attr]
                            for k in chain])
        bases = [shared_modes(r[None], e - a, np.array([dt]), doppler) for r, (a, e) in zip(kernels, ranges)]
        if not all(b[2][0] and (b[3][0] or not doppler) for b in bases):
            continue  # a window without a usable basis: the windows keep their own results
        solved = _solve_chain(data, config, kinds, factors, mult, seg, ranges, [b[0][0] for b in bases],
                              [b[1][0] for b in bases], fits, jobs, chain)
        if solved is None:
            continue
        x, kept, passes = solved
        for k in chain:
            job, fit = jobs[k], out[k]
            w_hat = fit.w_hat.copy()  # type: ignore[union-attr]
            own = seg.epochs[job.lo : job.hi]
            w_hat[job.lo - job.a : job.hi - job.a] = (x[own] - seg.origin) @ seg.rot.T
            out[k] = replace(fit, w_hat=w_hat, message=f"{fit.message}; tied to its neighbours: {kept} of the "
                                                       f"{len(chain) - 1} ties of a run of {len(chain)} windows agree, "
                                                       f"{passes} linearizations")
    return out


def _window_normals(rows: dict[str, F64], phr: dict[str, F64] | None, epochs: NDArray[np.intp], e: NDArray[np.intp],
                    y: F64, yv: F64, x: F64, origin: F64, mult: F64, factors: tuple[float, ...], doppler: bool,
                    cover: F64 | None, pair_cover: F64 | None) -> tuple[F64, F64]:
    """``H, g`` of one window's coefficients (:func:`~gnss_cli.behavior.behavior_solve.behavior_normals`)
    from its rows, each weight divided by the number of windows holding the epoch (``cover``; None: 1)."""
    at = np.searchsorted(epochs, e)
    share = np.ones(e.size) if cover is None else cover[e]
    pair_share = np.ones(e.size) if pair_cover is None else np.maximum(pair_cover[e], 1.0)
    pr = reduce_epochs(rows["P"][at], rows["w"][at] * mult[0, e] / (factors[0] * share[:, None]), rows["y"][at],
                       rows["C"][at])
    rr = reduce_epochs(rows["H"][at], rows["wd"][at] * mult[1, e] / (factors[1] * share[:, None]),
                       rows["yd"][at]) if doppler else None
    ph = None
    if phr is not None:
        w_ph = phr["w"][at] * mult[2, e] / (factors[2] * pair_share[:, None])
        w_ph[0] = 0.0  # the pair ending at the window's first epoch: its other epoch is outside
        ph = reduce_epochs(phr["P6"][at], w_ph, phr["y"][at], phr["C"][at])
    H, g, _ = behavior_normals(y[None], yv[None] if doppler else None, (x[e] - origin)[None], pr, rr, ph)
    width = H.shape[1]
    return H[0] + 1e-12 * max(float(np.trace(H[0])), 1e-30) * np.eye(width), g[0]


def _agreeing_ties(ties: F64, blocks: list[F64], rhs: list[F64], pfa: float) -> NDArray[np.bool_]:
    """Which ties (3 rows each) join windows that agree: the jump between the two windows' own
    positions at the tied epoch against its covariance (the sum of theirs), chi-square with 3
    degrees of freedom at ``pfa``."""
    width = blocks[0].shape[0]
    n_w = len(blocks)
    u = np.concatenate([np.linalg.solve(H, g) for H, g in zip(blocks, rhs)])
    cov = [np.linalg.inv(H) for H in blocks]
    limit = float(chi2.isf(pfa, 3))
    keep = np.zeros(n_w - 1, dtype=bool)
    for i in range(n_w - 1):
        rows = ties[3 * i : 3 * i + 3]
        left, right = rows[:, i * width : (i + 1) * width], rows[:, (i + 1) * width : (i + 2) * width]
        jump = rows @ u
        c = left @ cov[i] @ left.T + right @ cov[i + 1] @ right.T
        keep[i] = float(jump @ np.linalg.solve(c, jump)) <= limit
    return keep


def _solve_chain(data: EpochData, config: ProcessingConfig, kinds: frozenset[str], factors: tuple[float, ...],
                 mult: F64, seg: Segment, ranges: list[tuple[int, int]], ys: list[F64], yvs: list[F64],
                 fits: list[Fit], jobs: list[WindowJob], chain: list[int]) -> tuple[F64, int, int] | None:
    """The chain's supplied positions ``(T, 3)`` (ECEF, m; NaN elsewhere), the number of ties kept and
    of linearizations; None when no tie is kept or the system is singular.

    Every window keeps its whole range of epochs; an epoch's rows are shared among the windows that
    hold it (weights divided by their number, so each measurement counts once); consecutive windows
    give the same position at the first epoch the later one supplies. The rows are linearized at one
    trajectory: each epoch at the position of the window that supplies it (or of the window that
    holds it, beyond the supplied ones).
    """
    doppler, phase = "doppler" in kinds, "phase" in kinds
    pfa = config.stls.behavior_pfa
    eps = [seg.epochs[a:e] for a, e in ranges]
    epochs = np.unique(np.concatenate(eps))
    x = np.full((data.time_gps_s.size, 3), np.nan)
    for k, e in zip(chain, eps):  # start: each window's own result, the supplied epochs last
        job = jobs[k]
        n = min(e.size, job.b - job.a)
        x[e[:n]] = np.where(np.isnan(x[e[:n]]), seg.origin + fits[k].w_hat[:n] @ seg.rot, x[e[:n]])  # type: ignore[index]
    for k in chain:
        job = jobs[k]
        x[seg.epochs[job.lo : job.hi]] = seg.origin + fits[k].w_hat[job.lo - job.a : job.hi - job.a] @ seg.rot  # type: ignore[index]
    x[epochs] = np.where(np.isnan(x[epochs]), np.nanmean(x[epochs], axis=0), x[epochs])
    cover = np.zeros(data.time_gps_s.size)
    pair_cover = np.zeros(data.time_gps_s.size)  # windows holding both epochs of the pair ending at t
    for e in eps:
        cover[e] += 1
        pair_cover[e[1:]] += 1
    sub = take_epochs(data, epochs)
    lag = ys[0].shape[1]
    width = 3 * lag
    n_w = len(eps)
    ties = np.zeros((3 * (n_w - 1), n_w * width))
    for i in range(n_w - 1):  # Y_i(h) c_i - Y_{i+1}(h) c_{i+1} = 0 at h, the later window's first supplied epoch
        h = jobs[chain[i + 1]].lo
        for p in range(3):
            ties[3 * i + p, i * width + p : (i + 1) * width : 3] = ys[i][h - ranges[i][0]]
            ties[3 * i + p, (i + 1) * width + p : (i + 2) * width : 3] = -ys[i + 1][h - ranges[i + 1][0]]
    for npass in range(1, MAX_PASSES + 1):
        rows = measurement_rows(sub, x[epochs], config, doppler)
        phr = phase_pair_rows(sub, rows, config) if phase else None
        if npass == 1:  # the windows as solved alone (each with all its rows): where they do not meet, no tie
            own = [_window_normals(rows, phr, epochs, e, y, yv, x, seg.origin, mult, factors, doppler, None, None)
                   for e, y, yv in zip(eps, ys, yvs)]
            keep = _agreeing_ties(ties, [b for b, _ in own], [g for _, g in own], pfa)
            ties = ties[np.repeat(keep, 3)]
            if not keep.any():
                return None
        blocks, rhs = [], []
        for e, y, yv in zip(eps, ys, yvs):
            H, g = _window_normals(rows, phr, epochs, e, y, yv, x, seg.origin, mult, factors, doppler, cover, pair_cover)
            blocks.append(H)
            rhs.append(g)
        A = sp.csr_matrix(ties)
        kkt = sp.bmat([[sp.block_diag(blocks), A.T], [A, None]], format="csc")
        with np.errstate(all="ignore"):
            sol = spsolve(kkt, np.concatenate([*rhs, np.zeros(A.shape[0])]))
        if not np.all(np.isfinite(sol)):
            return None
        u = sol[: n_w * width].reshape(n_w, lag, 3)
        new = x.copy()
        for e, y, c in zip(eps, ys, u):  # the held epochs first, then the supplied ones win
            new[e] = seg.origin + y @ c
        for i, (k, y, c) in enumerate(zip(chain, ys, u)):
            job = jobs[k]
            new[seg.epochs[job.lo : job.hi]] = seg.origin + y[job.lo - ranges[i][0] : job.hi - ranges[i][0]] @ c
        step = float(np.max(np.abs(new[epochs] - x[epochs])))
        x = new
        if step <= STEP_TOL_M:
            break
    out = np.full_like(x, np.nan)
    for k in chain:
        own = seg.epochs[jobs[k].lo : jobs[k].hi]
        out[own] = x[own]
    return out, int(ties.shape[0] // 3), npass
