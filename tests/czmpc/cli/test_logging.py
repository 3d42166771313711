"""The command's log lines: text and JSON on stderr, syslog over UDP on 127.0.0.1."""

from __future__ import annotations

import datetime as dt
import json
import logging
import re
import socket
from collections.abc import Iterator

import pytest

from czmpc.cli._logging import configure_logging, log_to_syslog


@pytest.fixture
def restore_loggers() -> Iterator[None]:
    saved = {name: (logging.getLogger(name).handlers[:], logging.getLogger(name).level,
                    logging.getLogger(name).propagate) for name in ("czmpc", "asyncua")}
    yield
    for name, (handlers, level, propagate) in saved.items():
        logger = logging.getLogger(name)
        logger.handlers[:] = handlers
        logger.setLevel(level)
        logger.propagate = propagate


def test_text_lines_carry_utc_time_level_and_logger(capsys: pytest.CaptureFixture[str],
                                                    restore_loggers: None) -> None:
    configure_logging("INFO", "text")
    logging.getLogger("czmpc.runtime.loop").warning("link lost (%s)", "test")
    logging.getLogger("czmpc.runtime.loop").debug("not shown at INFO")
    logging.getLogger("asyncua.client").info("not shown: asyncua from WARNING on")
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1
    match = re.fullmatch(r"(\S+Z) WARNING czmpc\.runtime\.loop: link lost \(test\)", lines[0])
    assert match is not None
    stamp = dt.datetime.fromisoformat(match.group(1))
    assert abs((dt.datetime.now(dt.UTC) - stamp).total_seconds()) < 60.0


def test_json_lines_parse_and_configuring_twice_adds_no_second_handler(
        capsys: pytest.CaptureFixture[str], restore_loggers: None) -> None:
    configure_logging("DEBUG", "json")
    configure_logging("DEBUG", "json")
    logging.getLogger("czmpc.runtime.loop").info('quotes " and ümlauts')
    logging.getLogger("asyncua.client").warning("from asyncua")
    records = [json.loads(line) for line in capsys.readouterr().err.splitlines()]
    assert [r["message"] for r in records] == ['quotes " and ümlauts', "from asyncua"]
    assert [r["logger"] for r in records] == ["czmpc.runtime.loop", "asyncua.client"]
    assert all(r["time"].endswith("Z") and r["level"] in ("INFO", "WARNING") for r in records)


def test_syslog_receives_the_same_records(restore_loggers: None) -> None:
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(5.0)
    try:
        handler = log_to_syslog(f"127.0.0.1:{receiver.getsockname()[1]}", "local3")
        logging.getLogger("czmpc").setLevel(logging.INFO)
        logging.getLogger("czmpc.runtime.loop").error("ABORT: test")
        datagram = receiver.recv(4096).decode()
    finally:
        receiver.close()
        logging.getLogger("czmpc").removeHandler(handler)
        handler.close()
    # <PRI> = facility local3 (19) * 8 + severity error (3)
    assert datagram.startswith(f"<{19 * 8 + 3}>czmpc[")
    assert datagram.rstrip("\x00").endswith("ERROR czmpc.runtime.loop: ABORT: test")
