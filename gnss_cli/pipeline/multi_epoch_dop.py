"""DOP columns of the multi-epoch methods: unit-weight geometry of the pseudoranges under the motion model.

The ``gdop``, ``pdop``, ``hdop``, ``vdop``, ``tdop`` (and ``tdop_<system>``) columns of every
multi-epoch row are geometry, as the snapshot rows' (DESIGN.md sections 5 and 6): over the
window of ``N`` epochs centred on the epoch (clipped to its segment), with behavior basis ``O``
of the method's motion model (trajectories ``O x0``, clocks free per epoch and system),
``G_N = [blkdiag(A_t^pos) O, blkdiag(C_t)]`` and ``Q = (G_N^T G_N)^-1`` with unit weights on the
pseudoranges the method used. The epoch's (position, clocks) block of ``Q``, its position
rotated to local ENU at the epoch's position, gives the DOPs. Doppler, carrier phase, priors,
process noise and the measurement weights are not in it: the precision from all of them is
the covariance (``sde_m``...). Adding the behavior can only add information, so the
multi-epoch DOP never exceeds the snapshot DOP of the same epoch.

Motion models (:data:`MOTION_KERNELS`, shared kernels ``r(z) I_3``):

``static``      ``(z - 1) I``      the receiver does not move;
``cv``          ``(z - 1)^2 I``    constant velocity (``kf`` with ``model = "cv"``);
``ca``          ``(z - 1)^3 I``    constant acceleration (``smoother --motion ca``, ``kf`` ``ca``);
``quadrature``  ``(z - 1)^3 I``    the lag-L velocity quadrature of ``smoother --motion quadrature``.

Why ``(z - 1)^3 I`` for the quadrature: its velocities are free inputs observed only by the range
rates, so with the pseudoranges alone its position behavior is every trajectory -- the geometry
would be the snapshot's. What ties the positions is the weak prior on the velocities' second
difference (:data:`~gnss_cli.behavior.kinematic_solve.JERK_SIGMA_M_S3`): the trajectories it
leaves free are those of constant acceleration, on which the lag 1, 2 and 3 rules are all exact.
So the geometry of the smoother without Doppler is that of ``(z - 1)^3 I``, the same as ``ca``.
An identified kernel (``stls --lag L``) is given per epoch: the kernel of the window that
supplied the epoch's estimate.

An epoch whose window has fewer epochs than the kernel needs (``lag + 1``: with ``lag`` or fewer
the behavior is every trajectory), an epoch without a kernel (None) and an epoch outside the
segments get the snapshot DOP of its own pseudoranges. A window whose geometry does not observe
some trajectory of the behavior is *degenerate* (reported, :class:`DopColumns`): the epoch's DOPs
are still finite when its own position is determined (the unobserved trajectories vanish there),
else inf.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior import KernelRepresentation
from gnss_cli.behavior.multi_epoch import behavior_basis, epoch_information_root, shared_behavior_bases, target_covs
from gnss_cli.behavior.paper_gdop import DegeneratePaperGdopError, paper_stls_gdop, paper_stls_hankel
from gnss_cli.errors import UsageError
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.solvers.dop import dop_from_cov

__all__ = ["DopColumns", "MOTION_KERNELS", "DOP_WINDOW_EPOCHS", "motion_kernel", "multi_epoch_dops", "with_geometry_dops",
           "PaperGdopColumn", "paper_stls_gdops", "with_paper_gdop"]

F64 = NDArray[np.float64]

_EPOCH_BLOCK = 8192

#: Scalar kernel coefficients ``[r_0 .. r_lag]`` (ascending powers) of each motion model.
MOTION_KERNELS: dict[str, tuple[float, ...]] = {
    "static": (-1.0, 1.0), "cv": (1.0, -2.0, 1.0), "ca": (-1.0, 3.0, -3.0, 1.0), "quadrature": (-1.0, 3.0, -3.0, 1.0),
}
DOP_WINDOW_EPOCHS = 15
"""Window (epochs) of the geometry DOPs of ``smoother`` and ``kf`` rows, which estimate whole
segments: the window of ``stls --lag L`` (``[stls] window``), so that the DOP columns of the
three multi-epoch methods describe the same span of geometry."""


def motion_kernel(motion: str) -> KernelRepresentation:
    """The shared kernel ``r(z) I_3`` of a motion model (module docstring).

    >>> motion_kernel("cv").shared_coefficients().tolist()
    [1.0, -2.0, 1.0]
    """
    if motion not in MOTION_KERNELS:
        raise UsageError(f"motion: expected one of {', '.join(MOTION_KERNELS)}; received {motion!r}")
    return KernelRepresentation.shared(MOTION_KERNELS[motion], 3)


@dataclass(frozen=True, slots=True)
class DopColumns:
    """Geometry DOPs of every epoch (unitless).

    Attributes
    ----------
    gdop, pdop, hdop, vdop, tdop : ``(T,)``. ``gdop`` includes every clock with pseudoranges at
        the epoch; ``tdop`` is the first clock's (``tdops[:, 0]``). NaN where the epoch has no
        position; inf where its position is not determined by the window's geometry.
    tdops : ``(T, k)`` per clock (system); NaN also where the system has no pseudorange at the epoch
        (its clock is not estimated there).
    window_epochs : ``(T,)`` epochs of the window that gave the row: 1 for the snapshot DOP, 0 for
        an epoch without position.
    cond : ``(T,)`` condition number of the window's clock-reduced geometry (``s_max / s_min`` of
        the stacked rows); inf for a degenerate window.
    degenerate : ``(T,)`` the epoch's window (or snapshot) geometry is rank deficient.
    n_degenerate_windows : distinct degenerate windows of epochs with a position (a snapshot is a
        window of one epoch).
    """

    gdop: F64
    pdop: F64
    hdop: F64
    vdop: F64
    tdop: F64
    tdops: F64
    window_epochs: NDArray[np.int64]
    cond: F64
    degenerate: NDArray[np.bool_]
    n_degenerate_windows: int


def _checked(A_pos: F64, clock_cols: F64 | None, used: NDArray[np.bool_], x_ecef_m: F64,
             segments: Sequence[NDArray[np.intp]], window_epochs: int) -> tuple[F64, F64, NDArray[np.bool_], F64]:
    """Validated arrays: A_pos, clock_cols (T, n, k), used (only finite rows), x_ecef_m."""
    a = np.asarray(A_pos, dtype=np.float64)
    if a.ndim != 3 or a.shape[2] != 3:
        raise UsageError(f"multi_epoch_dops: 'A_pos' must have shape (T, n, 3); received shape {a.shape}")
    T, n = a.shape[:2]
    u = np.asarray(used)
    if u.shape != (T, n) or u.dtype != np.bool_:
        raise UsageError(f"multi_epoch_dops: 'used' must be a bool array of shape {(T, n)}; received {u.dtype} {u.shape}")
    c = np.ones((T, n, 1)) if clock_cols is None else np.asarray(clock_cols, dtype=np.float64)
    if c.ndim == 2:
        c = np.broadcast_to(c, (T, *c.shape))
    if c.ndim != 3 or c.shape[:2] != (T, n) or c.shape[2] < 1:
        raise UsageError(f"multi_epoch_dops: 'clock_cols' must have shape (T, n, k) or (n, k) with T={T}, n={n}; "
                         f"received shape {np.shape(clock_cols)}")
    x = np.asarray(x_ecef_m, dtype=np.float64)
    if x.shape != (T, 3):
        raise UsageError(f"multi_epoch_dops: 'x_ecef_m' must have shape {(T, 3)}; received shape {x.shape}")
    has_x = np.isfinite(x).all(axis=1)
    finite = np.isfinite(a).all(axis=2) & np.isfinite(c).all(axis=2)
    if np.any(u & ~finite & has_x[:, None]):
        raise UsageError("multi_epoch_dops: 'A_pos' or 'clock_cols' has non-finite values in used rows "
                         "of an epoch with a position")
    if isinstance(window_epochs, bool) or not isinstance(window_epochs, (int, np.integer)) or window_epochs < 1:
        raise UsageError(f"multi_epoch_dops: 'window_epochs' must be an integer >= 1; received {window_epochs!r}")
    seen = np.zeros(T, dtype=bool)
    for seg in segments:
        s = np.asarray(seg)
        if s.ndim != 1 or not np.issubdtype(s.dtype, np.integer) or (s.size and (s.min() < 0 or s.max() >= T)) \
                or np.any(np.diff(s) <= 0) or seen[s].any():
            raise UsageError("multi_epoch_dops: 'segments' must be disjoint increasing arrays of epoch indices in "
                             f"[0, {T})")
        seen[s] = True
    return a, c, u & finite, x


def _kernel_list(kernels: KernelRepresentation | Sequence[KernelRepresentation | None], T: int
                 ) -> tuple[list[KernelRepresentation], NDArray[np.intp]]:
    """Distinct kernels and the index of each epoch's (-1: none)."""
    if isinstance(kernels, KernelRepresentation):
        kernels = [kernels] * T
    if len(kernels) != T:
        raise UsageError(f"multi_epoch_dops: 'kernels' must be one KernelRepresentation or one per epoch ({T}); "
                         f"received {len(kernels)}")
    distinct: dict[int, int] = {}
    out: list[KernelRepresentation] = []
    kid = np.full(T, -1, dtype=np.intp)
    for t, ker in enumerate(kernels):
        if ker is None:
            continue
        if id(ker) not in distinct:
            if not isinstance(ker, KernelRepresentation) or ker.p != 3 or ker.q != 3:
                raise UsageError("multi_epoch_dops: each kernel must be a square KernelRepresentation on 3 position "
                                 f"coordinates; received {ker!r}")
            distinct[id(ker)] = len(out)
            out.append(ker)
        kid[t] = distinct[id(ker)]
    return out, kid


def _bases(kers: list[KernelRepresentation], pairs: NDArray[np.intp], frames: F64) -> list[F64 | None]:
    """ECEF behavior bases ``(N, 3, d)`` of (kernel, length, segment) triples; None where ``R_lag`` is singular.

    Shared kernels ``r(z) I_3`` do not depend on the frame and are computed in batches."""
    out: list[F64 | None] = [None] * len(pairs)
    shared: dict[tuple[int, int], list[int]] = {}
    for j, (k, n_t, seg) in enumerate(pairs):
        ker = kers[k]
        if ker.is_shared(rtol=1e-12):
            shared.setdefault((int(n_t), ker.lag), []).append(j)
            continue
        try:
            basis = behavior_basis(ker.normalized(), int(n_t))
        except (UsageError, np.linalg.LinAlgError):
            continue
        out[j] = np.einsum("ji,tjk->tik", frames[seg], basis)  # frame -> ECEF: R^T
    for (n_t, _), members in shared.items():
        r = np.stack([kers[pairs[j][0]].blocks[:, 0, 0] for j in members])
        for j, basis in zip(members, shared_behavior_bases(r, n_t, 3)):
            out[j] = basis
    return out


def _plan(segments: Sequence[NDArray[np.intp]], kers: list[KernelRepresentation], kid: NDArray[np.intp],
          n_win: int, T: int) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """Each epoch's window: segment (-1: snapshot), start in the segment, length, and the epoch's
    position in the segment."""
    seg_of = np.full(T, -1, dtype=np.intp)
    start = np.zeros(T, dtype=np.intp)
    length = np.ones(T, dtype=np.intp)
    local = np.zeros(T, dtype=np.intp)
    need = np.array([ker.lag + 1 for ker in kers] + [np.iinfo(np.intp).max], dtype=np.intp)[kid]  # kid -1: never
    for si, seg in enumerate(segments):
        seg = np.asarray(seg, dtype=np.intp)
        n_len = min(n_win, seg.size)
        a0 = np.clip(np.arange(seg.size) - (n_win - 1) // 2, 0, seg.size - n_len)
        multi = need[seg] <= n_len
        seg_of[seg[multi]] = si
        start[seg[multi]] = a0[multi]
        length[seg[multi]] = n_len
        local[seg] = np.arange(seg.size)
    return seg_of, start, length, local


def multi_epoch_dops(
    A_pos: F64,
    clock_cols: F64 | None,
    used: NDArray[np.bool_],
    x_ecef_m: F64,
    segments: Sequence[NDArray[np.intp]],
    kernels: KernelRepresentation | Sequence[KernelRepresentation | None],
    window_epochs: int,
    *,
    kernel_frames: Sequence[F64] | None = None,
    rcond: float | None = None,
) -> DopColumns:
    """Geometry DOPs of multi-epoch rows: unit-weight ``(G_N^T G_N)^-1`` of the pseudoranges under a motion model.

    Parameters
    ----------
    A_pos : ndarray, shape (T, n, 3)
        Position columns of the pseudorange rows, ``-e`` (unit line of sight); ``linearize(...).A[..., :3]``
        or ``-Measurements.unit``. Rows not used may hold anything.
    clock_cols : ndarray, shape (T, n, k) or (n, k), or None
        Clock columns (one-hot per system, ``linearize(...).A[..., 3:]``); None: one clock.
    used : ndarray of bool, shape (T, n)
        The pseudoranges the method used (not the clock-fixing constraint rows of ``linearize``).
    x_ecef_m : ndarray, shape (T, 3)
        The method's positions (ECEF, m): the ENU rotation of each epoch; NaN: no position (NaN DOPs).
    segments : sequence of int arrays
        Runs of consecutive, uniformly sampled epochs (disjoint, increasing) the windows stay in.
        Epochs outside them get the snapshot DOP.
    kernels : KernelRepresentation or sequence of (KernelRepresentation or None), length T
        The motion model (:func:`motion_kernel`), or each epoch's kernel (an identified kernel:
        the one of the window that supplied the epoch; None: snapshot DOP). ``p = q = 3``.
    window_epochs : int
        ``N``, epochs of the window centred on each epoch (``t - (N - 1) // 2`` to
        ``t + N // 2``), shifted to stay in the segment; the whole segment if it is shorter.
    kernel_frames : sequence of (3, 3) arrays, optional
        Per segment, the rotation ECEF -> the frame a non-shared kernel acts in (default: local
        ENU at the segment's first epoch with a position, as the smoother's). Shared kernels
        ``r(z) I_3`` do not depend on it.
    rcond : float, optional
        Relative rank tolerance of a window's geometry (:func:`~gnss_cli.behavior.multi_epoch.target_covs`).

    Returns
    -------
    DopColumns

    Raises
    ------
    UsageError
        Wrong shapes, overlapping segments, a kernel that is not square on 3 coordinates,
        non-finite used rows at an epoch with a position.

    Notes
    -----
    ``G_N = [blkdiag(A_t^pos) O, blkdiag(C_t)]`` over the window's epochs, ``O`` the orthonormal
    behavior basis of the kernel over ``N`` epochs; epoch ``t``'s block of ``(G_N^T G_N)^+`` is
    computed with each epoch's clocks eliminated and the stacked clock-reduced rows factored by
    QR (an SVD for a nearly singular window; :func:`~gnss_cli.behavior.multi_epoch.target_covs`). With identical geometry at every
    epoch and the static kernel, ``PDOP_N = PDOP_1 / sqrt(N)`` and ``TDOP_N^2 - 1/n =
    (TDOP_1^2 - 1/n) / N`` (each clock keeps the ``1/n`` of its own epoch's pseudoranges).

    Examples
    --------
    >>> import numpy as np
    >>> e = np.array([[0.0, 0, 1], [1, 0, 1], [0, 1, 1], [-1, 0, 1], [0, -1, 1]])
    >>> A = np.broadcast_to(-e / np.linalg.norm(e, axis=1, keepdims=True), (4, 5, 3))
    >>> x = np.broadcast_to([6378137.0, 0.0, 0.0], (4, 3))
    >>> d = multi_epoch_dops(A, None, np.ones((4, 5), bool), x, [np.arange(4)], motion_kernel("static"), 4)
    >>> snap = multi_epoch_dops(A, None, np.ones((4, 5), bool), x, [], motion_kernel("static"), 4)
    >>> bool(np.allclose(d.pdop, snap.pdop / 2))
    True
    """
    a, c, u, x = _checked(A_pos, clock_cols, used, x_ecef_m, segments, window_epochs)
    T, k = a.shape[0], c.shape[2]
    kers, kid = _kernel_list(kernels, T)
    segs = [np.asarray(s, dtype=np.intp) for s in segments]
    root, h, clock_var = np.empty((T, 3, 3)), np.empty((T, k, 3)), np.empty((T, k))
    for e0 in range(0, T, _EPOCH_BLOCK):  # bounded temporaries: a day of multi-GNSS rows is (86400, 40, 3)
        blk = slice(e0, min(T, e0 + _EPOCH_BLOCK))
        root[blk], h[blk], clock_var[blk] = epoch_information_root(a[blk], u[blk].astype(np.float64), c[blk])
    seg_of, start, length, local = _plan(segs, kers, kid, int(window_epochs), T)
    frames = _frames(segs, x, kernel_frames)
    # the basis of each epoch's window: distinct (kernel, length, frame's segment) triples
    multi = seg_of >= 0
    shared = np.array([ker.is_shared(rtol=1e-12) for ker in kers] + [False], dtype=bool)
    frame_seg = np.where(shared[kid], 0, seg_of)  # kid -1 (no kernel) is never multi
    triples, basis_of = np.unique(np.stack([kid, length, frame_seg], axis=1)[multi], axis=0, return_inverse=True)
    bases = _bases(kers, triples, frames)
    missing = np.array([b is None for b in bases], dtype=bool)
    multi[np.flatnonzero(multi)[missing[basis_of.ravel()]]] = False  # R_lag singular: the snapshot
    epoch_basis = np.full(T, -1, dtype=np.intp)
    epoch_basis[seg_of >= 0] = basis_of.ravel()
    seg_of[~multi], start[~multi], length[~multi], epoch_basis[~multi] = -1, np.arange(T)[~multi], 1, -1
    position = np.where(multi, local - start, 0)
    return _columns(root, h, clock_var, segs, (seg_of, start, length, position, epoch_basis), bases, x, rcond)


def _frames(segs: list[NDArray[np.intp]], x: F64, kernel_frames: Sequence[F64] | None) -> F64:
    """``(S, 3, 3)`` ECEF -> kernel-frame rotations per segment."""
    if kernel_frames is not None:
        f = np.asarray(kernel_frames, dtype=np.float64)
        if f.shape != (len(segs), 3, 3):
            raise UsageError(f"multi_epoch_dops: 'kernel_frames' must have shape {(len(segs), 3, 3)}; received {f.shape}")
        return f
    out = np.tile(np.eye(3), (max(len(segs), 1), 1, 1))
    for si, seg in enumerate(segs):
        ok = seg[np.isfinite(x[seg]).all(axis=1)]
        if ok.size:
            lat, lon, _ = ecef2geodetic(x[ok[0]])
            out[si] = ecef2enu_rotation(float(lat), float(lon))
    return out


def _columns(root: F64, h: F64, clock_var: F64, segs: list[NDArray[np.intp]],
             plan: tuple[NDArray[np.intp], ...], bases: list[F64 | None], x: F64, rcond: float | None) -> DopColumns:
    """The windows' covariance blocks (one :func:`target_covs` per window shape) and the DOP columns.

    ``plan``: per epoch, its window's segment (-1: snapshot) and start (for a snapshot: the epoch),
    length, the epoch's position in it and the window's basis (index into ``bases``, -1: ``I_3``)."""
    seg_of, start, length, position, epoch_basis = plan
    T, k = clock_var.shape
    cov = np.full((T, 3 + k, 3 + k), np.nan)
    determined = np.zeros(T, dtype=bool)
    cond = np.full(T, np.inf)
    full_rank = np.zeros(T, dtype=bool)
    flat = np.concatenate([*segs, np.arange(T, dtype=np.intp)])  # the segments, then every epoch (snapshots)
    offset = np.cumsum([0] + [s.size for s in segs])
    first = np.where(seg_of >= 0, offset[np.maximum(seg_of, 0)] + start, offset[-1] + start)
    d_of = np.array([3] + [0 if b is None else b.shape[-1] for b in bases])[epoch_basis + 1]
    all_bases = [np.eye(3)[None, None]] + [np.zeros((0, 0, 3, 0)) if b is None else b[None] for b in bases]
    has_x = np.isfinite(x).all(axis=1)
    n_degenerate = 0
    for n_len, d in sorted(set(zip(length.tolist(), d_of.tolist()))):
        members = np.flatnonzero((length == n_len) & (d_of == d))
        # a window: its first epoch (in ``flat``) and its basis, as one integer key
        keys, window_of = np.unique(first[members] * (len(bases) + 1) + epoch_basis[members] + 1, return_inverse=True)
        used_bases, basis_of = np.unique(keys % (len(bases) + 1), return_inverse=True)
        stack = np.concatenate([all_bases[b] for b in used_bases])
        spans = flat[(keys // (len(bases) + 1))[:, None] + np.arange(n_len)]
        res = target_covs(root, h, clock_var, spans, stack, basis_of, window_of, position[members], rcond=rcond)
        cov[members], determined[members], cond[members], full_rank[members] = res.cov, res.determined, res.cond, res.full_rank
        n_degenerate += int(np.unique(window_of[~res.full_rank & has_x[members]]).size)
    return _dop_columns(cov, determined, cond, ~full_rank, clock_var, x, length, n_degenerate)


def _dop_columns(cov: F64, determined: NDArray[np.bool_], cond: F64, degenerate: NDArray[np.bool_], clock_var: F64,
                 x: F64, length: NDArray[np.intp], n_degenerate: int) -> DopColumns:
    """DOPs of the covariance blocks: ENU at each position; inf where not determined, NaN without position."""
    T, k = clock_var.shape
    has_x = np.isfinite(x).all(axis=1)
    out = {name: np.full(T, np.nan) for name in ("gdop", "pdop", "hdop", "vdop", "tdop")}
    tdops = np.full((T, k), np.nan)
    ok = np.flatnonzero(has_x & determined)
    if ok.size:
        lat, lon, _ = ecef2geodetic(x[ok])
        d = dop_from_cov(cov[ok], ecef2enu_rotation(lat, lon))
        for name in out:
            out[name][ok] = getattr(d, name)
        present = clock_var[ok] > 0
        q_clk = cov[ok][:, 3 + np.arange(k), 3 + np.arange(k)]
        tdops[ok] = np.where(present, np.sqrt(np.clip(q_clk, 0.0, None)), np.nan)
        out["tdop"][ok] = tdops[ok, 0]
    lost = has_x & ~determined
    for name in ("gdop", "pdop", "hdop", "vdop"):
        out[name][lost] = np.inf
    tdops[lost] = np.where(clock_var[lost] > 0, np.inf, np.nan)
    out["tdop"][lost] = tdops[lost, 0]
    return DopColumns(**out, tdops=tdops, window_epochs=np.where(has_x, length, 0).astype(np.int64),
                      cond=np.where(has_x, cond, np.nan), degenerate=degenerate & has_x,
                      n_degenerate_windows=n_degenerate)


def with_geometry_dops(data: Any, sol: Any, config: Any, motion: str,
                       window_epochs: int = DOP_WINDOW_EPOCHS, gap_factor: float = 1.5) -> Any:
    """``sol`` (a multi-epoch method's :class:`~gnss_cli.pipeline.results.MethodSolution` on the
    epochs ``data``) with its DOP columns replaced by the geometry of :func:`multi_epoch_dops`
    under the fixed ``motion`` model: the pseudoranges the method used (finite residuals) at its
    positions, windows of ``window_epochs`` within the runs of uniformly sampled epochs with a
    position. Degenerate windows are counted in ``data``-independent terms: their epochs keep
    inf DOPs (an empty CSV cell)."""
    from dataclasses import replace

    from gnss_cli.behavior.windows import segments
    from gnss_cli.gnss.range_model import linearize

    has = np.all(np.isfinite(sol.x_ecef_m), axis=1)
    rows = np.flatnonzero(has)
    if not rows.size:
        return sol
    T, n = data.time_gps_s.size, data.sv.size
    k = sol.clocks_m.shape[1]
    lin = linearize(data, rows, sol.x_ecef_m[rows], np.zeros((rows.size, k)), config)
    A_pos = np.zeros((T, n, 3))
    clock_cols = np.zeros((T, n, k))
    A_pos[rows] = lin.A[:, :n, :3]
    clock_cols[rows] = lin.A[:, :n, 3:]
    used = np.isfinite(sol.residuals_m) & has[:, None]
    d = multi_epoch_dops(A_pos, clock_cols, used, sol.x_ecef_m, segments(data.time_gps_s, has, gap_factor),
                         motion_kernel(motion), window_epochs)
    tdops = None if sol.tdops is None else d.tdops
    return replace(sol, gdop=d.gdop, pdop=d.pdop, hdop=d.hdop, vdop=d.vdop, tdop=d.tdop, tdops=tdops)


@dataclass(frozen=True, slots=True)
class PaperGdopColumn:
    """The paper's STLS GDOP of the epochs of ``stls --lag L`` rows (:mod:`gnss_cli.behavior.paper_gdop`).

    Attributes
    ----------
    gdop_paper : ``(T,)`` the value of the window that supplied each epoch, 1/m (it is the gain of
        the identified kernel's parameters from the window's fixes, not a geometry DOP); NaN for an
        epoch no window supplied and for the epochs of a window where the formula is degenerate.
    n_windows : windows evaluated.
    degenerate : ``((index, message), ...)`` one per window where the formula does not exist
        (nongeneric ``H_p H_p^T - s^2 I``, lag 1 with the shared kernel's fixed root): its index
        in the ``windows`` given, and why.
    """

    gdop_paper: F64
    n_windows: int
    degenerate: tuple[tuple[int, str], ...]


def paper_stls_gdops(n_epochs: int, windows: Iterable[tuple[F64, NDArray[np.intp]]], lag: int,
                     structure: str = "shared") -> PaperGdopColumn:
    """The paper's STLS GDOP per window, written to the epochs each window supplies.

    Parameters
    ----------
    n_epochs : int
        ``T``, length of the column.
    windows : iterable of (w, epochs)
        Each window's trajectory ``w`` ``(N, 3)`` (the fixes the kernel was identified from, ENU, m)
        and the epoch indices ``(k,)`` whose estimate it supplied.
    lag, structure : int, {"shared", "full"}
        The identified kernel class (``[stls] lag`` and ``kernel``); the shared kernel keeps its
        fixed root at ``z = 1`` (:func:`~gnss_cli.behavior.paper_gdop.paper_stls_hankel`).

    Returns
    -------
    PaperGdopColumn

    Raises
    ------
    UsageError
        A window's ``w`` is not a finite ``(N, 3)`` array or too short for ``lag``; ``epochs``
        out of range.
    """
    out = np.full(int(n_epochs), np.nan)
    degenerate: list[tuple[int, str]] = []
    n = 0
    for w, epochs in windows:
        e = np.asarray(epochs, dtype=np.intp)
        if e.size and (e.min() < 0 or e.max() >= out.size):
            raise UsageError(f"paper_stls_gdops: window epochs must be in [0, {out.size}); received {e.min()}..{e.max()}")
        n += 1
        try:
            out[e] = paper_stls_gdop(*paper_stls_hankel(w, lag, structure)).gdop
        except DegeneratePaperGdopError as err:
            degenerate.append((n - 1, str(err)))
    return PaperGdopColumn(out, n, tuple(degenerate))


def with_paper_gdop(sol: Any, segs: Sequence[Any], jobs: Sequence[Any], fits: Sequence[Any], lag: int,
                    structure: str) -> tuple[Any, dict[int, str]]:
    """``sol`` (an ``stls --lag L`` :class:`~gnss_cli.pipeline.results.MethodSolution`) with
    ``gdop_paper`` from :func:`paper_stls_gdops`, and why the formula does not exist for a window
    (``{job index: message}``; the caller records it with the window).

    ``segs``, ``jobs``, ``fits``: the segments (``.w`` ENU fixes, ``.epochs``), windows (``.segment``,
    ``.a:.b`` the window, ``.lo:.hi`` the epochs it supplies, segment-local) and fits (``.w_hat``
    None for a failed window) of :mod:`gnss_cli.pipeline.behavioral`. Each epoch gets the value of
    the window that supplied it; NaN (an empty cell) where the epoch has no position, no window
    supplied it or the formula is degenerate for its window. Always an array, so the column is
    present for these rows."""
    from dataclasses import replace

    used = [k for k, f in enumerate(fits) if f.w_hat is not None]
    windows = [(segs[jobs[k].segment].w[jobs[k].a : jobs[k].b], segs[jobs[k].segment].epochs[jobs[k].lo : jobs[k].hi])
               for k in used]
    col = paper_stls_gdops(sol.x_ecef_m.shape[0], windows, lag, structure)
    degenerate = {used[i]: message for i, message in col.degenerate}
    return replace(sol, gdop_paper=np.where(np.all(np.isfinite(sol.x_ecef_m), axis=1), col.gdop_paper, np.nan)), degenerate
