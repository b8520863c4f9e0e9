"""Record selection rules shared with RTKLIB, on small synthetic record tables."""

from __future__ import annotations

import numpy as np

from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.multi_gnss import select_system_ephemeris

T0 = 1_000_000_000.0  # an arbitrary GPS time, s


def _table(sv: list[str], toe: list[float], health: list[float]) -> KeplerEphemeris:
    """Records that differ only by satellite, toe (= toc) and health."""
    n = len(sv)
    eph = KeplerEphemeris.empty()
    values = {}
    for f in eph.__dataclass_fields__:
        ref = getattr(eph, f)
        values[f] = np.zeros(n, dtype=ref.dtype)
    values.update(sv=np.array(sv, dtype="<U3"), toe_gps_s=np.array(toe) + T0, toc_gps_s=np.array(toe) + T0,
                  health=np.array(health, dtype=np.float64), fit_interval_h=np.full(n, 4.0))
    return KeplerEphemeris(**values)


def _pick(eph: KeplerEphemeris, sv: str, t: float, system: str) -> int:
    return int(select_system_ephemeris(eph, np.array([sv]), np.array([T0 + t]), system)[0, 0])


def test_unhealthy_nearest_record_is_not_replaced_by_an_older_healthy_one() -> None:
    eph = _table(["G05", "G05"], [0.0, 7200.0], [0.0, 1.0])
    assert _pick(eph, "G05", 7000.0, "G") == -1  # nearest (7200 s) is unhealthy: skipped
    assert _pick(eph, "G05", 3000.0, "G") == 0  # nearest (0 s) is healthy
    gal = _table(["E11", "E11"], [0.0, 600.0], [0.0, 1.0])
    assert _pick(gal, "E11", 900.0, "E") == -1  # the record in force is unhealthy


def test_exact_tie_keeps_the_later_toe() -> None:
    eph = _table(["G05", "G05"], [0.0, 7200.0], [0.0, 0.0])
    assert _pick(eph, "G05", 3600.0, "G") == 1
    eph = _table(["G05", "G05"], [7200.0, 0.0], [0.0, 0.0])  # table order does not matter
    assert _pick(eph, "G05", 3600.0, "G") == 0


def test_beidou_uses_the_nearest_toe_also_before_it() -> None:
    eph = _table(["C08", "C08"], [0.0, 3600.0], [0.0, 0.0])
    assert _pick(eph, "C08", 3000.0, "C") == 1  # 600 s before the second toe
    assert _pick(eph, "C08", 1000.0, "C") == 0
    assert _pick(eph, "C08", -1000.0, "C") == 0  # before every toe, still the nearest
    assert _pick(eph, "C08", 3600.0 + 5 * 3600.0, "C") == -1  # beyond 4 h


def test_qzss_health_bit_0_is_ignored_other_bits_are_not() -> None:
    eph = _table(["J01", "J02"], [0.0, 0.0], [1.0, 2.0])
    assert _pick(eph, "J01", 60.0, "J") == 0
    assert _pick(eph, "J02", 60.0, "J") == -1
    gps = _table(["G01"], [0.0], [1.0])
    assert _pick(gps, "G01", 60.0, "G") == -1  # GPS: every bit counts
