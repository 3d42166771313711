"""czmpc.pid.schedule and design on the shipped model: Ms bounds hold, breakpoints added where needed."""

from __future__ import annotations

import numpy as np
import pytest

from czmpc.pid.design import (
    MIN_TI_SAMPLES,
    DesignSpec,
    design_local,
    load_step_iae,
    tune_local,
    tune_sampled_integral,
    worst_ms,
)
from czmpc.pid.discretization import INTEGRAL_FORMS, controller_frequency_response
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.margins import sampled_margins
from czmpc.pid.plant import local_plant, reduce_to_rule_plant
from czmpc.pid.schedule import MAX_GAIN_CHANGE, merge_regions, tune_schedule
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sysid.model import HammersteinModel
from sysid.modelfile import load_model
from tests.tolerances import IDENTITY_RTOL

RANGE = (28.0, 70.0)  # the shipped model's identified 33..65 % widened by 5 %


@pytest.fixture(scope="module")
def shipped() -> HammersteinModel:
    return load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))


def _independent_ms(model: HammersteinModel, kc: float, ti: float, s_pct: float) -> float:
    """Ms of the forward-Euler PI on g B/A at s, on a dense grid (no refinement)."""
    g = float(model.input_nonlinearity_slope(s_pct - model.operating_point.triac_pct))
    w = np.linspace(1e-4, np.pi / model.ts_s, 200_000)
    z1 = np.exp(-1j * w * model.ts_s)
    c = kc * (1 + (model.ts_s / ti) * z1 / (1 - z1))
    plant = g * np.polyval(np.asarray(model.b)[::-1], z1) / np.polyval(np.asarray(model.a)[::-1], z1)
    return float(np.max(np.abs(1 / (1 + c * plant))))


def test_ms_14_holds_at_and_between_every_breakpoint_on_the_sampled_loop(
    shipped: HammersteinModel,
) -> None:
    schedule = tune_schedule(shipped, DesignSpec(ms=1.4), triac_range_pct=RANGE)
    assert len(schedule.rows) >= 3 and schedule.warnings == ()
    for row, nxt in zip(schedule.rows, schedule.breakpoints_pct[1:] + (RANGE[1],), strict=True):
        assert row.margins.ms <= 1.4 and row.worst_ms_to_next <= 1.4
        assert row.margins.ms == max(row.margins_by_form[f].ms for f in INTEGRAL_FORMS)
        assert max(row.worst_ms_to_next_by_form.values()) == row.worst_ms_to_next
        # checked independently of czmpc.pid.margins, at the row and at the next breakpoint
        for s in (row.triac_pct, nxt):
            assert _independent_ms(shipped, row.tuning.kc_pct_per_kw, row.tuning.ti_s, s) <= 1.4
        assert row.worst_gain_change <= MAX_GAIN_CHANGE


def test_breakpoints_are_added_where_the_schedule_does_not_hold(shipped: HammersteinModel) -> None:
    coarse = tune_schedule(shipped, DesignSpec(ms=1.4), triac_range_pct=RANGE,
                           breakpoints_pct=RANGE, add_breakpoints=False)
    # f' falls from 1.66 to 1.02 kW/% over the range: one row cannot hold it
    assert coarse.rows[0].worst_gain_change > 0.35
    assert any("does not hold" in w and "28 % and 70 %" in w for w in coarse.warnings)
    filled = tune_schedule(shipped, DesignSpec(ms=1.4), triac_range_pct=RANGE,
                           breakpoints_pct=RANGE)
    assert set(RANGE) <= set(filled.breakpoints_pct)
    assert filled.added_breakpoints_pct and filled.warnings == ()
    assert max(r.worst_gain_change for r in filled.rows) <= MAX_GAIN_CHANGE


def test_a_gain_rising_with_the_input_is_tuned_on_each_intervals_highest_gain(
    shipped: HammersteinModel,
) -> None:
    # f' rising with s: a row's controller meets higher gains up to the next breakpoint; tuned
    # at its breakpoint it would break the bound there
    rising = shipped.with_updates(input_poly=np.array([1.0, 0.006]))
    schedule = tune_schedule(rising, DesignSpec(ms=1.4), triac_range_pct=RANGE)
    assert all(r.worst_ms_to_next <= 1.4 for r in schedule.rows)
    # each row is tuned on its interval's highest gain: the next breakpoint's plant
    for row, nxt in zip(schedule.rows, schedule.breakpoints_pct[1:], strict=False):
        assert row.tuned_at_pct == nxt
        assert row.worst_ms_to_next > row.margins.ms  # the breakpoint's plant is easier


def test_the_ms_rule_beats_simc_on_load_iae_under_the_same_bound(
    shipped: HammersteinModel,
) -> None:
    # for ScheduledPID's law alone (forward Euler) and, on a plant with a lag, for all three
    plant = local_plant(shipped, 45.0)
    simc = tune_local(plant, DesignSpec(ms=1.4, discretization="forward"))
    best = tune_local(plant, DesignSpec(rule="ms", ms=1.4, discretization="forward"))
    assert sampled_margins(best, plant).ms <= 1.4
    assert load_step_iae(best, plant) < 0.8 * load_step_iae(simc, plant)  # measured 0.56
    lag = local_plant(shipped.with_updates(a=np.array([1.0, -0.9]), b=np.array([0.0, 0.0, 1.0]),
                                           c=np.array([1.0, -0.9])), 45.0)
    simc = tune_local(lag, DesignSpec(ms=1.4))
    best = tune_local(lag, DesignSpec(rule="ms", ms=1.4))
    assert worst_ms(best, lag, INTEGRAL_FORMS) <= 1.4
    assert (max(load_step_iae(best, lag, f) for f in INTEGRAL_FORMS)
            < 0.8 * max(load_step_iae(simc, lag, f) for f in INTEGRAL_FORMS))  # measured 0.71


def test_a_rule_asking_for_ti_below_ts_is_floored_and_said_integral_dominant(
    shipped: HammersteinModel,
) -> None:
    # nearly a gain and a dead time: SIMC's delay-dominant PI has Ti = theta/3 = Ts/2, the
    # ms rule's optimum lies below Ts too; the table holds Ti = Ts, Kc for the bound in every form
    plant = local_plant(shipped, 45.0)
    for rule in ("simc", "ms"):
        design = design_local(plant, DesignSpec(rule=rule, ms=1.4))  # type: ignore[arg-type]
        assert design.integral_dominant and design.rule_ti_s < plant.ts_s
        assert design.tuning.ti_s == MIN_TI_SAMPLES * plant.ts_s
        assert worst_ms(design.tuning, plant, INTEGRAL_FORMS) <= 1.4
        assert worst_ms(design.tuning.scaled(1.01), plant, INTEGRAL_FORMS) > 1.4  # on the bound
    assert design_local(plant, DesignSpec(rule="simc", ms=1.4)).rule_ti_s == pytest.approx(
        1.0, rel=IDENTITY_RTOL)  # theta/3 with theta = 3 s
    # the integral-only law: one law, so one Ms; forward Euler with Ti = Ts is that law
    law = tune_sampled_integral(plant, 1.4)
    forward = law.as_tuning("forward")
    assert forward is not None and forward.ti_s == plant.ts_s
    assert sampled_margins(forward, plant).ms == pytest.approx(1.4, abs=1e-6)
    tustin = law.as_tuning("tustin")
    assert tustin is not None
    w = np.linspace(0.01, 1.0, 5) * np.pi / plant.ts_s
    np.testing.assert_allclose(controller_frequency_response(tustin, plant.ts_s, w, "tustin"),
                               controller_frequency_response(forward, plant.ts_s, w, "forward"),
                               rtol=1e-12)
    assert law.as_tuning("backward") is None
    # a plant with a lag: no floor, no integral-only law
    lag = local_plant(shipped.with_updates(a=np.array([1.0, -0.9]), b=np.array([0.0, 0.0, 1.0]),
                                           c=np.array([1.0, -0.9])), 45.0)
    assert not design_local(lag, DesignSpec(rule="ms", ms=1.4)).integral_dominant
    schedule = tune_schedule(shipped, DesignSpec(ms=1.4), triac_range_pct=RANGE)
    assert schedule.integral_dominant_pct == schedule.breakpoints_pct
    assert all(r.sampled_integral is not None and r.sampled_integral.worst_ms_to_next <= 1.4
               for r in schedule.rows)


def test_the_heater_reduces_to_a_gain_with_a_sample_and_a_half_of_dead_time(
    shipped: HammersteinModel,
) -> None:
    # B = q^-1 (1 + b2 q^-1), A = 1 + a1 q^-1 with b2 ~ a1: the power jumps to f' and sags
    # slowly, so the rule sees f' with delay Ts plus Ts/2 for the hold
    rp = reduce_to_rule_plant(local_plant(shipped, 45.0))
    assert rp.tau1_s == 0.0 and rp.dead_time_s == pytest.approx(3.0, rel=IDENTITY_RTOL)
    assert rp.gain_kw_per_pct == pytest.approx(shipped.input_poly[0], rel=IDENTITY_RTOL)


def test_a_first_order_lag_reduces_exactly(shipped: HammersteinModel) -> None:
    lag = shipped.with_updates(a=np.array([1.0, -0.9]), b=np.array([0.0, 0.0, 1.0]),
                               c=np.array([1.0, -0.9]))
    rp = reduce_to_rule_plant(local_plant(lag, 45.0))
    assert rp.tau1_s == pytest.approx(-2.0 / np.log(0.9), rel=IDENTITY_RTOL)
    assert rp.dead_time_s == pytest.approx(2.0 + 1.0, rel=IDENTITY_RTOL)  # one sample + hold
    assert rp.gain_kw_per_pct == pytest.approx(shipped.input_poly[0] / 0.1, rel=IDENTITY_RTOL)


def test_three_regions_cover_the_range_and_report_their_worst_ms(shipped: HammersteinModel) -> None:
    schedule = tune_schedule(shipped, DesignSpec(ms=1.4), triac_range_pct=RANGE)
    regions = merge_regions(schedule, shipped, 3)
    assert len(regions) == 3
    assert regions[0].lo_pct == RANGE[0] and regions[-1].hi_pct == RANGE[1]
    assert all(a.hi_pct == b.lo_pct for a, b in zip(regions, regions[1:], strict=False))
    assert all(r.worst_ms <= 1.4 for r in regions)


@pytest.mark.parametrize("spec, match", [
    (lambda: DesignSpec(rule="amigo", ms=1.4), r"AMIGO has no knob"),
    (lambda: DesignSpec(tau_c_s=3.0, ms=1.4), r"either tau_c_s .* or ms"),
    (lambda: DesignSpec(rule="ms", tau_c_s=3.0), r"tau_c_s: expected a time > 0 .* got 3.0"),
    (lambda: DesignSpec(ms=0.9), r"ms: expected a bound > 1.*got 0.9"),
    (lambda: DesignSpec(discretization="euler"), r"discretization: expected one of .*got 'euler'"),
])
def test_design_spec_refuses_contradictions(spec: object, match: str) -> None:
    with pytest.raises(PIDTuningError, match=match):
        spec()  # type: ignore[operator]


def test_schedule_refuses_breakpoints_outside_the_range(shipped: HammersteinModel) -> None:
    with pytest.raises(PIDTuningError, match=r"inside the range \[28, 70\] %; got \[20.0, 50.0\]"):
        tune_schedule(shipped, DesignSpec(), triac_range_pct=RANGE, breakpoints_pct=(20.0, 50.0))
