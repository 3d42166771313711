"""One writer per plant: a lock on this machine and a watch for other writers at the plant.

Two controllers writing one TRIAC command fight, and neither knows it. Two guards:

`PlantLock`
    An exclusive lock per (endpoint, command node) on this machine for the run's life:
    a second ``czmpc run`` for the plant refuses to start and names the first. The
    operating system releases it on any exit, ``kill -9`` included.
`WriterWatch`
    czmpc reads back what it wrote (command, heartbeat, the optional ``[nodes] owner``
    lease): a value changed by another writer stops czmpc's writes, raises the alarm,
    exit 1. Before its first write, nodes that move over one period refuse the start
    (exit 2, `moved`). A single foreign write that lands between czmpc's read and its
    own write of the same sample (the step's latency, milliseconds in a period of
    seconds) is overwritten unseen; a controller writing every period is seen at the
    next read after it lands outside that window.

Values are compared as the node holds them (`same_value`: a Float node's float32).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import socket
import sys
import tempfile
from pathlib import Path
from typing import IO, Any

import numpy as np

from czmpc.errors import CzmpcError

#: Where the locks live (override with the environment variable ``CZMPC_LOCK_DIR``).
LOCK_DIR_ENV = "CZMPC_LOCK_DIR"


class PlantBusyError(CzmpcError):
    """Another controller already drives this plant (exit 2)."""


def identity(log_path: Path | None = None) -> str:
    """This controller's identity as written to a lease node: host, pid, start time, log."""
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    where = "" if log_path is None else f" log {log_path}"
    return f"czmpc@{socket.gethostname()} pid {os.getpid()} since {started}{where}"


def lock_dir() -> Path:
    """The directory of the plant locks: ``$CZMPC_LOCK_DIR`` or ``<tmp>/czmpc-locks``."""
    return Path(os.environ.get(LOCK_DIR_ENV) or Path(tempfile.gettempdir()) / "czmpc-locks")


class PlantLock:
    """Exclusive lock of one plant's command node on this machine (module docstring).

    Parameters
    ----------
    endpoint, command_node :
        What the lock guards (their hash names the lock file).
    holder :
        Written into the lock file for the next one to read (`identity`).
    """

    def __init__(self, endpoint: str, command_node: str, holder: str) -> None:
        key = hashlib.sha256(f"{endpoint}\n{command_node}".encode()).hexdigest()[:20]
        self.path = lock_dir() / f"plant-{key}.lock"
        self.endpoint, self.command_node, self.holder = endpoint, command_node, holder
        self._fh: IO[str] | None = None

    def acquire(self) -> None:
        """Take the lock or raise `PlantBusyError` naming its holder; never waits."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(self.path, "a+", encoding="utf-8")  # noqa: SIM115 - held for the run
        if not _try_lock(fh):
            fh.seek(0)
            held_by = fh.read().strip() or "another process"
            fh.close()
            raise PlantBusyError(
                f"another controller already drives {self.command_node} at {self.endpoint} from "
                f"this machine ({_holder_words(held_by)}); stop it first, or point "
                f"[nodes] triac_pct at another plant (lock {self.path})")
        fh.seek(0)
        fh.truncate()
        fh.write(json.dumps({"holder": self.holder, "endpoint": self.endpoint,
                             "command_node": self.command_node}) + "\n")
        fh.flush()
        self._fh = fh

    def release(self) -> None:
        """Give the lock back (the OS does it too when the process ends)."""
        fh, self._fh = self._fh, None
        if fh is not None:
            fh.close()

    def __enter__(self) -> PlantLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _holder_words(text: str) -> str:
    try:
        return str(json.loads(text.splitlines()[0])["holder"])
    except (ValueError, KeyError, IndexError, TypeError):
        return text[:200]


def _try_lock(fh: IO[str]) -> bool:
    """An exclusive, non-blocking lock on an open file (POSIX flock, Windows locking)."""
    try:
        if sys.platform == "win32":  # pragma: no cover - Windows
            import msvcrt

            fh.seek(0)
            msvcrt.locking(fh.fileno(), msvcrt.LK_NBLCK, 1)
        else:
            import fcntl

            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def same_value(written: Any, read: Any, type_name: str) -> bool:
    """True when ``read`` is what a node of ``type_name`` holds after czmpc wrote ``written``."""
    if type_name == "Float" and isinstance(written, float) and isinstance(read, int | float):
        return float(np.float32(written)) == float(np.float32(read))
    return bool(written == read)


class WriterWatch:
    """What czmpc wrote last to each watched node, and whether a read-back says otherwise."""

    def __init__(self) -> None:
        self._written: dict[str, tuple[Any, str]] = {}

    def wrote(self, key: str, value: Any, type_name: str) -> None:
        """czmpc's write of ``value`` (as sent: the raw value of the node's type) was accepted."""
        self._written[key] = (value, type_name)

    def forget(self, key: str) -> None:
        """czmpc no longer writes ``key`` (e.g. the command outside mode ON): do not watch it."""
        self._written.pop(key, None)

    def reset(self) -> None:
        """A new session: nothing written in it yet."""
        self._written.clear()

    def other_writer(self, read_back: dict[str, Any]) -> str | None:
        """Why the read-back values show another writer, or None (key -> value read)."""
        for key, value in read_back.items():
            if key not in self._written:
                continue
            written, type_name = self._written[key]
            if not same_value(written, value, type_name):
                return (f"[nodes] {key} holds {value!r} where czmpc wrote {written!r}: another "
                        "writer drives the plant")
        return None


def moved(first: dict[str, Any], second: dict[str, Any]) -> str | None:
    """Why two read-backs one period apart, with no write by czmpc between, show a driven
    plant, or None."""
    for key, value in first.items():
        if key in second and value != second[key]:
            return (f"[nodes] {key} changed from {value!r} to {second[key]!r} within one period "
                    "before czmpc wrote anything: the plant is already driven by another "
                    "controller; stop it first")
    return None


__all__ = ["LOCK_DIR_ENV", "PlantBusyError", "PlantLock", "WriterWatch", "identity", "lock_dir",
           "moved", "same_value"]
