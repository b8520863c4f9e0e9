"""Open a RINEX file of any common packaging and return its plain text.

One opener for every compression a GNSS archive uses, so that the readers only ever see
plain RINEX text:

========================  ==========================================================
packaging                 detected by
========================  ==========================================================
gzip (``.gz``)            magic bytes ``1f 8b``
Unix compress (``.Z``)    magic bytes ``1f 9d`` (decompressed with ``ncompress``)
zip (``.zip``)            magic bytes ``PK\\x03\\x04`` (the first member is read)
bzip2 (``.bz2``)          magic bytes ``BZh``
Hatanaka (``.crx``,       first line ``CRINEX VERS / TYPE`` (after any of the above;
``.??d``)                 decompressed with the ``hatanaka`` package)
plain                     anything else
========================  ==========================================================

Detection uses the content, not the file name, so a mis-named file still opens; the
name only appears in error messages.
"""

from __future__ import annotations

import bz2
import gzip
import importlib.util
import io
import os
import re
import subprocess
import tempfile
import threading
import warnings
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from gnss_cli.errors import InputFileNotFoundError, RinexFormatError

__all__ = ["open_bytes", "expand_crinex", "open_text", "open_header_lines", "fault_text", "prefetch", "prefetched", "is_hatanaka", "iter_bytes"]

_GZIP_MAGIC = b"\x1f\x8b"
_LZW_MAGIC = b"\x1f\x9d"
_ZIP_MAGIC = b"PK\x03\x04"
_BZ2_MAGIC = b"BZh"


def is_hatanaka(content: bytes) -> bool:
    """Tell whether decompressed file content is Compact RINEX (Hatanaka).

    Parameters
    ----------
    content : bytes
        The beginning (at least the first 80 characters) of the file content.

    Returns
    -------
    bool
        True when the first line carries the ``CRINEX VERS   / TYPE`` label.
    """
    first_line = content[:160].split(b"\n", 1)[0]
    return b"CRINEX VERS" in first_line[60:] or b"COMPACT RINEX" in first_line


def _check_path(path: str | os.PathLike[str]) -> Path:
    """Return ``path`` as a :class:`Path` or raise when it is not a readable file."""
    p = Path(path).expanduser()
    if not p.exists():
        raise InputFileNotFoundError(f"{p}: file not found")
    if not p.is_file():
        raise InputFileNotFoundError(f"{p}: not a regular file")
    return p


def _unpack(raw: bytes, name: str) -> bytes:
    """Undo one layer of gzip / compress / zip / bzip2 packaging, if any."""
    try:
        if raw.startswith(_GZIP_MAGIC):
            return gzip.decompress(raw)
        if raw.startswith(_LZW_MAGIC):
            import ncompress  # small optional C extension, imported only when needed

            return bytes(ncompress.decompress(raw))
        if raw.startswith(_ZIP_MAGIC):
            with zipfile.ZipFile(io.BytesIO(raw)) as archive:
                members = [m for m in archive.infolist() if not m.is_dir()]
                if not members:
                    raise RinexFormatError(f"{name}: zip archive holds no file")
                return archive.read(members[0])
        if raw.startswith(_BZ2_MAGIC):
            return bz2.decompress(raw)
    except RinexFormatError:
        raise
    except ImportError as exc:
        raise RinexFormatError(
            f"{name}: Unix-compressed (.Z) file needs the 'ncompress' package ({exc})"
        ) from exc
    except (OSError, EOFError, ValueError, zlib.error, zipfile.BadZipFile) as exc:
        raise RinexFormatError(f"{name}: corrupt or truncated compressed file ({exc})") from exc
    return raw


def open_bytes(path: str | os.PathLike[str], keep_crinex3: bool = False) -> bytes:
    """Read a RINEX file and return its decompressed plain-RINEX content as bytes.

    Parameters
    ----------
    path : str or os.PathLike
        Plain, gzip, Unix-compress, zip or bzip2 file, holding RINEX or Compact RINEX
        (Hatanaka) text.
    keep_crinex3 : bool, default False
        Return Compact RINEX 3 content as it is (unpacked, not expanded: the observation reader
        decodes it itself, :mod:`gnss_cli.io.crinex3`; :func:`expand_crinex` expands it).

    Returns
    -------
    bytes
        Plain RINEX text (ASCII bytes, line ends as in the file).

    Raises
    ------
    InputFileNotFoundError
        ``path`` does not exist or is not a regular file.
    RinexFormatError
        The compressed stream or the Hatanaka content is corrupt (also when ``crx2rnx``
        only warns and skips the epochs it cannot restore: their data would be missing).

    Notes
    -----
    Hatanaka decompression is done by the ``hatanaka`` package's C ``crx2rnx``; on a 24 h
    30 s multi-GNSS file (4 MB ``.crx.gz`` -> 33 MB RINEX) it takes about 0.45 s of CPU, more
    than the parsing of the text. The RINEX 3/4 observation reader therefore asks for Compact
    RINEX 3 as it is (``keep_crinex3``) and decodes it itself, in about 0.2 s; where a second
    core is idle (``gnss-solve`` while it imports, :func:`prefetch`) ``crx2rnx`` runs there.
    """
    p = _check_path(path)
    job = _PENDING.pop(_file_key(p), None)
    if job is not None:
        return job.result()
    return _read(p, keep_crinex3)


def _read(p: Path, keep_crinex3: bool = False) -> bytes:
    """:func:`open_bytes` of a checked path."""
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InputFileNotFoundError(f"{p}: cannot read file ({exc})") from exc
    content = _unpack(raw, p.name)
    if is_hatanaka(content) and not (keep_crinex3 and content.startswith(b"3.0")):
        content = _crx2rnx(content, p.name)
    return content


def expand_crinex(content: bytes, name: str) -> bytes:
    """Plain RINEX of Compact RINEX ``content`` (``crx2rnx``); other content as it is."""
    return _crx2rnx(content, name) if is_hatanaka(content) else content


def _crx2rnx(content: bytes, name: str) -> bytes:
    """Plain RINEX from Compact RINEX with the ``hatanaka`` package's C ``crx2rnx``.

    The program reads a temporary file and writes one, so that no Python thread pumps the
    33 MB of a 24 h file through a pipe (which also lets :func:`prefetch` run it beside the
    main thread without competing for the interpreter lock). Its warnings (records it
    skipped: data are missing) are errors here, as its errors are.
    """
    exe = _crx2rnx_executable()
    if exe is None:  # a hatanaka build without the bundled executable: its own pipe
        return _crx2rnx_library(content, name)
    with tempfile.TemporaryFile() as src, tempfile.TemporaryFile() as dst:
        src.write(content)
        src.seek(0)
        proc = subprocess.run([str(exe), "-"], stdin=src, stdout=dst, stderr=subprocess.PIPE, check=False)
        stderr = proc.stderr.decode("ascii", errors="backslashreplace").strip()
        if proc.returncode not in (0, 2):
            message = re.sub("^ +", "", stderr, flags=re.M)
            message = re.sub("\n(?!WARNING|ERROR)", " ", message)
            message = re.sub("^ERROR *: *", "", message, flags=re.M)
            raise RinexFormatError(f"{name}: corrupt Compact RINEX (Hatanaka) file ({message})")
        if proc.returncode == 2 or stderr:
            message = re.sub("^ +", "", stderr, flags=re.M).replace("\n", " ")
            message = re.sub("^ *WARNING *:? *", "", message) or "exited with an unspecified warning"
            raise RinexFormatError(f"{name}: corrupt Compact RINEX (Hatanaka) file (crx2rnx: {message})")
        dst.seek(0)
        return dst.read()


def _crx2rnx_executable() -> Path | None:
    """The ``crx2rnx`` program that the ``hatanaka`` package bundles, or None."""
    spec = importlib.util.find_spec("hatanaka")  # the package's folder, without importing it
    if spec is None or not spec.submodule_search_locations:
        return None
    exe = Path(list(spec.submodule_search_locations)[0]) / "bin" / ("crx2rnx.exe" if os.name == "nt" else "crx2rnx")
    return exe if exe.is_file() else None


def _crx2rnx_library(content: bytes, name: str) -> bytes:
    """Plain RINEX from Compact RINEX through ``hatanaka.crx2rnx`` (warnings are errors)."""
    import hatanaka

    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            content = hatanaka.crx2rnx(content)
    except (hatanaka.HatanakaException, ValueError, UnicodeError) as exc:
        raise RinexFormatError(f"{name}: corrupt Compact RINEX (Hatanaka) file ({exc})") from exc
    # crx2rnx warns (HatanakaWarning, a UserWarning) when it skipped records it could not
    # restore: data are missing. Deprecation notices of the library itself (hatanaka 2.7 on
    # Python 3.11: "pathlib.Path.__enter__() is deprecated") say nothing about the file.
    damage = [w for w in caught if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning))]
    if damage:
        raise RinexFormatError(f"{name}: corrupt Compact RINEX (Hatanaka) file ({damage[0].message})")
    return content


class _Prefetch(threading.Thread):
    """:func:`open_bytes` of one file on a background thread; :meth:`result` waits for it."""

    def __init__(self, path: Path) -> None:
        super().__init__(name=f"prefetch {path.name}", daemon=True)  # never delays the exit of a failed run
        self.path = path
        self.content: bytes | None = None
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.content = _read(self.path)
        except BaseException as exc:  # noqa: BLE001 - handed to the reader, which raises it
            self.error = exc

    def result(self) -> bytes:
        self.join()
        if self.error is not None:
            raise self.error
        if self.content is None:  # a forked child, whose copy of the reading thread never ran on
            return _read(self.path)
        return self.content


_PENDING: dict[tuple[str, int, int], _Prefetch] = {}
"""Prefetched files by :func:`_file_key`, until :func:`open_bytes` or :func:`iter_bytes` takes them."""


def _file_key(path: str | os.PathLike[str]) -> tuple[str, int, int] | None:
    """The real path, modification time (ns) and size of a file; None when it cannot be stat'ed."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return os.path.realpath(path), st.st_mtime_ns, st.st_size


PREFETCH_MAX_BYTES = 8 << 20
"""Files up to this size on disk (bytes) are prefetched: a day of 30 s multi-GNSS observations as
``.crx.gz`` (ESBC: 4 MB) and navigation files; longer files are read as the run goes."""


def prefetch(*paths: str | os.PathLike[str]) -> None:
    """Start reading and decompressing ``paths`` on background threads.

    The next :func:`open_bytes` of each file (unchanged since) takes the result instead of
    reading it again. The work happens outside the interpreter lock (file reads, zlib and
    bzip2 inflation, the ``crx2rnx`` program on temporary files), so on a second core it
    overlaps the imports and the parsing of the other files: ``gnss-solve`` calls this for
    its inputs before it imports the numerical modules. Files that cannot be stat'ed are
    left to :func:`open_bytes` and its error messages; files larger than
    :data:`PREFETCH_MAX_BYTES` on disk too: a long observation file is read part by part
    (:func:`iter_bytes`), and its whole text held in advance would be the run's largest
    allocation (a plain 24 h 1 Hz file: 86 MB, the peak 268 instead of 190 MiB).

    Compact RINEX 3 is expanded here too, although the observation reader could decode it
    with less CPU (:mod:`gnss_cli.io.crinex3`): on the idle core ``crx2rnx`` costs no wall
    time, its text is parsed in 0.12 s against the decoder's 0.2 s, and the text can be cut
    between processes (:func:`gnss_cli.io.obs_chunks.split_obs`).
    """
    for path in paths:
        key = _file_key(path)
        if key is None or key in _PENDING or not os.path.isfile(path) or os.path.getsize(path) > PREFETCH_MAX_BYTES:
            continue
        job = _Prefetch(Path(path))
        _PENDING[key] = job
        job.start()


def prefetched(path: str | os.PathLike[str]) -> bytes | None:
    """The content of a file that :func:`prefetch` is reading (after waiting for it), left for the
    next :func:`open_bytes` or :func:`iter_bytes`; None when the file is not being prefetched.
    Raises what :func:`open_bytes` raises."""
    job = _PENDING.get(_file_key(path))  # type: ignore[arg-type]
    return job.result() if job is not None else None


def fault_text(exc: BaseException) -> str:
    """What went wrong reading or inflating a file, in words: the exception's own text (gzip's
    "CRC check failed ...", zlib's "invalid stored block lengths"), never Python's class name;
    one without text is described by its kind."""
    text = str(exc).strip()
    if text:
        return text
    if isinstance(exc, EOFError):
        return "the file ends inside its compressed data (truncated)"
    if isinstance(exc, ImportError):
        return "a package needed to inflate it is not installed"
    return "unreadable data"


def open_header_lines(path: str | os.PathLike[str], max_lines: int = 2000) -> list[str]:
    """The lines of a RINEX file up to its ``END OF HEADER`` line (at most ``max_lines``).

    Gzip and bzip2 files are inflated only as far as the header; a Compact RINEX header is
    plain RINEX after its two ``CRINEX`` lines, which are returned too. Lines keep their
    line ends; bytes that are not ASCII are dropped.

    Raises
    ------
    OSError, EOFError, zlib.error, zipfile.BadZipFile, ImportError
        The file cannot be read or inflated (the caller names the file).
    """
    p = Path(path)
    with p.open("rb") as raw:
        magic = raw.read(4)
        raw.seek(0)
        if magic.startswith(_GZIP_MAGIC) or magic.startswith(_BZ2_MAGIC):
            stream: Any = gzip.GzipFile(fileobj=raw) if magic.startswith(_GZIP_MAGIC) else bz2.BZ2File(raw)
            return _header_of(stream, max_lines)
        if magic.startswith(_LZW_MAGIC) or magic.startswith(_ZIP_MAGIC):
            return _header_of(io.BytesIO(_unpack(raw.read(), p.name)), max_lines)
        return _header_of(raw, max_lines)


def _header_of(stream: Any, max_lines: int) -> list[str]:
    lines: list[str] = []
    for line in stream:
        lines.append(line.decode("ascii", errors="ignore"))
        if "END OF HEADER" in lines[-1] or len(lines) > max_lines:
            break
    return lines


def open_text(path: str | os.PathLike[str]) -> str:
    """Read a RINEX file of any packaging and return its plain-RINEX text.

    Parameters
    ----------
    path : str or os.PathLike
        Plain, ``.gz``, ``.Z``, ``.zip``, ``.bz2``, Hatanaka (``.crx``, ``.??d``) or a
        compressed Hatanaka file.

    Returns
    -------
    str
        The plain RINEX text. Bytes that are not ASCII are replaced (RINEX is ASCII).

    Raises
    ------
    InputFileNotFoundError
        ``path`` does not exist or is not a regular file.
    RinexFormatError
        The compressed stream or the Hatanaka content is corrupt.

    Examples
    --------
    >>> text = open_text("sample_rinex/static/obs.rnx")  # from the repository's root
    >>> text.splitlines()[0][60:]
    'RINEX VERSION / TYPE'
    """
    return open_bytes(path).decode("ascii", errors="replace")


BLOCK_BYTES = 1 << 22
"""Bytes per block of :func:`iter_bytes` (4 MiB)."""


def _stream(p: Path, raw_head: bytes) -> IO[bytes] | None:
    """A decompressing reader of ``p`` for the packagings that stream (plain, gzip, bzip2,
    zip), None for Unix compress (decompressed whole)."""
    if raw_head.startswith(_GZIP_MAGIC):
        return gzip.open(p, "rb")
    if raw_head.startswith(_BZ2_MAGIC):
        return bz2.open(p, "rb")
    if raw_head.startswith(_ZIP_MAGIC):
        archive = zipfile.ZipFile(p)
        members = [m for m in archive.infolist() if not m.is_dir()]
        if not members:
            raise RinexFormatError(f"{p.name}: zip archive holds no file")
        return archive.open(members[0])
    if raw_head.startswith(_LZW_MAGIC):
        return None
    return open(p, "rb")


def _blocks(content: bytes, block_bytes: int) -> Iterator[memoryview]:
    """``content`` in views of ``block_bytes`` (not copies: a 24 h file is 33 MB)."""
    with memoryview(content) as view:
        for k in range(0, len(content), block_bytes):
            yield view[k : k + block_bytes]


def iter_bytes(path: str | os.PathLike[str], block_bytes: int = BLOCK_BYTES) -> Iterator[bytes | memoryview]:
    """The decompressed plain-RINEX content of ``path`` in blocks of about ``block_bytes``.

    Plain, gzip, bzip2 and zip files are decompressed as they are read, so memory does not
    grow with the file. Unix-compressed (``.Z``) and Compact RINEX (Hatanaka) content is
    restored whole first (``crx2rnx`` takes the whole text) and then handed out in blocks
    (read-only views of that text, valid while the iteration lasts).
    A file that :func:`prefetch` has read already is handed out from that text (and the text
    is let go: a second reading streams). The errors are those of :func:`open_bytes`.
    """
    p = _check_path(path)
    try:
        job = _PENDING.pop(_file_key(p), None)
        if job is not None:
            content = job.result()
            yield from _blocks(content, block_bytes)
            return
        with open(p, "rb") as f:
            raw_head = f.read(4)
        reader = _stream(p, raw_head)
        if reader is None:
            content = open_bytes(p)
            yield from _blocks(content, block_bytes)
            return
        with reader:
            first = reader.read(block_bytes)
            if is_hatanaka(first):
                content = open_bytes(p)
                yield from _blocks(content, block_bytes)
                return
            block = first
            while block:
                yield block
                block = reader.read(block_bytes)
    except RinexFormatError:
        raise
    except OSError as exc:
        if not isinstance(exc, (FileNotFoundError, PermissionError)):  # gzip.BadGzipFile is an OSError
            raise RinexFormatError(f"{p.name}: corrupt or truncated compressed file ({exc})") from exc
        raise InputFileNotFoundError(f"{p}: cannot read file ({exc})") from exc
    except (EOFError, ValueError, zlib.error, zipfile.BadZipFile) as exc:
        raise RinexFormatError(f"{p.name}: corrupt or truncated compressed file ({exc})") from exc
