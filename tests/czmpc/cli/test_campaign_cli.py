"""czmpc campaign run / report through the console entry point."""

from __future__ import annotations

from pathlib import Path

import pytest

from czmpc.campaigns.runner import read_results
from czmpc.cli import main

SPEC = """
name = "cli"
seeds = 1
time_scale = 0.02
scenarios = ["staircase"]
[[controllers]]
preset = "mpc"
[[plants]]
kind = "perturbed"
gain_factors = [0.9, 1.1]
time_constant_factors = [1.0, 2.0]
"""


def test_run_then_report_writes_table_markdown_and_figures(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC, encoding="utf-8")
    out = tmp_path / "out"
    assert main(["campaign", "run", str(spec), "--out", str(out), "--worst", "1"]) == 0
    assert "4 runs (4 run now, 0 resumed), 0 crashed" in capsys.readouterr().out
    rows = read_results(out)
    assert [r["plant"] for r in rows] == ["perturbed g0.9 m1 d+0", "perturbed g1.1 m1 d+0",
                                         "perturbed g0.9 m2 d+0", "perturbed g1.1 m2 d+0"]
    assert main(["campaign", "report", str(out)]) == 0
    report = (out / "report.md").read_text(encoding="utf-8")
    worst = max(rows, key=lambda r: r["iae_kw_s"])
    assert f"`{worst['run_id']}` | {worst['iae_kw_s']:.2f}" in report
    for name in ("iae_distribution.png", "iae_heatmap.png", "worst_runs.png"):
        assert (out / name).stat().st_size > 1000


def test_bad_spec_exits_2_with_the_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    spec = tmp_path / "bad.toml"
    spec.write_text(SPEC.replace('preset = "mpc"', 'preset = "lqr"'), encoding="utf-8")
    assert main(["campaign", "run", str(spec), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "czmpc: error:" in err and "'lqr'" in err and "Traceback" not in err


def test_missing_spec_and_unfinished_dir_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["campaign", "run", str(tmp_path / "nope.toml"), "--out", str(tmp_path)]) == 2
    assert main(["campaign", "report", str(tmp_path)]) == 2
    assert "no results.parquet" in capsys.readouterr().err
