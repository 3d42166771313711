"""A served plant in a process of its own, on a free loopback port.

`serving` starts ``czmpc plant serve`` (`czmpc.runtime.served`) as a subprocess on
127.0.0.1, waits until it listens, yields its endpoint and stops it when the block
ends. The plant runs on its own clock in its own interpreter, as a real plant does, so a
controller in this process meets the same timing as against a PLC. Used by the
commissioning study through the plant link and the loopback tests (not installed).
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from czmpc.errors import CzmpcError

#: Longest wait for the served plant to listen [s of wall time] (an interpreter and
#: asyncua start in a few seconds; a loaded machine takes longer).
START_TIMEOUT_S = 60.0
#: Wait for the plant to stop on SIGINT before it is killed [s of wall time].
STOP_TIMEOUT_S = 10.0


class ServeProcessError(CzmpcError, RuntimeError):
    """The served plant did not start; the message names its output file."""


def free_loopback_port() -> int:
    """A TCP port free on 127.0.0.1 at the time of the call."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def serving(*args: str, output: Path, time_scale: float = 1.0,
            duration_s: float | None = None) -> Iterator[str]:
    """Run ``czmpc plant serve ARGS`` on a free loopback port; yield its endpoint.

    Parameters
    ----------
    *args :
        Further options of ``czmpc plant serve`` (``--plant``, ``--seed``, ``--log`` ...);
        not ``--endpoint``, ``--time-scale`` or ``--duration-s``, which are set here.
    output :
        File that receives the server's stdout and stderr (its start line, watchdog
        events, its stop).
    time_scale :
        Plant samples per Ts of wall time.
    duration_s :
        The server stops by itself after this plant time [s]; None: when the block ends.

    Raises
    ------
    ServeProcessError
        The server exited, or did not listen within `START_TIMEOUT_S`.
    """
    for flag in ("--endpoint", "--time-scale", "--duration-s"):
        if flag in args:
            raise ValueError(f"serving() sets {flag} itself; got it in args {args!r}")
    port = free_loopback_port()
    endpoint = f"opc.tcp://127.0.0.1:{port}/czmpc/"
    timing = ["--time-scale", f"{time_scale:g}"]
    if duration_s is not None:
        timing += ["--duration-s", f"{duration_s:g}"]
    output.parent.mkdir(parents=True, exist_ok=True)
    with open(output, "w", encoding="utf-8") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "czmpc.cli", "plant", "serve", "--endpoint", endpoint,
             *timing, *args],
            stdout=out, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            give_up = time.monotonic() + START_TIMEOUT_S
            while True:
                with socket.socket() as s:
                    if s.connect_ex(("127.0.0.1", port)) == 0:
                        break
                if proc.poll() is not None or time.monotonic() > give_up:
                    raise ServeProcessError(
                        f"czmpc plant serve did not start on {endpoint} (exit code "
                        f"{proc.poll()}); see {output}")
                time.sleep(0.2)
            yield endpoint
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(STOP_TIMEOUT_S)
