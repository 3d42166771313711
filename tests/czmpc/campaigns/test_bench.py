"""czmpc.campaigns.bench and `czmpc bench`: runs, goals, files, progress, BENCHMARKS.md section."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from czmpc.campaigns.bench import (
    CONTROLLERS,
    CSV_COLUMNS,
    SECTION_HEADING,
    BenchError,
    BenchModels,
    BenchRun,
    build_controller,
    build_plant,
    check_goals,
    run_bench,
    run_case,
    write_benchmarks_section,
    write_outputs,
)
from czmpc.cli import main
from sim.protocols import Controller
from sim.scenario import load_scenario

SHORT = 0.02


@pytest.fixture(scope="module")
def models() -> BenchModels:
    return BenchModels.shipped()


@pytest.fixture(scope="module")
def runs(models: BenchModels) -> tuple[BenchRun, ...]:
    scenarios = [load_scenario(n).shortened(SHORT) for n in ("staircase", "large_step")]
    return run_bench(scenarios, models=models)


def test_every_controller_is_a_controller_starting_at_the_plants_input(
    models: BenchModels,
) -> None:
    scenario = load_scenario("meltdown_ramp").shortened(SHORT)
    plant, s0 = build_plant("heater", models.hammerstein, scenario)
    y0 = plant.reset(0)
    assert abs(y0 - 20.0) < 0.5  # the heater starts at the initial setpoint's input
    for name in CONTROLLERS:
        ctrl = build_controller(name, models, scenario, initial_triac_pct=s0)
        assert isinstance(ctrl, Controller)
        ctrl.reset()
        s = ctrl.step(scenario.initial_setpoint_kw, scenario.initial_setpoint_kw)
        assert 28.0 - 1e-9 <= s <= 70.0 + 1e-9  # the shared allowed range [28, 70] %


def test_same_seed_same_run(models: BenchModels) -> None:
    scenario = load_scenario("missing_samples").shortened(SHORT)
    first = run_case(scenario, "model", "pi_gs", models)
    again = run_case(scenario, "model", "pi_gs", models)
    assert np.array_equal(first.result.triac_pct, again.result.triac_pct)
    assert first.metrics.iae_kw_s == again.metrics.iae_kw_s


def test_goals_are_computed_from_the_runs_metrics(runs: tuple[BenchRun, ...]) -> None:
    goals = check_goals(runs)
    by_run = {(r.scenario, r.plant, r.controller): r.metrics for r in runs}
    for g in goals:
        mpc = by_run[(g.scenario, g.plant, "mpc")]
        if g.goal.startswith("MPC IAE within"):
            ref = by_run[(g.scenario, g.plant, "nmpc")].iae_kw_s
            assert g.value == pytest.approx(mpc.iae_kw_s / ref - 1.0, rel=1e-12)
            assert g.met == (abs(g.value) <= 0.02)
        elif g.goal.startswith("MPC median step time"):
            ratio = by_run[(g.scenario, g.plant, "nmpc")].step_time_median_ms / \
                mpc.step_time_median_ms
            assert g.value == pytest.approx(ratio, rel=1e-12)
        elif g.goal == "MPC IAE below linear MPC":
            assert g.scenario == "large_step-short"  # only the nonlinear scenarios
            assert g.met == (mpc.iae_kw_s < by_run[(g.scenario, g.plant, "linear_mpc")].iae_kw_s)
        else:
            assert g.met == (mpc.iae_kw_s < by_run[(g.scenario, g.plant, "pi_gs")].iae_kw_s)
    assert len(goals) == 2 * 2 * 3 + 2  # per (scenario, plant): 3, plus linear on large_step


def test_outputs_are_a_table_a_csv_row_per_run_and_a_figure_per_scenario(
    runs: tuple[BenchRun, ...], tmp_path: Path,
) -> None:
    paths = write_outputs(runs, check_goals(runs), tmp_path, header="# head")
    with open(tmp_path / "bench.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert len(rows) == len(runs) == 2 * 2 * len(CONTROLLERS)
    assert {float(r["iae_kw_s"]) for r in rows} == {r.metrics.iae_kw_s for r in runs}
    md = (tmp_path / "bench.md").read_text(encoding="utf-8")
    assert md.startswith("# head") and "| staircase-short | heater | nmpc |" in md
    for name in ("staircase-short", "large_step-short"):
        png = tmp_path / "figures" / f"{name}.png"
        assert png in paths and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unknown_names_are_refused(models: BenchModels) -> None:
    scenario = load_scenario("staircase").shortened(SHORT)
    with pytest.raises(BenchError, match="controllers among mpc, nmpc"):
        run_bench([scenario], controllers=["mpc", "fuzzy"], models=models)
    with pytest.raises(BenchError, match="plants among model, heater"):
        run_bench([scenario], plants=["real"], models=models)
    with pytest.raises(BenchError, match="at least one scenario"):
        run_bench([], models=models)


def test_section_replaces_only_its_own_part(tmp_path: Path) -> None:
    md = tmp_path / "B.md"
    md.write_text("# Benchmarks\n\n## Other\n\nkeep me\n\n" + SECTION_HEADING
                  + "\n\nold\n\n## Later\n\nkeep too\n", encoding="utf-8")
    write_benchmarks_section(md, "new body")
    text = md.read_text(encoding="utf-8")
    assert "keep me" in text and "keep too" in text and "new body" in text
    assert "old" not in text
    assert text.index("## Other") < text.index(SECTION_HEADING) < text.index("## Later")


def test_cli_runs_prints_progress_and_records_the_section(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    md = tmp_path / "BENCH.md"
    code = main(["bench", "--short", str(SHORT), "--scenarios", "staircase", "--controllers",
                 "mpc,pi_gs,open_loop", "--plants", "model", "--out", str(tmp_path / "o"),
                 "--benchmarks-md", str(md)])
    out, err = capsys.readouterr()
    assert code == 0
    assert "[1/3] staircase-short / model / mpc" in err and "ETA" in err
    assert "MPC IAE below gain-scheduled PI" in out and "Machine:" in out
    assert SECTION_HEADING in md.read_text(encoding="utf-8")
    assert (tmp_path / "o" / "bench.csv").is_file()


def test_cli_bad_input_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--controllers", "fuzzy", "--short", "0.01", "--scenarios",
                 "staircase", "--out", str(tmp_path), "--no-record"]) == 2
    assert "czmpc: error: bench: expected controllers among" in capsys.readouterr().err
    assert main(["bench", "--scenarios", "staircase"]) == 2
    assert "--out DIR is required" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--short", "2", "--out", str(tmp_path)])
    assert exc.value.code == 2
