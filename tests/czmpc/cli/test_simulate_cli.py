"""`czmpc simulate`: files written, metrics table, options, exit codes, help text."""

from __future__ import annotations

import csv
import gc
import hashlib
import json
import re
import signal
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import czmpc.campaigns.simulation as simulation
import czmpc.cli.simulate as simulate_cmd
from czmpc.campaigns.simulation import run_simulation, write_outputs
from czmpc.cli import build_parser, main
from czmpc.cli._exit import ExitCode
from czmpc.reports.closed_loop_figure import DISTURBANCE_LABEL, PLOT_LIMIT, plot_closed_loop
from czmpc.reports.figure_style import FigureError
from czmpc.settings import MPCSettings
from sim.loop import CSV_COLUMNS, STATUS_COLUMNS
from sim.scenario import (
    BYTES_PER_STEP,
    MAX_N_STEPS,
    Scenario,
    SetpointStep,
    list_scenarios,
    load_scenario,
)
from sysid._version import __version__ as czmpc_version
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
    assert tuple(rows[0]) == (*CSV_COLUMNS, "disturbance_estimate_kw", *STATUS_COLUMNS)
    scenario = load_scenario("missing_samples").shortened(0.2)
    assert len(rows) == 1 + scenario.n_steps
    measured = np.array([float(r[2]) for r in rows[1:]])
    assert np.isnan(measured).sum() > 0        # the outage is in the file as nan
    status = {name: [r[rows[0].index(name)] for r in rows[1:]] for name in STATUS_COLUMNS}
    assert set(status["mode"]) == {"on"} and set(status["fallback"]) == {"none"}
    # no usable measurement: the step runs on the model's prediction, and says so
    assert [s for s, p in zip(status["status"], measured, strict=True) if np.isnan(p)] == [
        "predicted"] * int(np.isnan(measured).sum())
    assert set(status["solver_status"]) <= {"solved", "solved inaccurate"}
    doc = json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
    assert doc["model_sha256"] == hashlib.sha256(SHIPPED_MODEL.read_bytes()).hexdigest()
    assert doc["czmpc_version"] == czmpc_version
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


# --- scenarios that exhaust the machine, outputs only after a whole run (issue 13.5) ---
@pytest.mark.parametrize("duration", ["1e8", "1" + "0" * 39])
def test_a_scenario_beyond_the_memory_bound_exits_2_before_running(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], duration: str) -> None:
    (tmp_path / "huge.toml").write_text(
        f'name = "huge"\nduration_s = {duration}\ninitial_setpoint_kw = 45.0\n', encoding="utf-8")
    argv = _simulate(tmp_path)
    argv[argv.index("--scenario") + 1] = str(tmp_path / "huge.toml")
    rc, _, err = _run(argv, capsys)
    assert rc == 2
    assert err.startswith("czmpc: error: ")
    assert "key 'duration_s'" in err and "MAX_TIME_S" in err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_bytes_per_step_bounds_the_memory_a_closed_loop_run_holds() -> None:
    """The per-sample memory `sim.scenario.MAX_N_STEPS` is derived from, on two short runs."""
    model = load_model(SHIPPED_MODEL)
    held = []
    for duration_s in (200.0, 600.0):
        scenario = Scenario(name="m", duration_s=duration_s, initial_setpoint_kw=45.0,
                            setpoints=(SetpointStep(at_s=20.0, power_kw=50.0),))
        gc.collect()
        tracemalloc.start()
        try:
            outcome = run_simulation(model, scenario, plant="model", seed=1)
            gc.collect()
            held.append(tracemalloc.get_traced_memory()[0])
        finally:
            tracemalloc.stop()
        del outcome
    per_step = (held[1] - held[0]) / ((600.0 - 200.0) / 2.0)
    assert 0 < per_step <= BYTES_PER_STEP
    assert MAX_N_STEPS * BYTES_PER_STEP <= 4e9


@pytest.mark.parametrize("setpoint_kw", [1e308, -1e308, np.inf])
def test_the_figure_draws_setpoints_near_the_float_range(
        tmp_path: Path, setpoint_kw: float) -> None:
    t = np.arange(50) * 2.0
    setpoint = np.full(50, 45.0)
    setpoint[20:] = setpoint_kw
    fig = plot_closed_loop(t, setpoint, np.full(50, 45.0), np.full(50, 45.0), np.full(50, 40.0),
                           None, allowed_triac_range_pct=(5.0, 95.0), title="huge",
                           path=tmp_path / "f.png")
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    lo, hi = fig.axes[0].get_ylim()
    assert np.isfinite([lo, hi]).all()
    assert max(abs(lo), abs(hi)) >= PLOT_LIMIT          # the clipped setpoint is in view


def test_a_failing_figure_leaves_the_output_directory_as_it_was(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    model = load_model(SHIPPED_MODEL)
    outcome = run_simulation(model, load_scenario("missing_samples").shortened(0.05),
                             plant="model", seed=3)
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text("old", encoding="utf-8")

    def broken(*args: object, **kwargs: object) -> None:
        raise FigureError("figure failed")

    monkeypatch.setattr(simulation, "plot_outcome", broken)
    with pytest.raises(FigureError):
        write_outputs(outcome, out)
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json"]   # no trajectory, no scratch
    assert (out / "metrics.json").read_text(encoding="utf-8") == "old"
    monkeypatch.undo()
    written = write_outputs(outcome, out)
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in written)
    assert json.loads((out / "metrics.json").read_text(encoding="utf-8"))["seed"] == 3


# --- SIGTERM while writing (issue 13.6) ------------------------------------------------
_CHILD = """
import pathlib, sys, time
import sysid.atomic
from czmpc.cli import main

marker = pathlib.Path(sys.argv[1])
real_fsync = sysid.atomic._fsync_file

def slow_fsync(path):
    # the temporary file is written, not yet renamed: tell the parent (the marker appears
    # whole, by a rename: the parent must never read it half written), wait for SIGTERM
    partial = marker.with_name(marker.name + ".partial")
    partial.write_text(str(path))
    partial.replace(marker)
    time.sleep(60)
    real_fsync(path)

sysid.atomic._fsync_file = slow_fsync
sys.exit(main(sys.argv[2:]))
"""


def test_sigterm_while_writing_leaves_no_temporary_file_and_exits_143(tmp_path: Path) -> None:
    marker = tmp_path / "writing"
    argv = _simulate(tmp_path)
    argv[argv.index("--short") + 1] = "0.05"
    # the context manager closes the pipes whatever happens (an unclosed one warns later,
    # in whichever test the garbage collector runs)
    with subprocess.Popen([sys.executable, "-c", _CHILD, str(marker), *argv],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO) as child:
        try:
            deadline = time.monotonic() + 120.0
            while not marker.exists() and child.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            assert marker.exists(), child.communicate(timeout=10)[1].decode()
            temporary = Path(marker.read_text())
            assert temporary.exists() and temporary.name.startswith("."), temporary
            child.send_signal(signal.SIGTERM)
            _, err = child.communicate(timeout=30)
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()
    assert child.returncode == ExitCode.TERMINATED == 143
    assert "czmpc: error" not in err.decode() and "Traceback" not in err.decode()
    assert "terminated" in err.decode()
    out = tmp_path / "out"
    assert [p.name for p in out.rglob("*")] == []      # no temporary file, no scratch dir


@pytest.mark.parametrize(("power_kw", "rc"), [(1e100, 0), (1e308, 2)])
def test_simulate_with_astronomical_setpoints_writes_all_or_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], power_kw: float, rc: int) -> None:
    """1e100 kW (the bound) runs, metrics and figure included; 1e308 is refused up front."""
    (tmp_path / "big.toml").write_text(
        'name = "big"\nduration_s = 200\ninitial_setpoint_kw = 45.0\n'
        f'[[setpoint]]\nkind = "step"\nat_s = 50\npower_kw = {power_kw!r}\n', encoding="utf-8")
    argv = _simulate(tmp_path)
    argv[argv.index("--scenario") + 1] = str(tmp_path / "big.toml")
    argv.remove("--short")
    argv.remove("0.2")
    got, _, err = _run(argv, capsys)
    assert got == rc, err
    if rc == 0:
        assert sorted(p.name for p in (tmp_path / "out").iterdir()) == \
            ["figure.png", "metrics.json", "trajectory.csv"]
    else:
        assert "setpoint[1].power_kw" in err and "MAX_ABS_POWER_KW" in err and "Traceback" not in err
        assert not (tmp_path / "out").exists()
