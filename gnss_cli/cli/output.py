"""All-or-nothing output files for the command-line tools.

A run stages every output file next to its target (a hidden temporary file in the same
folder), and only when all of them are written does it rename them into place. Any failure
on the way (disk full, read-only folder, a path that is not a folder, Ctrl-C, SIGTERM)
removes every staged file and every folder the run created, so no partial file of any kind
is left behind. Renames and the creation of temporary files run with SIGINT and SIGTERM
held back (:func:`gnss_cli.cli.signals.deferred`), so a signal cannot land between creating
a temporary file and recording it, nor between two renames of one set.

A whole folder tree (``gnss-batch``'s Parquet dataset) is staged the same way: a hidden
temporary folder beside its target, renamed into place with the files; a folder of that
name from an earlier run is moved aside first and removed once everything is in place.

Files get the permissions of an ordinary ``open()``: ``0o666`` less the user's umask (an
existing regular file keeps its own mode). A target that exists and is not a regular file
(``/dev/stdout``, a named pipe, ``/dev/full``) is written directly, since it cannot be
replaced by a rename.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

from gnss_cli.cli.signals import deferred
from gnss_cli.errors import ConfigError, OutputError

def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def _file_mode(target: Path) -> int:
    """Mode of a new file: the existing regular file's, else 0o666 less the umask."""
    try:
        st = target.stat()
        if stat.S_ISREG(st.st_mode):
            return stat.S_IMODE(st.st_mode)
    except OSError:
        pass
    return 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _message(path: Path, exc: OSError) -> str:
    reason = exc.strerror or str(exc)
    return f"{path}: cannot write output ({reason})"


class OutputSet:
    """Output files that appear together or not at all.

    Parameters
    ----------
    inputs
        Files the run reads; an output naming one of them is refused (:class:`ConfigError`),
        before anything is computed when :meth:`add` is called early.
    """

    def __init__(self, inputs: Iterable[Path | str] = ()) -> None:
        self._inputs = [Path(p) for p in inputs]
        self._targets: list[Path] = []
        self._staged: list[tuple[Path, Path]] = []
        self._direct: list[Path] = []
        self._created_dirs: list[Path] = []
        self._staging_dirs: list[Path] = []
        self._folders: list[tuple[Path, Path]] = []

    def add(self, path: Path | str, option: str) -> Path:
        """Register an output path (checked against the inputs and for a usable folder)."""
        target = Path(path)
        for source in self._inputs:
            if _same_file(target, source):
                raise ConfigError(f"{option}: {target} is one of the input files; refusing to overwrite it")
        if any(_same_file(target, t) for t in self._targets):
            raise ConfigError(f"{option}: {target} is given as two outputs")
        if target.is_dir():
            raise OutputError(f"{target}: cannot write output (is a folder)")
        parent = target.parent
        for p in (parent, *parent.parents):
            if p.exists():
                if not p.is_dir():
                    raise OutputError(f"{target}: cannot write output ({p} is not a folder)")
                if not os.access(p, os.W_OK | os.X_OK) and p == parent:
                    raise OutputError(f"{target}: cannot write output (folder {p} is not writable)")
                break
        self._targets.append(target)
        return target

    def _make_dirs(self, folder: Path) -> None:
        missing = []
        p = folder
        while not p.exists():
            missing.append(p)
            p = p.parent
        for d in reversed(missing):
            with deferred():
                d.mkdir()
                self._created_dirs.append(d)

    def _temporary(self, target: Path) -> Path:
        self._make_dirs(target.parent)
        with deferred():
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
            self._staged.append((Path(tmp), target))
        try:
            os.fchmod(fd, _file_mode(target))
        finally:
            os.close(fd)
        return Path(tmp)

    def write_text(self, path: Path | str, text: str) -> None:
        """Stage ``text`` for ``path`` (which must have been :meth:`add`-ed)."""
        target = Path(path)
        try:
            if target.exists() and not target.is_file() and not target.is_dir():
                # A device or a pipe: it cannot be renamed over, so write into it.
                self._direct.append(target)
                with open(target, "w", newline="") as f:
                    f.write(text)
                return
            tmp = self._temporary(target)
            with open(tmp, "w", newline="") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise OutputError(_message(target, exc)) from None

    def write_with(self, path: Path | str, writer: Callable[[Path], object]) -> None:
        """Stage ``path`` by calling ``writer(temporary_path)``."""
        target = Path(path)
        try:
            writer(self._temporary(target))
        except OSError as exc:
            raise OutputError(_message(target, exc)) from None

    def staging_dir(self, final_dir: Path | str) -> Path:
        """A hidden temporary folder inside ``final_dir`` whose files :meth:`commit` moves there."""
        final = Path(final_dir)
        if final.exists() and not final.is_dir():
            raise OutputError(f"{final}: cannot write output (not a folder)")
        try:
            self._make_dirs(final)
            with deferred():
                tmp = Path(tempfile.mkdtemp(prefix=".staging.", dir=final))
                self._staging_dirs.append(tmp)
        except OSError as exc:
            raise OutputError(_message(final, exc)) from None
        return tmp

    def stage_folder(self, path: Path | str, option: str) -> Path:
        """Register a whole folder tree as one output; returns the hidden temporary folder to fill.

        The temporary folder sits beside ``path``; :meth:`commit` renames it to ``path``,
        replacing a folder of that name left by an earlier run (moved aside first, removed
        once every output is in place)."""
        target = Path(path)
        if target.exists() and not target.is_dir():
            raise OutputError(f"{target}: cannot write output (not a folder)")
        for source in self._inputs:
            if source.resolve().is_relative_to(target.resolve()):
                raise ConfigError(f"{option}: {target} holds the input {source}; refusing to replace it")
        try:
            self._make_dirs(target.parent)
            with deferred():
                tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent))
                self._folders.append((tmp, target))
        except OSError as exc:
            raise OutputError(_message(target, exc)) from None
        os.chmod(tmp, 0o777 & ~_umask())
        return tmp

    def _commit_folders(self) -> list[tuple[Path, Path, Path | None]]:
        """Rename the staged folders into place; returns ``(staged, target, replaced folder
        moved aside or None)`` of each, for :meth:`_restore_folders` or the final clean-up."""
        done: list[tuple[Path, Path, Path | None]] = []
        try:
            for tmp, target in self._folders:
                old = None
                if target.exists():
                    old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
                    os.replace(target, old)
                done.append((tmp, target, old))
                os.replace(tmp, target)
        except OSError as exc:
            self._restore_folders(done)
            raise OutputError(_message(target, exc)) from None
        return done

    @staticmethod
    def _restore_folders(done: list[tuple[Path, Path, Path | None]]) -> None:
        """Undo :meth:`_commit_folders`: staged folders back to their temporary names, old ones back in place."""
        for tmp, target, old in reversed(done):
            with contextlib.suppress(OSError):
                if not tmp.exists():
                    os.replace(target, tmp)
                if old is not None:
                    os.replace(old, target)

    def adopt_staged(self, staging: Path, final_dir: Path | str) -> list[Path]:
        """Record every file written into ``staging`` as output of ``final_dir``; returns the targets."""
        targets = []
        for f in sorted(staging.iterdir()):
            target = Path(final_dir) / f.name
            self.add(target, "--out-dir")
            self._staged.append((f, target))
            targets.append(target)
        return targets

    def commit(self) -> None:
        """Rename every staged file into place (all of them, with signals held)."""
        with deferred():
            done: list[Path] = []
            folders = self._commit_folders()
            try:
                for tmp, target in self._staged:
                    os.replace(tmp, target)
                    done.append(target)
            except OSError as exc:
                for written in done:
                    with contextlib.suppress(OSError):
                        written.unlink()
                self._restore_folders(folders)
                self._staged = [(t, g) for t, g in self._staged if g not in done]
                raise OutputError(_message(target, exc)) from None
            self._staged = []
            self._folders = []
            self._created_dirs = []
            for d in [old for _, _, old in folders if old is not None] + self._staging_dirs:
                shutil.rmtree(d, ignore_errors=True)
            self._staging_dirs = []

    def discard(self) -> None:
        """Remove every staged file, staging folder and folder this set created."""
        with deferred():
            for tmp, _ in self._staged:
                with contextlib.suppress(OSError):
                    tmp.unlink()
            self._staged = []
            for d in self._staging_dirs + [tmp for tmp, _ in self._folders]:
                shutil.rmtree(d, ignore_errors=True)
            self._staging_dirs = []
            self._folders = []
            for d in reversed(self._created_dirs):
                with contextlib.suppress(OSError):
                    d.rmdir()
            self._created_dirs = []

    def __enter__(self) -> "OutputSet":
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is not None:
            self.discard()
            return
        try:
            self.commit()
        except BaseException:
            self.discard()
            raise
