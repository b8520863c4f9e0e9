"""Galileo, GPS and GLONASS broadcast orbits against GFZ precise orbits (esbc-2020177);
BeiDou (GEO/IGSO/MEO), QZSS, GPS, Galileo and GLONASS against RTKLIB's own routines."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.constants import C_M_S
from gnss_cli.gnss.glonass import GlonassEphemeris, glonass_states, select_glonass_ephemeris
from gnss_cli.gnss.multi_gnss import (
    ephemeris_for_system,
    is_bds_geo,
    select_forward_ephemeris,
    select_system_ephemeris,
    system_states,
)
from gnss_cli.gnss.time import datetime2gps_s
from gnss_cli.io.rinex import read_nav

NAV = "esbc-2020177/ESBC00DNK_R_20201770000_01D_MN.rnx.gz"
SP3 = "esbc-2020177/GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz"


@pytest.fixture(scope="module")
def nav(rinex_dir):
    return read_nav(rinex_dir / NAV)


@pytest.fixture(scope="module")
def sp3(rinex_dir):
    import georinex

    path = rinex_dir / SP3
    import gzip

    with gzip.open(path, "rt") as f:
        head = [next(f) for _ in range(20)]
    time_system = [line for line in head if line.startswith("%c")][0][9:12]
    assert time_system == "GPS"  # SP3 epochs are GPST: no conversion needed
    return georinex.load_sp3(path, None)


def _compare(nav, sp3, system):
    svs = np.array([s for s in sp3.sv.values.astype(str) if s.startswith(system)])
    sub = sp3.sel(sv=svs)
    t = datetime2gps_s(sub.time.values)
    if system == "R":
        eph = GlonassEphemeris.from_dataset(nav)
        idx = select_glonass_ephemeris(eph, svs, t)
        states = glonass_states(eph, idx, t[:, None])
    else:
        eph = ephemeris_for_system(nav, system)
        idx = select_system_ephemeris(eph, svs, t, system)
        states = system_states(eph, idx, t[:, None], system)
    precise = sub.position.values * 1e3  # km -> m
    clock = sub.clock.values
    clock = np.where(np.abs(clock) >= 999999.0, np.nan, clock) * 1e-6  # us; 999999.999999 = bad
    return states, precise, clock


@pytest.mark.parametrize(
    ("system", "rms_max_m", "max_max_m", "radial_range_m", "min_samples"),
    [
        ("G", 2.5, 7.0, (-1.5, -0.3), 2000),
        ("E", 1.5, 2.5, (-1.5, -0.3), 1200),
        ("R", 5.0, 10.0, (-3.0, -1.0), 900),
    ],
)
def test_broadcast_orbits_match_precise_orbits_whole_day(nav, sp3, system, rms_max_m, max_max_m, radial_range_m, min_samples):
    states, precise, _ = _compare(nav, sp3, system)
    diff = states.pos_ecef_m - precise
    err = np.linalg.norm(diff, axis=-1)
    ok = np.isfinite(err)
    assert ok.sum() >= min_samples
    rms = np.sqrt(np.mean(err[ok] ** 2))
    assert rms <= rms_max_m, rms
    assert err[ok].max() <= max_max_m, err[ok].max()
    # Broadcast orbits refer to the antenna phase centre, SP3 to the centre of mass.
    radial = np.sum(diff * precise / np.linalg.norm(precise, axis=-1, keepdims=True), axis=-1)
    assert radial_range_m[0] < np.mean(radial[ok]) < radial_range_m[1]


@pytest.mark.parametrize(("system", "rms_max_m"), [("G", 1.0), ("E", 1.0), ("R", 4.0)])
def test_broadcast_clocks_match_precise_clocks(nav, sp3, system, rms_max_m):
    states, _, clock = _compare(nav, sp3, system)
    # SP3 clocks exclude the periodic relativistic term (GLONASS: included in TauN, 0 here).
    d = (states.clock_s - states.relativistic_s - clock) * C_M_S
    d = d - np.nanmean(d, axis=1, keepdims=True)  # the reference clock is common
    assert np.isfinite(d).sum() > 900
    assert np.sqrt(np.nanmean(d**2)) <= rms_max_m


def test_galileo_records_never_used_before_toe(nav):
    eph = ephemeris_for_system(nav, "E")
    sv = np.unique(eph.sv)
    t = eph.toe_gps_s.min() + np.arange(0.0, 86400.0, 300.0)
    idx = select_system_ephemeris(eph, sv, t, "E")
    ok = idx >= 0
    age = t[:, None] - eph.toe_gps_s[np.where(ok, idx, 0)]
    assert ok.sum() > 1000
    assert (age[ok] >= 0).all() and (age[ok] <= 3 * 3600 + 1e-6).all()
    # I/NAV only: the E1-E5b group delay is non-zero, and every id is a plain 'Exx'
    assert np.all(np.char.str_len(eph.sv.astype(str)) == 3)
    assert np.count_nonzero(eph.tgd_s) > 0.9 * len(eph)


def test_beidou_times_are_gpst_and_geo_flagged(nav):
    eph = ephemeris_for_system(nav, "C")
    assert len(eph) > 0
    # BeiDou toe are whole hours of BDT: in GPST they end in 14 s.
    assert np.allclose(np.mod(eph.toe_gps_s, 3600.0), 14.0)
    assert is_bds_geo(np.array(["C01", "C05", "C06", "C59", "C63", "G01"])).tolist() == [
        True, True, False, True, True, False]
    idx = select_forward_ephemeris(eph, np.array(["C06"]), eph.toe_gps_s[:1] - 1.0)
    assert idx[0, 0] == -1 or eph.toe_gps_s[idx[0, 0]] <= eph.toe_gps_s[0] - 1.0


def test_glonass_velocity_is_derivative_of_position(nav):
    eph = GlonassEphemeris.from_dataset(nav)
    sv = np.unique(eph.sv)
    t = eph.toe_gps_s.min() + np.arange(600.0, 86400.0, 450.0)
    idx = select_glonass_ephemeris(eph, sv, t)
    s0 = glonass_states(eph, idx, t[:, None])
    sp = glonass_states(eph, idx, t[:, None] + 0.5)
    sm = glonass_states(eph, idx, t[:, None] - 0.5)
    fd = sp.pos_ecef_m - sm.pos_ecef_m
    ok = np.isfinite(fd).all(axis=-1)
    assert ok.sum() > 50
    assert np.max(np.abs(fd[ok] - s0.vel_ecef_m_s[ok])) < 1e-3
    assert set(np.unique(eph.freq_num)) <= set(range(-7, 7))


def test_beidou_geo_velocity_is_derivative_of_position(nav):
    eph = ephemeris_for_system(nav, "C")
    sv = np.unique(eph.sv)
    assert is_bds_geo(sv).any()
    t = eph.toe_gps_s.min() + np.arange(600.0, 86400.0, 1800.0)
    idx = select_system_ephemeris(eph, sv, t, "C")
    s0 = system_states(eph, idx, t[:, None], "C")
    sp = system_states(eph, idx, t[:, None] + 0.5, "C")
    sm = system_states(eph, idx, t[:, None] - 0.5, "C")
    fd = sp.pos_ecef_m - sm.pos_ecef_m
    ok = np.isfinite(fd).all(axis=-1)
    assert ok[:, is_bds_geo(sv)].sum() > 10
    assert np.max(np.abs(fd[ok] - s0.vel_ecef_m_s[ok])) < 1e-3
    # GEO: nearly fixed in ECEF (inclined by a few degrees: tens of m/s), radius ~42164 km
    geo = ok & is_bds_geo(sv)[None, :]
    r = np.linalg.norm(s0.pos_ecef_m[geo], axis=-1)
    assert np.all(np.abs(r - 42_164e3) < 100e3)
    assert np.all(np.linalg.norm(s0.vel_ecef_m_s[geo], axis=-1) < 200.0)


# --- RTKLIB's own routines (pyrtklib, test-only dependency) ---------------------------

GPS_UNIX_OFFSET_S = 315_964_800.0  # 1980-01-06 minus 1970-01-01 (RTKLIB gtime_t counts from 1970)
_RTKLIB_SYS = {1: "G", 4: "R", 8: "E", 16: "J", 32: "C"}


@pytest.fixture(scope="module")
def rtklib_nav(rinex_dir, tmp_path_factory):
    p = pytest.importorskip("pyrtklib", reason="pyrtklib (RTKLIB's routines) not installed: pip install pyrtklib")
    import gzip
    import shutil

    plain = tmp_path_factory.mktemp("rtklib") / "esbc.rnx"
    with gzip.open(rinex_dir / NAV, "rb") as src, open(plain, "wb") as dst:
        shutil.copyfileobj(src, dst)
    nav = p.nav_t()
    assert p.readrnx(str(plain), 1, "", p.obs_t(), nav, p.sta_t()) == 1
    return p, nav


def _sv_id(p, sat):
    prn = p.Arr1Dint(1)
    sys = p.satsys(sat, prn)
    number = prn[0] - 192 if sys == 16 else prn[0]  # RTKLIB numbers QZSS as PRN 193..
    return f"{_RTKLIB_SYS.get(sys, '?')}{number:02d}"


def _gtime2gps_s(t):
    return t.time - GPS_UNIX_OFFSET_S + t.sec


OFFSETS_S = np.array([0.0, 450.0, 1234.5, 3600.0, 7199.0])


@pytest.mark.parametrize("system", ["G", "E", "C", "J"])
def test_kepler_orbits_and_clocks_equal_rtklib(nav, rtklib_nav, system):
    p, rnav = rtklib_nav
    eph = ephemeris_for_system(nav, system)
    key = {(s, round(toe), round(toc), int(iode)): i for i, (s, toe, toc, iode) in
           enumerate(zip(eph.sv, eph.toe_gps_s, eph.toc_gps_s, eph.iode))}
    rs, dts, var = p.Arr1Ddouble(6), p.Arr1Ddouble(2), p.Arr1Ddouble(1)
    ours_i, ours_t, ref_pos, ref_clk, geo = [], [], [], [], []
    for n in range(rnav.n):
        e = rnav.eph[n]
        sv = _sv_id(p, e.sat)
        if sv[0] != system or (system == "E" and not e.code & 0b101):
            continue
        i = key.get((sv, round(_gtime2gps_s(e.toe)), round(_gtime2gps_s(e.toc)), int(e.iode)))
        assert i is not None, f"RTKLIB record {sv} toe {_gtime2gps_s(e.toe)} not in our table"
        for dt in OFFSETS_S:
            p.eph2pos(p.timeadd(e.toe, float(dt)), e, rs, dts, var)
            ours_i.append(i)
            ours_t.append(_gtime2gps_s(e.toe) + dt)
            ref_pos.append([rs[0], rs[1], rs[2]])
            ref_clk.append(dts[0])
            geo.append(bool(is_bds_geo(np.array([sv]))[0]))
    assert len(ours_i) >= (50 if system == "J" else 500)  # QZSS: 15 records that day
    states = system_states(eph, np.array(ours_i), np.array(ours_t), system)
    err = np.linalg.norm(states.pos_ecef_m - np.array(ref_pos), axis=-1)
    print(f"{system}: {len(err)} samples, max |dpos| {np.max(err):.2e} m, "
          f"max |dclk| {np.max(np.abs(states.clock_s - np.array(ref_clk))) * C_M_S:.2e} m")
    assert np.max(err) <= 0.01, np.max(err)
    assert np.max(np.abs(states.clock_s - np.array(ref_clk))) * C_M_S <= 0.01
    if system == "C":
        assert np.count_nonzero(geo) > 20  # GEO satellites included
        assert np.max(err[np.array(geo)]) <= 0.01


def test_glonass_orbits_and_clocks_equal_rtklib(nav, rtklib_nav):
    p, rnav = rtklib_nav
    eph = GlonassEphemeris.from_dataset(nav)
    key = {(s, round(toe)): i for i, (s, toe) in enumerate(zip(eph.sv, eph.toe_gps_s))}
    rs, dts, var = p.Arr1Ddouble(6), p.Arr1Ddouble(2), p.Arr1Ddouble(1)
    ours_i, ours_t, ref_pos, ref_clk = [], [], [], []
    for n in range(rnav.ng):
        g = rnav.geph[n]
        sv = _sv_id(p, g.sat)
        i = key.get((sv, round(_gtime2gps_s(g.toe))))
        assert i is not None, f"RTKLIB record {sv} toe {_gtime2gps_s(g.toe)} not in our table"
        assert eph.freq_num[i] == g.frq
        for dt in (-1799.0, -900.0, -30.5, 0.0, 61.0, 900.0, 1800.0):
            p.geph2pos(p.timeadd(g.toe, dt), g, rs, dts, var)
            ours_i.append(i)
            ours_t.append(_gtime2gps_s(g.toe) + dt)
            ref_pos.append([rs[0], rs[1], rs[2]])
            ref_clk.append(dts[0])
    assert len(ours_i) > 100
    states = glonass_states(eph, np.array(ours_i), np.array(ours_t))
    err = np.linalg.norm(states.pos_ecef_m - np.array(ref_pos), axis=-1)
    print(f"R: {len(err)} samples, max |dpos| {np.max(err):.2e} m, "
          f"max |dclk| {np.max(np.abs(states.clock_s - np.array(ref_clk))) * C_M_S:.2e} m")
    assert np.max(err) <= 0.01, np.max(err)
    assert np.max(np.abs(states.clock_s - np.array(ref_clk))) * C_M_S <= 0.01


def test_glonass_record_dated_wrongly_does_not_shift_the_others(rinex_dir, tmp_path):
    """GPST - UTC comes from each record's own date: one GLONASS record dated 1980 (0 leap
    seconds then) once set the leap seconds of every record, moving every GLONASS satellite
    by 18 s of orbit (km) and wrecking every epoch of kms3."""
    import gzip

    text = gzip.decompress((rinex_dir / "kms3-2022159-rinex4/KMS300DNK_R_20221591000_01H_MN.rnx.gz").read_bytes())
    lines = text.split(b"\n")
    first = next(i for i, line in enumerate(lines) if line[:1] == b"R" and line[4:8] == b"2022")
    lines[first] = lines[first][:4] + b"1980" + lines[first][8:]
    (tmp_path / "clean.rnx").write_bytes(text)
    (tmp_path / "dated1980.rnx").write_bytes(b"\n".join(lines))
    clean = GlonassEphemeris.from_dataset(read_nav(tmp_path / "clean.rnx"))
    damaged = GlonassEphemeris.from_dataset(read_nav(tmp_path / "dated1980.rnx"))
    assert len(damaged) == len(clean)
    late = damaged.toe_gps_s > datetime2gps_s(np.datetime64("2000-01-01"))
    assert late.sum() == len(clean) - 1  # the 1980 record stays in 1980
    keep = np.lexsort((clean.toe_gps_s, clean.sv))
    other = np.lexsort((damaged.toe_gps_s[late], damaged.sv[late]))
    c = {(s, t) for s, t in zip(clean.sv[keep], clean.toe_gps_s[keep])}
    d = {(s, t) for s, t in zip(damaged.sv[late][other], damaged.toe_gps_s[late][other])}
    assert d <= c and len(c - d) == 1
    # in GPST the 2022 tb (whole quarter hours of UTC(SU) - 3 h) end in 18 s
    assert np.allclose(np.mod(damaged.toe_gps_s[late], 900.0), 18.0)


@pytest.mark.parametrize("system", ["G", "E", "C", "J", "R"])
def test_clock_only_evaluation_gives_the_full_evaluations_clock(nav, system):
    """The clock-drift path evaluates clocks without orbits: bit for bit the clocks of the full
    evaluation (BeiDou GEO and MEO, GLONASS without its integration), NaN where no record."""
    from gnss_cli.gnss.glonass import glonass_clock_s

    t = datetime2gps_s(np.array(["2020-06-25T00:00", "2020-06-25T07:13:31", "2020-06-25T23:59:30"], dtype="datetime64[ns]"))
    if system == "R":
        eph = GlonassEphemeris.from_dataset(nav)
        idx = select_glonass_ephemeris(eph, np.unique(eph.sv), t)
        full, fast = glonass_states(eph, idx, t[:, None]).clock_s, glonass_clock_s(eph, idx, t[:, None])
    else:
        eph = ephemeris_for_system(nav, system)
        idx = select_system_ephemeris(eph, np.unique(eph.sv), t, system)
        full = system_states(eph, idx, t[:, None], system).clock_s
        only = system_states(eph, idx, t[:, None], system, clock_only=True)
        fast = only.clock_s
        assert np.isnan(only.pos_ecef_m).all()
    assert (idx >= 0).sum() >= 3 and np.isnan(full[idx < 0]).all() and np.isfinite(full[idx >= 0]).all()
    np.testing.assert_array_equal(fast, full)


def _stepped_each(eph, idx, t, step_s):
    """Reference: every element stepped on its own (full steps, then the shorter last one)."""
    from gnss_cli.gnss.glonass import _derivative

    k = idx
    dt = t - eph.toe_gps_s[k]
    state = np.concatenate([eph.pos_m[k], eph.vel_m_s[k]], axis=-1)
    acc = eph.acc_m_s2[k]
    remaining = dt.copy()
    for _ in range(int(np.ceil(np.max(np.abs(remaining)) / step_s - 1e-12))):
        hh = (np.sign(remaining) * np.minimum(np.abs(remaining), step_s))[..., None]
        k1 = _derivative(state, acc)
        k2 = _derivative(state + 0.5 * hh * k1, acc)
        k3 = _derivative(state + 0.5 * hh * k2, acc)
        k4 = _derivative(state + hh * k3, acc)
        state = state + hh / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        remaining = remaining - hh[..., 0]
        remaining = np.where(np.abs(remaining) < 1e-9, 0.0, remaining)
    return state


@pytest.mark.parametrize("step_s", [60.0, 17.0])
def test_glonass_shared_full_steps_equal_stepping_each_time(nav, step_s):
    """The full steps are integrated once per record and direction; the states equal those
    of stepping every (record, time) on its own bit for bit, at toe, at exact multiples of
    the step, a hair after toe and anywhere in +-30 min."""
    eph = GlonassEphemeris.from_dataset(nav)
    rng = np.random.default_rng(5)
    k = rng.integers(0, len(eph), 3000)
    offsets = np.concatenate([rng.uniform(-1800.0, 1800.0, 2990), [0.0, 60.0, -120.0, 1e-10, -3e-11, 59.99999999999,
                                                                  1799.9999999999, -step_s, 2 * step_s, 1e-9]])
    t = eph.toe_gps_s[k] + offsets
    got = glonass_states(eph, k, t, step_s=step_s)
    want = _stepped_each(eph, k, t, step_s)
    np.testing.assert_array_equal(got.pos_ecef_m, want[:, :3])
    np.testing.assert_array_equal(got.vel_ecef_m_s, want[:, 3:])
