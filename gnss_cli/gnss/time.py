"""GPS time conversions.

Inside gnss-solve an instant is a float64 number of seconds since the GPS epoch
(1980-01-06 00:00:00 GPST), named ``*_gps_s``. Its resolution near 2026 is about
2.4e-7 s, i.e. under 1 mm of satellite motion. RINEX epochs are already GPS time
(not UTC): no leap seconds are applied in the processing. Output in UTC
(``--time-system utc``) subtracts GPS - UTC: the navigation header's ``LEAP SECONDS`` when
present, else :data:`GPS_UTC_STEPS` (:func:`gps_minus_utc_s`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.constants import GPS_EPOCH_ISO, SECONDS_PER_WEEK

GPS_EPOCH = np.datetime64(GPS_EPOCH_ISO, "ns")


GPS_UTC_STEPS: tuple[tuple[str, int], ...] = (
    ("1980-01-06", 0), ("1981-07-01", 1), ("1982-07-01", 2), ("1983-07-01", 3), ("1985-07-01", 4),
    ("1988-01-01", 5), ("1990-01-01", 6), ("1991-01-01", 7), ("1992-07-01", 8), ("1993-07-01", 9),
    ("1994-07-01", 10), ("1996-01-01", 11), ("1997-07-01", 12), ("1999-01-01", 13), ("2006-01-01", 14),
    ("2009-01-01", 15), ("2012-07-01", 16), ("2015-07-01", 17), ("2017-01-01", 18),
)
"""GPS - UTC (s) from each UTC date on: every leap second since the GPS epoch (IERS
Bulletin C), valid from 1980-01-06 until the next leap second is announced (none up to
Bulletin C 70, July 2025: 18 s since 2017-01-01)."""


def gps_minus_utc_s(t_gps_s: ArrayLike, *, utc: bool = False) -> NDArray[np.float64]:
    """GPS - UTC (s) at GPS instants (s since the GPS epoch), from :data:`GPS_UTC_STEPS`;
    with ``utc=True`` the instants are UTC readings (UTC date and time counted from the GPS
    epoch as if they were GPS seconds).

    >>> float(gps_minus_utc_s(datetime2gps_s(np.datetime64("2005-04-02T00:00:00"))))
    13.0
    >>> float(gps_minus_utc_s(datetime2gps_s(np.datetime64("2020-01-01"))))
    18.0
    >>> [float(gps_minus_utc_s(datetime2gps_s(np.datetime64(u)), utc=True))
    ...  for u in ("2016-12-31T23:59:59", "2017-01-01T00:00:00")]
    [17.0, 18.0]
    """
    t = np.asarray(t_gps_s, dtype=np.float64)
    starts_utc = datetime2gps_s(np.array([d for d, _ in GPS_UTC_STEPS], dtype="datetime64[ns]"))
    steps = np.array([v for _, v in GPS_UTC_STEPS], dtype=np.float64)
    starts = starts_utc if utc else starts_utc + steps  # a step takes effect at its UTC date = GPST + steps
    k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, steps.size - 1)
    return steps[k]


def datetime2gps_s(t: ArrayLike) -> NDArray[np.float64]:
    """Convert numpy ``datetime64`` instants (GPS time scale) to seconds since the GPS epoch."""
    t64 = np.asarray(t, dtype="datetime64[ns]")
    return (t64 - GPS_EPOCH).astype(np.int64).astype(np.float64) * 1e-9


def gps_s2datetime(t_gps_s: ArrayLike) -> NDArray[np.datetime64]:
    """Convert seconds since the GPS epoch to ``datetime64[ns]`` (GPS time scale)."""
    ns = np.round(np.asarray(t_gps_s, dtype=np.float64) * 1e9).astype(np.int64)
    return GPS_EPOCH + ns.astype("timedelta64[ns]")


def gps_s2week_tow(t_gps_s: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Split seconds since the GPS epoch into GPS week and seconds of week."""
    t = np.asarray(t_gps_s, dtype=np.float64)
    week = np.floor(t / SECONDS_PER_WEEK).astype(np.int64)
    return week, t - week * SECONDS_PER_WEEK
