"""A RINEX observation file as a sequence of datasets of at most N epochs each.

:func:`iter_obs_chunks` decompresses the file as it reads it (:func:`~gnss_cli.io.compression.iter_bytes`),
cuts the body at epoch records and hands each run of ``max_epochs`` epoch records to the
readers' parsers (:func:`~gnss_cli.io.rinex3_obs.parse_obs3`,
:func:`~gnss_cli.io.rinex2_obs.parse_obs2`, with the header of the file and the file's line
numbers in their messages), so that the memory of a reading does not grow with the file's
length. Each dataset has the layout of :func:`~gnss_cli.io.rinex.read_obs` for its epochs;
together they hold the epochs of ``read_obs`` of the whole file. (A satellite appears in the
``sv`` axis of the chunks it is observed in.)

RINEX 3/4 epoch records start with ``>``; RINEX 2 records are measured from their epoch
line (satellite count, observation types per satellite). Where a RINEX 2 body cannot be cut
(a line that is not an epoch line where one is expected) the rest of the file goes into one
chunk, whose parser then reports the line.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import xarray as xr

from gnss_cli.errors import RinexFormatError
from gnss_cli.io.compression import iter_bytes, prefetched

__all__ = ["iter_obs_chunks", "ObsRuns", "split_obs"]


def _header(blocks: Iterator[bytes], name: str) -> tuple[str, bytearray]:
    """The header text (through the ``END OF HEADER`` line) and the bytes read after it."""
    buf = bytearray()
    for block in blocks:
        buf += block
        pos = buf.find(b"END OF HEADER")
        if pos >= 0:
            nl = buf.find(b"\n", pos)
            if nl >= 0 or len(buf) - pos > 200:
                end = len(buf) if nl < 0 else nl + 1
                return bytes(buf[:end]).decode("ascii", errors="replace"), buf[end:]
    if not buf.strip():
        raise RinexFormatError(f"{name}: empty file")
    pos = buf.find(b"END OF HEADER")
    if pos < 0:
        raise RinexFormatError(f"{name}: no 'END OF HEADER' line (not a RINEX file, or truncated)")
    return bytes(buf).decode("ascii", errors="replace"), bytearray()


class _Cut3:
    """Where to cut a RINEX 3/4 body after ``max_epochs`` epoch records: the offset of the
    (max_epochs + 1)-th epoch line ``>``, None before it.

    The epoch lines found so far are kept, so each block appended to the buffer is scanned
    once (scanning the whole buffer at every block of a 33 MB day file read 150 MB).
    """

    def __init__(self) -> None:
        self.starts = np.zeros(0, dtype=np.intp)  # epoch line offsets in the buffer
        self.scanned = 0  # bytes of the buffer searched

    def __call__(self, buf: bytearray, max_epochs: int) -> int | None:
        arr = np.frombuffer(buf, dtype=np.uint8)
        new = np.flatnonzero(arr[self.scanned :] == ord(">")) + self.scanned  # rare: epoch lines only
        new = new[(new == 0) | (arr[np.maximum(new - 1, 0)] == ord("\n"))]  # at a line start
        self.starts = np.concatenate((self.starts, new))
        self.scanned = arr.size
        if self.starts.size <= max_epochs:
            return None
        at = int(self.starts[max_epochs])
        self.starts = self.starts[max_epochs:] - at  # the caller drops the bytes before the cut
        self.scanned -= at
        return at


class _Cut2:
    """Where to cut a RINEX 2 body after ``max_epochs`` epoch records (observation or event)."""

    def __init__(self, n_types: int) -> None:
        self.n_types = n_types
        self.stuck = False  # a line that is not an epoch line: no more cuts (the parser reports it)

    def __call__(self, buf: bytearray, max_epochs: int) -> int | None:
        from gnss_cli.io.rinex2_obs import record_line_count

        if self.stuck:
            return None
        pos, epochs = 0, 0
        while epochs < max_epochs:
            nl = buf.find(b"\n", pos)
            if nl < 0:
                return None
            line = bytes(buf[pos:nl]).decode("ascii", errors="replace").rstrip("\r")
            count = record_line_count(line, self.n_types)
            if count is None:
                self.stuck = True
                return None
            for _ in range(count):
                nl = buf.find(b"\n", pos)
                if nl < 0:
                    return None
                pos = nl + 1
            epochs += 1 if line.strip() else 0
        return pos


class _Runs:
    """Parse the runs of epoch records in order; check that epochs increase across runs. The
    last run is parsed together with the one before when it holds a single epoch: numpy takes
    another summation order over an axis of length one, and a part of one epoch would get
    other last bits than the same epoch in the whole file."""

    def __init__(self, name: str, info: object, parse: Callable[[bytes, int], xr.Dataset], before: int) -> None:
        self.name, self.info, self.parse = name, info, parse
        self.before = before  # file lines before the next run
        self.last: np.datetime64 | None = None
        self.yielded = 0
        self.held: tuple[bytes, int] | None = None  # a parsed run not yet handed out (body, first line)

    def _parse(self, body: bytes, before: int) -> xr.Dataset | None:
        try:
            return self.parse(body, before)
        except RinexFormatError as exc:
            if "no observation records" in str(exc):  # none of the chosen systems in this run
                return None
            raise

    def add(self, body: bytes | bytearray, final: bool = False) -> Iterator[xr.Dataset]:
        """Take the next run (``final``: the rest of the file) and hand out what is settled."""
        before = self.before
        self.before += body.count(b"\n")
        if not final:
            if self.held is not None:
                yield from self._out(self._parse(*self.held), self.held[1])
            self.held = (body, before)
            return
        ds = self._parse(body, before) if body and not body.isspace() else None  # (strip() would copy the body)
        if self.held is not None:
            held_body, held_before = self.held
            self.held = None
            if ds is not None and ds.sizes["time"] == 1:  # join the last epoch to the run before
                yield from self._out(self._parse(held_body + body, held_before), held_before)
                return
            yield from self._out(self._parse(held_body, held_before), held_before)
        yield from self._out(ds, before)

    def _out(self, ds: xr.Dataset | None, before: int) -> Iterator[xr.Dataset]:
        if ds is None or ds.sizes["time"] == 0:
            return
        t = ds["time"].values
        if self.last is not None and t[0] <= self.last:
            raise RinexFormatError(f"{self.name}: the epoch after line {before} is not later than the one before it "
                                   f"({np.datetime_as_string(t[0], 's')})")
        self.last, self.yielded = t[-1], self.yielded + 1
        ds.attrs["filename"] = self.info.path.name  # type: ignore[attr-defined]
        ds.attrs["rinex_version"] = self.info.version  # type: ignore[attr-defined]
        yield ds


def iter_obs_chunks(
    path: str | os.PathLike[str],
    systems: Sequence[str] | None = None,
    codes: Sequence[str] | None = None,
    max_epochs: int = 3600,
) -> Iterator[xr.Dataset]:
    """Read a RINEX 2/3/4 observation file in runs of at most ``max_epochs`` epoch records.

    Parameters
    ----------
    path, systems, codes
        As :func:`gnss_cli.io.rinex.read_obs` (validated the same way).
    max_epochs : int
        Epoch records per chunk (>= 1). A chunk with no record of ``systems`` is skipped.

    Yields
    ------
    xarray.Dataset
        ``read_obs``'s layout for the chunk's epochs, with the attributes ``filename`` and
        ``rinex_version``.

    Raises
    ------
    InputFileNotFoundError, RinexFormatError
        As ``read_obs``; also when an epoch is not later than the last of the chunk before.
    """
    from gnss_cli.io.rinex import rinex_info

    if max_epochs < 1:
        raise RinexFormatError(f"max_epochs: expected an integer >= 1, received {max_epochs}")
    info = rinex_info(path)
    if info.kind != "obs":
        raise RinexFormatError(f"{info.path}: is a RINEX navigation file, expected an observation file (OBS and NAV swapped?)")
    name = Path(path).name
    blocks = iter_bytes(path)
    header, buf = _header(blocks, name)
    if info.version < 3:
        from gnss_cli.io.rinex2_obs import obs_type_count, parse_obs2

        cut = _Cut2(obs_type_count(header, name))

        def parse(body: bytes, before: int) -> xr.Dataset:
            return parse_obs2(name, header, body, list(systems) if systems else None,
                              list(codes) if codes else None, lines_before=before)
    else:
        from gnss_cli.io.rinex3_obs import parse_obs3

        cut = _Cut3()  # type: ignore[assignment]

        def parse(body: bytes, before: int) -> xr.Dataset:
            return parse_obs3(name, header, body, list(systems) if systems else None,
                              list(codes) if codes else None, lines_before=before)

    runs = _Runs(name, info, parse, header.count("\n"))
    while True:
        at = cut(buf, max_epochs)
        if at is not None:
            with memoryview(buf) as view:
                body = bytes(view[:at])  # (bytes(buf[:at]) would copy twice)
            del buf[:at]
            yield from runs.add(body)
            continue
        block = next(blocks, None)
        if block is None:
            yield from runs.add(buf, final=True)  # the rest, not copied: buf changes no more
            break
        buf += block
    if not runs.yielded:
        raise RinexFormatError(f"{info.path}: no observation records" + (f" for systems {','.join(systems)}" if systems else ""))


class ObsRuns:
    """A RINEX 3/4 observation file already in memory, cut in runs of consecutive epoch records
    that can be parsed independently (:meth:`parse`, in any order or process) and then put in
    order with the checks of :func:`iter_obs_chunks` (:meth:`check_order`). Made by :func:`split_obs`."""

    def __init__(self, path: str | os.PathLike[str], info: object, header: str, bodies: list[tuple[bytes, int]],
                 systems: Sequence[str] | None, codes: Sequence[str] | None) -> None:
        self.name = Path(path).name
        self.info, self.header, self.bodies = info, header, bodies
        self.systems = list(systems) if systems else None
        self.codes = list(codes) if codes else None

    def __len__(self) -> int:
        return len(self.bodies)

    def parse(self, k: int) -> xr.Dataset | None:
        """The dataset of run ``k`` with the attributes of :func:`iter_obs_chunks`' chunks (None
        when it holds no record of the systems)."""
        from gnss_cli.io.rinex3_obs import parse_obs3

        body, before = self.bodies[k]
        runs = _Runs(self.name, self.info, lambda b, n: parse_obs3(self.name, self.header, b, self.systems, self.codes,
                                                                   lines_before=n), before)
        return next(runs._out(runs._parse(body, before), before), None)

    def check_order(self, spans: list[tuple[np.datetime64, np.datetime64] | None]) -> None:
        """Check the runs' (first, last) epochs (None: a run without records) as
        :func:`iter_obs_chunks` checks its chunks: every run later than the one before, and some run."""
        last = None
        for k, span in enumerate(spans):
            if span is None:
                continue
            if last is not None and span[0] <= last:
                raise RinexFormatError(f"{self.name}: the epoch after line {self.bodies[k][1]} is not later than "
                                       f"the one before it ({np.datetime_as_string(span[0], 's')})")
            last = span[1]
        if last is None:
            raise RinexFormatError(f"{self.info.path}: no observation records"  # type: ignore[attr-defined]
                                   + (f" for systems {','.join(self.systems)}" if self.systems else ""))


def split_obs(path: str | os.PathLike[str], systems: Sequence[str] | None, codes: Sequence[str] | None,
              runs: int, max_epochs: int, min_run_epochs: int) -> ObsRuns | None:
    """A RINEX 3/4 observation file that :func:`~gnss_cli.io.compression.prefetch` holds in memory,
    cut in ``runs`` runs of nearly equal size (at the first epoch record after each equal share
    of the bytes; fewer runs where a run would average fewer than ``min_run_epochs`` epochs).
    None when that is not so: another kind or version of file
    (RINEX 2 records are cut line by line: :func:`iter_obs_chunks`), a file not prefetched (a long
    one, read part by part), more than ``max_epochs`` epoch records (a file run in parts), or
    fewer than two runs. Parsed and ordered (:class:`ObsRuns`), the runs hold what
    ``iter_obs_chunks(path, systems, codes, max_epochs)`` yields in one chunk.
    """
    from gnss_cli.io.rinex import rinex_info

    info = rinex_info(path)
    if info.kind != "obs" or info.version < 3:
        return None
    content = prefetched(path)
    if content is None:
        return None
    end = content.find(b"END OF HEADER")
    end = content.find(b"\n", end) + 1 if end >= 0 else 0
    if end <= 0:
        return None  # (iter_obs_chunks reports the file)
    n_epochs = content.count(b"\n>", end - 1)  # epoch lines (the header's last newline before the first)
    runs = min(runs, n_epochs // max(min_run_epochs, 1))
    if n_epochs > max_epochs or runs < 2:
        return None
    cuts = [end]  # at the first epoch line after each equal share of the bytes: parsing costs by the byte
    for k in range(1, runs):
        at = content.find(b"\n>", end + (len(content) - end) * k // runs)
        if at < 0 or at + 1 <= cuts[-1]:
            return None
        cuts.append(at + 1)
    cuts.append(len(content))
    header = content[:end].decode("ascii", errors="replace")
    before = header.count("\n")
    bodies = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        bodies.append((content[a:b], before))
        before += content.count(b"\n", a, b)
    return ObsRuns(path, info, header, bodies, systems, codes)
