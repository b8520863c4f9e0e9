"""How ``[processing] urban_variance_factor`` (``environment = "auto"``) was set: on training data only.

    python benchmarks/choose_environment.py [--quick]

``environment = "auto"`` takes a file for a street canyon, and runs it with ``configs/urban.toml``'s
settings, when the median WLS variance factor of its first 500 epochs (chi-square statistic over
degrees of freedom, ``gnss_cli/pipeline/environment.py``) exceeds ``urban_variance_factor``. This
script measures that factor on files whose environment is known and sets the threshold.

Training data: open sky -- simulated open-sky drives of seeds 101-110 with each receiver profile's
systems (GPS + BeiDou; GPS, Galileo, BeiDou) and simulated flights of the same seeds, and the real
stations ESBC (24 h, every system), p433, rtklib-0759 and kms3; street
canyons -- the simulated urban drives of seeds 101-110 of both receiver profiles (those of
``choose_nlos.py``), tst2 (every system, and GPS alone) and smartloc-berlin (GPS). Every run
300 s at 1 Hz for the simulated files.

Rule: the open-sky and the street-canyon factors must not overlap; the threshold is their
geometric mean, ``sqrt(largest open-sky factor x smallest street-canyon factor)``, rounded down to
one significant digit. Then reported, not used: the evaluation seeds 1-20 of the same kinds
(``bench_urban.py``'s drives are seeds 1-20) and the real Yamatogawa walk. Prints a table and
writes ``benchmarks/results/choose_environment.json``. About 10 minutes on one core.
"""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from gnss_cli.config import load_config
from gnss_cli.pipeline import process
from gnss_cli.pipeline.environment import HEAD_EPOCHS, head_variance_factor

sys.path.insert(0, str(Path(__file__).resolve().parent))
from choose_cn0_weights import training_run  # noqa: E402
from choose_nlos import TRAINING_SEEDS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RINEX = ROOT.parent / "shared" / "rinex"
OUT = ROOT / "benchmarks" / "results" / "choose_environment.json"
EVALUATION_SEEDS = list(range(1, 21))
OPEN_SYSTEMS = {"single": "G,C", "dual": "G,E,C"}
"""The systems of each receiver profile of the simulator's canyons, for the open-sky drives."""


def simulate(work: Path, kind: str, seed: int, duration_s: float) -> tuple[Path, list[Path], str | None]:
    """One simulated file: ``urban-<profile>`` (a canyon drive), ``open-<profile>`` (an open-sky
    drive with that profile's systems) or ``flight`` (open sky, GPS)."""
    folder = work / f"{kind}-{seed}"
    args = [sys.executable, "-m", "gnss_cli.cli.simulate", "--duration", str(duration_s), "--interval", "1",
            "--seed", str(seed), "--out-dir", str(folder), "-q"]
    if kind.startswith("urban-"):
        args += ["--environment", "urban", "--receiver", kind.split("-")[1], "--trajectory", "drive"]
    elif kind.startswith("open-"):
        args += ["--systems", OPEN_SYSTEMS[kind.split("-")[1]], "--trajectory", "drive"]
    else:
        args += ["--trajectory", "flight"]
    subprocess.run(args, check=True)
    return folder / "obs.rnx", [folder / "nav.rnx"], None


def real_files() -> dict[str, tuple[str, tuple[Path, list[Path], str | None]]]:
    """The shared sets: name -> (kind, (obs, navs, systems)); kind ``open``, ``canyon`` or ``evaluation``."""
    tst = RINEX / "tst2-2020155-urban-static"
    ber = RINEX / "smartloc-berlin-2016158-urban-kinematic"
    esbc = RINEX / "esbc-2020177"
    yam = RINEX / "yamatogawa-2010006-kinematic"
    out = {
        "ESBC": ("open", (esbc / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz", [esbc / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"], None)),
        "p433": ("open", (RINEX / "p433-2019" / "P43300USA_R_20190012056_17M_15S_MO.crx", [RINEX / "p433-2019" / "brdc0010.19n"], None)),
        "rtklib-0759": ("open", (RINEX / "rtklib-0759" / "07590920.05o", [RINEX / "rtklib-0759" / "07590920.05n"], None)),
        "kms3": ("open", (RINEX / "kms3-2022159-rinex4" / "KMS300DNK_R_20221591000_01H_30S_MO.crx",
                          [RINEX / "kms3-2022159-rinex4" / "KMS300DNK_R_20221591000_01H_MN.rnx.gz"], None)),
        "tst2": ("canyon", (tst / "2020_06_03_TST_03.obs.gz", sorted(tst.glob("hksc155d.20?")), None)),
        "tst2 GPS": ("canyon", (tst / "2020_06_03_TST_03.obs.gz", [tst / "hksc155d.20n"], None)),
        "smartloc-berlin GPS": ("canyon", (ber / "Berlin_Potsdamer_Platz.obs.gz", [ber / "BRDC00WRD_U_20161580000_01D_MN.rnx.gz"], "G")),
        "Yamatogawa walk": ("evaluation", (yam / "yamatogawa_rover.obs", [yam / "brdc0060.10n"], None)),
    }
    return {k: v for k, v in out.items() if v[1][0].exists()}


def factor_of(obs: Path, navs: list[Path], systems: str | None) -> float:
    """The variance factor ``auto`` judges a file by (``head_variance_factor``: the plain WLS fix of its
    first :data:`HEAD_EPOCHS` epochs)."""
    over: dict[str, object] = {"methods": "wls", "environment": "open"}
    if systems:
        over["systems"] = systems
    config = load_config(None, over)
    return head_variance_factor(config, process(obs, navs, config).epochs)


def main() -> None:
    seeds, duration, quick = training_run(__doc__, "one training seed per kind, 120 s; nothing written")
    seeds = seeds if quick else TRAINING_SEEDS
    evaluation = [] if quick else EVALUATION_SEEDS
    rows: list[list[object]] = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for role, seed_list in (("training", seeds), ("evaluation", evaluation)):
            for kind in ("open-single", "open-dual", "flight", "urban-single", "urban-dual"):
                for seed in seed_list:
                    f = factor_of(*simulate(work, kind, seed, duration))
                    env = "canyon" if kind.startswith("urban") else "open"
                    rows.append([f"sim {kind} {seed}", env, role, round(f, 3)])
                    print(rows[-1], flush=True)
                    (work / f"{kind}-{seed}" / "obs.rnx").unlink()
    for name, (kind, files) in real_files().items():
        f = factor_of(*files)
        rows.append([name, "open" if kind == "evaluation" else kind, "evaluation" if kind == "evaluation" else "training",
                     round(f, 3) if np.isfinite(f) else None])
        print(rows[-1], flush=True)
    train = [r for r in rows if r[2] == "training" and r[3] is not None]
    open_max = max(r[3] for r in train if r[1] == "open")
    canyon_min = min(r[3] for r in train if r[1] == "canyon")
    chosen = None
    if open_max < canyon_min:
        mean = math.sqrt(open_max * canyon_min)
        digit = 10.0 ** math.floor(math.log10(mean))
        chosen = math.floor(mean / digit) * digit
    notes = (f"training: open sky at most {open_max:.3f}, street canyons at least {canyon_min:.3f}; "
             f"threshold = their geometric mean rounded down to one digit")
    if chosen is not None:
        wrong = [r[0] for r in rows if r[3] is not None and (r[3] > chosen) != (r[1] == "canyon")]
        notes += f"; judged otherwise than their kind at {chosen:g}: {', '.join(wrong) if wrong else 'none'}"
    from choose_cn0_weights import report_choice

    report_choice(OUT, "environment = auto: urban_variance_factor", "python benchmarks/choose_environment.py",
                  ["case", "kind", "role", "variance factor"], rows, None if chosen is None else f"{chosen:g}", notes, quick)
    print(notes)


if __name__ == "__main__":
    main()
