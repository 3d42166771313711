"""`czmpc` itself: the commands grouped by task in ``--help``, ``--debug`` on either side."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from czmpc.cli import COMMAND_GROUPS, UNGROUPED, _command_modules, command_groups, main

#: The bound on the commands a user meets: issue 30's 17, plus `czmpc codegen`, which
#: issue 42 names as a command of its own (a task of its own: the step for a PLC).
MAX_COMMANDS = 18
#: Commands that left the CLI for benchmarks/ or another command (CHANGELOG.md).
REMOVED = ("bench", "bench-identify", "bench-mpc", "bench-health", "bench-commission",
           "robustness", "history")


def _help(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    return capsys.readouterr().out


def test_every_command_is_in_exactly_one_group_and_there_are_at_most_18() -> None:
    registered = sorted(_command_modules())
    grouped = [c for names in COMMAND_GROUPS.values() for c in names]
    assert sorted(grouped) == registered            # a new command needs a group
    assert len(set(grouped)) == len(grouped)        # ... and only one
    assert len(registered) <= MAX_COMMANDS
    assert UNGROUPED not in command_groups(registered)


def test_a_command_no_group_names_is_listed_apart() -> None:
    groups = command_groups(["identify", "frobnicate", "demo"])
    assert list(groups) == ["start here", *(t for t in COMMAND_GROUPS if t.startswith("identify")),
                            UNGROUPED]
    assert groups[UNGROUPED] == ("frobnicate",)


def test_help_lists_each_command_once_under_its_group(capsys: pytest.CaptureFixture[str]) -> None:
    text = _help(capsys)
    listing = text[text.index("commands, by task:"):]
    names = re.findall(r"^    (\S+)\s", listing, flags=re.MULTILINE)
    assert names == [c for group in COMMAND_GROUPS.values() for c in group]
    headings = re.findall(r"^  (\S.*)$", listing, flags=re.MULTILINE)
    assert headings == list(COMMAND_GROUPS)
    assert "{" not in text          # no flat choice list in the usage or under COMMAND
    for title in ("start here", "identify:", "control:", "plant:"):
        assert f"\n  {title}" in listing


def test_a_commands_own_help_is_its_module_docstring(capsys: pytest.CaptureFixture[str]) -> None:
    text = _help(capsys, "plant", "history")
    assert text.startswith("usage: czmpc plant history [-h] --from T0 --to T1 --out LOG.csv")
    assert "HistoryRead" in text and "--debug" in text


@pytest.mark.parametrize("command", REMOVED)
def test_removed_commands_are_refused_with_exit_2(command: str,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main([command])
    assert exc.value.code == 2
    assert f"invalid choice: '{command}'" in capsys.readouterr().err


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_shows_the_traceback_before_or_after_the_command(
        tmp_path: Path, where: str) -> None:
    argv = ["identify", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "out")]
    with pytest.raises(FileNotFoundError, match="missing.csv"):
        main(["--debug", *argv] if where == "before" else [*argv, "--debug"])


def test_without_debug_the_error_is_one_line_and_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["identify", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "czmpc: error:" in err and "missing.csv" in err and "Traceback" not in err


def test_debug_after_an_action_of_a_command_shows_the_traceback(tmp_path: Path) -> None:
    from czmpc.runtime.config import RunConfigError

    argv = ["plant", "history", str(tmp_path / "missing.toml"), "--from", "2026-11-26T06:00:00Z",
            "--to", "2026-11-26T07:00:00Z", "--out", str(tmp_path / "log.csv")]
    assert main(argv) == 2
    with pytest.raises(RunConfigError, match="missing.toml"):
        main([*argv, "--debug"])
