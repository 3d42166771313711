"""Progress on stderr for every command: one style, elapsed seconds first.

Library functions take plain callbacks (``progress(message)`` or
``progress(done, total)``); the commands pass one `Progress`, which prints

    [   12.3 s] message                          (`Progress.__call__`)
    [   12.3 s] [2/4] title                      (`Progress.stage`)
    [   12.3 s] simulating: 40 % (1560/3900), ETA 8 s   (`Progress.fraction`)

Lines go to stderr so that stdout keeps only results. On a terminal the fraction line
rewrites itself in place; in a log file it is printed every 10 % only. The one result
line every writing command ends with, ``wrote FILE, FILE``, is `print_written`'s (stdout).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import TextIO


class Progress:
    """Progress printer of one command run (elapsed time since construction).

    Parameters
    ----------
    n_stages :
        Number of numbered stages `stage` will announce, or None when the command
        has none.
    stream :
        Where to print (stderr unless a test passes another stream).
    quiet_for_s :
        `fraction` prints nothing until the command has run this long [s], so that
        short runs stay silent.
    """

    def __init__(self, *, n_stages: int | None = None, stream: TextIO | None = None,
                 quiet_for_s: float = 0.0) -> None:
        self._quiet_for_s = quiet_for_s
        self._t0 = time.perf_counter()
        self._n_stages = n_stages
        self._stage = 0
        self._stream = stream if stream is not None else sys.stderr
        self._tty = self._stream.isatty()
        self._last_decile = -1
        self._open_line = False

    @property
    def elapsed_s(self) -> float:
        """Seconds since the command started [s]."""
        return time.perf_counter() - self._t0

    def _print(self, text: str, *, end: str = "\n") -> None:
        if self._open_line and end == "\n":
            self._stream.write("\n")
            self._open_line = False
        self._stream.write(f"[{self.elapsed_s:7.1f} s] {text}{end}")
        self._stream.flush()

    def __call__(self, message: str, *_: object) -> None:
        """Print one progress message (extra arguments of richer callbacks are ignored)."""
        self._print(message)

    def stage(self, title: str) -> None:
        """Announce the next numbered stage, ``[i/n] title``."""
        self._stage += 1
        count = f"{self._stage}/{self._n_stages}" if self._n_stages else str(self._stage)
        self._print(f"[{count}] {title}")

    def fraction(self, done: int, total: int, *, what: str = "running") -> None:
        """Report ``done`` of ``total`` units with an estimate of the time left.

        On a terminal the line is rewritten in place at every call; otherwise it is
        printed when a new tenth of the work is reached.
        """
        if total <= 0 or self.elapsed_s < self._quiet_for_s:
            return
        share = min(max(done / total, 0.0), 1.0)
        decile = int(share * 10)
        if not self._tty and decile == self._last_decile:
            return
        self._last_decile = decile
        eta = ""
        if 0 < done < total:
            eta = f", ETA {self.elapsed_s * (total - done) / done:.0f} s"
        text = f"{what}: {share:4.0%} ({done}/{total}){eta}"
        if self._tty:
            self._stream.write(f"\r[{self.elapsed_s:7.1f} s] {text}")
            self._stream.flush()
            self._open_line = done < total
            if done >= total:
                self._stream.write("\n")
        else:
            self._print(text)


def print_written(files: Iterable[Path | str]) -> None:
    """Print ``wrote FILE, FILE, ...`` on stdout: the files a command wrote, in order."""
    print(f"wrote {', '.join(str(f) for f in files)}")


__all__ = ["Progress", "print_written"]
