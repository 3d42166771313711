"""The step-against-bare-OSQP measurement of `benchmarks.mpc_step` (issue 30).

Speed is never asserted; these check that the replay solves the very QPs the controller
solved, and how the numbers are reported.
"""

from __future__ import annotations

from dataclasses import replace

from benchmarks._md import machine_info
from benchmarks.mpc_step import (
    STEP_OVER_QP_GOAL,
    DayRun,
    MPCBenchmark,
    OverheadRun,
    StepTimeRun,
    format_report,
    measure_qp_overhead,
)
from sysid.model import HammersteinModel


def test_the_replay_solves_the_controllers_qps_with_the_same_iterations(
        paper_armax_model: HammersteinModel) -> None:
    (run,) = measure_qp_overhead(paper_armax_model, repeats=1)
    assert run.n_steps == 3900  # the shipped staircase
    # Same q, l, u in the same order from the same warm starts: the same ADMM runs.
    assert run.same_iterations == 1.0
    assert run.ratio == run.step_median_ms / run.bare_median_ms
    assert run.solver_median_ms > 0.0 and run.bare_median_ms > 0.0  # measured, not judged


def _bench(*ratios: float) -> MPCBenchmark:
    step = StepTimeRun(n_steps=3900, median_ms=0.05, p95_ms=0.1, p99_ms=0.2, max_ms=3.0,
                       mean_iterations=5.0, n_fallbacks=0)
    day = tuple(DayRun(plant=p, n_steps=43_200, wall_s=3.0, controller_s=1.0, horizon_steps=38,
                       max_abs_steady_state_error_kw=0.001) for p in ("model", "heater"))
    overhead = tuple(OverheadRun(n_steps=3900, step_median_ms=0.04 * r, bare_median_ms=0.04,
                                 solver_median_ms=0.025, same_iterations=1.0) for r in ratios)
    return MPCBenchmark(machine=replace(machine_info(), n_cpus=2, load_average=0.1),
                        model_label="m", step_runs=(step,), day_runs=day, command="c",
                        overhead_runs=overhead)


def test_the_report_gives_each_run_and_judges_the_median_ratio() -> None:
    good = format_report(_bench(1.1, 1.2, 1.6))
    assert "### Step against a bare OSQP solve, N = 50" in good
    assert "| 2 | 0.0480 | 0.0400 | 0.0250 | 1.20 | 1.92 | 100.0% |" in good
    assert f"at most {STEP_OVER_QP_GOAL:g} x" in good and "(median over the runs: 1.20 x): **met**" in good
    assert "(median over the runs: 1.30 x): **missed**" in format_report(_bench(1.3, 1.2, 1.4))
    no_overhead = replace(_bench(1.0), overhead_runs=())
    assert "bare OSQP" not in format_report(no_overhead)
