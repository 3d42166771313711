"""The campaign benchmarks (tracking goals, robustness table, executor throughput) on
hand-made rows and, end to end, on short runs of the shipped specs."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from benchmarks import campaign_throughput, robustness, tracking
from czmpc.campaigns.campaign import spec_from_dict


def _row(controller: str, scenario: str, iae: float, step_ms: float, plant: str = "model",
         **extra: object) -> dict[str, object]:
    return {"run_id": f"{controller}|{plant}|{scenario}|0", "controller": controller,
            "scenario": scenario, "plant": plant, "status": "ok", "error": "", "seed": 7,
            "iae_kw_s": iae, "step_time_median_ms": step_ms, "n_steps": 100, **extra}


def test_tracking_goals_are_ratios_of_the_rows_numbers() -> None:
    rows = [_row("mpc", "large_step", 100.0, 0.3), _row("nmpc", "large_step", 101.0, 60.0),
            _row("linear_mpc", "large_step", 120.0, 0.3), _row("pi_gs", "large_step", 99.0, 0.01),
            _row("mpc", "staircase", 50.0, 0.3), _row("linear_mpc", "staircase", 40.0, 0.3)]
    checks = tracking.check_goals(rows)
    by_goal = {g.goal: g for g in checks if g.scenario == "large_step"}
    iae_goal = by_goal["MPC IAE within 2 % of NMPC"]
    assert iae_goal.value == pytest.approx(-1.0 / 101.0, rel=1e-12) and iae_goal.met
    speed = by_goal["MPC median step time >= 100x lower than NMPC"]
    assert speed.value == pytest.approx(200.0, rel=1e-12) and speed.met
    assert by_goal["MPC IAE below linear MPC"].met
    assert not by_goal["MPC IAE below gain-scheduled PI"].met
    # the linear-MPC goal holds on the nonlinear scenarios only
    assert [g.scenario for g in checks if g.goal == "MPC IAE below linear MPC"] == ["large_step"]
    text = tracking.section_text(rows, checks, command="c", machine="m", wall_time_s=1.0,
                                 time_scale=0.5)
    assert "Goals: 3 of 4 met." in text and "| large_step | 100.0 | 101.0 | 120.0 | 99.0 |" in text


def test_robustness_ratios_are_taken_to_the_nominal_plant_of_the_same_controller() -> None:
    common = {"max_abs_steady_state_error_reachable_kw": 0.001, "max_overshoot_reachable_kw": 0.1,
              "max_overshoot_reachable_pct": 2.0, "n_allowed_range_violations": 0,
              "n_solver_failures": 0, "offset_free": True, "n_unreachable_changes": 0}
    rows = [_row("mpc", "staircase", 0.0, 0.3, plant="perturbed g1 m1 d+0",
                 iae_changes_reachable_kw_s=80.0, **common),
            _row("mpc", "staircase", 0.0, 0.3, plant="perturbed g0.7 m2 d+1",
                 iae_changes_reachable_kw_s=314.0, **{**common, "n_unreachable_changes": 2}),
            _row("mpc", "staircase", 0.0, 0.3, plant="heater", iae_changes_reachable_kw_s=79.6,
                 **common)]
    ratios = robustness.iae_ratios(rows)
    assert [ratios[str(r["run_id"])] for r in rows] == pytest.approx([1.0, 314.0 / 80.0,
                                                                     79.6 / 80.0], rel=1e-12)
    text = robustness.section_text(rows, command="c", machine="m", wall_time_s=1.0)
    assert "| mpc | perturbed g0.7 m2 d+1 | staircase | yes (2 unreachable) |" in text
    assert "Offset-free on 3 of 3 plants; 0 input violations; worst IAE ratio 3.92" in text


def test_the_tracking_benchmark_runs_the_shipped_spec_and_records_its_section(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    md = tmp_path / "BENCHMARKS.md"
    md.write_text("# Benchmarks\n\n## Other\n\nkeep me\n", encoding="utf-8")
    assert tracking.main(["--time-scale", "0.01", "--controllers", "mpc,pi_gs",
                          "--benchmarks-md", str(md), "--out", str(tmp_path / "c")]) == 0
    text = md.read_text(encoding="utf-8")
    assert "keep me" in text and tracking.SECTION_HEADING in text
    assert "28 runs" in text and "MPC IAE below gain-scheduled PI" in text
    assert (tmp_path / "c" / "results.parquet").is_file()
    capsys.readouterr()
    assert tracking.main(["--time-scale", "0.01", "--controllers", "mpc,pi_gs", "--no-record",
                          "--out", str(tmp_path / "c")]) == 0
    assert "(28 runs resumed from an earlier run)" in capsys.readouterr().out
    assert tracking.main(["--time-scale", "2"]) == 2
    assert "time_scale" in capsys.readouterr().err


@pytest.mark.slow
def test_throughput_reports_every_executor_and_consistent_rates() -> None:
    pytest.importorskip("dask.distributed")
    spec = spec_from_dict({
        "name": "tiny", "seeds": 1, "time_scale": 0.02, "scenarios": ["staircase"],
        "controllers": [{"preset": "mpc"}, {"preset": "pi"}],
        "plants": [{"kind": "model"}, {"kind": "perturbed", "gain_factors": [0.8, 1.2]}]})
    timings = campaign_throughput.benchmark_executors(spec, workers=2)
    assert [(t.executor, t.workers, t.n_runs, t.n_errors) for t in timings] == [
        ("serial", 1, 6, 0), ("processes", 2, 6, 0), ("dask", 2, 6, 0)]
    for t in timings:
        assert t.runs_per_s == pytest.approx(t.n_runs / t.wall_s)
        assert math.isfinite(t.overhead_per_run_ms)
    assert timings[0].efficiency == pytest.approx(1.0)
    text = campaign_throughput.format_benchmark_markdown(timings, spec=spec, command="c",
                                                         machine="m")
    assert text.count("\n| ") == 5  # header, separator, three executors
