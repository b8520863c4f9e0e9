"""Physical constants and reference frames (SI units).

References: IS-GPS-200 (GPS constants), NIMA TR8350.2 (WGS-84), Galileo OS SIS ICD,
BeiDou ICD, GLONASS ICD (PZ-90).
"""

from __future__ import annotations


C_M_S = 299_792_458.0
"""Speed of light in vacuum, m/s."""

OMEGA_E_RAD_S = 7.2921151467e-5
"""WGS-84 Earth rotation rate used by GPS (IS-GPS-200), rad/s."""

GM_GPS_M3_S2 = 3.986005e14
"""Earth's gravitational constant as used by GPS broadcast orbits, m^3/s^2."""

GM_GAL_M3_S2 = 3.986004418e14
"""Earth's gravitational constant as used by Galileo and BeiDou (CGCS2000), m^3/s^2."""

OMEGA_E_BDS_RAD_S = 7.292115e-5
"""CGCS2000 Earth rotation rate used by BeiDou, rad/s."""

F_REL_S_SQRT_M = -4.442807633e-10
"""Relativistic clock correction constant F = -2 sqrt(GM) / c^2, s/sqrt(m)."""

WGS84_A_M = 6_378_137.0
"""WGS-84 semi-major axis, m."""

WGS84_F = 1.0 / 298.257223563
"""WGS-84 flattening."""

WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
"""WGS-84 first eccentricity squared."""

GPS_EPOCH_ISO = "1980-01-06T00:00:00"
"""Origin of GPS time (week 0, second 0), ISO 8601 (``numpy.datetime64(GPS_EPOCH_ISO, "ns")``).
A string, so that this module, read by the command line's start-up, needs no numpy."""

SECONDS_PER_WEEK = 604_800.0

BDT_MINUS_GPST_S = -14.0
"""BDT - GPST, s (BDT started 2006-01-01 00:00:00 UTC, 14 s behind GPST; integer leap-second offset)."""

FREQ_L1_HZ = 1_575.42e6
FREQ_L2_HZ = 1_227.60e6
FREQ_L5_HZ = 1_176.45e6
FREQ_E5B_HZ = 1_207.14e6
FREQ_B1I_HZ = 1_561.098e6
FREQ_B3I_HZ = 1_268.52e6

METHOD_KEYS: tuple[str, ...] = ("ls", "wls", "tls", "dls", "mtls", "stls", "wtls")
"""Estimator keys, the user's words everywhere (CLI, configuration, solver registry, CSV ``method``)."""

MULTI_EPOCH_METHOD_KEYS: tuple[str, ...] = ("smoother", "kf")
"""Multi-epoch methods beside the solver family: ``smoother``, the batch least-squares smoother of
whole segments with a fixed motion model, and ``kf``, the extended Kalman filter with its
Rauch-Tung-Striebel smoother. ``stls`` with ``lag >= 1`` is multi-epoch too (the identified
Hankel STLS). ``--method all`` means :data:`METHOD_KEYS` (the single-epoch family)."""
