"""Robustness campaign: verdicts, metrics against an independent run, outputs and the CLI."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from czmpc.campaigns.robustness import (
    GRIDS,
    RobustnessError,
    RobustnessGrid,
    RobustnessReport,
    draw_heatmap,
    format_csv,
    format_markdown,
    run_robustness,
)
from czmpc.cli import main
from czmpc.controller import OffsetFreeMPC
from czmpc.settings import MPCSettings
from sim.loop import run_closed_loop
from sim.model_plant import ModelPlant, steady_state_triac_pct
from sim.perturbed import perturb_model
from sim.scenario import Scenario, SetpointStep
from sysid.errors import SamplingTimeError
from sysid.model import HammersteinModel
from tests.conftest import REPO

PAPER_MODEL_FILE = REPO / "tests" / "data" / "models" / "paper_armax.json"

#: Two steps with room to settle (the slow mode of the paper model is about 200 s).
TWO_STEPS = Scenario(
    name="two-steps", duration_s=1200.0, initial_setpoint_kw=45.0,
    setpoints=(SetpointStep(at_s=100.0, power_kw=50.0), SetpointStep(at_s=700.0, power_kw=47.0)),
)
#: A grid holding plants the aggressive controller cannot stabilize (gain x2..3 with a
#: 3-sample extra delay) beside ones it handles.
HARD_GRID = RobustnessGrid(gain_factors=(1.0, 3.0), time_constant_factors=(1.0, 2.0),
                           extra_delays_steps=(0, 3))


@pytest.fixture(scope="module")
def hard_report(paper_armax_model: HammersteinModel) -> RobustnessReport:
    return run_robustness(paper_armax_model, TWO_STEPS, grid=HARD_GRID, seed=3,
                          settings=MPCSettings.preset("aggressive", paper_armax_model))


def _csv_rows(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(text)))


def test_nominal_plant_tracks_without_offset_and_has_iae_ratio_one(
    hard_report: RobustnessReport,
) -> None:
    nominal = hard_report.nominal
    assert nominal.offset_free
    assert nominal.iae_ratio == 1.0
    assert nominal.max_abs_steady_state_error_kw < 1e-3
    assert [r.variant.kind for r in hard_report.results].count("heater") == 1


def test_unstable_plants_fail_offset_free_but_inputs_stay_in_range(
    hard_report: RobustnessReport,
) -> None:
    unstable = hard_report.result_for(gain_factor=3.0, time_constant_factor=1.0,
                                      extra_delay_steps=3)
    assert not unstable.offset_free
    assert unstable.max_abs_steady_state_error_kw > 1.0
    assert unstable.iae_ratio > 100.0
    mild = hard_report.result_for(gain_factor=3.0, time_constant_factor=2.0, extra_delay_steps=0)
    assert mild.offset_free
    assert all(r.n_input_violations == 0 for r in hard_report.results)


def test_iae_and_overshoot_equal_an_independent_closed_loop_run(
    paper_armax_model: HammersteinModel,
) -> None:
    m = paper_armax_model
    settings = MPCSettings.default_for(m)
    grid = RobustnessGrid(gain_factors=(1.0, 1.3), time_constant_factors=(1.0, 2.0),
                          extra_delays_steps=(0, 1))
    report = run_robustness(m, TWO_STEPS, grid=grid, settings=settings, seed=5,
                            include_heater=False)
    # by hand: the same plant and controller, errors summed with numpy
    plant_model = perturb_model(m, gain_factor=1.3, time_constant_factor=2.0, extra_delay_steps=1)
    s0 = steady_state_triac_pct(plant_model, TWO_STEPS.initial_setpoint_kw)
    plant = ModelPlant(plant_model, noise=False, initial_triac_pct=s0)
    mpc = OffsetFreeMPC(m, settings.with_updates(initial_triac_pct=s0, triac_min_pct=0.0,
                                                 triac_max_pct=100.0))
    run = run_closed_loop(plant, mpc, TWO_STEPS, rng=5)
    first_change = 50                                   # t = 100 s at Ts = 2 s
    error = run.power_true_kw[first_change:] - run.setpoint_kw[first_change:]
    iae = float(np.sum(np.abs(error)) * 2.0)
    result = report.result_for(gain_factor=1.3, time_constant_factor=2.0, extra_delay_steps=1)
    assert result.n_unreachable_changes == 0
    assert_allclose(result.iae_kw_s, iae, rtol=1e-12, atol=0,
                    err_msg="same deterministic run; only the summation order differs")
    assert_allclose(result.iae_ratio, iae / report.nominal.iae_kw_s, rtol=1e-12, atol=0,
                    err_msg="ratio of two sums")
    over_first = float(np.max(run.power_true_kw[50:350] - 50.0))     # step up to 50 kW
    over_second = float(np.max(47.0 - run.power_true_kw[350:]))      # step down to 47 kW
    expected = max(over_first, over_second, 0.0)
    assert_allclose(result.max_overshoot_kw, expected, rtol=1e-12, atol=0,
                    err_msg="max over the same samples")


def test_unreachable_setpoint_is_counted_and_tracked_to_the_plants_limit(
    paper_armax_model: HammersteinModel,
) -> None:
    m = paper_armax_model
    scenario = Scenario(name="high", duration_s=3000.0, initial_setpoint_kw=45.0,
                        setpoints=(SetpointStep(at_s=100.0, power_kw=70.0),))
    grid = RobustnessGrid(gain_factors=(0.7, 1.0), time_constant_factors=(1.0,),
                          extra_delays_steps=(0,))
    report = run_robustness(m, scenario, grid=grid, include_heater=False)
    s_max = OffsetFreeMPC(m).allowed_triac_range_pct[1]
    # independent: steady power of the -30 % plant at the largest allowed input
    p_limit = 45.0 + m.linear_static_gain * 0.7 * float(m.input_nonlinearity(s_max - 45.0))
    assert p_limit < 70.0 < float(m.steady_state_power_kw(s_max))
    weak = report.result_for(gain_factor=0.7, time_constant_factor=1.0, extra_delay_steps=0)
    assert weak.n_unreachable_changes == 1 and report.nominal.n_unreachable_changes == 0
    assert weak.offset_free      # it settles at p_limit, the best any controller can do
    assert abs(weak.steady_state_errors_kw[0]) < 0.05


def test_same_seed_gives_the_same_numbers_and_noise_changes_them(
    paper_armax_model: HammersteinModel,
) -> None:
    grid = RobustnessGrid(gain_factors=(1.0,), time_constant_factors=(1.0, 2.0),
                          extra_delays_steps=(0,))
    kwargs = {"grid": grid, "seed": 11, "include_heater": True, "noise": True}
    first = run_robustness(paper_armax_model, TWO_STEPS, **kwargs)  # type: ignore[arg-type]
    second = run_robustness(paper_armax_model, TWO_STEPS, **kwargs)  # type: ignore[arg-type]
    quiet = run_robustness(paper_armax_model, TWO_STEPS, grid=grid, seed=11, noise=False)
    for a, b, c in zip(first.results, second.results, quiet.results, strict=True):
        assert a.iae_kw_s == b.iae_kw_s
        assert a.steady_state_errors_kw == b.steady_state_errors_kw
        assert a.iae_kw_s != c.iae_kw_s


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"grid": "huge"}, "grid"),
     ({"sse_threshold_kw": 0.0}, "sse_threshold_kw"),
     ({"sse_threshold_kw": math.nan}, "sse_threshold_kw"),
     ({"seed": -1}, "seed")],
)
def test_invalid_campaign_options_raise_robustness_error(
    paper_armax_model: HammersteinModel, kwargs: dict[str, object], match: str
) -> None:
    with pytest.raises(RobustnessError, match=match):
        run_robustness(paper_armax_model, TWO_STEPS, **kwargs)  # type: ignore[arg-type]


def test_grid_without_the_nominal_plant_is_refused() -> None:
    with pytest.raises(RobustnessError, match="nominal value 1.0"):
        RobustnessGrid(gain_factors=(0.7, 1.3), time_constant_factors=(1.0,),
                       extra_delays_steps=(0,))


def test_scenario_without_setpoint_changes_or_other_ts_is_refused(
    paper_armax_model: HammersteinModel,
) -> None:
    flat = Scenario(name="flat", duration_s=100.0, initial_setpoint_kw=45.0)
    with pytest.raises(RobustnessError, match="setpoint changes"):
        run_robustness(paper_armax_model, flat)
    other_ts = Scenario(name="fast", duration_s=100.0, ts_s=1.0, initial_setpoint_kw=45.0,
                        setpoints=(SetpointStep(at_s=10.0, power_kw=46.0),))
    with pytest.raises(SamplingTimeError):
        run_robustness(paper_armax_model, other_ts)


def test_shipped_grids_span_the_issue_ranges() -> None:
    for grid in GRIDS.values():
        assert (min(grid.gain_factors), max(grid.gain_factors)) == (0.7, 1.3)
        assert (min(grid.time_constant_factors), max(grid.time_constant_factors)) == (0.5, 2.0)
        assert grid.extra_delays_steps == (0, 1)


def test_heatmap_has_a_panel_per_delay_labelled_axes_and_crosses_where_it_fails(
    hard_report: RobustnessReport,
) -> None:
    fig = draw_heatmap(hard_report)
    panels = [ax for ax in fig.axes if ax.get_title().startswith("extra input delay")]
    assert len(panels) == len(HARD_GRID.extra_delays_steps)
    for ax in panels:
        assert ax.get_xlabel() == "plant gain relative to the model [%]"
        assert ax.get_ylabel().endswith("[-]")
    crosses = sum(1 for ax in panels for line in ax.get_lines() if line.get_marker() == "x")
    failures = sum(1 for r in hard_report.results if r.variant.kind == "model" and not r.offset_free)
    assert crosses == failures >= 1


def test_csv_and_markdown_have_one_row_per_plant(hard_report: RobustnessReport) -> None:
    rows = _csv_rows(format_csv(hard_report))
    assert len(rows) == len(hard_report.results) == HARD_GRID.n_variants + 1
    assert rows[-1]["plant"] == "heater" and rows[-1]["gain_factor"] == ""
    assert {row["offset_free"] for row in rows} == {"true", "false"}
    md = format_markdown(hard_report, command="czmpc robustness --out x")
    table = [ln for ln in md.splitlines() if ln.startswith("| model") or ln.startswith("| virtual")]
    assert len(table) == len(rows)
    assert "|steady-state error| < 0.05 kW" in md
    assert "**NO**" in md


def test_cli_writes_csv_markdown_and_heatmap_with_progress_on_stderr(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scenario_file = tmp_path / "short.toml"
    scenario_file.write_text(
        'name = "short"\nduration_s = 1200\ninitial_setpoint_kw = 45.0\n'
        '[[setpoint]]\nkind = "step"\nat_s = 100\npower_kw = 50.0\n', encoding="utf-8")
    out = tmp_path / "campaign"
    code = main(["robustness", "--model", str(PAPER_MODEL_FILE), "--scenario",
                 str(scenario_file), "--grid", "quick", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    n_plants = GRIDS["quick"].n_variants + 1
    assert f"[{n_plants}/{n_plants}] virtual heater" in captured.err
    assert "input violations: 0" in captured.out
    assert sorted(p.name for p in out.iterdir()) == [
        "robustness.csv", "robustness.md", "robustness_heatmap.png"]
    rows = _csv_rows((out / "robustness.csv").read_text(encoding="utf-8"))
    assert len(rows) == n_plants
    assert all(row["n_input_violations"] == "0" for row in rows)
    assert (out / "robustness_heatmap.png").read_bytes()[:4] == b"\x89PNG"
    assert "czmpc robustness --model" in (out / "robustness.md").read_text(encoding="utf-8")


def test_cli_bad_model_file_exits_2_without_outputs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "model.json"
    bad.write_text("{not json", encoding="utf-8")
    code = main(["robustness", "--model", str(bad), "--out", str(tmp_path / "out")])
    assert code == 2
    assert "czmpc: error:" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
