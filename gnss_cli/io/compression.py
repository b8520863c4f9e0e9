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
import io
import os
import warnings
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from gnss_cli.errors import InputFileNotFoundError, RinexFormatError

__all__ = ["open_bytes", "open_text", "is_hatanaka", "iter_bytes"]

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


def open_bytes(path: str | os.PathLike[str]) -> bytes:
    """Read a RINEX file and return its decompressed plain-RINEX content as bytes.

    Parameters
    ----------
    path : str or os.PathLike
        Plain, gzip, Unix-compress, zip or bzip2 file, holding RINEX or Compact RINEX
        (Hatanaka) text.

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
    30 s multi-GNSS file (4 MB ``.crx.gz`` -> 33 MB RINEX) it takes about 0.4 s and
    usually dominates the reading time.
    """
    p = _check_path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InputFileNotFoundError(f"{p}: cannot read file ({exc})") from exc
    content = _unpack(raw, p.name)
    if is_hatanaka(content):
        import hatanaka  # import cost only for Compact RINEX input

        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                content = hatanaka.crx2rnx(content)
        except (hatanaka.HatanakaException, ValueError, UnicodeError) as exc:
            raise RinexFormatError(f"{p.name}: corrupt Compact RINEX (Hatanaka) file ({exc})") from exc
        # crx2rnx warns (HatanakaWarning, a UserWarning) when it skipped records it could not
        # restore: data are missing. Deprecation notices of the library itself (hatanaka 2.7 on
        # Python 3.11: "pathlib.Path.__enter__() is deprecated") say nothing about the file.
        damage = [w for w in caught if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning))]
        if damage:
            raise RinexFormatError(f"{p.name}: corrupt Compact RINEX (Hatanaka) file ({damage[0].message})")
    return content


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


def iter_bytes(path: str | os.PathLike[str], block_bytes: int = BLOCK_BYTES) -> Iterator[bytes]:
    """The decompressed plain-RINEX content of ``path`` in blocks of about ``block_bytes``.

    Plain, gzip, bzip2 and zip files are decompressed as they are read, so memory does not
    grow with the file. Unix-compressed (``.Z``) and Compact RINEX (Hatanaka) content is
    restored whole first (``crx2rnx`` takes the whole text) and then handed out in blocks.
    The errors are those of :func:`open_bytes`.
    """
    p = _check_path(path)
    try:
        with open(p, "rb") as f:
            raw_head = f.read(4)
        reader = _stream(p, raw_head)
        if reader is None:
            content = open_bytes(p)
            for k in range(0, len(content), block_bytes):
                yield content[k : k + block_bytes]
            return
        with reader:
            first = reader.read(block_bytes)
            if is_hatanaka(first):
                content = open_bytes(p)
                for k in range(0, len(content), block_bytes):
                    yield content[k : k + block_bytes]
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
