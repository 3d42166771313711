"""The one plant and controller builder, and the reachable-setpoint measures against numpy."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from czmpc.campaigns.build import CONTROLLERS, BuildError, build_controller, build_plant
from czmpc.campaigns.measure import OFFSET_FREE_THRESHOLD_KW, metric_row, reachable_row
from czmpc.controller import OffsetFreeMPC
from czmpc.settings import MPCSettings
from czmpc.shipped import ARMAX_MODEL_JSON, HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.loop import run_closed_loop
from sim.model_plant import ModelPlant, steady_state_triac_pct
from sim.perturbed import perturb_model
from sim.protocols import Controller
from sim.scenario import Scenario, SetpointStep, load_scenario
from sysid.model import HammersteinModel
from sysid.modelfile import load_model

#: Two steps with room to settle (the slow mode of the paper model is about 200 s).
TWO_STEPS = Scenario(
    name="two-steps", duration_s=1200.0, initial_setpoint_kw=45.0,
    setpoints=(SetpointStep(at_s=100.0, power_kw=50.0), SetpointStep(at_s=700.0, power_kw=47.0)),
)


def test_every_controller_kind_starts_at_the_plants_input_inside_the_shared_range() -> None:
    model = load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))
    scenario = load_scenario("meltdown_ramp").shortened(0.02)
    plant, s0, power_at = build_plant("heater", model, scenario, noise=True)
    assert abs(plant.reset(np.random.default_rng(0)) - 20.0) < 0.5   # at the initial setpoint
    assert power_at(s0) == pytest.approx(20.0, abs=1e-6)
    for kind in CONTROLLERS:
        if kind == "c_step":    # needs a generated directory: test_c_step_kind.py
            continue
        ctrl = build_controller(kind, model, scenario, initial_triac_pct=s0,
                                linear_model=load_model(shipped_path(ARMAX_MODEL_JSON)))
        assert isinstance(ctrl, Controller)
        s = ctrl.step(scenario.initial_setpoint_kw, scenario.initial_setpoint_kw)
        assert 28.0 - 1e-9 <= s <= 70.0 + 1e-9, kind  # the shared allowed range [28, 70] %
    with pytest.raises(BuildError, match="'lqr'"):
        build_controller("lqr", model, scenario, initial_triac_pct=s0)
    with pytest.raises(BuildError, match="'pond'"):
        build_plant("pond", model, scenario, noise=False)


def test_reachable_measures_equal_numpy_on_an_independent_closed_loop_run(
    paper_armax_model: HammersteinModel,
) -> None:
    m = paper_armax_model
    plant_model = perturb_model(m, gain_factor=1.3, time_constant_factor=2.0, extra_delay_steps=1)
    s0 = steady_state_triac_pct(plant_model, TWO_STEPS.initial_setpoint_kw)
    mpc = OffsetFreeMPC(m, MPCSettings.default_for(m).with_updates(initial_triac_pct=s0))
    run = run_closed_loop(ModelPlant(plant_model, noise=False, initial_triac_pct=s0), mpc,
                          TWO_STEPS, rng=5)
    allowed = mpc.allowed_triac_range_pct
    row = reachable_row(run, TWO_STEPS, lambda s: float(plant_model.steady_state_power_kw(s)),
                        allowed, None)
    # by hand: both setpoints are inside the plant's reach, so errors are to the setpoint
    error = run.power_true_kw[50:] - run.setpoint_kw[50:]            # from t = 100 s
    assert row["n_unreachable_changes"] == 0
    assert_allclose(row["iae_changes_reachable_kw_s"], float(np.sum(np.abs(error)) * 2.0),
                    rtol=1e-12, atol=0, err_msg="same samples; only the summation order differs")
    expected = max(float(np.max(run.power_true_kw[50:350] - 50.0)),     # step up to 50 kW
                   float(np.max(47.0 - run.power_true_kw[350:])), 0.0)  # step down to 47 kW
    assert_allclose(row["max_overshoot_reachable_kw"], expected, rtol=1e-12, atol=0)
    sse = [abs(float(np.mean(run.power_measured_kw[a:b] - sp)))
           for a, b, sp in ((275, 350, 50.0), (537, 600, 47.0))]  # last quarters, rounded up
    assert_allclose(row["max_abs_steady_state_error_reachable_kw"], max(sse), rtol=1e-9, atol=0)
    assert row["offset_free"] is (max(sse) < OFFSET_FREE_THRESHOLD_KW)
    counted = int(np.sum((run.triac_pct < allowed[0]) | (run.triac_pct > allowed[1])))
    assert row["n_allowed_range_violations"] == counted == 0


def test_an_unreachable_setpoint_is_counted_and_judged_at_the_plants_limit(
    paper_armax_model: HammersteinModel,
) -> None:
    m = paper_armax_model
    high = Scenario(name="high", duration_s=3000.0, initial_setpoint_kw=45.0,
                    setpoints=(SetpointStep(at_s=100.0, power_kw=70.0),))
    weak = perturb_model(m, gain_factor=0.7, time_constant_factor=1.0, extra_delay_steps=0)
    s0 = steady_state_triac_pct(weak, 45.0)
    mpc = OffsetFreeMPC(m, MPCSettings.default_for(m).with_updates(initial_triac_pct=s0))
    run = run_closed_loop(ModelPlant(weak, noise=False, initial_triac_pct=s0), mpc, high, rng=1)
    s_max = mpc.allowed_triac_range_pct[1]
    # independent: steady power of the -30 % plant at the largest allowed input
    p_limit = 45.0 + m.linear_static_gain * 0.7 * float(m.input_nonlinearity(s_max - 45.0))
    assert p_limit < 70.0
    row = reachable_row(run, high, lambda s: float(weak.steady_state_power_kw(s)),
                        mpc.allowed_triac_range_pct, None)
    assert row["n_unreachable_changes"] == 1
    assert row["offset_free"]            # it settles at p_limit, the best any controller can do
    tail = run.power_measured_kw[-(len(run.power_measured_kw) - 50) // 4:]
    assert abs(float(np.mean(tail)) - p_limit) < OFFSET_FREE_THRESHOLD_KW


def test_metric_row_takes_overshoot_and_settling_over_the_changes_nan_without_one(
    paper_armax_model: HammersteinModel,
) -> None:
    flat = Scenario(name="flat", duration_s=200.0, initial_setpoint_kw=45.0)
    plant = ModelPlant(paper_armax_model, noise=False, initial_triac_pct=45.0)
    run = run_closed_loop(plant, OffsetFreeMPC(paper_armax_model), flat, rng=1)
    row = metric_row(run)
    assert np.isnan(row["max_overshoot_kw"]) and np.isnan(row["max_settling_time_s"])
    assert row["n_not_settled"] == 0 and row["n_steps"] == 100
    assert_allclose(row["iae_kw_s"], float(np.sum(np.abs(run.power_true_kw - 45.0)) * 2.0),
                    rtol=1e-12, atol=1e-12)
