"""The README is a map: short, opening with the two commands, with a library example that
runs, a row for every room of the file tree and the commands of the console script."""

from __future__ import annotations

import argparse
import math
import os
import re
from pathlib import Path

import pytest

from czmpc.cli import build_parser

REPO = Path(__file__).resolve().parents[2]
README = REPO / "README.md"
#: What a map may take; longer knowledge belongs in a guide or reference page of docs/.
MAX_LINES = 200
#: The packages and the project's own benchmarks: each of them and each folder of Python
#: modules inside them is a room.
TOP_ROOMS = ("sysid", "sim", "czmpc", "benchmarks")


@pytest.fixture(scope="module")
def text() -> str:
    return README.read_text(encoding="utf-8")


def _section(text: str, heading: str) -> str:
    match = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    assert match, f"README has no '## {heading}' section"
    return match.group(1)


def _table_rows(section: str) -> list[list[str]]:
    rows = [[cell.strip() for cell in line.strip().strip("|").split("|")]
            for line in section.splitlines() if line.startswith("|")]
    return [row for row in rows[2:]]          # without the header and the |---| line


def rooms_in_tree() -> list[str]:
    """Every package folder of the project, as ``name/``: the top rooms and each folder
    below them that holds a Python module (namespace packages count)."""
    rooms: list[str] = []
    for top in TOP_ROOMS:
        if not (REPO / top).is_dir():
            continue
        rooms.append(f"{top}/")
        for folder in sorted(p for p in (REPO / top).rglob("*") if p.is_dir()):
            if "__pycache__" in folder.parts or folder.name.startswith((".", "_")):
                continue
            if any(folder.glob("*.py")):
                rooms.append(f"{folder.relative_to(REPO).as_posix()}/")
    return rooms


def test_the_readme_is_at_most_a_map_long(text: str) -> None:
    n_lines = len(text.splitlines())
    assert n_lines <= MAX_LINES, f"README.md has {n_lines} lines; a map has at most {MAX_LINES}"


def test_the_readme_opens_with_the_two_commands(text: str) -> None:
    lines = text.splitlines()
    assert lines[0].startswith("# czmpc")
    first_block = re.search(r"```sh\n(.*?)```", text, re.S)
    assert first_block and text.index("```sh") < text.index("\n## ")
    commands = [line.split("#")[0].strip() for line in first_block.group(1).splitlines()]
    assert commands == ["make demo", "make test"]


def test_the_tree_has_the_rooms_the_layout_names() -> None:
    # the walk itself: it must see the namespace packages and the benchmarks
    rooms = rooms_in_tree()
    for room in ("sysid/", "sim/", "czmpc/", "czmpc/cli/", "czmpc/campaigns/", "czmpc/reports/",
                 "czmpc/runtime/", "czmpc/commissioning/", "czmpc/testing/", "czmpc/peers/",
                 "czmpc/pid/"):
        assert room in rooms
    assert not any("__pycache__" in room for room in rooms)


def test_every_room_of_the_tree_has_a_row(text: str) -> None:
    rows = _table_rows(_section(text, "Rooms"))
    listed = {m.group(1) for row in rows if (m := re.match(r"`([\w/]+/)`", row[0]))}
    missing = [room for room in rooms_in_tree() if room not in listed]
    assert missing == [], f"rooms without a row in the README's room table: {missing}"
    stale = sorted(room for room in listed
                   if room.split("/")[0] in TOP_ROOMS and not (REPO / room).is_dir())
    assert stale == [], f"rows for rooms that are not in the tree: {stale}"
    assert all(len(row) == 2 and row[1] for row in rows), "every room needs its job"


def _sub_commands(parser: argparse.ArgumentParser, prefix: str) -> set[str]:
    """``PREFIX NAME`` for each sub-command of ``parser``."""
    names: set[str] = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            names |= {f"{prefix} {name}" for name in action.choices}
    return names


def _parser_commands() -> set[str]:
    """``czmpc NAME`` for each command of the console script."""
    return _sub_commands(build_parser(), "czmpc")


def test_the_command_table_lists_exactly_the_console_script_commands(text: str) -> None:
    rows = _table_rows(_section(text, "Commands"))
    named: set[str] = set()
    for row in rows:
        for code in re.findall(r"`(czmpc [a-z][a-z-]*(?: [a-z][a-z-]*)?)", row[1]):
            named.add(code)
    # 'czmpc plant serve' names the command 'czmpc plant'
    listed = {" ".join(name.split()[:2]) for name in named}
    assert listed == _parser_commands(), (
        f"README only: {sorted(listed - _parser_commands())}; "
        f"parser only: {sorted(_parser_commands() - listed)}")
    # a sub-command the table names ('czmpc plant serve') is one of that command's
    subparsers = {f"czmpc {name}": sub for action in build_parser()._actions
                  if isinstance(action, argparse._SubParsersAction)
                  for name, sub in action.choices.items()}
    for name in (n for n in named if len(n.split()) == 3):
        parent = " ".join(name.split()[:2])
        assert name in _sub_commands(subparsers[parent], parent), f"{name} is not a sub-command"


def test_the_command_table_groups_the_commands_as_the_help_does(text: str) -> None:
    from czmpc.cli import COMMAND_GROUPS

    # the task column names a group of `czmpc --help` by its first words ('identify' for
    # 'identify: from a logged data set to a checked model')
    expected = [(title.split(":")[0], f"czmpc {name}")
                for title, names in COMMAND_GROUPS.items() for name in names]
    rows = _table_rows(_section(text, "Commands"))
    listed = [(row[0], " ".join(code.split()[:2]))
              for row in rows for code in re.findall(r"`(czmpc [a-z][a-z-]*)", row[1])[:1]]
    assert listed == expected


def test_the_library_example_runs(text: str, monkeypatch: pytest.MonkeyPatch) -> None:
    block = re.search(r"^## The library in six lines\n.*?```python\n(.*?)```", text, re.S | re.M)
    assert block, "README has no library example"
    code = block.group(1)
    assert len(code.strip().splitlines()) == 6
    monkeypatch.chdir(REPO)                      # it reads data/cz_heater_experiment.csv
    monkeypatch.setenv("MPLBACKEND", os.environ.get("MPLBACKEND", "Agg"))
    namespace: dict[str, object] = {}
    exec(compile(code, "README.md", "exec"), namespace)
    triac_pct = namespace["triac_pct"]
    assert isinstance(triac_pct, float) and math.isfinite(triac_pct) and 45.0 < triac_pct <= 50.0
    import sim

    run = namespace["run"]
    assert isinstance(run, sim.ClosedLoopResult)
    assert sim.compute_metrics(run).max_abs_steady_state_error_kw < 0.05


def test_every_path_the_readme_names_exists(text: str) -> None:
    paths = set(re.findall(r"`((?:docs|tests|tools|examples|data)/[\w./-]+)`", text))
    paths |= set(re.findall(r"\]\(([\w.]+)\)", text))
    # what `make docs` builds is named, not shipped: a clean clone has no docs/_build yet
    missing = sorted(p for p in paths
                     if not p.startswith("docs/_build/") and not (REPO / p).exists())
    assert missing == [], f"the README names files that do not exist: {missing}"
