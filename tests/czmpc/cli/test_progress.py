"""czmpc.cli._progress: the one progress style of every command."""

from __future__ import annotations

import io
import re

from czmpc.cli._progress import Progress


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_messages_and_stages_carry_elapsed_seconds() -> None:
    out = io.StringIO()
    progress = Progress(n_stages=3, stream=out)
    progress("reading heater.csv")
    progress.stage("identification")
    lines = out.getvalue().splitlines()
    assert re.fullmatch(r"\[\s*\d+\.\d s\] reading heater\.csv", lines[0])
    assert re.fullmatch(r"\[\s*\d+\.\d s\] \[1/3\] identification", lines[1])


def test_fraction_prints_each_tenth_once_in_a_log() -> None:
    out = io.StringIO()
    progress = Progress(stream=out)
    for done in range(0, 101):
        progress.fraction(done, 100, what="simulating")
    lines = out.getvalue().splitlines()
    assert len(lines) == 11                                   # 0 %, 10 %, ..., 100 %
    assert "simulating:  50% (50/100), ETA" in lines[5]
    assert lines[-1].endswith("simulating: 100% (100/100)")   # no ETA once done


def test_fraction_rewrites_one_line_on_a_terminal_and_stays_quiet_when_short() -> None:
    tty = _Tty()
    progress = Progress(stream=tty)
    progress.fraction(1, 4)
    progress.fraction(4, 4)
    assert tty.getvalue().count("\r") == 2 and tty.getvalue().endswith("\n")
    quiet = io.StringIO()
    Progress(stream=quiet, quiet_for_s=3600.0).fraction(1, 2)
    assert quiet.getvalue() == ""
