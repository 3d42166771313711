"""Where the library's log records go when czmpc runs as a command: stderr, one line each.

The library only logs (loggers ``czmpc.*``, with a NullHandler on ``czmpc``); the
command decides where records go. `configure_logging` sends the ``czmpc`` and
``asyncua`` records to stderr, one line each with its UTC time and level, whether or
not stderr is a terminal (a service manager or a container collects it), so that a
link lost, a refused write or an abort is never only a status line that the next step
overwrites. ``--log-format json`` writes one JSON object per line instead (journald,
ELK, Loki); a run config's ``[logging] syslog`` sends the same records to syslog.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import logging
import logging.handlers
import socket
import sys
import time
from typing import TextIO

#: The line of one record: ``2026-11-26T07:12:03.481Z WARNING czmpc.runtime.loop: ...``.
LINE_FORMAT = "%(asctime)s.%(msecs)03dZ %(levelname)s %(name)s: %(message)s"
#: The levels ``--log-level`` accepts.
LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")


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


class JsonLineFormatter(logging.Formatter):
    """One JSON object per record: ``time`` (UTC, ISO 8601), ``level``, ``logger``, ``message``."""

    def format(self, record: logging.LogRecord) -> str:
        doc = {
            "time": dt.datetime.fromtimestamp(record.created, dt.UTC).isoformat(
                timespec="milliseconds").replace("+00:00", "Z"),
            "level": record.levelname, "logger": record.name, "message": record.getMessage(),
        }
        if record.exc_info:
            doc["exception"] = self.formatException(record.exc_info)
        return json.dumps(doc, ensure_ascii=False)


def _text_formatter() -> logging.Formatter:
    formatter = logging.Formatter(LINE_FORMAT, datefmt="%Y-%m-%dT%H:%M:%S")
    formatter.converter = time.gmtime
    return formatter


def add_logging_options(parser: argparse.ArgumentParser) -> None:
    """``--log-level`` and ``--log-format`` of a command that runs for long."""
    parser.add_argument("--log-level", choices=LEVELS, default="INFO",
                        help="least severe records written to stderr (default: INFO: start, "
                             "link lost and restored, shed and resumed, mode changes, refused "
                             "writes, aborts, alarms, the end)")
    parser.add_argument("--log-format", choices=("text", "json"), default="text",
                        help="stderr lines: 'text' (UTC time, level, logger, message) or "
                             "'json' (one JSON object per line, for journald, ELK, Loki)")


def configure_logging(level: str = "INFO", fmt: str = "text") -> None:
    """Send czmpc's records at ``level`` and up, and asyncua's warnings, to stderr (once)."""
    handler = _StderrHandler()
    handler.setFormatter(JsonLineFormatter() if fmt == "json" else _text_formatter())
    numeric = getattr(logging, level)
    for name, name_level in (("czmpc", numeric), ("asyncua", max(numeric, logging.WARNING))):
        logger = logging.getLogger(name)
        for old in [h for h in logger.handlers if isinstance(h, _StderrHandler)]:
            logger.removeHandler(old)
        logger.addHandler(handler)
        logger.setLevel(name_level)
        # records still propagate: the command's root logger has no handler, and a host
        # that has one (pytest's log capture, an embedding program) sees them too


def log_to_syslog(address: str, facility: str = "daemon") -> logging.Handler:
    """Also send czmpc's records to syslog at ``address``: a socket path or ``HOST:PORT`` (UDP).

    Returns the handler (the caller may remove it).
    """
    target: str | tuple[str, int]
    if address.startswith("/"):
        target = address
    else:
        host, _, port = address.rpartition(":")
        target = (host, int(port))
    handler = logging.handlers.SysLogHandler(
        address=target, facility=logging.handlers.SysLogHandler.facility_names[facility],
        socktype=socket.SOCK_DGRAM)
    handler.setFormatter(logging.Formatter("czmpc[%(process)d]: %(levelname)s %(name)s: "
                                           "%(message)s"))
    logging.getLogger("czmpc").addHandler(handler)
    return handler
