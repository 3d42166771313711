"""Scoring of the commissioning study through the plant link, and the served plant's log."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from benchmarks.commission_length import (
    LinkRun,
    LinkStudyError,
    Tracking,
    commissioning_staircase,
    format_link_study,
    tracking_from_logs,
    write_staircase_recipe,
)
from czmpc.runtime.config import load_schedule
from czmpc.runtime.served import PLANT_LOG_COLUMNS


def _write(path: Path, header: tuple[str, ...], rows: list[tuple[object, ...]]) -> Path:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def test_the_recipe_is_the_staircase_of_the_in_process_study(tmp_path: Path) -> None:
    recipe = load_schedule(write_staircase_recipe(tmp_path / "recipe.csv"))
    scenario = commissioning_staircase()
    profile = scenario.setpoint_profile_kw()
    for t_s in (0.0, 598.0, 600.0, 2398.0, 2400.0, 4200.0, 5998.0):
        assert recipe.setpoint_at(t_s) == profile[round(t_s / scenario.ts_s)], t_s


def test_tracking_lines_the_plant_log_up_with_the_run_by_wall_time(tmp_path: Path) -> None:
    # run: setpoint 36 kW for rows at wall 100.0, 100.1, then 40 kW from wall 100.2 on
    run = _write(tmp_path / "run.csv", ("k", "time_s", "wall_time_s", "setpoint_kw"),
                 [(k, 2.0 * k, 100.0 + 0.1 * k, 36.0 if k < 2 else 40.0) for k in range(30)])
    # plant samples at wall 100.05, 100.15, ...: the one before 100.0 is outside the run;
    # true power 36 kW at the first two inside, then 39 kW (1 kW short of 40)
    rows = [(2.0 * k, f"{99.95 + 0.1 * k:.6f}", 45.0, 36.0 if k < 3 else 39.0, 0.0, "good", 0)
            for k in range(31)]
    plant = _write(tmp_path / "plant.csv", PLANT_LOG_COLUMNS, rows)
    tracking = tracking_from_logs(plant, run, ts_s=2.0)
    # inside the run: plant k = 1..29 (wall 100.05 .. 102.85 <= 102.9); setpoint 40 from
    # plant k = 3 (wall 100.25 after the row at 100.2); error 1 kW on k = 3..29: 27 x 2 s
    assert tracking.iae_kw_s == pytest.approx(27 * 2.0)
    assert tracking.segment_errors_kw == pytest.approx((0.0, 1.0))
    assert not tracking.offset_free


def test_a_plant_log_that_misses_the_run_is_refused(tmp_path: Path) -> None:
    run = _write(tmp_path / "run.csv", ("k", "time_s", "wall_time_s", "setpoint_kw"),
                 [(k, 2.0 * k, 500.0 + k, 40.0) for k in range(5)])
    plant = _write(tmp_path / "plant.csv", PLANT_LOG_COLUMNS,
                   [(2.0 * k, 10.0 + k, 45.0, 40.0, 40.0, "good", 0) for k in range(5)])
    with pytest.raises(LinkStudyError, match="no samples inside the run"):
        tracking_from_logs(plant, run)


def test_the_table_gives_the_ratio_and_says_whether_the_goal_is_met() -> None:
    good = Tracking(iae_kw_s=230.0, segment_errors_kw=(0.01, -0.02, 0.03))
    ref = Tracking(iae_kw_s=240.0, segment_errors_kw=(0.0, 0.01, 0.02))
    runs = [LinkRun(seed=0, test_s=7200.0, stage="switched on", verdict="ready",
                    orders=(2, 2, 1, 3), fit_pct=95.0, commissioned=good, reference=ref,
                    n_overruns=1, wall_s=900.0)]
    assert runs[0].iae_ratio == pytest.approx(230.0 / 240.0)
    text = format_link_study(runs, command="python -m benchmarks.commission_length --plant-link", machine="m",
                             time_scale=20.0)
    assert "| 0 | 7200 | ready | (2, 2, 1, 3) | 95.0 | 230.0 | 240.0 | 0.958 | yes | yes | 1 |" \
        in text
    assert "Goal met" in text
    held = LinkRun(seed=1, test_s=7200.0, stage="checked", verdict="ready with conditions",
                   reasons=("residual whiteness",), failure="not switched on")
    assert math.isnan(held.iae_ratio)
    text = format_link_study([*runs, held], command="c", machine="m", time_scale=20.0)
    assert "ready with conditions (residual whiteness)" in text and "Goal not met" in text


@pytest.mark.realtime
def test_the_served_plant_logs_its_true_power(tmp_path: Path) -> None:
    """`czmpc plant serve --log`: one row per sample, the true power beside the published."""
    pytest.importorskip("asyncua")
    import subprocess
    import sys

    from benchmarks._serving import free_loopback_port

    log = tmp_path / "plant.csv"
    endpoint = f"opc.tcp://127.0.0.1:{free_loopback_port()}/czmpc/"
    proc = subprocess.run(
        [sys.executable, "-m", "czmpc.cli", "plant", "serve", "--plant", "heater",
         "--endpoint", endpoint, "--time-scale", "50", "--duration-s", "40", "--log", str(log),
         "--initial-triac-pct", "50"],
        capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    with open(log, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == PLANT_LOG_COLUMNS
    assert [float(r["plant_time_s"]) for r in rows] == [2.0 * k for k in range(21)]
    true_kw = np.array([float(r["power_true_kw"]) for r in rows])
    measured = np.array([float(r["power_measured_kw"]) for r in rows])
    assert {r["triac_applied_pct"] for r in rows} == {"50"}     # --initial-triac-pct
    # the heater at rest at 50 %: true power steady within its grid wander; the published
    # power is that plus sensor noise (0.1 kW), so the two differ but stay close
    assert np.ptp(true_kw) < 1.0
    assert 0.0 < np.max(np.abs(measured - true_kw)) < 1.0
    wall = np.array([float(r["wall_time_s"]) for r in rows])
    assert np.all(np.diff(wall) > 0.0)
