"""``czmpc run-report``: a log in the run-log format drawn and summarised; bad logs exit 2."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from czmpc.cli import main
from czmpc.reports.run_report import plot_run, summary_markdown

pytest.importorskip("asyncua")

from czmpc.runtime.logfiles import LOG_COLUMNS, RunLog  # noqa: E402
from czmpc.runtime.runlog import read_run_record  # noqa: E402


def _synthetic_log(path: Path) -> None:
    """300 steps: PREDICT then ON, 10 bad samples, one overrun, health crossing 1 at k = 200."""
    log = RunLog(path)
    for k in range(300):
        bad = 100 <= k < 110
        health = 0.2 + 0.8 * k / 200.0
        log.row({c: "" for c in LOG_COLUMNS} | {"k": k, "time_s": 2.0 * k,
                 "wall_time_s": 1.7e9 + 0.04 * k,
                 "power_kw": math.nan if bad else 45.0 + 0.01 * math.sin(k),
                 "quality": "bad" if bad else "good", "setpoint_kw": 45.0,
                 "triac_pct": 40.0, "applied_triac_pct": 40.0, "status": "OK",
                 "verdict": "VALID", "mode": "PREDICT" if k < 50 else "ON", "connected": 1,
                 "written": int(k >= 50), "lateness_s": 0.001, "step_latency_s": 0.002,
                 "skipped": 1 if k == 150 else 0, "predicted_kw": 45.0, "health": health,
                 "stale_alarm": int(health >= 1.0), "event": ""})
    for u in (38.0, 36.0):
        log.row({c: "" for c in LOG_COLUMNS} | {"triac_pct": u, "status": "SAFE_RAMP",
                                               "written": 1, "wall_time_s": 1.8e9})
    log.close()


def test_run_report_draws_and_summarises_a_run_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    log = tmp_path / "run.csv"
    _synthetic_log(log)
    record = read_run_record(log)
    assert record.n_steps == 300 and record.n_safe_rows == 2
    assert record.alarm_time_s == 400.0
    code = main(["run-report", str(log), "--out", str(tmp_path / "report")])
    assert code == 0
    text = (tmp_path / "report" / "report.md").read_text(encoding="utf-8")
    assert "- samples not good: 10; commands written: 250" in text
    assert "- overruns: 1 (1 periods skipped)" in text
    assert "**stale-model alarm at 400 s**" in text
    assert "- safe action after the stop: 2 rows" in text
    png = (tmp_path / "report" / "run.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_every_axis_of_the_run_figure_has_a_unit(tmp_path: Path) -> None:
    log = tmp_path / "run.csv"
    _synthetic_log(log)
    fig = plot_run(read_run_record(log), tmp_path / "run.png")
    axes = fig.get_axes()
    assert len(axes) == 5
    for ax in axes:
        assert re.search(r"\[.+\]", ax.get_ylabel()), ax.get_ylabel()
    assert axes[-1].get_xlabel() == "plant time [s]"
    health_line = axes[-1].get_lines()[0]
    np.testing.assert_allclose(health_line.get_ydata()[:3], [0.2, 0.204, 0.208], rtol=1e-12,
                               atol=0.0)


def test_a_file_that_is_no_run_log_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "data.csv"
    bad.write_text("time_s,triac_pct,power_kw\n0,45,45\n", encoding="utf-8")
    assert main(["run-report", str(bad), "--out", str(tmp_path / "r")]) == 2
    assert "missing columns ['k'" in capsys.readouterr().err


def test_the_report_compares_a_shadow_candidate_with_the_active_model(tmp_path: Path) -> None:
    log = tmp_path / "run.csv"
    run_log = RunLog(log)
    for k in range(40):
        power = 45.0 + (1.0 if k >= 20 else 0.0)
        run_log.row({c: "" for c in LOG_COLUMNS} | {
            "k": k, "time_s": 2.0 * k, "wall_time_s": 1.7e9 + k, "power_kw": power,
            "quality": "good", "setpoint_kw": 46.0, "triac_pct": 40.0, "mode": "PREDICT",
            "predicted_kw": power + 0.1, "candidate_predicted_kw": power - 0.3})
    run_log.close()
    record = read_run_record(log)
    text = summary_markdown(record, "run.png")
    assert ("one-step prediction, RMS error over 40 samples: active model 0.1 kW, candidate "
            "model (shadow) 0.3 kW") in text
