"""``czmpc inspect`` and ``czmpc experiment``: what they print and write, and exit codes."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from czmpc.cli import main
from sysid.data import read_csv
from sysid.steps import detect_steps
from tests.conftest import SHIPPED_EXPERIMENT


def test_inspect_summarizes_the_shipped_experiment(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["inspect", str(SHIPPED_EXPERIMENT)]) == 0
    out = capsys.readouterr().out
    data = read_csv(SHIPPED_EXPERIMENT)
    assert "samples:        12000\n" in out
    assert "duration:       23998 s (0 s to 23998 s)" in out
    assert "sampling time:  2 s" in out
    assert f"input range:    {data.triac_pct.min():g} to {data.triac_pct.max():g} %" in out
    assert f"output range:   {data.power_kw.min():g} to {data.power_kw.max():g} kW" in out
    assert f"sha256:         {data.sha256}" in out
    steps = detect_steps(data)
    assert f"input steps:    {len(steps)} larger than" in out
    table = out[out.index("r [kW/%]"):].splitlines()[1:]
    assert len(table) == len(steps)
    for line, step in zip(table, steps, strict=True):
        fields = line.split()
        assert int(fields[0]) == step.k
        assert float(fields[-1]) == pytest.approx(step.gain_kw_per_pct, abs=5e-5)  # 4 decimals


def test_inspect_options_change_the_step_threshold_and_delay(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    path = tmp_path / "small.csv"
    path.write_text("time_s,triac_pct,power_kw\n0,40,40\n2,40,40\n4,40.5,40\n6,40.5,40.6\n"
                    "8,60,40.6\n10,60,66\n12,60,65\n", encoding="utf-8")
    assert main(["inspect", str(path)]) == 0
    assert "input steps:    1 larger than 1 %" in capsys.readouterr().out
    assert main(["inspect", str(path), "--min-step", "0.1", "--delay-steps", "1"]) == 0
    out = capsys.readouterr().out
    assert "input steps:    2 larger than 0.1 %" in out
    assert re.search(r"\b1\.2000\n", out) and re.search(r"\b1\.3026\n", out)


def test_inspect_without_steps_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "flat.csv"
    path.write_text("time_s,triac_pct,power_kw\n0,45,45\n2,45,45.01\n4,45,44.99\n",
                    encoding="utf-8")
    assert main(["inspect", str(path)]) == 0
    assert capsys.readouterr().out.endswith("no input steps found\n")


@pytest.mark.parametrize(
    "option", [["--ts-s", "0"], ["--ts-s", "nan"], ["--sampling-rtol", "-1"],
               ["--min-step", "x"], ["--delay-steps", "-1"]],
    ids=["ts-zero", "ts-nan", "rtol-negative", "min-step-text", "delay-negative"],
)
def test_inspect_refuses_bad_options_with_exit_code_2(
    option: list[str], capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as caught:
        main(["inspect", str(SHIPPED_EXPERIMENT), *option])
    assert caught.value.code == 2
    assert f"czmpc: error: argument {option[0]}:" in capsys.readouterr().err


def test_experiment_writes_the_shipped_file_and_prints_table3(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    out_path = tmp_path / "experiment.csv"
    assert main(["experiment", "--out", str(out_path)]) == 0
    assert out_path.read_bytes() == SHIPPED_EXPERIMENT.read_bytes()
    out = capsys.readouterr().out
    assert "12000 samples, 23998 s at 2 s (seed 2010)" in out
    rows = [line.split() for line in out.splitlines() if re.match(r"^\s+\d{5}\s", line)]
    assert [row[0] for row in rows] == ["10300", "13500", "17098", "22170"]
    assert [row[-2] for row in rows] == ["1.35", "1.31", "1.23", "1.14"]      # paper
    gains = np.array([float(row[-1]) for row in rows])
    np.testing.assert_allclose(gains, [1.35, 1.31, 1.23, 1.14], rtol=0.0, atol=0.06,
                               err_msg="issue tolerance on Table 3 gains")


def test_experiment_seed_changes_the_noise_only(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    out_path = tmp_path / "seed7.csv"
    assert main(["experiment", "--seed", "7", "--out", str(out_path)]) == 0
    assert "(seed 7)" in capsys.readouterr().out
    seven, shipped = read_csv(out_path), read_csv(SHIPPED_EXPERIMENT)
    assert np.array_equal(seven.triac_pct, shipped.triac_pct)
    assert not np.array_equal(seven.power_kw, shipped.power_kw)


def test_experiment_refuses_bad_arguments_and_unwritable_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    for argv in (["experiment"], ["experiment", "--seed", "-3", "--out", "x.csv"],
                 ["experiment", "--seed", "abc", "--out", "x.csv"]):
        with pytest.raises(SystemExit) as caught:
            main(argv)
        assert caught.value.code == 2
        assert "czmpc: error:" in capsys.readouterr().err
    assert main(["experiment", "--out", str(tmp_path / "missing_dir" / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("czmpc: error:") and "Traceback" not in err
