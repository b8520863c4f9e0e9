"""Behavioral (multi-epoch) modelling: block-Hankel matrices, kernel representations, STLS.

Pure numerics, no GNSS: a time series is an array ``(T, q)`` (time first), uniformly
sampled; per-epoch covariances are ``(T, q, q)``, ``(T, q)`` or None.

Public API::

    H = hankel(w, depth)                       # (q*depth, T-depth+1)
    K = KernelRepresentation(R)                # R = [R_0 ... R_lag], (p, q(lag+1))
    m, w_hat = misfit(w, K, cov)               # inner problem, O(T)
    res = stls(w, lag, order, cov, structure="full" | "shared", fixed_roots=(1.0,))
    res = wtls(w, lag, order, cov)             # unstructured SVD baseline
    P = projection_matrix(K, T, cov)           # d w_hat / d w for a fixed kernel
    fits = identify_windows(W, lag, cov)       # shared kernels of many short windows (B, N, q) at once
    m, W_hat = project_windows(W, r, cov)      # fixed shared kernel r(z) I for every window

Modules, one job each::

    banded               The block-banded matrix G(R) Sigma G(R)^T of a kernel, its banded Cholesky...
    batch                Shared-kernel STLS and fixed-kernel projections for many short windows at o...
    batch_descent        The lockstep damped Newton descent of identify_windows.
    batch_projection     The inner problem of batch for many short windows at once.
    behavior_solve       A trajectory in the behavior of a fixed shared kernel, from clock-reduced n...
    chart                Affine charts on the set of kernels: the free parameters of the STLS outer...
    covariance           Per-epoch covariances of a vector time series: validation and the products...
    descent              The outer problem of the STLS: a damped Newton (Levenberg--Marquardt) desce...
    hankel               Block-Hankel matrices of vector time series.
    kernel               Kernel representations R(z) = R_0 + R_1 z + ... + R_lag z^lag of linear tim...
    kinematic_solve      Positions and velocities of a whole segment under a fixed motion model, fro...
    multi_epoch          Multi-epoch geometry of a behavior (DESIGN.md section 5): bases, informatio...
    paper_gdop           The paper's STLS GDOP: its TLS GDOP formula carried over to the block-Hank...
    piecewise            A trajectory in a piecewise behavior: consecutive spans, each with its own ...
    projection           The inner problem of the STLS: the closest trajectory of a fixed kernel's b...
    records              Kernel records: what a fitted kernel reports (coefficients, order, poles),...
    result               Result and status types of the behavioral identification (STLS / WTLS).
    starts               Starting kernels of the STLS descent beyond the WTLS kernel.
    stls                 Weighted Hankel structured low-rank approximation (STLS) of a vector time s...
    window_solve         Clock-reduced normal equations of epochs (numerics only).
    windows              Segments and sliding windows of a uniformly sampled series (the smoothing s...
    wtls                 Unstructured (weighted) total least squares kernels: the SVD of the block-H...
"""

from gnss_cli.behavior.banded import SingularGramError
from gnss_cli.behavior.batch import WindowFits, identify_windows, project_windows
from gnss_cli.behavior.covariance import EpochCovariance
from gnss_cli.behavior.hankel import hankel
from gnss_cli.behavior.kernel import KernelRepresentation
from gnss_cli.behavior.result import STATUS_MESSAGES, StlsResult, StlsStatus
from gnss_cli.behavior.stls import misfit, projection_matrix, stls
from gnss_cli.behavior.wtls import wtls

__all__ = [
    "hankel",
    "KernelRepresentation",
    "misfit",
    "stls",
    "wtls",
    "projection_matrix",
    "identify_windows",
    "project_windows",
    "WindowFits",
    "StlsResult",
    "StlsStatus",
    "STATUS_MESSAGES",
    "EpochCovariance",
    "SingularGramError",
]
