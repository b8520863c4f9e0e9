"""The spans of ``stls --lag L`` solved together: one trajectory in the piecewise identified behavior.

The spans chosen by the behavior test (:mod:`gnss_cli.pipeline.spans`) are identified and
alternated one at a time (:mod:`gnss_cli.pipeline.identified`): each span's kernel, and a
trajectory that rests on that span's own measurements. This stage keeps the kernels and solves
the trajectory of every run of consecutive spans at once, in the measurement domain, subject to
the piecewise behavior (:func:`~gnss_cli.behavior.piecewise.piecewise_terms`: each span's kernel
rows, one row of its kernel across each switch, the velocities tied to the positions by the
quadrature rule of ``smoother`` with range rates, by the modes' derivatives without), with the rows,
variance factors, residual gate and Gauss-Newton passes of ``smoother``
(:func:`~gnss_cli.pipeline.smoother.solve_segments`). The model is the identified one; what the
joint solve adds is that every measurement of the run counts for every span: the range rates
and the carrier-phase pairs carry the position from span to span, so a span's position no
longer rests on its own pseudoranges alone.

Only with range rates or phase: with the pseudoranges alone nothing but the switch rows ties
the spans, and each kernel then holds only its own span's epochs where, alone, it is fitted on
its whole window. Measured on the six training flights and drives of
``benchmarks/multi_epoch_fair.py`` (seeds 1-3, 1 m code noise, 3D RMS pooled): pseudoranges
alone, tied 1.554 m against 1.479 m alone (30-epoch windows, switch rows at the whole
disagreement; worse on all three drives) and 2.026 against 1.237 m (whole segments, 1e-3, a
tenth of it: worse on all six); with range rates 1.067 against 1.115 m (whole segments, the
whole disagreement; better on four of six), when the velocities were still the modes'
derivatives. With the quadrature rows the tie gains more: on the training drive 1001, 0.38 m
tied against 1.24 m alone (``tests/pipeline/test_tied.py``).

A span whose windows the run's measurements rejected down to the shortest, and which then passed
with fewer of them (:mod:`gnss_cli.pipeline.spans`), is in its run without a behavior:
no kernel rows and no switch row out of it, its positions held by the measurements and (with
range rates) the quadrature rows and their weak prior alone, as in ``smoother``. Its kernel
contradicts the range rates or phase the run uses; tied in with its rows (roots such as -1.24 and 1.29 at the start of an evaluation
drive of ``benchmarks/multi_epoch_fair.py``), it put that drive's first epochs 7 m off; on the
six training runs the rule (with the position-domain spans below) takes the pooled 3D RMS from
0.437 to 0.433 m in whole segments, from 0.466 to 0.443 m in 20-epoch windows
(``benchmarks/stls_structure.py``).

A span whose result stayed in the position domain (its kernel identified on the fixes alone and
untested, or without a velocity for the range rates) is in its run the same way, without a
behavior: tied in with its kernel rows, such a kernel moved a simulated flight's track by
metres; ending the run, as it did before, it kept its position-domain result (4.4 m off on an
evaluation drive with phase of ``benchmarks/multi_epoch_fair.py``, where the spans around it
were within 0.4 m) and cut the segment into runs whose pseudoranges were averaged apart.

A run is a maximal sequence of spans of one segment whose epochs follow without a gap and
which each supplied a trajectory with a shared kernel: a span whose epochs keep the WLS fix ends
a run. With range rates a run bridges missed epochs, and epochs WLS could not fix (too few
satellites: in no segment), as ``smoother`` does
(:data:`~gnss_cli.pipeline.smoother.MAX_STEP_INTERVALS`): the runs of spans on either side of a
step of up to five sampling intervals, and the epochs of a segment too short for a window between
them, are one run (:func:`bridged_runs`). The identification stays on uniformly sampled segments
(a kernel is a recursion at the sampling interval), so across such a step there is no switch row;
the quadrature rows, at the epochs' own times, and the phase pair carry the trajectory over it,
and a short segment's epochs are in the run without a behavior (``ok``, their covariance and DOPs
the WLS ones). On the Yamatogawa walk, whose first epoch is two seconds before the rest, that
epoch had kept its WLS fix (1.5 m off horizontally): with phase 0.371 -> 0.358 m horizontal RMS,
with Doppler 0.571 -> 0.566 m (``benchmarks/multi_epoch_fair.py``). A simulated
single-profile canyon drive of ``benchmarks/bench_urban.py`` (seed 10), whose first 29 epochs were
cut off by an epoch of three satellites, had them 25 m off in a run of their own (3D RMS 5.71 m);
bridged, 1.74 m (``smoother`` 2.19 m). Without range rates nothing ties the spans across a gap. A run
whose system is singular keeps the spans' own trajectories; its windows' records say so.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.kinematic_solve import Motion, MotionTerms
from gnss_cli.behavior.piecewise import piecewise_terms, velocity_rule
from gnss_cli.behavior.windows import nominal_step, segments
from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.behavioral import Fit, Segment, WindowJob
from gnss_cli.pipeline.measurements import kinds_text
from gnss_cli.pipeline.results import EpochData, MethodSolution
from gnss_cli.pipeline.smoother import GAP_FACTOR, SegmentRun, solve_segments

__all__ = ["tie_spans", "span_runs", "bridged_runs", "switch_sigma", "SWITCH_SIGMA_FACTOR"]

F64 = NDArray[np.float64]

_MIN_SWITCH_SIGMA_M = 1e-3
#: The switch rows' sigma as a fraction of the untied spans' disagreement (:func:`switch_sigma`),
#: which holds the spans' own estimation noise beside the model's error at the switch. Chosen on
#: the six training runs of ``benchmarks/multi_epoch_fair.py`` (range rates, 20-epoch windows,
#: ``behavior_pfa`` 1e-12; 3D RMS pooled): 1 -> 0.754 m, 0.3 -> 0.645, 0.1 -> 0.625, 0.03 ->
#: 0.622; the largest within 1 % of the best. The noise-free manoeuvring flight stays exact to 1 cm
#: with each (a hard row: 8 cm). Those were measured with the modes' derivatives as velocities; with
#: the quadrature rows (whole segments, chosen since) the factor no longer matters on the same runs:
#: 0.4414, 0.4413, 0.4410, 0.4411 m for 1, 0.3, 0.1, 0.03, so it stays.
SWITCH_SIGMA_FACTOR = 0.1


def _free(fit: Fit, kinds: frozenset[str]) -> bool:
    """Whether a span enters its run without a behavior: its result stayed in the position domain,
    or the run's measurements rejected its windows down to the shortest and it passed with fewer
    of them (:mod:`gnss_cli.pipeline.spans`)."""
    return fit.domain != "measurement" or (fit.measurements is not None and fit.measurements != kinds)


def _why_free(fit: Fit, kinds: frozenset[str]) -> str:
    """The record's words for a span in its run without a behavior (:func:`_free`)."""
    if fit.domain != "measurement":
        return "its result stayed in the position domain"
    return f"its behavior was rejected with {kinds_text(kinds)}"


def span_runs(segs: list[Segment], jobs: list[WindowJob], fits: list[Fit]) -> list[list[int]]:
    """Runs of consecutive spans (indices into ``jobs``) that each supplied a trajectory with a
    shared kernel (module docstring)."""
    out: list[list[int]] = []
    for s in range(len(segs)):
        ks = sorted((k for k, (j, f) in enumerate(zip(jobs, fits)) if j.segment == s and j.hi > j.lo),
                    key=lambda k: jobs[k].lo)
        run: list[int] = []
        for k in ks:
            good = fits[k].w_hat is not None and fits[k].kernel is not None \
                and fits[k].kernel.shared_coefficients is not None  # type: ignore[union-attr]
            if good and run and jobs[run[-1]].hi == jobs[k].lo:
                run.append(k)
                continue
            if run:
                out.append(run)
            run = [k] if good else []
        if run:
            out.append(run)
    return out


def _switch_residuals(jobs: list[WindowJob], fits: list[Fit], run: list[int], lag: int) -> list[F64]:
    """``r_k`` on the spans' own trajectories at each switch of ``run`` (:func:`switch_sigma`)."""
    res = []
    for k, k_next in zip(run[:-1], run[1:]):
        job, nxt = jobs[k], jobs[k_next]
        if job.hi - job.lo < lag or fits[k].domain != "measurement" or fits[k_next].domain != "measurement":
            continue
        w = fits[k].w_hat[job.hi - lag - job.a : job.hi - job.a]  # type: ignore[index]
        w = np.vstack([w, fits[k_next].w_hat[nxt.lo - nxt.a]])  # type: ignore[index]
        res.append(np.asarray(fits[k].kernel.shared_coefficients, dtype=np.float64) @ w)  # type: ignore[union-attr]
    return res


def switch_sigma(jobs: list[WindowJob], fits: list[Fit], runs: list[list[int]], lag: int) -> float:
    """How far the untied spans of a run disagree at their switches (m): the RMS, over its switches
    and the three axes, of ``r_k`` on the spans' own trajectories at each switch (the last ``l``
    epochs of span ``k``, the first of span ``k + 1``); 1 mm at least. It holds the manoeuvres
    between spans and the spans' own errors; the switch rows take :data:`SWITCH_SIGMA_FACTOR` of it.
    ``runs``: the runs of spans a bridged run joins (no switch across a gap)."""
    res = [r for run in runs for r in _switch_residuals(jobs, fits, run, lag)]
    return max(float(np.sqrt(np.mean(np.square(res)))) if res else 0.0, _MIN_SWITCH_SIGMA_M)


Part = tuple[list[int], NDArray[np.intp]]
"""A part of a tied run: a run of spans (indices into the jobs) and its epochs, or no spans and the
epochs of a segment too short for a window."""


def bridged_runs(t: F64, segs: list[Segment], jobs: list[WindowJob], fits: list[Fit], short: NDArray[np.intp],
                 bridge: bool) -> list[list[Part]]:
    """The runs of spans (:func:`span_runs`), each joined with its neighbours across missed epochs
    when ``bridge`` (module docstring): consecutive parts whose epochs follow one another with a step
    of up to :data:`~gnss_cli.pipeline.smoother.MAX_STEP_INTERVALS` sampling intervals, the epochs
    ``short`` of segments too short for a window among them. Every run holds at least one run of spans."""
    parts: list[Part] = [(run, segs[jobs[run[0]].segment].epochs[jobs[run[0]].lo : jobs[run[-1]].hi])
                         for run in span_runs(segs, jobs, fits)]
    if not bridge:
        return [[p] for p in parts]
    parts += [([], g) for g in np.split(short, np.flatnonzero(np.diff(short) > 1) + 1) if g.size]
    member = np.zeros(t.size, dtype=bool)
    for _, e in parts:
        member[e] = True
    fixed = member.copy()  # epochs with a fix: one outside the parts (a span that kept its WLS fixes) ends a run
    for seg in segs:
        fixed[seg.epochs] = True
    have = np.flatnonzero(fixed)  # an epoch without a fix is bridged as a missed one is
    joined = np.full(t.size, -1)  # the smoother's segments of the parts' epochs: one rule for a bridgeable step
    for j, seg in enumerate(segments(t[have], member[have], GAP_FACTOR, nominal_step(t))):
        joined[have[seg]] = j
    out: dict[int, list[Part]] = {}
    for part in sorted(parts, key=lambda p: int(p[1][0])):
        out.setdefault(int(joined[part[1][0]]), []).append(part)
    return [run for run in out.values() if any(spans for spans, _ in run)]


def _run_plan(data: EpochData, segs: list[Segment], jobs: list[WindowJob], fits: list[Fit], run: list[Part],
              kinds: frozenset[str], sigma: float, config: ProcessingConfig) -> tuple[NDArray[np.intp], MotionTerms]:
    """The epochs of a tied run and its piecewise behavior (:func:`piecewise_terms`): each span's kernel,
    the short segments' epochs without a behavior, no switch row across a gap."""
    lag = config.stls.lag
    t = data.time_gps_s
    epochs = np.concatenate([e for _, e in run])
    kernels, starts, dt, windows, free, gap_after = [], [], [], [], [], []
    offset = 0
    for i, (spans, e) in enumerate(run):
        if spans:
            seg, lo = segs[jobs[spans[0]].segment], jobs[spans[0]].lo
            for k in spans:
                kernels.append(np.asarray(fits[k].kernel.shared_coefficients, dtype=np.float64))  # type: ignore[union-attr]
                starts.append(offset + jobs[k].lo - lo)
                dt.append(float(np.median(np.diff(t[seg.epochs[jobs[k].a : jobs[k].b]]))))
                windows.append((offset + jobs[k].a - lo, offset + jobs[k].b - lo))
                free.append(_free(fits[k], kinds))
                gap_after.append(False)
        else:  # a segment too short for a window: its epochs without a behavior
            kernels.append(np.zeros(lag + 1))
            starts.append(offset)
            dt.append(float(np.median(np.diff(t[epochs]))))
            windows.append((offset, offset + e.size))
            free.append(True)
            gap_after.append(False)
        gap_after[-1] = i < len(run) - 1
        offset += e.size
    bridge = {} if len(run) == 1 else {"steps_s": np.diff(t[epochs]), "gap_after": np.array(gap_after)}
    return epochs, piecewise_terms(np.stack(kernels), np.array(starts, dtype=np.intp), epochs.size, np.array(dt), sigma,
                                   "doppler" in kinds, np.array(windows, dtype=np.intp), np.array(free),
                                   config.stls.latency_m, **bridge)


def tie_spans(data: EpochData, wls: MethodSolution, config: ProcessingConfig, segs: list[Segment],
              jobs: list[WindowJob], fits: list[Fit], kinds: frozenset[str], factors: tuple[float, ...],
              short: NDArray[np.intp] | None = None) -> tuple[list[Fit], NDArray[np.bool_], NDArray[np.bool_], F64]:
    """Every run of spans solved together (module docstring).

    Parameters
    ----------
    data, wls, config : the prepared epochs (the WLS satellites and weights), the WLS solution, the configuration.
    segs, jobs, fits : the segments, spans and their fits (:func:`~gnss_cli.pipeline.spans.tested_windows`).
    kinds : the measurement kinds.
    factors : the variance factors of the kinds (those the spans were solved with).
    short : the epochs (with a WLS fix) of segments too short for a window; with range rates a run
        takes them in where only missed epochs separate them from its spans.

    Returns
    -------
    fits : the fits with each tied span's supplied epochs replaced by the joint solution.
    gated : ``(T, n)`` pseudoranges the joint solve's residual gate excluded (on the tied epochs).
    tied : ``(T,)`` the epochs whose position is the joint solution.
    bridged : ``(T, 3)`` ECEF positions (m) of the ``short`` epochs a run took in, NaN elsewhere.
    """
    lag = config.stls.lag
    T = data.time_gps_s.size
    short = np.zeros(0, dtype=np.intp) if short is None else short
    plan: list[tuple[NDArray[np.intp], MotionTerms]] = []
    members: list[list[Part]] = []
    sigmas: list[float] = []
    for run in bridged_runs(data.time_gps_s, segs, jobs, fits, short, "doppler" in kinds):
        if sum(e.size for _, e in run) < lag + 1:
            continue
        sigmas.append(SWITCH_SIGMA_FACTOR * switch_sigma(jobs, fits, [spans for spans, _ in run if spans], lag))
        plan.append(_run_plan(data, segs, jobs, fits, run, kinds, sigmas[-1], config))
        members.append(run)
    gated = np.zeros(data.usable.shape, dtype=bool)
    tied = np.zeros(T, dtype=bool)
    bridged = np.full((T, 3), np.nan)
    if not plan:
        return fits, gated, tied, bridged
    res = solve_segments(data, wls, config, Motion("quadrature"), kinds, factors=factors, plan=plan)
    out = list(fits)
    if res is None:
        return out, gated, tied, bridged
    return _write_back(out, res, plan, members, sigmas, segs, jobs, kinds, config, gated, tied, bridged)


def _write_back(out: list[Fit], res: SegmentRun, plan: list[tuple[NDArray[np.intp], MotionTerms]], members: list[list[Part]],
                sigmas: list[float], segs: list[Segment], jobs: list[WindowJob], kinds: frozenset[str],
                config: ProcessingConfig, gated: NDArray[np.bool_], tied: NDArray[np.bool_],
                bridged: F64) -> tuple[list[Fit], NDArray[np.bool_], NDArray[np.bool_], F64]:
    """The joint solution into the fits of the tied spans (their records say so) and the bridged epochs."""
    lag = config.stls.lag
    rule = velocity_rule(lag, "doppler" in kinds)
    latency = f" kernel rows soft, latency {config.stls.latency_m:.3g} m;" if config.stls.latency_m > 0 else ""
    for (epochs, _), run, bad, sigma, misfit, dof in zip(plan, members, res.degenerate, sigmas, res.misfit, res.dof):
        spans = [k for part, _ in run for k in part]
        if bad:
            for k in spans:
                out[k] = replace(out[k], message=f"{out[k].message}; not tied to its neighbours: the joint system "
                                                 "is singular")
            continue
        tied[epochs] = True
        gated[epochs] = res.gated[epochs]
        extra = sum(e.size for part, e in run if not part)
        across = "" if len(run) == 1 else (
            f", across {len(run) - 1} gap{'s' if len(run) > 2 else ''} of missed epochs"
            + (f" with {extra} epoch{'s' if extra > 1 else ''} of segments too short for a window" if extra else ""))
        for part, e in run:
            if not part:
                bridged[e] = res.x_ecef_m[e]
                continue
            seg = segs[jobs[part[0]].segment]
            for k in part:
                job = jobs[k]
                w_hat = out[k].w_hat.copy()  # type: ignore[union-attr]
                own = seg.epochs[job.lo : job.hi]
                w_hat[job.lo - job.a : job.hi - job.a] = np.einsum("ij,tj->ti", seg.rot, res.x_ecef_m[own] - seg.origin)
                free = f", without its kernel rows ({_why_free(out[k], kinds)})" if _free(out[k], kinds) else ""
                out[k] = replace(out[k], w_hat=w_hat, message=(
                    f"{out[k].message}; its epochs solved with the {len(spans)} spans of their run{across}{free}, "
                    f"tied ({rule}; switch rows sigma {sigma:.3g} m;{latency} run misfit {misfit:.6g} over {dof} dof)"))
    return out, gated, tied, bridged
