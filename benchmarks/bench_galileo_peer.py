"""Galileo alone against rnx2rtkp, epoch by epoch, on every shared set with Galileo.

    python benchmarks/bench_galileo_peer.py [--sets esbc,kms3,tst2]

For each set of ``../shared/rinex`` with Galileo observations and Galileo navigation records,
``gnss-solve OBS NAV... --systems E --method wls`` (every other option at its default: 10 deg
mask, broadcast Klobuchar, Saastamoinen, RTKLIB's variance model) and rnx2rtkp with
``../shared/peer/rnx2rtkp-spp.conf`` and ``pos1-navsys=8`` (Galileo) on plain copies in a
temporary folder. Epochs are matched by time (rnx2rtkp writes the receiver-clock-corrected time,
within 10 ms of the RINEX epoch). Per set: the epochs each program solves (gnss-solve: status
``ok``, or ``untested`` where four satellites leave nothing to test and rnx2rtkp writes the fix too; rnx2rtkp: the epochs it writes, after its chi-square and GDOP tests), the 3D distance
between the two fixes on common epochs (median, 95th percentile, max, count above 1 cm, m), and
each program's 3D RMS against the set's reference on its own epochs (tst2: the static antenna's
ground-truth position for every epoch; Galileo alone solves none in its 157-epoch truth window).

Then the same comparison with the three places where rnx2rtkp 2.4.3 uses the broadcast data
differently from gnss-solve applied to gnss-solve's input (:func:`as_rnx2rtkp_reads`; one after
the other in the JSON's ``steps``, all three in the table's "aligned" columns):
the group delay BGD(E1,E5b) of a satellite's first-transmitted record for the whole file (0 when
that record is an F/NAV one), SISA rounded down to RTKLIB's index (3.12 m -> 2.96 m), and no
RINEX 4 ionosphere records (its default Klobuchar coefficients instead). What is then still more
than 1 cm apart is attributed, epoch by epoch, to the two remaining different choices:

* ``toe``: the epoch is a toe of a Galileo record; gnss-solve uses that record already
  (``toe <= t``), rnx2rtkp only after it (``toe < t``) and keeps the previous one;
* ``tropo``: one fix is below -100 m ellipsoidal height and the other not: the Saastamoinen
  delay is zero below -100 m in both programs, and such a 4-5 satellite urban epoch has two
  self-consistent fixes, one on either side.

Anything else is counted as ``other``. Prints a markdown table and writes
``benchmarks/results/bench_galileo_peer.json``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gnss_cli.config import load_config  # noqa: E402
from gnss_cli.gnss.frames import ecef2geodetic  # noqa: E402
from gnss_cli.gnss.multi_gnss import ephemeris_for_system  # noqa: E402
from gnss_cli.io.compression import open_bytes  # noqa: E402
from gnss_cli.io.rinex import read_nav  # noqa: E402
from gnss_cli.pipeline import process  # noqa: E402

SHARED = REPO.parent / "shared"
RINEX = SHARED / "rinex"
PEER_CONF = SHARED / "peer" / "rnx2rtkp-spp.conf"
RESULT = REPO / "benchmarks" / "results" / "bench_galileo_peer.json"
MATCH_S = 0.02
"""Largest difference between matched epoch times, s."""
NEAR_M = 0.01
"""A distance above this (m) counts as a difference."""
TROPO_FLOOR_M = -100.0
"""Below this ellipsoidal height (m) both programs set the Saastamoinen delay to zero."""


@dataclass(frozen=True)
class GalileoSet:
    """One shared data set: files and reference (ECEF m, ``"header"`` or None)."""

    key: str
    folder: str
    obs: str
    navs: tuple[str, ...]
    reference: tuple[float, float, float] | str | None
    without_galileo: str = ""

    def obs_path(self) -> Path:
        return RINEX / self.folder / self.obs

    def nav_paths(self) -> list[Path]:
        return [RINEX / self.folder / n for n in self.navs]


SETS = (
    GalileoSet("esbc", "esbc-2020177", "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz",
               ("ESBC00DNK_R_20201770000_01D_MN.rnx.gz",), (3582104.922, 532590.196, 5232755.366)),
    GalileoSet("kms3", "kms3-2022159-rinex4", "KMS300DNK_R_20221591000_01H_30S_MO.crx",
               ("KMS300DNK_R_20221591000_01H_MN.rnx.gz",), "header"),
    GalileoSet("tst2", "tst2-2020155-urban-static", "2020_06_03_TST_03.obs.gz",
               ("hksc155d.20n", "hksc155d.20b", "hksc155d.20l", "hksc155d.20g"),
               (-2418077.2710, 5386069.6872, 2405174.1252)),
    GalileoSet("p433", "p433-2019", "", (), None, without_galileo="Galileo observed, GPS-only navigation file"),
    GalileoSet("rtklib-0759", "rtklib-0759", "", (), None, without_galileo="GPS only"),
    GalileoSet("berlin", "smartloc-berlin-2016158-urban-kinematic", "", (), None,
               without_galileo="observations G/R/S only"),
    GalileoSet("orbits-2021-118", "orbits-2021-118", "", (), None, without_galileo="no observations"),
    GalileoSet("yamatogawa", "yamatogawa-2010006-kinematic", "", (), None, without_galileo="GPS only"),
)


# rnx2rtkp 2.4.3's reading of Galileo records, applied to a navigation file's text

def rtklib_sisa_m(sisa_m: float) -> float:
    """SISA (m) as rnx2rtkp 2.4.3 uses it: rounded down to an index of the Galileo OS SIS ICD
    bands (5.1.12: 0.01 m steps below 0.5 m, 0.02 m to 1 m, 0.04 m to 2 m, 0.16 m to 6 m).

    rnx2rtkp's trace gives an exact 3.12 m (index 107) the variance 8.762 m^2 = (2.96 m)^2, index
    106: the rounding down happens in single precision (``(3.12f - 2) / 0.16f = 6.9999995``),
    emulated here with float32; in double precision the quotient is 7.000000000000001. Outside
    0-6 m: unchanged (NAPA).

    >>> round(rtklib_sisa_m(3.12), 2), round(rtklib_sisa_m(0.3), 2), rtklib_sisa_m(-1.0)
    (2.96, 0.3, -1.0)
    """
    if not 0.0 <= sisa_m <= 6.0:
        return sisa_m
    value = np.float32(sisa_m)
    for start, step in ((2.0, 0.16), (1.0, 0.04), (0.5, 0.02), (0.0, 0.01)):
        if value >= np.float32(start):
            index = int((value - np.float32(start)) / np.float32(step))
            return start + index * step
    return sisa_m


def _field(line: str, k: int) -> float:
    """The ``k``-th 19-character field of a broadcast-orbit line (RINEX 3/4, after 4 spaces)."""
    text = line[4 + 19 * k: 4 + 19 * (k + 1)].strip()
    return float(text.replace("D", "E")) if text else float("nan")


def _set_field(line: str, k: int, value: float) -> str:
    start = 4 + 19 * k
    body = line.rstrip("\n").ljust(4 + 19 * 4)
    return body[:start] + f"{value:19.12E}" + body[start + 19:] + "\n"


def _galileo_records(lines: list[str]) -> list[int]:
    """Line index of the first line of every Galileo record after the header."""
    start = next((i + 1 for i, ln in enumerate(lines) if "END OF HEADER" in ln), len(lines))
    return [i for i in range(start, len(lines) - 7)
            if lines[i][:1] == "E" and lines[i][1:3].isdigit() and lines[i][3:4] == " "]


def first_record_bgd_s(lines: list[str]) -> dict[str, float]:
    """BGD(E1,E5b) (s) of each Galileo satellite's first record in transmission order (Galileo
    week, then transmission time of the message)."""
    first: dict[str, tuple[float, float]] = {}
    for i in _galileo_records(lines):
        order = _field(lines[i + 5], 2) * 604800.0 + _field(lines[i + 7], 0)
        sv = lines[i][:3]
        if sv not in first or order < first[sv][0]:
            first[sv] = (order, _field(lines[i + 6], 3))
    return {sv: bgd for sv, (_, bgd) in first.items()}


STEPS = ("bgd", "sisa", "ion")
"""The parts of :func:`as_rnx2rtkp_reads`, in the order the benchmark adds them."""


def as_rnx2rtkp_reads(text: str, steps: tuple[str, ...] = STEPS) -> str:
    """A RINEX 3/4 navigation text with Galileo data as rnx2rtkp 2.4.3 uses it.

    * every Galileo record's BGD(E1,E5b) is replaced by that of the satellite's first record in
      transmission order (Galileo week and transmission time): rnx2rtkp takes one group delay
      per satellite from the first record of its sorted list; when that record is F/NAV, whose
      BGD(E1,E5b) field RINEX writes as 0, the satellite gets none;
    * SISA is replaced by :func:`rtklib_sisa_m` of it;
    * RINEX 4 ``> ION`` records are dropped: rnx2rtkp 2.4.3 does not read them and falls back to
      its default Klobuchar coefficients (so does gnss-solve when a file has none).

    Parameters
    ----------
    text : the navigation file's text (plain, decompressed).
    steps : which of the three to apply: ``"bgd"``, ``"sisa"``, ``"ion"`` (default all).

    Returns
    -------
    str : the edited text; records of other systems unchanged.
    """
    lines = text.splitlines(keepends=True)
    first = first_record_bgd_s(lines)
    for i in _galileo_records(lines):
        line = _set_field(lines[i + 6], 3, first[lines[i][:3]]) if "bgd" in steps else lines[i + 6]
        sisa = _field(line, 0)
        lines[i + 6] = _set_field(line, 0, rtklib_sisa_m(sisa)) if "sisa" in steps and np.isfinite(sisa) else line
    out, skipping = [], False
    for ln in lines:
        if ln.startswith(">"):
            skipping = "ion" in steps and ln.startswith("> ION")
        if not skipping:
            out.append(ln)
    return "".join(out)


# The two programs

def plain_copy(src: Path, folder: Path, edit=None) -> Path:
    """Decompressed copy of ``src`` in ``folder`` (``edit``: a text -> text function applied)."""
    target = folder / src.name.removesuffix(".gz").replace(".crx", ".rnx")
    data = open_bytes(src)
    if edit is not None:
        data = edit(data.decode("ascii", errors="replace")).encode("ascii")
    target.write_bytes(data)
    return target


def run_peer(exe: str, obs: Path, navs: list[Path], folder: Path) -> dict[str, np.ndarray]:
    """rnx2rtkp, Galileo alone, on plain files in ``folder``: GPS time (s), ECEF fix (m), count."""
    lines = [("pos1-navsys        =8" if ln.startswith("pos1-navsys") else ln) for ln in PEER_CONF.read_text().splitlines()]
    conf = folder / "peer-galileo.conf"
    conf.write_text("\n".join(lines) + "\n")
    out = folder / "peer.pos"
    subprocess.run([exe, "-k", str(conf), "-p", "0", "-e", "-o", str(out), str(obs), *map(str, navs)],
                   check=True, capture_output=True, timeout=1200)
    rows = [ln.split() for ln in out.read_text().splitlines() if ln.strip() and not ln.startswith("%")]
    return {"time_gps_s": np.array([int(r[0]) * 604800.0 + float(r[1]) for r in rows]),
            "x_ecef_m": np.array([[float(v) for v in r[2:5]] for r in rows]).reshape(-1, 3)}


def run_ours(obs: Path, navs: list[Path]) -> dict[str, np.ndarray]:
    """gnss-solve ``--systems E --method wls``: GPS time (s), fix (m), status, satellites used."""
    res = process(obs, navs, load_config(None, {"systems": ["E"], "methods": "wls", "weights.cn0_model": "off",
                                                 "nlos.detector": "off"}))  # the peer's weights, no NLOS detector
    sol = res.solutions["wls"]
    return {"time_gps_s": res.epochs.time_gps_s, "x_ecef_m": sol.x_ecef_m, "solved": np.isin(sol.status, ("ok", "untested")),
            "used": np.isfinite(sol.residuals_m), "sv": np.asarray(res.epochs.sv).astype(str),
            "approx_ecef_m": np.asarray(res.epochs.approx_ecef_m, dtype=np.float64)}


def match_epochs(t_peer: np.ndarray, t_ours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each peer epoch the index of the nearest gnss-solve epoch, and whether it is within
    :data:`MATCH_S`."""
    k = np.clip(np.searchsorted(t_ours, t_peer), 1, max(t_ours.size - 1, 1))
    k = np.where(np.abs(t_ours[k - 1] - t_peer) <= np.abs(t_ours[k] - t_peer), k - 1, k)
    return k, np.abs(t_ours[k] - t_peer) <= MATCH_S


def compare(peer: dict[str, np.ndarray], ours: dict[str, np.ndarray]) -> dict[str, object]:
    """Per-epoch 3D distance (m) between the fixes on the epochs both solve."""
    k, near = match_epochs(peer["time_gps_s"], ours["time_gps_s"])
    both = near & ours["solved"][k]
    d = np.linalg.norm(ours["x_ecef_m"][k[both]] - peer["x_ecef_m"][both], axis=1)
    out: dict[str, object] = {"common": int(both.sum()), "peer_only": int((~both).sum()),
                              "ours_only": int(ours["solved"].sum() - both.sum())}
    if d.size:
        out.update(median_m=float(np.median(d)), p95_m=float(np.percentile(d, 95)), max_m=float(d.max()),
                   above_1cm=int((d > NEAR_M).sum()))
    out["_d"], out["_k"], out["_both"] = d, k[both], both
    return out


def rms_3d_m(x: np.ndarray, ref: np.ndarray) -> float | None:
    e = np.linalg.norm(x - ref, axis=1)
    return float(np.sqrt(np.mean(e**2))) if e.size else None


def classify(d: np.ndarray, t_gps_s: np.ndarray, x_ours: np.ndarray, x_peer: np.ndarray,
             toe_gps_s: np.ndarray) -> dict[str, int]:
    """Cause of each distance above :data:`NEAR_M` (see the module notes): toe, tropo or other."""
    big = d > NEAR_M
    at_toe = np.isin(np.round(t_gps_s, 1), np.round(np.unique(toe_gps_s), 1))
    h_ours, h_peer = ecef2geodetic(x_ours)[2], ecef2geodetic(x_peer)[2]
    tropo = (h_ours < TROPO_FLOOR_M) != (h_peer < TROPO_FLOOR_M)
    return {"toe": int((big & at_toe).sum()), "tropo": int((big & ~at_toe & tropo).sum()),
            "other": int((big & ~at_toe & ~tropo).sum())}


def galileo_toes(navs: list[Path]) -> np.ndarray:
    """Every Galileo record's toe (GPS s) in ``navs``."""
    return ephemeris_for_system(read_nav(navs, systems=["E"]), "E").toe_gps_s


def run_set(s: GalileoSet, exe: str) -> dict[str, object]:
    """The raw and the aligned comparison of one set (see the module notes)."""
    row: dict[str, object] = {"set": s.folder}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        obs = plain_copy(s.obs_path(), folder)
        navs = [plain_copy(p, folder) for p in s.nav_paths()]
        peer = run_peer(exe, obs, navs, folder)
        ours = run_ours(obs, navs)
        partial: dict[str, dict[str, np.ndarray]] = {}
        for n in range(1, len(STEPS) + 1):  # the parts one after the other; the last is the whole
            steps = STEPS[:n]
            step_dir = folder / "+".join(steps)
            step_dir.mkdir()
            partial["+".join(steps)] = run_ours(
                obs, [plain_copy(p, step_dir, lambda t, st=steps: as_rnx2rtkp_reads(t, st)) for p in s.nav_paths()])
        aligned = partial["+".join(STEPS)]
        toes = galileo_toes(navs)
        without_bgd = sorted(sv for p in navs for sv, b in first_record_bgd_s(p.read_text().splitlines(keepends=True)).items()
                             if b == 0.0)
    ref = np.array(ours["approx_ecef_m"] if s.reference == "header" else s.reference, dtype=np.float64)
    row["reference"] = "header APPROX POSITION" if s.reference == "header" else "README reference"

    wo = ours["solved"]
    row.update(epochs=int(ours["time_gps_s"].size), ours_solved=int(ours["solved"].sum()), peer_written=int(peer["time_gps_s"].size),
               rms_ours_m=rms_3d_m(ours["x_ecef_m"][wo], ref), rms_peer_m=rms_3d_m(peer["x_ecef_m"], ref))
    raw = compare(peer, ours)
    both, k_raw, d_raw = raw.pop("_both"), raw.pop("_k"), raw.pop("_d")
    common_ours = ours["x_ecef_m"][k_raw]
    # The satellites rnx2rtkp gives no group delay, and how many raw differences above 10 cm use one.
    cols = np.isin(ours["sv"], without_bgd)
    uses = ours["used"][k_raw][:, cols].any(axis=1) if cols.any() else np.zeros(k_raw.size, dtype=bool)
    raw["peer_without_bgd"] = without_bgd
    raw["above_10cm"] = int((d_raw > 0.1).sum())
    raw["above_10cm_using_those"] = int(((d_raw > 0.1) & uses).sum())
    row["rms_common_ours_m"] = rms_3d_m(common_ours, ref)
    row["rms_common_peer_m"] = rms_3d_m(peer["x_ecef_m"][both], ref)
    row["raw"] = raw
    row["steps"] = {}
    for name, run in partial.items():
        part = compare(peer, run)
        part.pop("_k"), part.pop("_both"), part.pop("_d")
        row["steps"][name] = part  # type: ignore[index]
    al = compare(peer, aligned)
    d, k, both_a = al.pop("_d"), al.pop("_k"), al.pop("_both")
    al["causes"] = classify(d, peer["time_gps_s"][both_a], aligned["x_ecef_m"][k], peer["x_ecef_m"][both_a], toes)
    away = ~np.isin(np.round(peer["time_gps_s"][both_a], 1), np.round(np.unique(toes), 1))
    al["max_not_at_toe_m"] = float(d[away].max()) if away.any() else None
    row["aligned"] = al
    row["rms_aligned_ours_m"] = rms_3d_m(aligned["x_ecef_m"][aligned["solved"]], ref)
    return row


COLUMNS = ["set", "epochs ours / rnx2rtkp / common", "median (m)", "95 % (m)", "max (m)", "> 1 cm",
           "3D RMS ours / rnx2rtkp (m)", "same on common epochs (m)", "aligned: max (m)",
           "aligned: > 1 cm (toe / tropo / other)"]


def table_row(row: dict[str, object]) -> list[object]:
    """One table row (numbers rounded for reading; the JSON keeps them whole)."""
    if "raw" not in row:
        return [row["set"], row.get("note", ""), "", "", "", "", "", "", "", ""]
    raw, al = row["raw"], row["aligned"]
    assert isinstance(raw, dict) and isinstance(al, dict)
    c = al["causes"]

    def m(v: object, nd: int = 3) -> str:
        return "" if v is None else f"{v:.{nd}f}"
    return [row["set"], f"{row['ours_solved']} / {row['peer_written']} / {raw['common']}", m(raw.get("median_m"), 4),
            m(raw.get("p95_m")), m(raw.get("max_m")), raw.get("above_1cm", 0),
            f"{m(row['rms_ours_m'], 2)} / {m(row['rms_peer_m'], 2)}",
            f"{m(row['rms_common_ours_m'], 2)} / {m(row['rms_common_peer_m'], 2)}", m(al.get("max_m"), 4),
            f"{al.get('above_1cm', 0)} ({c['toe']} / {c['tropo']} / {c['other']})"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sets", default="", help="comma list of set keys (default: every set)")
    args = parser.parse_args()
    if not RINEX.is_dir():
        sys.exit(f"{RINEX} not found: the comparison needs the shared real data")
    exe = shutil.which("rnx2rtkp")
    if exe is None or not PEER_CONF.is_file():
        sys.exit("rnx2rtkp (apt-get install -y rtklib) and ../shared/peer/rnx2rtkp-spp.conf are needed")
    chosen = [s for s in SETS if not args.sets or s.key in args.sets.split(",")]
    rows: list[dict[str, object]] = []
    for s in chosen:
        if s.without_galileo:
            rows.append({"set": s.folder, "note": f"no Galileo: {s.without_galileo}"})
            continue
        rows.append(run_set(s, exe))
        print(f"{s.key}: {json.dumps(rows[-1], default=str)}", file=sys.stderr)
    table = [table_row(r) for r in rows]
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    for t in table:
        print("| " + " | ".join(str(v) for v in t) + " |")
    RESULT.parent.mkdir(parents=True, exist_ok=True)
    RESULT.write_text(json.dumps({
        "command": "python benchmarks/bench_galileo_peer.py" + (f" --sets {args.sets}" if args.sets else ""),
        "title": "Galileo alone (wls) against rnx2rtkp pos1-navsys=8, per epoch",
        "table": {"columns": COLUMNS, "rows": table},
        "sets": rows,
    }, indent=1, default=str) + "\n")
    print(f"\nwrote {RESULT}", file=sys.stderr)


if __name__ == "__main__":
    main()
