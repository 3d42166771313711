"""Atomic file output: write a temporary file in the target's directory, then rename it.

Every file the toolkit writes for a user (data CSVs, model files, closed-loop records,
reports, figures) goes through here, so a run that fails half-way (an exception, a full
disk, Ctrl-C) never leaves a half-written output: the target either keeps its old
content (or stays absent) or gets the complete new content. `os.replace` within one
directory is atomic on POSIX and Windows.

What is *not* covered: a power loss (no ``fsync``), and a process killed by
``SIGKILL`` mid-write, which can leave the hidden temporary file (``.NAME.XXXX.tmp...``)
behind, though never a partial target.

The temporary file is created with mode ``0o666`` minus the process umask, like a
plain ``open(path, "w")``, so the finished file gets the usual permissions.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: Attempts to find an unused temporary name before giving up (collisions need the
#: same 8 random hex digits twice in one directory).
_MAX_NAME_ATTEMPTS = 100


def _temporary_sibling(path: Path) -> Path:
    """Create an empty, unused file next to ``path``; its name keeps ``path``'s suffix.

    The suffix is kept so that tools which pick a format from the extension
    (matplotlib's ``savefig``) see the same one as for the target.
    """
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
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


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


__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text"]
