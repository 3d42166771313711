"""czmpc.pid.discretization: each form's transfer function is its difference equation, run step by step."""

from __future__ import annotations

import math

import numpy as np
import pytest

from czmpc.pid.controller import ScheduledPID, TableSchedule
from czmpc.pid.discretization import INTEGRAL_FORMS, controller_polynomials, covering, forms_of
from czmpc.pid.discretization import controller_frequency_response as form_response
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.plant import local_plant
from czmpc.pid.report import simulate_row
from czmpc.pid.rules import PIDTuning
from sysid.model import HammersteinModel

TS = 2.0
PID = PIDTuning(kc_pct_per_kw=0.4, ti_s=1.3, td_s=3.0, td_filter_s=0.5, setpoint_weight=0.6)
PI = PIDTuning(kc_pct_per_kw=0.3, ti_s=0.8)


def _velocity_law(tuning: PIDTuning, form: str, ys: np.ndarray, rs: np.ndarray) -> np.ndarray:
    """The form's velocity law, written out from the textbook rules (czmpc.pid.discretization notes)."""
    kc, r, td, tf = tuning.kc_pct_per_kw, TS / tuning.ti_s, tuning.td_s, tuning.td_filter_s
    u, p_prev, d_prev, e_prev, y_prev, out = 0.0, 0.0, 0.0, 0.0, math.nan, []
    for y, ref in zip(ys, rs, strict=True):
        e, p, d = ref - y, tuning.setpoint_weight * ref - y, 0.0
        if td > 0 and not math.isnan(y_prev):
            if form == "tustin":  # trapezoidal rule on Tf d' + d = -Td y'
                d = ((2 * tf - TS) * d_prev - 2 * td * (y - y_prev)) / (2 * tf + TS)
            else:  # backward Euler
                d = (tf * d_prev - td * (y - y_prev)) / (tf + TS)
        integral = {"forward": e_prev, "backward": e, "tustin": (e + e_prev) / 2}[form]
        u += kc * (p - p_prev + d - d_prev + r * integral)
        out.append(u)
        p_prev, d_prev, e_prev, y_prev = p, d, e, y
    return np.array(out)


@pytest.mark.parametrize("tuning", [PID, PI], ids=["pid", "pi"])
@pytest.mark.parametrize("form", INTEGRAL_FORMS)
def test_each_forms_transfer_function_is_its_velocity_law(tuning: PIDTuning, form: str) -> None:
    # (1 - z^-1) C(z) is the DTFT of the law's moves after y = -delta (r = 0), as in
    # test_pid_controller's check of ScheduledPID
    n = 4096
    y = np.zeros(n + 1)
    y[1] = -1.0  # after one sample at rest, so the derivative has a previous measurement
    moves = np.diff(np.concatenate([[0.0], _velocity_law(tuning, form, y, np.zeros_like(y))]))[1:]
    w = np.linspace(0.01, 0.99, 9) * np.pi / TS
    dtft = np.array([np.sum(moves * np.exp(-1j * wi * TS * np.arange(n))) for wi in w])
    expected = (1 - np.exp(-1j * w * TS)) * form_response(tuning, TS, w, form)  # type: ignore[arg-type]
    np.testing.assert_allclose(dtft, expected, rtol=1e-10, atol=1e-12)
    num, den = controller_polynomials(tuning, TS, form)  # type: ignore[arg-type]
    zinv = np.exp(-1j * w * TS)
    np.testing.assert_allclose(np.polynomial.polynomial.polyval(zinv, num)
                               / np.polynomial.polynomial.polyval(zinv, den),
                               form_response(tuning, TS, w, form), rtol=1e-12)  # type: ignore[arg-type]


def test_forward_is_the_law_scheduledpid_runs() -> None:
    rng = np.random.default_rng(5)
    ys, rs = rng.normal(size=40), np.repeat([0.0, 1.0, -0.5, 0.2], 10)
    pid = ScheduledPID(schedule=TableSchedule(breakpoints_pct=(0.0,), tunings=(PID,)), ts_s=TS,
                       initial_triac_pct=0.0, triac_limits_pct=(-1e9, 1e9))
    got = [pid.step(power_kw=float(y), setpoint_kw=float(r)) for y, r in zip(ys, rs, strict=True)]
    np.testing.assert_allclose(got, _velocity_law(PID, "forward", ys, rs), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("form", INTEGRAL_FORMS)
def test_report_responses_run_each_forms_law(paper_armax_model: HammersteinModel, form: str) -> None:
    plant = local_plant(paper_armax_model, 45.0)
    y, u = simulate_row(PID, plant, setpoint_kw=1.0, load_pct=0.5, n_samples=30, form=form)  # type: ignore[arg-type]
    # the same loop closed around the law written out here
    g, a, b = plant.gain_kw_per_pct, plant.a, plant.b
    y_ref, u_ref = np.zeros(30), np.zeros(30)
    for k in range(30):
        y_ref[k] = (sum(g * b[i] * (u_ref[k - i] + 0.5) for i in range(1, len(b)) if k >= i)
                    - sum(a[i] * y_ref[k - i] for i in range(1, len(a)) if k >= i))
        u_ref[: k + 1] = _velocity_law(PID, form, y_ref[: k + 1], np.ones(k + 1))
    np.testing.assert_allclose(y, y_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(u, u_ref, rtol=1e-12, atol=1e-12)


def test_forms_differ_by_half_the_integral_gain_at_nyquist() -> None:
    # every form's PI is (q0 + q1 z^-1)/(1 - z^-1) with q0 + q1 = Kc Ts/Ti; at z = -1 they
    # are Kc (1 - r/2), Kc (1 + r/2) and Kc
    r = TS / PI.ti_s
    at_nyquist = {f: form_response(PI, TS, np.array([math.pi / TS]), f)[0] for f in INTEGRAL_FORMS}
    expected = {"forward": 1 - r / 2, "backward": 1 + r / 2, "tustin": 1.0}
    for form, value in at_nyquist.items():
        assert value == pytest.approx(PI.kc_pct_per_kw * expected[form], rel=1e-12)
    for form in INTEGRAL_FORMS:
        num, den = controller_polynomials(PI, TS, form)
        assert np.sum(num) == pytest.approx(PI.kc_pct_per_kw * r, rel=1e-12)
        np.testing.assert_array_equal(den, [1.0, -1.0])


def test_discretization_names_and_their_forms() -> None:
    assert forms_of("worst") == ("forward", "backward", "tustin")
    assert forms_of("backward") == ("backward",)
    assert covering("forward", "forward") == "forward"
    assert covering("forward", "backward") == "worst"
    assert covering("tustin", "worst") == "worst"
    with pytest.raises(PIDTuningError, match=r"discretization: expected one of .*got 'euler'"):
        forms_of("euler")  # type: ignore[arg-type]
    with pytest.raises(PIDTuningError, match=r"integral form: expected one of"):
        controller_polynomials(PI, TS, "worst")  # type: ignore[arg-type]
