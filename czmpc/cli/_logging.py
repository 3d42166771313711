"""Where the library's log records go when czmpc runs as a command: stderr, one line each.

The library only logs (loggers ``czmpc.*``, with a NullHandler on ``czmpc``); the
command decides where records go. `log_to_stderr` sends the ``czmpc`` and ``asyncua``
records to stderr, one line each with its UTC time and level, whether or not stderr is
a terminal (a service manager or a container collects it), so that a link lost, a
refused write or an abort is never only a status line that the next step overwrites.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import TextIO

#: The line of one record: ``2026-11-26T07:12:03.481Z WARNING czmpc.runtime.loop: ...``.
LINE_FORMAT = "%(asctime)s.%(msecs)03dZ %(levelname)s %(name)s: %(message)s"


class _StderrHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """Writes to the current ``sys.stderr``; on a terminal it first clears the status line.

    The stream is looked up at each record, not kept: a caller that swaps ``sys.stderr``
    (pytest's capture, a service wrapper) gets the records where it now points.
    """

    @property
    def stream(self) -> TextIO:
        return sys.stderr

    @stream.setter
    def stream(self, _value: object) -> None:
        pass

    def emit(self, record: logging.LogRecord) -> None:
        if self.stream.isatty():
            self.stream.write("\r\033[K")
        super().emit(record)


def log_to_stderr(level: int = logging.INFO) -> None:
    """Send czmpc's records at ``level`` and up, and asyncua's warnings, to stderr (once)."""
    handler = _StderrHandler()
    formatter = logging.Formatter(LINE_FORMAT, datefmt="%Y-%m-%dT%H:%M:%S")
    formatter.converter = time.gmtime
    handler.setFormatter(formatter)
    for name, name_level in (("czmpc", level), ("asyncua", max(level, logging.WARNING))):
        logger = logging.getLogger(name)
        if not any(isinstance(h, _StderrHandler) for h in logger.handlers):
            logger.addHandler(handler)
        logger.setLevel(name_level)
        logger.propagate = False
