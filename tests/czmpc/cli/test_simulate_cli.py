"""`czmpc simulate`: files written, metrics table, options, exit codes, help text."""

from __future__ import annotations

import csv
import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import czmpc.cli.simulate as simulate_cmd
from czmpc.campaigns.bench_mpc import (
    SECTION_HEADING,
    DayRun,
    MPCBenchmark,
    StepTimeRun,
    day_scenario,
    format_report,
    write_benchmarks_section,
)
from czmpc.campaigns.simulation import run_simulation, write_outputs
from czmpc.cli import build_parser, main
from czmpc.reports.benchmarks_md import machine_info
from czmpc.reports.closed_loop_figure import DISTURBANCE_LABEL, plot_closed_loop
from czmpc.reports.identification_figures import FigureError
from czmpc.settings import MPCSettings
from sim.loop import CSV_COLUMNS
from sim.scenario import list_scenarios, load_scenario
from sysid.modelfile import load_model

REPO = Path(__file__).resolve().parents[3]
SHIPPED_MODEL = REPO / "data" / "cz_heater_model.json"


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def _simulate(tmp_path: Path, *extra: str, scenario: str = "missing_samples") -> list[str]:
    return ["simulate", "--model", str(SHIPPED_MODEL), "--scenario", scenario,
            "--short", "0.2", "--out", str(tmp_path / "out"), *extra]


def test_simulate_writes_trajectory_metrics_and_figure(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = _run(_simulate(tmp_path, "--plant", "heater", "--seed", "4"), capsys)
    assert rc == 0, err
    folder = tmp_path / "out"
    with open(folder / "trajectory.csv", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == (*CSV_COLUMNS, "disturbance_estimate_kw")
    scenario = load_scenario("missing_samples").shortened(0.2)
    assert len(rows) == 1 + scenario.n_steps
    measured = np.array([float(r[2]) for r in rows[1:]])
    assert np.isnan(measured).sum() > 0        # the outage is in the file as nan
    doc = json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
    assert doc["scenario"] == "missing_samples-short" and doc["plant"] == "heater"
    assert doc["seed"] == 4 and doc["noise"] is True
    assert doc["controller_settings"]["initial_triac_pct"] == pytest.approx(
        doc["initial_triac_pct"], abs=1e-12)  # reason: inside the allowed range, not clipped
    assert doc["metrics"]["n_constraint_violations"] == 0
    assert len(doc["metrics"]["changes"]) == 1
    png = (folder / "figure.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    # the table: one row per setpoint change, units in the headers, then the whole run
    assert "IAE [kW s]" in out and "overshoot [kW]" in out and "settling [s]" in out
    assert "steady error true [kW]" in out and "steady error measured [kW]" in out
    assert "overall:" in out
    assert doc["metrics_measured"]["power_signal"] == "measured"
    assert re.search(r"^\s+\d+\s+45\.0 -> 50\.0 ", out, flags=re.M)
    assert "trajectory.csv" in out and "figure.png" in out


def test_cli_files_match_the_library_run_for_the_same_seed(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, _, err = _run(_simulate(tmp_path, "--seed", "7", "--preset", "smooth"), capsys)
    assert rc == 0, err
    model = load_model(SHIPPED_MODEL)
    outcome = run_simulation(model, load_scenario("missing_samples").shortened(0.2),
                             plant="model", seed=7, settings=MPCSettings.preset("smooth", model))
    write_outputs(outcome, tmp_path / "lib")
    # same samples, inputs and estimates; only the controller's wall time differs
    assert _rows_without_step_time(tmp_path / "out" / "trajectory.csv") == \
        _rows_without_step_time(tmp_path / "lib" / "trajectory.csv")
    doc = json.loads((tmp_path / "out" / "metrics.json").read_text(encoding="utf-8"))
    assert doc["controller_settings"]["move_weight"] == 1.0       # the smooth preset


def _rows_without_step_time(path: Path) -> list[list[str]]:
    idx = CSV_COLUMNS.index("step_time_s")
    rows = [r.split(",") for r in path.read_text(encoding="utf-8").splitlines()]
    return [r[:idx] + r[idx + 1:] for r in rows]


def test_no_noise_gives_a_noise_free_measurement(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, _, err = _run(_simulate(tmp_path, "--no-noise", scenario="staircase"), capsys)
    assert rc == 0, err
    with open(tmp_path / "out" / "trajectory.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    measured = np.array([float(r["power_measured_kw"]) for r in rows])
    true = np.array([float(r["power_true_kw"]) for r in rows])
    assert np.array_equal(measured, true)
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["noise"] is False


@pytest.mark.parametrize(
    ("argv_change", "message"),
    [
        ({"--scenario": "stair"}, "did you mean 'staircase'"),
        ({"--scenario": "BAD.toml"}, "not a valid TOML file"),
        ({"--scenario": "TS1.toml"}, "sampling time"),
        ({"--model": "BADMODEL.json"}, "format"),
        ({"--model": "MISSING.json"}, "No such file"),
    ],
)
def test_bad_input_exits_2_with_a_clear_message(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], argv_change: dict[str, str],
        message: str) -> None:
    (tmp_path / "BAD.toml").write_text('name = "x\n', encoding="utf-8")
    (tmp_path / "TS1.toml").write_text(
        'name = "ts1"\nduration_s = 100\nts_s = 1.0\ninitial_setpoint_kw = 45.0\n',
        encoding="utf-8")
    (tmp_path / "BADMODEL.json").write_text('{"format": "other"}', encoding="utf-8")
    argv = _simulate(tmp_path)
    for option, value in argv_change.items():
        argv[argv.index(option) + 1] = value if value == "stair" else str(tmp_path / value)
    rc, out, err = _run(argv, capsys)
    assert rc == 2
    assert err.startswith("czmpc: error: ") and message in err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("option", [["--short", "0"], ["--short", "2"], ["--seed", "-1"],
                                    ["--plant", "oven"], ["--preset", "fast"]])
def test_bad_option_values_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                  option: list[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main([*_simulate(tmp_path), *option])
    assert info.value.code == 2
    assert "czmpc: error:" in capsys.readouterr().err


def test_help_says_what_it_does_what_it_writes_and_each_option_with_units(
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["simulate", "--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    assert "simulate" in build_parser().format_help()
    for name in ("trajectory.csv", "metrics.json", "figure.png", "[kW]", "[%]", "[s]",
                 "--model", "--scenario", "--plant", "--seed", "--preset", "--noise",
                 "--no-noise", "--short", "--out", "Exit codes"):
        assert name in text, name
    # the shipped scenarios listed in the help are the ones that exist
    listed = re.search(r"Shipped scenarios: ([^.]*)\.", simulate_cmd.__doc__ or "", flags=re.S)
    assert listed is not None
    assert sorted(n.strip() for n in listed.group(1).split(",")) == sorted(list_scenarios())


def test_figure_has_three_labelled_panels_sharing_time(tmp_path: Path) -> None:
    t = 2.0 * np.arange(50)
    power = np.full(50, 45.0)
    fig = plot_closed_loop(t, power, power, power, np.full(50, 45.0), np.zeros(50),
                           allowed_triac_range_pct=(28.0, 70.0),
                           soft_power_limits_kw=(None, 46.0), title="t", path=tmp_path / "f.png")
    axes = fig.axes
    assert [ax.get_ylabel() for ax in axes] == ["power P [kW]", "TRIAC input s [%]",
                                                DISTURBANCE_LABEL]
    assert axes[2].get_xlabel() == "time [s]"
    assert axes[0].get_shared_x_axes().joined(axes[0], axes[2])
    labels = axes[0].get_legend_handles_labels()[1]
    assert "setpoint" in labels and "soft max 46 kW" in labels
    with pytest.raises(FigureError, match="triac_pct"):
        plot_closed_loop(t, power, power, power, np.full(49, 45.0), None,
                         allowed_triac_range_pct=(28.0, 70.0), title="t", path=tmp_path / "g.png")


# --- czmpc bench-mpc: the pieces (the benchmark itself runs for seconds, see BENCHMARKS.md) ---
def _bench(step_median_ms: float, day_wall_s: float, load: float = 0.1) -> MPCBenchmark:
    step = StepTimeRun(n_steps=3900, median_ms=step_median_ms, p95_ms=0.1, p99_ms=0.2,
                       max_ms=3.0, mean_iterations=5.0, n_fallbacks=0)
    day = tuple(DayRun(plant=p, n_steps=43_200, wall_s=day_wall_s, controller_s=1.0,
                       horizon_steps=38, max_abs_steady_state_error_kw=0.001)
                for p in ("model", "heater"))
    machine = replace(machine_info(), n_cpus=2, load_average=load)
    return MPCBenchmark(machine=machine, model_label="m", step_runs=(step, step),
                        day_runs=day, command="czmpc bench-mpc --repeats 2")


def test_bench_report_says_whether_each_goal_is_met() -> None:
    good = format_report(_bench(0.07, 3.0))
    assert good.count("**met**") == 2 and "**missed**" not in good
    assert "osqp" in good and "load average" in good and "czmpc bench-mpc --repeats 2" in good
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
