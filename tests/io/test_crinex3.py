"""Compact RINEX 3 decoded directly (:mod:`gnss_cli.io.crinex3`) against ``crx2rnx`` and the text reader.

The reference is the reader's own path for plain RINEX: the same file expanded by the
``hatanaka`` package's ``crx2rnx`` and parsed as text. Random RINEX 3 files (satellites coming
and going, blank fields, loss-of-lock flags, negative and sub-metre values) are compressed with
its ``rnx2crx``; the real files of ``../shared/rinex`` are compared too.
"""

from __future__ import annotations

import gzip
import subprocess
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.errors import RinexFormatError
from gnss_cli.io import compression, crinex3
from gnss_cli.io.crinex3 import _repair, _undifference
from gnss_cli.io.rinex3_header import header_end, read_header
from gnss_cli.io.rinex3_obs import parse_crinex3, parse_obs3, read_obs3

TYPES = {"G": ["C1C", "L1C", "D1C", "S1C", "C2W", "L2W"], "E": ["C1C", "L1C", "D1C", "S1C", "C5Q"]}
CODE_SETS = [None, ["C1C", "L1C", "L1Clli", "L2Wlli", "D1C"], ["C"]]


def _differences(y: np.ndarray, order: int) -> np.ndarray:
    """What CRINEX stores for one arc: the ``min(k, order)``-th backward difference at step ``k``."""
    out = np.empty_like(y)
    for k in range(y.size):
        d = y[: k + 1].copy()
        for _ in range(min(k, order)):
            d = np.diff(d)
        out[k] = d[-1]
    return out


def test_undifference_restores_arcs_of_every_order() -> None:
    rng = np.random.default_rng(3)
    arcs = [(rng.integers(-(10**13), 10**13, size=int(n)), int(m)) for n, m in
            zip(rng.integers(1, 12, size=60), rng.integers(0, 6, size=60))]
    given = np.concatenate([_differences(y, m) for y, m in arcs])
    start = np.concatenate([np.eye(1, y.size, 0, dtype=bool)[0] for y, _ in arcs])
    order = np.concatenate([np.full(y.size, m) for y, m in arcs])
    assert np.array_equal(_undifference(given, start, order), np.concatenate([y for y, _ in arcs]))


def test_repair_applies_a_text_difference() -> None:
    assert _repair(b"> 2020 06 25 00 00  0.0000000  0 3", b" " * 20 + b"3") == b"> 2020 06 25 00 00  3.0000000  0 3"
    assert _repair(b"ABCDEF", b"  &  Z") == b"AB DEZ"
    assert _repair(b"AB", b"  &&xy") == b"AB  xy"
    assert _repair(b"ABCD", b"  &&") == b"AB"  # blanked at the end: cut


def _line(label: str, text: str = "") -> str:
    return f"{text:<60}{label}\n"


def random_rinex3(seed: int, n_epochs: int = 60, event_at: int | None = None) -> bytes:
    """A RINEX 3.04 observation file of GPS and Galileo whose satellites rise, set and drop out,
    with blank fields, loss-of-lock and signal-strength flags."""
    rng = np.random.default_rng(seed)
    head = [_line("RINEX VERSION / TYPE", f"{'3.04':>9}{'':11}{'OBSERVATION DATA':<20}M"),
            _line("MARKER NAME", "TEST"), _line("APPROX POSITION XYZ", f"{3581113.4754:14.4f}{535200.9948:14.4f}{5233152.9614:14.4f}")]
    for sys_char, types in TYPES.items():
        head.append(_line("SYS / # / OBS TYPES", f"{sys_char}{len(types):>5} " + " ".join(types)))
    head += [_line("INTERVAL", f"{30.0:10.3f}"), _line("END OF HEADER")]
    sats = [f"G{k:02d}" for k in range(1, 11)] + [f"E{k:02d}" for k in range(1, 7)]
    base = {sv: rng.uniform([2.0e7, 1.0e8, -4000.0, 30.0], [2.6e7, 1.4e8, 4000.0, 50.0]) for sv in sats}
    present = rng.random(len(sats)) < 0.8
    body = []
    for k in range(n_epochs):
        present ^= rng.random(len(sats)) < 0.08  # satellites come and go
        if k == event_at:
            body.append("> 2024 03 01 00 00 00.0000000  4  1\n" + _line("COMMENT", "an event record"))
        listed = [sv for sv, p in zip(sats, present) if p]
        minute, sec = divmod(30 * k, 60)
        body.append(f"> 2024 03 01 {minute // 60:02d} {minute % 60:02d} {sec:10.7f}  0{len(listed):>3}\n")
        for sv in listed:
            fields = []
            for j, code in enumerate(TYPES[sv[0]]):
                if rng.random() < 0.06:
                    fields.append(" " * 16)
                    continue
                c, ph, dop, snr = base[sv]
                value = {"C": c + 150.0 * k + rng.normal(0, 3), "L": ph + 790.0 * k + rng.normal(0, 0.01),
                         "D": dop / 7 + rng.normal(0, 0.5) - 0.9 * k, "S": snr + rng.normal(0, 2)}[code[0]]
                value = rng.choice([value, -0.123, 0.5, -2.25, 0.0]) if rng.random() < 0.03 else value
                lli = rng.choice([" ", "1", "2"], p=[0.85, 0.1, 0.05]) if code[0] == "L" else " "
                ssi = rng.choice([" ", "5", "7", "9"])
                fields.append(f"{value:14.3f}{lli}{ssi}")
            body.append((sv + "".join(fields)).rstrip() + "\n")
    return ("".join(head) + "".join(body)).encode("ascii")


def rnx2crx(text: bytes, *options: str) -> bytes:
    """Compact RINEX of ``text`` from the ``hatanaka`` package's ``rnx2crx`` (``-e N``: every
    arc and the epoch line start anew every N epochs)."""
    exe = compression._crx2rnx_executable()
    if exe is None:
        pytest.skip("the hatanaka package has no bundled rnx2crx")
    proc = subprocess.run([str(exe.with_name("rnx2crx")), "-", *options], input=text, capture_output=True, check=True)
    return proc.stdout


def text_reading(path: Path, codes: list[str] | None):  # type: ignore[no-untyped-def]
    """The reference: crx2rnx, then the text reader."""
    name, content, end, header = read_header(path)
    return parse_obs3(name, header, content[end:], None, codes)


def assert_direct_equals_text(path: Path, codes: list[str] | None) -> None:
    raw = path.read_bytes()
    part = crinex3.crinex3_rinex_part(gzip.decompress(raw) if path.suffix == ".gz" else raw)
    assert part is not None
    end = header_end(part, path.name)
    direct = parse_crinex3(path.name, part[:end].decode(), part[end:], None, codes)
    assert direct is not None, "decoded by crx2rnx, not directly"
    reference = text_reading(path, codes)
    assert direct.identical(reference)
    assert read_obs3(path, codes=codes).identical(reference)


@pytest.mark.parametrize(("seed", "options"), [(1, ()), (2, ()), (3, ("-e", "7"))])
@pytest.mark.parametrize("codes", CODE_SETS)
def test_random_files_decode_as_crx2rnx_expands_them(tmp_path: Path, seed: int, options: tuple[str, ...],
                                                     codes: list[str] | None) -> None:
    path = tmp_path / "TEST00XXX_R_20240610000_01H_30S_MO.crx"
    path.write_bytes(rnx2crx(random_rinex3(seed), *options))
    assert_direct_equals_text(path, codes)
    plain = tmp_path / "plain.rnx"
    plain.write_bytes(random_rinex3(seed))
    ds = read_obs3(path, codes=codes)
    assert ds.drop_attrs().identical(read_obs3(plain, codes=codes).drop_attrs())
    if codes is not None and "L1Clli" in codes:
        assert np.nanmax(ds["L1Clli"].values) >= 1  # the flags were decoded, not left blank


def test_an_event_record_is_left_to_crx2rnx(tmp_path: Path) -> None:
    path = tmp_path / "event.crx"
    path.write_bytes(rnx2crx(random_rinex3(5, event_at=20)))
    part = crinex3.crinex3_rinex_part(path.read_bytes())
    end = header_end(part, path.name)
    assert parse_crinex3(path.name, part[:end].decode(), part[end:], None, None) is None
    assert read_obs3(path).identical(text_reading(path, None))


def test_a_damaged_arc_gives_the_crx2rnx_message(tmp_path: Path) -> None:
    content = rnx2crx(random_rinex3(6))
    first = content.index(b"3&", content.index(b"\n>", content.index(b"END OF HEADER")) + 200)
    path = tmp_path / "damaged.crx"
    path.write_bytes(content[:first] + content[first + 2:])  # an arc's start marker removed
    with pytest.raises(RinexFormatError, match="corrupt Compact RINEX"):
        read_obs3(path)


EPOCH_1 = b"> 2024 03 01 00 00  0.0000000  0  1      G01\n\n3&100 2&-5 &&&&\n"  # (a new satellite's flags in full)


@pytest.mark.parametrize(("second", "values"), [
    (b" " * 19 + b"3\n\n7 3\n", [[0.1, 0.107], [-0.005, -0.002]]),  # an epoch line as a difference: arcs go on
    (b" " * 19 + b"3\n\n7\n", [[0.1, 0.107], [-0.005, np.nan]]),  # a field left out: no observation
    (b"> 2024 03 01 00 00 30.0000000  0  1      G01\n\n7 3 &&&&\n", None),  # given in full: every arc starts anew
])
def test_arcs_go_on_across_epoch_lines_given_as_differences_only(second: bytes, values: list | None) -> None:
    decode = lambda: crinex3.decode_body(EPOCH_1 + second, {"G": 2}, {"G": [(0, "C1C"), (1, "C2W")]}, set())  # noqa: E731
    if values is None:
        with pytest.raises(crinex3.Unsupported, match="arc"):
            decode()
        return
    got = [v.tolist() for _, _, v in decode().values]
    np.testing.assert_array_equal(got, values)


@pytest.mark.parametrize("relative", [
    "esbc-2020177/ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz",
    "kms3-2022159-rinex4/KMS300DNK_R_20221591000_01H_30S_MO.crx",
    "p433-2019/P43300USA_R_20190012056_17M_15S_MO.crx",
])
@pytest.mark.parametrize("codes", CODE_SETS[1:])
def test_real_files_decode_as_crx2rnx_expands_them(rinex_dir: Path, relative: str, codes: list[str]) -> None:
    assert_direct_equals_text(rinex_dir / relative, codes)


def _damage(content: bytes, rng: np.random.Generator) -> bytes:
    """``content`` with its body damaged once: bytes changed, inserted or deleted, a line deleted,
    repeated or swapped with the next, or the file cut."""
    end = content.index(b"\n", content.index(b"END OF HEADER")) + 1
    body, kind = bytearray(content[end:]), int(rng.integers(7))
    at = int(rng.integers(len(body)))
    if kind == 0:
        body[at] = int(rng.integers(32, 127))
    elif kind == 1:
        body[at] = int(rng.choice(list(b"0123456789")))
    elif kind == 2:
        body[at:at] = bytes(rng.choice(list(b" 0123456789&-"), size=int(rng.integers(1, 4))).tolist())
    elif kind == 3:
        del body[at:at + int(rng.integers(1, 4))]
    elif kind in (4, 5, 6):
        lines = bytes(body).split(b"\n")
        i = int(rng.integers(len(lines) - 1))
        if kind == 4:
            del lines[i]
        elif kind == 5:
            lines.insert(i, lines[i])
        else:
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
        body = bytearray(b"\n".join(lines))
    if rng.random() < 0.1:
        body = body[: int(rng.integers(len(body)))]
    return content[:end] + bytes(body)


def test_damaged_files_decode_as_crx2rnx_expands_them_or_are_left_to_it() -> None:
    """Whatever the damage: either the decoder leaves the file to crx2rnx, or crx2rnx expands it too
    and the text reader reads the same values (every code, so that every field is checked)."""
    rng = np.random.default_rng(17)
    sources = [rnx2crx(random_rinex3(s), *opt) for s, opt in ((21, ()), (22, ("-e", "5")))]
    outcomes = {"decoded": 0, "left": 0}
    for _ in range(160):
        damaged = _damage(sources[int(rng.integers(len(sources)))], rng)
        part = crinex3.crinex3_rinex_part(damaged)
        end = header_end(part, "damaged.crx")
        direct = parse_crinex3("damaged.crx", part[:end].decode(), part[end:], None, None)
        if direct is None:
            outcomes["left"] += 1
            continue
        outcomes["decoded"] += 1
        text = compression.expand_crinex(damaged, "damaged.crx")  # raises if crx2rnx refuses the file
        text_end = header_end(text, "damaged.crx")
        assert direct.identical(parse_obs3("damaged.crx", text[:text_end].decode(), text[text_end:], None, None))
    assert min(outcomes.values()) > 20, outcomes  # both outcomes are exercised
