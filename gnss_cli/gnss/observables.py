"""Choosing one pseudorange per satellite and epoch from a RINEX observation dataset.

Signal priority per system (first present wins, per satellite and epoch). RINEX 2 codes
are listed beside their RINEX 3 equivalents: ``C1`` is the L1 C/A code (= ``C1C``),
``P1`` the L1 P(Y) code (= ``C1W``). The defaults follow RTKLIB's L1 priority (C/A first),
so both programs use the same observable on the same file; ``gnss_cli/configs/default.toml``
can change them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from gnss_cli.gnss.time import datetime2gps_s
from gnss_cli.io.fixed_width import lli_name

DEFAULT_SIGNAL_PRIORITY: dict[str, tuple[str, ...]] = {
    "G": ("C1C", "C1", "C1W", "P1", "C1X", "C1P"),
    "E": ("C1C", "C1X", "C1B", "C1"),
    "C": ("C2I", "C1I", "C2X", "C1", "C2"),
    "J": ("C1C", "C1X", "C1"),
    "R": ("C1C", "C1", "C1P", "P1"),
}

DEFAULT_SECOND_SIGNAL_PRIORITY: dict[str, tuple[str, ...]] = {
    "G": ("C2P", "C2Y", "C2W", "P2", "C2C", "C2D", "C2L", "C2S", "C2X", "C2"),
    "E": ("C7I", "C7Q", "C7X", "C5I", "C5Q", "C5X"),
    "C": ("C7I", "C7Q", "C7X", "C6I", "C6Q", "C6X"),
    "J": ("C2L", "C2S", "C2X"),
    "R": ("C2P", "P2", "C2C", "C2"),
}
"""Second frequency of the ionosphere-free combination (``gnss_cli/configs/default.toml``
``[signals.second]`` explains the choice): GPS/QZSS L2 (P(Y) first, as RTKLIB), Galileo E5b
then E5a, BeiDou B2I then B3I, GLONASS G2 (P code first)."""


@dataclass(frozen=True)
class Pseudoranges:
    """One pseudorange per satellite and epoch.

    Attributes
    ----------
    time_gps_s : ``(T,)`` reception epochs (receiver time tags), s since the GPS epoch.
    sv : ``(n,)`` satellite ids.
    pr_m : ``(T, n)`` pseudoranges, m (NaN where missing).
    code : ``(T, n)`` observation code used ('' where missing).
    """

    time_gps_s: NDArray[np.float64]
    sv: NDArray[np.str_]
    pr_m: NDArray[np.float64]
    code: NDArray[np.str_]


def codes_for(systems: Sequence[str], priority: Mapping[str, Sequence[str]] | None = None) -> list[str]:
    """All observation codes the priority lists name for ``systems`` (for filtered reading)."""
    prio = DEFAULT_SIGNAL_PRIORITY if priority is None else priority
    out: list[str] = []
    for s in systems:
        for c in prio.get(s, ()):
            if c not in out:
                out.append(c)
    return out


def select_pseudoranges(
    obs: xr.Dataset,
    systems: Sequence[str],
    priority: Mapping[str, Sequence[str]] | None = None,
) -> Pseudoranges:
    """Pick, per satellite and epoch, the first available code of the system's priority list.

    Parameters
    ----------
    obs
        Observation dataset (dims ``time, sv``; one variable per code).
    systems
        System letters to keep.
    priority
        Code priority per system letter (default :data:`DEFAULT_SIGNAL_PRIORITY`).

    Returns
    -------
    Pseudoranges
        Only satellites of ``systems`` with at least one pseudorange; sorted by id.
    """
    prio = DEFAULT_SIGNAL_PRIORITY if priority is None else priority
    svs = np.asarray(obs["sv"].values).astype(str)
    keep = np.isin(np.array([s[:1] for s in svs]), list(systems))
    svs = svs[keep]
    t = datetime2gps_s(obs["time"].values)
    pr = np.full((t.size, svs.size), np.nan)
    code = np.full((t.size, svs.size), "", dtype="<U3")
    sys_of = np.array([s[:1] for s in svs])
    for system in systems:
        cols = np.flatnonzero(sys_of == system)
        if cols.size == 0:
            continue
        sv_idx = np.flatnonzero(keep)[cols]
        for c in prio.get(system, ()):
            if c not in obs:
                continue
            vals = np.asarray(obs[c].values, dtype=np.float64)[:, sv_idx]  # the one variable, not an isel of all
            vals = np.where(vals > 1e6, vals, np.nan)  # zero/blank fields are missing
            take = np.isnan(pr[:, cols]) & np.isfinite(vals)
            block = pr[:, cols]
            block[take] = vals[take]
            pr[:, cols] = block
            cblock = code[:, cols]
            cblock[take] = c
            code[:, cols] = cblock
    have = np.isfinite(pr).any(axis=0)
    order = np.argsort(svs[have], kind="stable")
    return Pseudoranges(t, svs[have][order], pr[:, have][:, order], code[:, have][:, order])


def align_pseudoranges(prs: Pseudoranges, sv: NDArray[np.str_]) -> Pseudoranges:
    """``prs`` on the satellite axis ``sv`` (same epochs): NaN and '' for satellites it lacks."""
    pr = np.full((prs.time_gps_s.size, len(sv)), np.nan)
    code = np.full(pr.shape, "", dtype=prs.code.dtype if prs.code.size else "<U3")
    where = {s: j for j, s in enumerate(prs.sv)}
    src = np.array([where.get(s, -1) for s in sv], dtype=np.intp)
    have = src >= 0
    pr[:, have] = prs.pr_m[:, src[have]]
    code[:, have] = prs.code[:, src[have]]
    return Pseudoranges(prs.time_gps_s, np.asarray(sv), pr, code)


def doppler_code(code: str) -> str:
    """The Doppler observation of a pseudorange code's signal: ``C1C`` -> ``D1C``, ``C1``/``P1`` -> ``D1``.

    Examples
    --------
    >>> doppler_code("C1C"), doppler_code("P1"), doppler_code("C2I")
    ('D1C', 'D1', 'D2I')
    """
    return "D" + code[1:]


def select_dopplers(obs: xr.Dataset, prs: Pseudoranges) -> NDArray[np.float64] | None:
    """``(T, n)`` Doppler (Hz) of the signal of each chosen pseudorange code, on ``prs``'s axes.

    The Doppler of the same signal as the pseudorange (:func:`doppler_code`), so the two share
    the priority order of :data:`DEFAULT_SIGNAL_PRIORITY`. NaN where the file has no value
    (blank, or exactly 0, which some receivers write for a missing Doppler). None when the
    file has no Doppler observation of any chosen code.
    """
    have = [c for c in np.unique(prs.code) if c and doppler_code(str(c)) in obs]
    if not have:
        return None
    col = {sv: i for i, sv in enumerate(np.asarray(obs["sv"].values).astype(str))}
    idx = np.array([col[sv] for sv in prs.sv], dtype=np.intp)
    out = np.full(prs.pr_m.shape, np.nan)
    for c in have:
        vals = np.asarray(obs[doppler_code(str(c))].values, dtype=np.float64)[:, idx]
        use = (prs.code == c) & np.isfinite(vals) & (vals != 0.0)
        out[use] = vals[use]
    return out if np.isfinite(out).any() else None


def phase_code(code: str) -> str:
    """The carrier-phase observation of a pseudorange code's signal: ``C1C`` -> ``L1C``, ``C1``/``P1`` -> ``L1``.

    >>> phase_code("C1C"), phase_code("P1"), phase_code("C2I")
    ('L1C', 'L1', 'L2I')
    """
    return "L" + code[1:]


def select_phases(obs: xr.Dataset, prs: Pseudoranges) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """``(T, n)`` carrier phase (cycles) of the signal of each chosen pseudorange code and its
    loss-of-lock indicator (the reader's ``<code>lli``; 0 where the file has none), on ``prs``'s
    axes, as :func:`select_dopplers`. NaN where the file has no value (blank, or exactly 0). None
    when the file has no phase of any chosen code."""
    have = [c for c in np.unique(prs.code) if c and phase_code(str(c)) in obs]
    if not have:
        return None
    col = {sv: i for i, sv in enumerate(np.asarray(obs["sv"].values).astype(str))}
    idx = np.array([col[sv] for sv in prs.sv], dtype=np.intp)
    out, lli = np.full(prs.pr_m.shape, np.nan), np.zeros(prs.pr_m.shape)
    for c in have:
        code = phase_code(str(c))
        vals = np.asarray(obs[code].values, dtype=np.float64)[:, idx]
        use = (prs.code == c) & np.isfinite(vals) & (vals != 0.0)
        out[use] = vals[use]
        if lli_name(code) in obs:
            flags = np.asarray(obs[lli_name(code)].values, dtype=np.float64)[:, idx]
            lli[use] = np.nan_to_num(flags[use])
    return (out, lli) if np.isfinite(out).any() else None
