"""benchmarks._md: the command line recorded with the numbers, bad input, the section writer."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from benchmarks._md import BENCHMARKS_MD, run_main, write_benchmarks_section
from sysid.errors import SysidError


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.demo")
    parser.add_argument("--data", type=Path)
    return parser


def test_the_recorded_command_reruns_the_benchmark_with_its_arguments_quoted() -> None:
    seen: list[str] = []

    def run(args: argparse.Namespace) -> int:
        seen.append(args.command_line)
        return 0

    assert run_main(_parser(), run, ["--data", "my log.csv"]) == 0
    assert seen == ["python -m benchmarks.demo --data 'my log.csv'"]


def test_bad_input_is_one_line_with_the_program_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    def run(args: argparse.Namespace) -> int:
        raise SysidError("log.csv, line 3: expected a number; got 'x'")

    assert run_main(_parser(), run, []) == 2
    assert capsys.readouterr().err == (
        "python -m benchmarks.demo: error: log.csv, line 3: expected a number; got 'x'\n")


def test_a_run_failure_is_the_benchmarks_own_exit_code() -> None:
    assert run_main(_parser(), lambda args: 1, []) == 1


def test_the_default_file_is_this_repositorys_benchmarks_md() -> None:
    assert BENCHMARKS_MD == Path(__file__).resolve().parents[2] / "BENCHMARKS.md"
    assert BENCHMARKS_MD.is_file()


def test_a_missing_section_is_appended_and_a_present_one_replaced(tmp_path: Path) -> None:
    md = tmp_path / "B.md"
    write_benchmarks_section(md, "one", heading="## A")
    write_benchmarks_section(md, "two", heading="## B")
    write_benchmarks_section(md, "three", heading="## A")
    assert md.read_text(encoding="utf-8") == "# Benchmarks\n\n## A\n\nthree\n\n## B\n\ntwo\n"


@pytest.mark.parametrize("name", ["identify", "mpc_step", "health", "commission_length"])
def test_every_benchmark_says_how_to_run_it(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    import importlib

    module = importlib.import_module(f"benchmarks.{name}")
    with pytest.raises(SystemExit) as exc:
        module.main(["--help"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: python -m benchmarks.{name} ")
