"""The DAQP measurement of `benchmarks.mpc_step` (issue 42): what it replays and reports.

Speed is never asserted; these check that the DAQP replay solves the very QPs its loop
solved, that the plans' difference is OSQP's tolerance, and how the numbers are reported.
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from benchmarks._md import machine_info
from benchmarks.mpc_step import (
    DAQPRun,
    DayRun,
    MPCBenchmark,
    OverheadRun,
    StepTimeRun,
    format_report,
    measure_qp_overhead,
)
from czmpc.qp_daqp import DAQP_ITER_LIMIT
from sysid.model import HammersteinModel

#: OSQP's plans against the exact ones at eps 1e-5 (`czmpc.settings.OSQPOptions`): about
#: eps times the plan's scale (|w| up to ~20 kW) plus the iterate's lag (measured 2.2e-4 kW
#: on the shipped model, N = 50); 1e-3 kW, while a wrong plan is off by tenths of a kW.
PLAN_DIFF_MAX_KW = 1e-3


def test_the_daqp_replay_solves_its_loops_qps_and_the_plans_differ_by_osqps_tolerance(
        paper_armax_model: HammersteinModel) -> None:
    pytest.importorskip("daqp")
    (run,) = measure_qp_overhead(paper_armax_model, repeats=1)
    daqp = run.daqp
    assert daqp is not None
    # The same q, l, u in the same order from the same working sets: the same solves.
    assert daqp.same_iterations == 1.0 and daqp.n_fallbacks == 0
    assert 1.0 <= daqp.mean_iterations <= daqp.max_iterations < DAQP_ITER_LIMIT
    assert 0.0 < daqp.max_plan_diff_kw <= PLAN_DIFF_MAX_KW
    assert min(daqp.step_median_ms, daqp.bare_median_ms, daqp.internal_median_ms,
               daqp.osqp_internal_median_ms) > 0.0   # measured, not judged


def _run(step_ms: float, solver_ms: float, daqp: DAQPRun | None) -> OverheadRun:
    return OverheadRun(n_steps=3900, step_median_ms=step_ms, bare_median_ms=0.05,
                       solver_median_ms=solver_ms, same_iterations=1.0, daqp=daqp)


def _daqp(step_ms: float, bare_ms: float, max_it: int, diff_kw: float) -> DAQPRun:
    return DAQPRun(step_median_ms=step_ms, bare_median_ms=bare_ms, internal_median_ms=0.0018,
                   osqp_internal_median_ms=0.0266, mean_iterations=1.01, max_iterations=max_it,
                   same_iterations=1.0, max_plan_diff_kw=diff_kw, n_fallbacks=0)


def _bench(overhead: tuple[OverheadRun, ...]) -> MPCBenchmark:
    step = StepTimeRun(n_steps=3900, median_ms=0.08, p95_ms=0.1, p99_ms=0.2, max_ms=3.0,
                       mean_iterations=5.0, n_fallbacks=0)
    day = tuple(DayRun(plant=p, n_steps=43_200, wall_s=3.0, controller_s=1.0, horizon_steps=39,
                       max_abs_steady_state_error_kw=0.001) for p in ("model", "heater"))
    return MPCBenchmark(machine=replace(machine_info(), n_cpus=2, load_average=0.1),
                        model_label="m", step_runs=(step,), day_runs=day, command="c",
                        overhead_runs=overhead)


def test_the_report_gives_daqps_step_solve_iterations_and_plan_difference() -> None:
    text = format_report(_bench((
        _run(0.08, 0.030, _daqp(0.060, 0.0094, 5, 2.2e-4)),
        _run(0.10, 0.028, _daqp(0.070, 0.0090, 7, 1.1e-4)),
        _run(0.07, 0.031, _daqp(0.050, 0.0100, 4, 3.0e-4)),
    )))
    assert '### The same with DAQP (`solver = "daqp"`), N = 50' in text
    assert ("| 2 | 0.1000 | 0.0700 | 0.0280 | 0.0090 | 0.0266 | 0.0018 | 1.01 / 7 | 100.0% | "
            "1.10e-04 | 0 |") in text
    # Medians over the runs: steps 0.060 against 0.080 ms, solves 9.4 against 30.0 us.
    assert ("the step with DAQP 0.0600 ms against 0.0800 ms with OSQP (0.75 x); DAQP's update "
            "and solve 9.4 us against 30.0 us for OSQP's solver object (0.31 x)") in text
    assert f"DAQP's worst iteration count: 7 (cap {DAQP_ITER_LIMIT})." in text
    assert "plans are at most 3.00e-04 kW apart" in text


def test_no_daqp_table_without_a_daqp_measurement() -> None:
    text = format_report(_bench((_run(0.08, 0.03, None),)))
    assert "### Step against a bare OSQP solve, N = 50" in text and "DAQP" not in text
