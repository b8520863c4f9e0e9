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
