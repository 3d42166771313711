"""`czmpc tune-pid` and `czmpc simulate --controller`: files, columns, exit codes, no tracebacks."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from czmpc.cli import main
from czmpc.pid.table import COLUMNS
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

MODEL = str(shipped_path(HAMMERSTEIN_MODEL_JSON))


@pytest.fixture(scope="module")
def tuned(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("tuned")
    assert main(["tune-pid", MODEL, "--ms", "1.4", "--out", str(out), "--form", "deltav",
                 "--form", "rockwell", "--pv-range-kw", "0", "100", "--out-range-pct", "0",
                 "100"]) == 0
    return out


def test_tune_pid_writes_the_table_vendor_forms_and_report(tuned: Path) -> None:
    names = {p.name for p in tuned.iterdir()}
    assert {"pid_table.csv", "characterizer.csv", "vendor_deltav.csv", "vendor_rockwell.csv",
            "report.md", "schedule.png", "margins.png", "responses.png"} <= names
    with open(tuned / "pid_table.csv", newline="") as fh:  # after its header comments
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    assert tuple(rows[0]) == COLUMNS and len(rows) >= 3
    assert all(float(r["ms"]) <= 1.4 and float(r["worst_ms_to_next"]) <= 1.4 for r in rows)
    report = (tuned / "report.md").read_text()
    assert "Breakpoints added" in report and "![margins](margins.png)" in report
    assert "RESET in seconds per repeat" in report


def test_a_vendor_form_without_spans_exits_2_without_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["tune-pid", MODEL, "--out", str(tmp_path / "o"), "--form", "honeywell"]) == 2
    err = capsys.readouterr().err
    assert "czmpc: error: tune-pid: --form honeywell needs the spans" in err
    assert "--pv-range-kw LO HI" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv, message", [
    (["--rule", "amigo", "--ms", "1.4"], "AMIGO has no knob"),
    (["--breakpoints-pct", "10", "50"], "inside the range [28, 70] %; got [10.0, 50.0]"),
    (["--pv-range-kw", "0", "100"], "give both --pv-range-kw LO HI and --out-range-pct LO HI"),
])
def test_bad_options_exit_2_with_the_reason(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                            argv: list[str], message: str) -> None:
    assert main(["tune-pid", MODEL, "--out", str(tmp_path), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_simulate_compares_the_table_with_the_mpc_and_a_fixed_pi(
    tuned: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["simulate", "--model", MODEL, "--scenario", "staircase", "--short", "0.05",
                 "--controller", str(tuned / "pid_table.csv"), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "pi_table" in out and "pi_fixed" in out and "IAE / MPC [-]" in out
    with open(tmp_path / "comparison.csv", newline="") as fh:
        rows = {r["controller"]: r for r in csv.DictReader(fh)}
    assert set(rows) == {"pi_table", "mpc", "pi_fixed"}
    assert float(rows["mpc"]["iae_ratio_to_mpc"]) == 1.0
    for name in rows:
        assert (tmp_path / name / "trajectory.csv").is_file()


def test_simulate_refuses_a_file_that_is_not_a_pid_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    bad = tmp_path / "t.csv"
    bad.write_text("a,b\n1,2\n")
    assert main(["simulate", "--model", MODEL, "--scenario", "staircase", "--controller",
                 str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "t.csv, line 1: expected the pid_table.csv header" in err and "Traceback" not in err
