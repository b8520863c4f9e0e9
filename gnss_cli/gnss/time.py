"""GPS time conversions.

Inside gnss-solve an instant is a float64 number of seconds since the GPS epoch
(1980-01-06 00:00:00 GPST), named ``*_gps_s``. Its resolution near 2026 is about
2.4e-7 s, i.e. under 1 mm of satellite motion. RINEX epochs are already GPS time
(not UTC): no leap seconds are applied anywhere.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.constants import GPS_EPOCH_ISO, SECONDS_PER_WEEK

GPS_EPOCH = np.datetime64(GPS_EPOCH_ISO, "ns")


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
