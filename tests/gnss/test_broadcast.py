"""The records of one system behind one interface (:mod:`gnss_cli.gnss.broadcast`): the
orbit-and-clock sigma of a record as RTKLIB's ``var_uraeph`` reads it, and the interface on real
records of every kind (Keplerian, BeiDou, GLONASS)."""

from __future__ import annotations

import numpy as np

from gnss_cli.constants import FREQ_B1I_HZ, FREQ_L1_HZ
from gnss_cli.gnss.broadcast import GlonassRecords, KeplerRecords, ephemeris_sigma_m, system_records
from gnss_cli.gnss.time import datetime2gps_s
from gnss_cli.io.rinex import read_nav


def test_gps_ura_is_rounded_up_to_the_is_gps_200_table():
    """IS-GPS-200 20.3.3.3.1.3: URA index N covers (table[N-1], table[N]]; blank fields 2.4 m."""
    ura = np.array([0.0, 2.0, 2.4, 2.5, 4.85, 5.0, 100.0, 6144.0, 7000.0, np.nan])
    expected = [2.4, 2.4, 2.4, 3.4, 4.85, 6.85, 192.0, 6144.0, 6144.0, 2.4]
    for system in ("G", "J", "C"):
        np.testing.assert_array_equal(ephemeris_sigma_m(system, ura), expected)


def test_galileo_sisa_and_glonass_sigmas():
    """Galileo: SISA itself up to 6 m, NAPA (500 m) beyond or <= 0, blank 2.4 m. GLONASS: 5 m."""
    sisa = np.array([0.5, 3.12, 6.0, 6.5, 0.0, -1.0, np.nan])
    np.testing.assert_array_equal(ephemeris_sigma_m("E", sisa), [0.5, 3.12, 6.0, 500.0, 500.0, 500.0, 2.4])
    np.testing.assert_array_equal(ephemeris_sigma_m("R", np.array([1.0, np.nan])), [5.0, 5.0])


def test_one_interface_for_every_system(rinex_dir):
    """On KMS3's mixed RINEX 4 records: every system answers select/states/sigma/iono scale/delays."""
    nav = read_nav([rinex_dir / "kms3-2022159-rinex4" / "KMS300DNK_R_20221591000_01H_MN.rnx.gz"])
    t = datetime2gps_s(np.array(["2022-06-08T10:05:00"], dtype="datetime64[ns]"))
    for system in ("G", "E", "C", "R"):
        records, toe = system_records(nav, system)
        assert isinstance(records, GlonassRecords if system == "R" else KeplerRecords) and toe.size
        sv = np.array(sorted({str(s) for s in nav["sv"].values if str(s)[0] == system}))
        idx = records.select(sv, t, True)[0]
        k = idx[idx >= 0]
        assert k.size >= 3, system
        st = records.states(k, np.full(k.shape, t[0]))
        radius = np.linalg.norm(st.pos_ecef_m, axis=1)
        assert ((radius > 2.5e7) & (radius < 4.3e7)).all(), system  # MEO to GEO/IGSO
        assert (np.abs(st.clock_s) < 1e-2).all()
        np.testing.assert_allclose(records.clock_s(k, np.full(k.shape, t[0])), st.clock_s, rtol=0, atol=1e-15)
        assert (records.sigma_m(k) > 0).all() and "tgd_s" in records.delays(k)
        scale = records.iono_scale(k)
        if system == "C":
            np.testing.assert_allclose(scale, (FREQ_L1_HZ / FREQ_B1I_HZ) ** 2)
        elif system == "R":
            assert ((scale > 0.96) & (scale < 0.975)).all()  # (1575.42 MHz / 1598-1606 MHz)^2
        else:
            np.testing.assert_array_equal(scale, 1.0)
