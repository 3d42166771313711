"""Atomic file output: write a temporary file in the target's directory, then rename it.

Every file the toolkit writes for a user (data CSVs, model files, closed-loop records,
reports, figures) goes through here, so a run that fails half-way (an exception, a full
disk, Ctrl-C) leaves the target as it was (or absent) or complete: `os.replace` within
one directory is atomic on POSIX and Windows. The temporary file is ``fsync``-ed before
the rename and the directory after it, so a returned write survives a power cut (where
the file system honours ``fsync``; Windows cannot sync a directory).

SIGINT raises ``KeyboardInterrupt``, which runs the cleanup. SIGTERM kills without
running Python code, so the console script (`czmpc.cli.main`) installs a handler raising
`czmpc.cli.Terminated` (exit 143 = 128 + 15); a library user must install one likewise.
Only ``SIGKILL`` or a power cut mid-write can leave the hidden temporary file
(``.NAME.XXXX.tmp...``) behind, never a partial target. The temporary file gets mode
``0o666`` minus the umask, like a plain ``open(path, "w")``.
"""

from __future__ import annotations

import hashlib
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: Attempts to find an unused temporary name before giving up (collisions need the
#: same 8 random hex digits twice in one directory).
_MAX_NAME_ATTEMPTS = 100


def _temporary_sibling(path: Path) -> Path:
    """Create an empty, unused file next to ``path``, with its suffix (``savefig`` reads it)."""
    for _ in range(_MAX_NAME_ATTEMPTS):
        tmp = path.with_name(f".{path.stem}.{secrets.token_hex(4)}.tmp{path.suffix}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"{path.parent}: no unused temporary name for {path.name}")


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path to write; on normal exit it replaces ``path`` atomically.

    Use it for writers that want a file name, such as ``Figure.savefig``::

        with atomic_path(out / "fig.png") as tmp:
            fig.savefig(tmp, format="png")

    Parameters
    ----------
    path :
        The final file. Its directory must exist.

    Yields
    ------
    Path
        An empty temporary file in the same directory (same suffix as ``path``).

    Raises
    ------
    OSError
        The directory cannot be written, or the rename fails. On any exception in the
        ``with`` body (or in the rename) the temporary file is removed and ``path`` is
        left as it was.
    """
    target = Path(path)
    tmp = _temporary_sibling(target)
    try:
        yield tmp
        _fsync_file(tmp)
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_directory(target.parent)


def _fsync_file(path: Path) -> None:
    """Flush ``path``'s content to the disk (whoever wrote it has closed it)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_directory(folder: Path) -> None:
    """Flush ``folder``'s entries (the rename) to the disk; a no-op where unsupported."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:          # Windows cannot open a directory: nothing to sync there
        return
    try:
        os.fsync(fd)
    except OSError:          # some file systems refuse fsync on directories
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see the module docstring).

    Parameters
    ----------
    path :
        The final file. Its directory must exist.
    data :
        The complete new content.
    """
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)


def atomic_write_text(path: str | os.PathLike[str], text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically, newlines as given (no ``\\r\\n`` translation).

    Parameters
    ----------
    path :
        The final file. Its directory must exist.
    text :
        The complete new content.
    encoding :
        Text encoding of the file.
    """
    atomic_write_bytes(path, text.encode(encoding))


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file's bytes, in hex: the provenance hash of models, configs and inputs.

    Raises
    ------
    OSError
        The file cannot be read.
    """
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "file_sha256"]
