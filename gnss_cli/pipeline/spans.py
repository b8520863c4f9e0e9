"""Spans chosen from the data for ``stls --lag L``: each window's behavior tested, shorter where it fails.

A lag-``L`` behavior holds a trajectory only piecewise: a straight leg, a constant-rate turn or
a steady climb each lie in one, the transitions between them do not (a noise-free manoeuvring
flight in fixed windows of 15 epochs is off by up to 2.7 m from the model class alone). So the
windows' spans are not taken as given. After the measurement-domain alternation
(:mod:`gnss_cli.pipeline.identified`) every window's result is tested against its own
measurements (:func:`~gnss_cli.pipeline.identified.behavior_tests`: the likelihood ratio of the
behavior against free per-epoch positions, velocities and pair displacements, in units of the
file's variance factors, ``chi2(d)`` under the behavior; a phase-pair row the residual gate left
out counts where its pair's own free displacement fits it, so that the gate cannot take away the
very misfit the test is for) at the false-alarm probability ``[stls] behavior_pfa``:

* passed: the window supplies its epochs;
* rejected: its epochs are solved again in windows of half its length, sliding by half of that
  or, where they are cross-faded (pseudoranges alone), by a quarter (:func:`split_window`; not
  below the shortest window the kernel can be identified on,
  :meth:`~gnss_cli.config.StlsConfig.min_window`), each identified and alternated afresh, and
  tested again;
* rejected at the shortest length with range rates or phase: its epochs are solved again without
  the most precise kind (:func:`fewer_measurements`: the phase first, then the range rates), from
  windows of ``[stls] window`` epochs down as above (the window records say which measurements
  each used; tied, such a span takes no kernel rows). A behavior that cannot follow the antenna to
  the millimetres of the phase differences may still hold it at the range rates' centimetres per
  second: going straight to the pseudoranges alone, as before, left a simulated urban drive's
  shortest windows rejected there too, its runs cut by WLS fixes and a minute of it 18.7 m off
  (stls 7.70 m 3D RMS against 1.66 m with this rule, ``smoother`` 1.48 m;
  ``benchmarks/bench_urban.py``, dual profile, seed 10);
* rejected at the shortest length with the pseudoranges alone: its epochs keep their WLS fix,
  status ``fallback_wls``;
* not tested, its result left in the position domain (the alternation could not use the
  measurements: a kernel without a velocity for the range rates, dependent free responses,
  singular normals): kept when no longer than ``[stls] window`` (the span the user gives a
  kernel; whole segments: the shortest window), else as rejected -- with whole segments such an
  untested 150-epoch window of a simulated drive was kept 62 m off. (Splitting the untested
  windows of 15 epochs, the former default, too cost the training flights and drives 0-8 % of
  their RMS.)

With range rates or phase, the spans that passed are then solved together, each in its own
behavior and tied at the switches (:mod:`gnss_cli.pipeline.tied`).

Every tested window stays in the model records, with its statistic, degrees of freedom and
limit; a rejected one says so (status ``rejected``) and which windows took its epochs. A shorter
window that two rejected neighbours both take is solved once
(:func:`~gnss_cli.pipeline.behavioral.distinct_windows`); each
copy has its record, for the epochs it supplies. Windows
left in the position domain have no measurement-domain misfit and no statistic.

The test is how the windows' spans are chosen, part of the method, not a check on faulty
measurements: it runs whatever ``integrity`` says (which switches the checks on the
measurements: the per-epoch tests, the levels, the residual and innovation gates,
docs/integrity.md), and only ``behavior_pfa = 0`` turns it off (then nothing is tested or
split: each window, a whole segment with ``window = 0``, is one kernel). When ``integrity = "off"``
turned the test off too, a whole segment of the Yamatogawa walk was one lag-3 kernel: 4.60 m
horizontal RMS with the pseudoranges, 0.91 m tested (0.94 m with ``fde``); 4.61 m with Doppler,
0.53 m tested (0.57 m; docs/multi-epoch.md gives the command).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from gnss_cli.behavior.windows import windows
from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.behavioral import Fit, Segment, WindowJob, distinct_windows, fit_all, spans_tied
from gnss_cli.pipeline.identified import alternate_windows
from gnss_cli.pipeline.measurements import KINDS, kinds_text
from gnss_cli.pipeline.results import EpochData, MethodSolution

__all__ = ["tested_windows", "split_window", "behavior_limit"]


def behavior_limit(dof: int, pfa: float) -> float:
    """The behavior test's limit: the ``1 - pfa`` quantile of ``chi2(dof)``."""
    return float(chi2.isf(pfa, dof))


def fewer_measurements(used: frozenset[str]) -> frozenset[str]:
    """The measurements a window rejected at the shortest length is solved again with: ``used``
    without its most precise kind (phase, then the range rates)."""
    return used - {next(k for k in reversed(KINDS) if k in used and k != "pseudorange")}


def split_window(job: WindowJob, length: int, n_segment: int, cross_faded: bool = False) -> list[WindowJob]:
    """Windows of ``length`` epochs that take over the epochs ``job`` supplied (``lo:hi``).

    The windows slide over the supplied epochs and half a window either side (within the
    segment of ``n_segment`` epochs), so an epoch at the edge is still near a window's centre;
    each window supplies the supplied epochs nearest its centre, and together they supply
    exactly ``lo:hi``. They slide by half their length, or by a quarter where they are
    ``cross_faded`` (:func:`~gnss_cli.pipeline.behavioral.window_weights`: the pseudoranges
    alone), so that every epoch is estimated by about four of them: on the training flights and
    drives of ``benchmarks/multi_epoch_fair.py`` with the pseudoranges, in whole segments, that
    took the 3D RMS from 1.133 to 1.097 m at twice the windows solved. Where spans are tied (range
    rates or phase) each epoch takes one window's estimate, and a quarter step would only cut
    the spans shorter than their kernel.
    """
    a0 = max(0, min(job.lo - length // 2, n_segment - length))
    b0 = min(n_segment, max(job.hi + length // 2, a0 + length))
    bounds, owner = windows(b0 - a0, length, step=max(1, length // (4 if cross_faded else 2)))
    out = []
    for wi, (a, b) in enumerate(bounds):
        own = np.flatnonzero(owner == wi) + a0
        own = own[(own >= job.lo) & (own < job.hi)]
        if own.size:
            out.append(WindowJob(job.segment, job.window, a0 + a, a0 + b, int(own[0]), int(own[-1]) + 1))
    return out


def tested_windows(data: EpochData, wls: MethodSolution, config: ProcessingConfig, segs: list[Segment],
                   jobs: list[WindowJob], fits: list[Fit], kinds: frozenset[str],
                   factors: tuple[float, ...] | None = None,
                   ) -> tuple[list[WindowJob], list[Fit], NDArray[np.bool_], dict[int, float]]:
    """The measurement-domain windows with spans chosen by the behavior test (module docstring).

    Parameters
    ----------
    data, wls, config, segs, jobs, fits, kinds, factors
        As :func:`~gnss_cli.pipeline.identified.alternate_windows` (``fits``: the position-domain
        fits of ``jobs``).

    Returns
    -------
    jobs, fits : every window solved, in time order and numbered within each segment; a rejected
        window supplies no epoch (``lo == hi``) unless it was the last try, whose epochs keep the
        WLS fix (``w_hat`` None).
    gated : ``(T, n)`` pseudoranges the gate of the window that supplied the epoch excluded.
    limits : the test's limit of every tested window (by index into ``jobs``).
    """
    opts = config.stls
    shortest = opts.min_window()
    trusted = max(opts.window, shortest)  # the longest span an untested kernel may cover
    testing = opts.behavior_pfa > 0
    alone = frozenset({"pseudorange"})
    gated = np.zeros(data.usable.shape, dtype=bool)
    done: list[tuple[WindowJob, Fit, float | None]] = []
    firsts, which = distinct_windows(jobs)
    stage = {kinds: (jobs, which, [jobs[k] for k in firsts], [fits[k] for k in firsts])}
    while stage:
        following: dict[frozenset[str], list[WindowJob]] = {}
        for used, (stage_jobs, which, distinct, distinct_fits) in stage.items():
            solved, runs, factors = alternate_windows(data, wls, config, segs, distinct, distinct_fits, used, factors)
            run_of = {int(k): (run, b) for run in runs for b, k in enumerate(run.jobs)}
            for job, k in zip(stage_jobs, which.tolist()):
                fit = solved[k]
                limit = behavior_limit(fit.test_dof, opts.behavior_pfa) if testing and fit.test_dof else None
                length, n_seg = job.b - job.a, segs[job.segment].epochs.size
                untested = testing and fit.domain != "measurement" and length > trusted
                if not untested and (limit is None or fit.test_stat is None or fit.test_stat <= limit):
                    if fit.domain == "measurement":
                        run, b = run_of[k]
                        own = slice(job.lo - job.a, job.hi - job.a)
                        gated[run.epochs[b, own]] |= run.gated[0, b, own]
                    done.append((job, replace(fit, measurements=used), limit))
                    continue
                why = ("rejected: not tested, its result stayed in the position domain" if untested else
                       f"rejected: behavior test {fit.test_stat:.4g} > {limit:.4g} (chi2, {fit.test_dof} dof)")
                if length > shortest:
                    retry, shorter, what = used, max(shortest, length // 2), "in windows of {n} epochs"
                elif used != alone:
                    retry, shorter = fewer_measurements(used), min(max(opts.window, shortest), n_seg)
                    what = "with " + ("the pseudoranges alone" if retry == alone else kinds_text(retry)) \
                        + " in windows of {n} epochs"
                else:
                    done.append((job, replace(fit, w_hat=None, basis=None, rejected=True,
                                              message=f"{why}; its epochs keep the WLS fix; {fit.message}"), limit))
                    continue
                done.append((replace(job, hi=job.lo), replace(
                    fit, w_hat=None, basis=None, rejected=True,
                    message=f"{why}; its epochs solved again {what.format(n=shorter)}; {fit.message}"), limit))
                following.setdefault(retry, []).extend(split_window(job, shorter, n_seg, not spans_tied(kinds)))
        stage = {}
        for used, more in following.items():
            firsts, which = distinct_windows(more)
            distinct = [more[k] for k in firsts]
            stage[used] = (more, which, distinct, fit_all(segs, distinct, opts))
    done.sort(key=lambda d: (d[0].segment, d[0].a, d[0].b))
    out_jobs, out_fits, limits = [], [], {}
    counter: dict[int, int] = {}
    for job, fit, limit in done:
        number = counter.get(job.segment, 0)
        counter[job.segment] = number + 1
        if limit is not None:
            limits[len(out_jobs)] = limit
        out_jobs.append(replace(job, window=number))
        out_fits.append(fit)
    return out_jobs, out_fits, gated, limits
