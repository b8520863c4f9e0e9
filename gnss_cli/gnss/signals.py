"""Signals of RINEX pseudorange codes: carrier frequency, broadcast group delay, iono-free pair.

Every broadcast satellite clock refers to one signal or one ionosphere-free pair of signals;
a pseudorange on another signal carries a group delay ``d_s`` relative to that clock, so
``P_s - c d_s = rho + c (dt_rx - dt_sv) + I_s + T`` (IS-GPS-200 20.3.3.3.3.2, Galileo OS SIS
ICD 5.1.5, BDS-SIS-ICD-B1I 5.2.4.10; the same conventions as RTKLIB 2.4.3 ``pntpos.c``):

========  ===========================  ===========================================
system    clock refers to              group delay ``d_s`` (s)
========  ===========================  ===========================================
GPS/QZSS  L1/L2 P(Y) iono-free (LNAV)  L1: TGD, L2: ``(f_L1/f_L2)^2`` TGD
Galileo   I/NAV: E1/E5b; F/NAV: E1/E5a E1: BGD_x, E5x: ``g_x`` BGD_x,
                                       E5y: BGD_x - (1 - ``g_y``) BGD_y
BeiDou    B3I (D1/D2 messages)         B1I: TGD1, B2I: TGD2, B3I: 0
GLONASS   (no broadcast delay in RINEX) G1: 0, G2: 0
========  ===========================  ===========================================

Galileo: x is the pair of the record's clock (E5b for I/NAV, E5a for F/NAV), y the other
E5 signal, ``g = (f_E1/f_E5)^2`` and BGD_y the record's other BGD
(:attr:`~gnss_cli.gnss.ephemeris.KeplerEphemeris.tgd2_s`). With the delays removed, the
ionosphere-free combination of two signals refers to the broadcast clock:

    P_IF = (f1^2 (P1 - c d1) - f2^2 (P2 - c d2)) / (f1^2 - f2^2)

The first-order ionospheric delay (``I_s ~ 1/f_s^2``) cancels. For the pair the clock refers
to (GPS L1/L2, Galileo E1/E5b with I/NAV) the delays cancel too and ``P_IF`` is the plain
combination. GLONASS FDMA: G1 = 1602 + k 0.5625 MHz and G2 = 1246 + k 0.4375 MHz, so
``f_G1/f_G2 = 9/7`` on every channel k; the frequencies are still taken per channel.

Signals whose group delay is not in the RINEX navigation records of this reader (GPS/QZSS
L5 needs the CNAV ISCs, BeiDou B1C/B2a/B2b the B-CNAV delays; Galileo E6, GLONASS G3) are
not combined: :func:`iono_free_pseudorange_m` gives NaN for them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.constants import C_M_S, FREQ_B1I_HZ, FREQ_B3I_HZ, FREQ_E5B_HZ, FREQ_L1_HZ, FREQ_L2_HZ, FREQ_L5_HZ
from gnss_cli.gnss.glonass import DFREQ_G1_HZ, DFREQ_G2_HZ, FREQ_G1_HZ, FREQ_G2_HZ

F64 = NDArray[np.float64]

_FIXED_FREQUENCY_HZ = {
    "L1": FREQ_L1_HZ, "L2": FREQ_L2_HZ, "L5": FREQ_L5_HZ, "L6": 1_278.75e6,
    "E1": FREQ_L1_HZ, "E5a": FREQ_L5_HZ, "E5b": FREQ_E5B_HZ, "E5": 1_191.795e6, "E6": 1_278.75e6,
    "B1I": FREQ_B1I_HZ, "B1C": FREQ_L1_HZ, "B2I": FREQ_E5B_HZ, "B2b": FREQ_E5B_HZ,
    "B2a": FREQ_L5_HZ, "B2ab": 1_191.795e6, "B3I": FREQ_B3I_HZ,
    "G3": 1_202.025e6, "G1a": 1_600.995e6, "G2a": 1_248.06e6,
}  # fmt: skip

_BANDS = {
    "G": {"1": "L1", "2": "L2", "5": "L5"},
    "J": {"1": "L1", "2": "L2", "5": "L5", "6": "L6"},
    "E": {"1": "E1", "5": "E5a", "7": "E5b", "8": "E5", "6": "E6"},
    "C": {"2": "B1I", "1": "B1C", "7": "B2I", "5": "B2a", "8": "B2ab", "6": "B3I"},
    "R": {"1": "G1", "2": "G2", "3": "G3", "4": "G1a", "6": "G2a"},
}

IONO_FREE_SIGNALS: dict[str, tuple[str, ...]] = {
    "G": ("L1", "L2"),
    "J": ("L1", "L2"),
    "E": ("E1", "E5a", "E5b"),
    "C": ("B1I", "B2I", "B3I"),
    "R": ("G1", "G2"),
}
"""Signals of each system whose group delay relative to the broadcast clock is known."""


def signal_of(system: str, code: str) -> str | None:
    """Signal name of a RINEX pseudorange code (``'C2W'`` of ``'G'`` -> ``'L2'``); None if unknown.

    RINEX 2 codes (``C1``, ``P1``, ``C2``, ``P2``) name the band by their digit. BeiDou
    band 1 with attribute I or Q (RINEX 3.02) or none (RINEX 2.12) is B1I; band 7 with
    attribute D, P or Z is B2b, otherwise B2I.

    Examples
    --------
    >>> signal_of("E", "C7Q"), signal_of("C", "C1I"), signal_of("C", "C7D")
    ('E5b', 'B1I', 'B2b')
    """
    if len(code) < 2 or code[0] not in "CP":
        return None
    band = _BANDS.get(system, {}).get(code[1])
    attribute = code[2:3]
    if system == "C" and band == "B1C" and attribute in ("I", "Q", ""):
        return "B1I"
    if system == "C" and band == "B2I" and attribute in ("D", "P", "Z"):
        return "B2b"
    return band


def carrier_frequency_hz(signal: str, glonass_channel: ArrayLike = 0) -> F64:
    """Carrier frequency (Hz) of a signal; GLONASS G1/G2 per frequency channel ``k`` (-7..+6).

    Raises
    ------
    KeyError
        For an unknown signal name.
    """
    k = np.asarray(glonass_channel, dtype=np.float64)
    if signal == "G1":
        return FREQ_G1_HZ + k * DFREQ_G1_HZ
    if signal == "G2":
        return FREQ_G2_HZ + k * DFREQ_G2_HZ
    return np.full(k.shape, _FIXED_FREQUENCY_HZ[signal])


def group_delay_s(
    system: str,
    signal: str,
    tgd_s: ArrayLike,
    tgd2_s: ArrayLike | None = None,
    fnav: ArrayLike | None = None,
) -> F64:
    """Broadcast group delay (s) of ``signal`` relative to the satellite clock (module table).

    Parameters
    ----------
    system
        ``'G' 'J' 'E' 'C' 'R'``.
    signal
        Signal name (:func:`signal_of`).
    tgd_s
        The record's single-frequency delay: GPS/QZSS TGD, Galileo BGD of the clock's pair,
        BeiDou TGD1 (any shape; ignored for GLONASS).
    tgd2_s
        Galileo: BGD of the other E5 pair; BeiDou: TGD2 (shape of ``tgd_s``; None = NaN).
    fnav
        Galileo: True where the record is F/NAV (clock for E1/E5a); None = I/NAV.

    Returns
    -------
    ndarray
        Shape of ``tgd_s``; NaN for signals outside :data:`IONO_FREE_SIGNALS`.
    """
    tgd = np.asarray(tgd_s, dtype=np.float64)
    tgd2 = np.full(tgd.shape, np.nan) if tgd2_s is None else np.asarray(tgd2_s, dtype=np.float64)
    if signal not in IONO_FREE_SIGNALS.get(system, ()):
        return np.full(tgd.shape, np.nan)
    if system == "R":
        return np.zeros(tgd.shape)
    if system in ("G", "J"):
        return tgd if signal == "L1" else (FREQ_L1_HZ / FREQ_L2_HZ) ** 2 * tgd
    if system == "C":
        return {"B1I": tgd, "B2I": tgd2, "B3I": np.zeros(tgd.shape)}[signal]
    if signal == "E1":
        return tgd
    f_nav = np.zeros(tgd.shape, dtype=bool) if fnav is None else np.asarray(fnav, dtype=bool)
    g = (FREQ_L1_HZ / _FIXED_FREQUENCY_HZ[signal]) ** 2
    own_pair = f_nav if signal == "E5a" else ~f_nav
    return np.where(own_pair, g * tgd, tgd - (1.0 - g) * tgd2)


def iono_free_combination_m(p1_m: ArrayLike, p2_m: ArrayLike, f1_hz: ArrayLike, f2_hz: ArrayLike) -> F64:
    """``(f1^2 P1 - f2^2 P2) / (f1^2 - f2^2)`` (m): the first-order ionosphere-free combination.

    Examples
    --------
    >>> import numpy as np
    >>> f1, f2 = 1575.42e6, 1227.60e6
    >>> iono = 5.0  # m on L1
    >>> round(float(iono_free_combination_m(2e7 + iono, 2e7 + iono * (f1 / f2) ** 2, f1, f2)), 6)
    20000000.0
    """
    a = np.asarray(f1_hz, dtype=np.float64) ** 2
    b = np.asarray(f2_hz, dtype=np.float64) ** 2
    return (a * np.asarray(p1_m, dtype=np.float64) - b * np.asarray(p2_m, dtype=np.float64)) / (a - b)


def iono_free_pseudorange_m(
    system: str,
    code1: NDArray[np.str_],
    p1_m: F64,
    code2: NDArray[np.str_],
    p2_m: F64,
    *,
    tgd_s: F64,
    tgd2_s: F64 | None = None,
    fnav: NDArray[np.bool_] | None = None,
    glonass_channel: F64 | None = None,
) -> F64:
    """Ionosphere-free pseudoranges (m) that refer to the broadcast clock, element by element.

    Parameters
    ----------
    system
        System letter of every element.
    code1, p1_m, code2, p2_m
        Observation codes and pseudoranges (m) of the two frequencies, same shape.
    tgd_s, tgd2_s, fnav
        Per element, from the ephemeris record in use (see :func:`group_delay_s`).
    glonass_channel
        GLONASS frequency channel per element.

    Returns
    -------
    ndarray
        NaN where a pseudorange is missing, a signal has no known group delay, or both
        codes are on the same frequency.
    """
    out = np.full(np.shape(p1_m), np.nan)
    chan = np.zeros(np.shape(p1_m)) if glonass_channel is None else np.asarray(glonass_channel, dtype=np.float64)
    have = np.isfinite(p1_m) & np.isfinite(p2_m)
    if not have.any():
        return out
    pairs = np.unique(np.char.add(np.char.add(code1[have].astype(str), "/"), code2[have].astype(str)))
    for pair in pairs:
        c1, c2 = str(pair).split("/")
        s1, s2 = signal_of(system, c1), signal_of(system, c2)
        if s1 is None or s2 is None or s1 == s2:
            continue
        sel = have & (code1 == c1) & (code2 == c2)
        f1 = carrier_frequency_hz(s1, chan[sel])
        f2 = carrier_frequency_hz(s2, chan[sel])
        tg2 = None if tgd2_s is None else tgd2_s[sel]
        fn = None if fnav is None else fnav[sel]
        d1 = group_delay_s(system, s1, tgd_s[sel], tg2, fn)
        d2 = group_delay_s(system, s2, tgd_s[sel], tg2, fn)
        out[sel] = iono_free_combination_m(p1_m[sel] - C_M_S * d1, p2_m[sel] - C_M_S * d2, f1, f2)
    return out
