"""Every input to OffsetFreeMPC.step is validated per call (issue 13, classes 2 and 3)."""

from __future__ import annotations

import dataclasses
import math

import pytest

from czmpc.controller import OffsetFreeMPC
from czmpc.errors import DesignError
from czmpc.modes import Status
from czmpc.settings import MPCSettings, ReliabilitySettings
from czmpc.supervision import MAX_SETPOINT_KW
from sim.model_plant import ModelPlant
from sysid.model import HammersteinModel


def _ramped(model: HammersteinModel) -> OffsetFreeMPC:
    rel = ReliabilitySettings(setpoint_ramp_kw_per_s=0.5, setpoint_filter_time_s=10.0)
    return OffsetFreeMPC(model, MPCSettings.default_for(model).with_updates(reliability=rel))


def test_power_none_is_a_missing_sample(paper_armax_model: HammersteinModel) -> None:
    mpc = OffsetFreeMPC(paper_armax_model)
    s = mpc.step(None, 45.0)
    last = mpc.last_step
    assert last is not None and math.isfinite(s)
    assert not last.measurement_used and last.verdict.name == "MISSING"
    assert last.status is Status.PREDICTED


@pytest.mark.parametrize(("setpoint", "verdict"), [
    (None, "missing"), (math.nan, "not finite"), (math.inf, "not finite"),
    (-1e308, "below power_min_kw"), (-1.0, "below power_min_kw"),
    (1e308, "beyond MAX_SETPOINT_KW"), (2 * MAX_SETPOINT_KW, "beyond MAX_SETPOINT_KW"),
])
def test_bad_setpoints_are_rejected_and_the_last_valid_one_kept(
        paper_armax_model: HammersteinModel, setpoint: float | None, verdict: str) -> None:
    mpc = _ramped(paper_armax_model)
    mpc.step(45.0, 47.0)
    mpc.step(45.2, setpoint)
    last = mpc.last_step
    assert last is not None
    assert last.setpoint_held and last.setpoint_verdict == verdict
    assert 45.0 <= last.setpoint_used_kw <= 47.0      # the ramp goes on towards 47 kW


def test_absurd_setpoints_leave_nothing_behind_in_the_ramp_and_filter(
        paper_armax_model: HammersteinModel) -> None:
    # 1e308 then -1e308 drove the ramp to -inf and the filter to NaN before (issue 13.3):
    # the heater went to its minimum under a normal-looking status until reset().
    mpc = _ramped(paper_armax_model)
    plant = ModelPlant(paper_armax_model, noise=False, initial_triac_pct=45.0)
    power = plant.reset(0)
    for setpoint in (1e308, -1e308, math.inf, 1e308):
        s = mpc.step(power, setpoint)
        power = plant.step(s)
    for _ in range(400):
        s = mpc.step(power, 46.0)
        power = plant.step(s)
    last = mpc.last_step
    assert last is not None and last.setpoint_verdict == "valid"
    assert last.setpoint_used_kw == pytest.approx(46.0, abs=1e-9)
    assert plant.true_power_kw == pytest.approx(46.0, abs=0.01)   # noise-free plant: settled


def test_setpoint_above_the_rated_power_is_rejected(paper_armax_model: HammersteinModel) -> None:
    rel = ReliabilitySettings(power_max_kw=100.0)
    mpc = OffsetFreeMPC(paper_armax_model, MPCSettings.default_for(paper_armax_model).with_updates(
        reliability=rel))
    mpc.step(45.0, 120.0)
    assert mpc.last_step is not None and mpc.last_step.setpoint_verdict == "above power_max_kw"


@pytest.mark.parametrize("b2", [-1.1, -1.5], ids=["negative-gain", "strongly-negative"])
def test_a_model_whose_static_gain_is_negative_is_refused(
        paper_armax_model: HammersteinModel, b2: float) -> None:
    # B(1)/A(1) = (1 + b2)/(1 + a1) < 0 with f'(0) > 0: power falls as the input rises.
    bad = dataclasses.replace(paper_armax_model, b=(0.0, 1.0, b2))
    with pytest.raises(DesignError, match=r"static gain over the allowed input range .* must be "
                                          r"positive and finite .*; got B\(1\)/A\(1\) = -"):
        OffsetFreeMPC(bad)
