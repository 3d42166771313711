"""Steady-state target: y_s = r for the current d, clipping and unreachable setpoints."""

from __future__ import annotations

import numpy as np
import pytest

from czmpc.controller import OffsetFreeMPC
from czmpc.errors import DesignError
from czmpc.realization import innovations_form
from czmpc.settings import MPCSettings
from czmpc.target import compute_target, steady_state_map
from sysid.model import HammersteinModel

#: Steady-state identities solved with one 2x2 solve: round-off of O(10) numbers.
STEADY_ATOL = 1e-12


@pytest.mark.parametrize("disturbance_model", ["input", "output"])
def test_reachable_target_is_a_steady_state_with_output_on_setpoint(
    disturbance_model: str, paper_armax_model: HammersteinModel
) -> None:
    base = innovations_form(paper_armax_model)
    ssm = steady_state_map(base, disturbance_model)  # type: ignore[arg-type]
    r, d = 3.0, 0.4
    tgt = compute_target(ssm, setpoint=r, disturbance=d, w_min=-50.0, w_max=50.0)
    assert tgt.is_reachable
    d_in = d if disturbance_model == "input" else 0.0
    d_out = d if disturbance_model == "output" else 0.0
    np.testing.assert_allclose(tgt.x_s, base.A @ tgt.x_s + base.B * (tgt.w_s + d_in),
                               rtol=0.0, atol=STEADY_ATOL)
    assert base.C @ tgt.x_s + d_out == pytest.approx(r, abs=STEADY_ATOL)
    assert tgt.y_s == r


@pytest.mark.parametrize("disturbance_model", ["input", "output"])
def test_unreachable_setpoint_clips_w_and_reports_the_reachable_output(
    disturbance_model: str, paper_armax_model: HammersteinModel
) -> None:
    ssm = steady_state_map(innovations_form(paper_armax_model), disturbance_model)  # type: ignore[arg-type]
    g = paper_armax_model.linear_static_gain
    high = compute_target(ssm, setpoint=100.0, disturbance=0.0, w_min=-40.0, w_max=30.0)
    assert not high.is_reachable
    assert high.w_s == 30.0
    assert high.y_s == pytest.approx(g * 30.0, rel=1e-12)
    assert high.w_unclipped == pytest.approx(100.0 / g, rel=1e-12)
    low = compute_target(ssm, setpoint=-100.0, disturbance=0.0, w_min=-40.0, w_max=30.0)
    assert not low.is_reachable and low.w_s == -40.0


def test_zero_static_gain_is_a_design_error(paper_oe_model: HammersteinModel) -> None:
    base = innovations_form(paper_oe_model.with_updates(b=[0.0, 1.0, -1.0]))
    with pytest.raises(DesignError, match=r"static gain B\(1\)/A\(1\) must be nonzero"):
        steady_state_map(base, "output")


def test_controller_reports_an_unreachable_setpoint_instead_of_chasing_it(
    paper_oe_model: HammersteinModel,
) -> None:
    mpc = OffsetFreeMPC(paper_oe_model, MPCSettings.default_for(paper_oe_model))
    s_max = mpc.allowed_triac_range_pct[1]
    expected_kw = float(paper_oe_model.steady_state_power_kw(s_max))
    power, x, w_prev = 45.0, 0.0, 0.0
    inputs = []
    for _ in range(1000):  # exact-model loop, no noise; 1000 samples = 10 slow time constants
        s = mpc.step(power, 120.0)
        inputs.append(s)
        w = float(paper_oe_model.input_nonlinearity(s - 45.0))
        x = 0.99 * x + w - 0.991 * w_prev
        w_prev, power = w, 45.0 + x
    last = mpc.last_step
    assert last is not None
    assert not last.setpoint_reachable
    assert last.target_power_kw == pytest.approx(expected_kw, rel=1e-9)
    assert last.target_triac_pct == pytest.approx(s_max, abs=1e-9)
    assert max(inputs) <= s_max  # never beyond the allowed range
    # It tracks the reachable power (approached from above: the instantaneous gain 1 of B
    # exceeds the static gain 0.9), not 120 kW: power ends within 0.01 kW of it.
    assert power == pytest.approx(expected_kw, abs=0.01)
    assert mpc.n_fallbacks == 0
