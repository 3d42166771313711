"""The MPC benchmark (`python -m benchmarks.mpc_step`): report, section, scenario, options.

The benchmark itself runs for a minute (BENCHMARKS.md); these test its pieces.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from benchmarks._md import machine_info
from benchmarks.mpc_step import (
    SECTION_HEADING,
    DayRun,
    MPCBenchmark,
    StepTimeRun,
    day_scenario,
    format_report,
    main,
    write_benchmarks_section,
)


def _bench(step_median_ms: float, day_wall_s: float, load: float = 0.1) -> MPCBenchmark:
    step = StepTimeRun(n_steps=3900, median_ms=step_median_ms, p95_ms=0.1, p99_ms=0.2,
                       max_ms=3.0, mean_iterations=5.0, n_fallbacks=0)
    day = tuple(DayRun(plant=p, n_steps=43_200, wall_s=day_wall_s, controller_s=1.0,
                       horizon_steps=38, max_abs_steady_state_error_kw=0.001)
                for p in ("model", "heater"))
    machine = replace(machine_info(), n_cpus=2, load_average=load)
    return MPCBenchmark(machine=machine, model_label="m", step_runs=(step, step),
                        day_runs=day, command="python -m benchmarks.mpc_step --repeats 2")


def test_bench_report_says_whether_each_goal_is_met() -> None:
    good = format_report(_bench(0.07, 3.0))
    assert good.count("**met**") == 2 and "**missed**" not in good
    assert "osqp" in good and "load average" in good and "python -m benchmarks.mpc_step --repeats 2" in good
    slow = _bench(0.5, 31.0)
    assert not slow.step_goal_met and not slow.day_goal_met
    assert format_report(slow).count("**missed**") == 2
    assert "other jobs shared the machine" not in good
    assert "other jobs shared the machine (load average 2.00 on 2 cores)" in format_report(
        _bench(0.07, 3.0, load=2.0))


def test_bench_section_replaces_only_its_own_body(tmp_path: Path) -> None:
    md = tmp_path / "BENCHMARKS.md"
    md.write_text("# Benchmarks\n\n## Identification pipeline\n\nkeep me\n\n"
                  f"{SECTION_HEADING}\n\nold numbers\n\n## Other\n\nkeep me too\n",
                  encoding="utf-8")
    write_benchmarks_section(md, "new numbers\n")
    text = md.read_text(encoding="utf-8")
    assert "old numbers" not in text and "new numbers" in text
    assert text.count(SECTION_HEADING) == 1
    assert "## Identification pipeline\n\nkeep me\n" in text and "## Other\n\nkeep me too\n" in text
    fresh = tmp_path / "NEW.md"
    write_benchmarks_section(fresh, "numbers")
    assert fresh.read_text(encoding="utf-8") == f"# Benchmarks\n\n{SECTION_HEADING}\n\nnumbers\n"


def test_day_scenario_is_24_h_of_2_s_samples_with_disturbances() -> None:
    day = day_scenario()
    assert day.n_steps == 43_200 and day.duration_s == 86_400.0
    levels = {s.power_kw for s in day.setpoints}
    assert min(levels) == 45.0 and max(levels) == 65.0
    assert len(day.disturbances) == 2


def test_a_bad_model_file_exits_2_with_the_file_named(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{}", encoding="utf-8")
    assert main(["--model", str(bad), "--no-record"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("python -m benchmarks.mpc_step: error: ") and "bad.json" in err


def test_zero_repeats_is_refused_with_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--repeats", "0"])
    assert exc.value.code == 2
    assert "expected an integer >= 1" in capsys.readouterr().err
