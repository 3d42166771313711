"""czmpc.pid.rules against the published formulas, re-typed here independently."""

from __future__ import annotations

import numpy as np
import pytest

from czmpc.pid.errors import PIDTuningError
from czmpc.pid.plant import RulePlant
from czmpc.pid.rules import amigo, gain_delay_sampled, lambda_imc, simc
from tests.tolerances import IDENTITY_RTOL

FOPDT = [RulePlant(gain_kw_per_pct=1.3, tau1_s=40.0, dead_time_s=3.0),
         RulePlant(gain_kw_per_pct=0.8, tau1_s=5.0, dead_time_s=6.0),
         RulePlant(gain_kw_per_pct=2.0, tau1_s=200.0, dead_time_s=1.0)]
SOPDT = [RulePlant(gain_kw_per_pct=1.3, tau1_s=40.0, tau2_s=8.0, dead_time_s=3.0),
         RulePlant(gain_kw_per_pct=0.5, tau1_s=12.0, tau2_s=12.0, dead_time_s=4.0)]
W = np.geomspace(1e-3, 10.0, 25)


def _ideal(kc: float, ti: float, td: float, w: np.ndarray) -> np.ndarray:
    s = 1j * w
    return kc * (1.0 + 1.0 / (ti * s) + td * s)


@pytest.mark.parametrize("plant", FOPDT + SOPDT, ids=lambda p: f"tau2={p.tau2_s:g},tau1={p.tau1_s:g}")
@pytest.mark.parametrize("tau_c", [1.0, 3.0, 20.0])
def test_simc_pi_is_skogestads_formula_with_the_half_rule(plant: RulePlant, tau_c: float) -> None:
    # Skogestad (2003), eqs. for PI: Kc = tau1/(k (tau_c + theta)), tauI = min(tau1, 4(tau_c + theta)),
    # a second-order plant first reduced by the half rule (tau1 + tau2/2, theta + tau2/2)
    k, tau1 = plant.gain_kw_per_pct, plant.tau1_s + plant.tau2_s / 2
    theta = plant.dead_time_s + plant.tau2_s / 2
    got = simc(plant, tau_c_s=tau_c)
    np.testing.assert_allclose([got.kc_pct_per_kw, got.ti_s, got.td_s],
                               [tau1 / (k * (tau_c + theta)), min(tau1, 4 * (tau_c + theta)), 0.0],
                               rtol=IDENTITY_RTOL, atol=0.0)


@pytest.mark.parametrize("plant", SOPDT, ids=lambda p: f"tau1={p.tau1_s:g}")
def test_simc_pid_equals_the_series_pid_of_the_paper(plant: RulePlant) -> None:
    # series PID Kc (1 + 1/(tauI s)) (1 + tauD s), tauD = tau2: the ideal form must have the
    # same frequency response
    tau_c = plant.dead_time_s
    kc = plant.tau1_s / (plant.gain_kw_per_pct * (tau_c + plant.dead_time_s))
    ti = min(plant.tau1_s, 4 * (tau_c + plant.dead_time_s))
    s = 1j * W
    series = kc * (1 + 1 / (ti * s)) * (1 + plant.tau2_s * s)
    got = simc(plant, tau_c_s=tau_c, controller="pid")
    np.testing.assert_allclose(_ideal(got.kc_pct_per_kw, got.ti_s, got.td_s, W), series,
                               rtol=IDENTITY_RTOL, atol=0.0)
    assert got.td_filter_s == pytest.approx(got.td_s / 10.0, rel=IDENTITY_RTOL)


def test_simc_delay_dominant_correction_adds_a_third_of_the_dead_time() -> None:
    # Grimholt and Skogestad (2012): tau1 -> tau1 + theta/3 in the PI
    plant = RulePlant(gain_kw_per_pct=1.4, tau1_s=0.0, dead_time_s=3.0)
    got = simc(plant, tau_c_s=3.0, delay_dominant=True)
    np.testing.assert_allclose([got.kc_pct_per_kw, got.ti_s], [1.0 / (1.4 * 6.0), 1.0],
                               rtol=IDENTITY_RTOL, atol=0.0)
    with pytest.raises(PIDTuningError, match=r"no lag \(tau1 = 0\).*integral control"):
        simc(plant, tau_c_s=3.0)


@pytest.mark.parametrize("plant", FOPDT, ids=lambda p: f"tau1={p.tau1_s:g}")
@pytest.mark.parametrize("lam", [2.0, 10.0])
def test_lambda_pid_is_the_imc_controller_with_a_pade_delay(plant: RulePlant, lam: float) -> None:
    # IMC: q = G+^-1 / (lambda s + 1) with G = k (1 - theta s/2) / ((tau s + 1)(1 + theta s/2));
    # C = q / (1 - G q), computed numerically here
    s = 1j * W
    k, tau, theta = plant.gain_kw_per_pct, plant.tau1_s, plant.dead_time_s
    g_pade = k * (1 - theta * s / 2) / ((tau * s + 1) * (1 + theta * s / 2))
    q = (tau * s + 1) * (1 + theta * s / 2) / (k * (lam * s + 1))
    imc = q / (1 - g_pade * q)
    got = lambda_imc(plant, lambda_s=lam, controller="pid")
    np.testing.assert_allclose(_ideal(got.kc_pct_per_kw, got.ti_s, got.td_s, W), imc,
                               rtol=1e-9, atol=0.0)  # q/(1-Gq) loses digits at low w
    pi = lambda_imc(plant, lambda_s=lam)
    assert (pi.kc_pct_per_kw, pi.ti_s, pi.td_s) == (got.kc_pct_per_kw, got.ti_s, 0.0)


@pytest.mark.parametrize("plant", SOPDT, ids=lambda p: f"tau1={p.tau1_s:g}")
def test_lambda_pid_on_a_second_order_plant_is_imc_with_a_taylor_delay(plant: RulePlant) -> None:
    s = 1j * W
    k, t1, t2, theta, lam = (plant.gain_kw_per_pct, plant.tau1_s, plant.tau2_s,
                             plant.dead_time_s, 5.0)
    g_taylor = k * (1 - theta * s) / ((t1 * s + 1) * (t2 * s + 1))
    q = (t1 * s + 1) * (t2 * s + 1) / (k * (lam * s + 1))
    got = lambda_imc(plant, lambda_s=lam, controller="pid")
    np.testing.assert_allclose(_ideal(got.kc_pct_per_kw, got.ti_s, got.td_s, W),
                               q / (1 - g_taylor * q), rtol=1e-9, atol=0.0)


@pytest.mark.parametrize("plant", FOPDT + SOPDT, ids=lambda p: f"tau2={p.tau2_s:g},tau1={p.tau1_s:g}")
def test_amigo_is_astrom_and_hagglunds_formula(plant: RulePlant) -> None:
    # Astrom & Hagglund, Advanced PID Control (2006), AMIGO rules for K e^{-sL}/(1 + sT)
    big_k = plant.gain_kw_per_pct
    t = plant.tau1_s + plant.tau2_s / 2
    el = plant.dead_time_s + plant.tau2_s / 2
    tau = el / (el + t)
    pi = amigo(plant)
    expected_k = 0.15 / big_k + (0.35 - el * t / (el + t) ** 2) * t / (big_k * el)
    expected_ti = 0.35 * el + 13 * el * t * t / (t * t + 12 * el * t + 7 * el * el)
    np.testing.assert_allclose([pi.kc_pct_per_kw, pi.ti_s], [expected_k, expected_ti],
                               rtol=IDENTITY_RTOL, atol=0.0)
    assert pi.setpoint_weight == (0.0 if tau <= 0.5 else 1.0)
    pid = amigo(plant, controller="pid")
    np.testing.assert_allclose(
        [pid.kc_pct_per_kw, pid.ti_s, pid.td_s],
        [(0.2 + 0.45 * t / el) / big_k, (0.4 * el + 0.8 * t) / (el + 0.1 * t) * el,
         0.5 * el * t / (0.3 * el + t)], rtol=IDENTITY_RTOL, atol=0.0)


def test_gain_delay_rule_places_the_dominant_pole_at_lambda() -> None:
    # z^2 + (beta - 1) z + beta (Ts/Ti - 1) = 0 (forward-Euler PI, gain g, one sample delay)
    got = gain_delay_sampled(1.4, lambda_s=60.0)
    beta, ts = 1.4 * got.kc_pct_per_kw, 2.0
    roots = np.roots([1.0, beta - 1.0, beta * (ts / got.ti_s - 1.0)])
    dominant = max(abs(roots))
    assert beta == pytest.approx(0.5, rel=IDENTITY_RTOL)
    # the rule's pole: z = 1 - ts/lambda to first order in ts/lambda
    assert dominant == pytest.approx(1 - ts / 60.0, abs=(ts / 60.0) ** 2)


@pytest.mark.parametrize("call, match", [
    (lambda: simc(FOPDT[0], tau_c_s=0.0), r"tau_c_s: expected a time > 0 \[s\]; got 0.0"),
    (lambda: lambda_imc(FOPDT[0], lambda_s=-1.0), r"lambda_s: expected a time > 0"),
    (lambda: gain_delay_sampled(1.0, lambda_s=6.0, loop_gain=1.5), r"loop_gain in \(0, 1\)"),
    (lambda: RulePlant(gain_kw_per_pct=1.0, tau1_s=1.0, tau2_s=2.0, dead_time_s=1.0),
     r"RulePlant.tau2_s.*got 2.0"),
])
def test_rules_refuse_bad_knobs_and_plants(call: object, match: str) -> None:
    with pytest.raises(PIDTuningError, match=match):
        call()  # type: ignore[operator]


def test_rule_plant_response_is_the_textbook_one() -> None:
    plant = SOPDT[0]
    w = 0.3
    expected = 1.3 * np.exp(-3j * w) / ((40j * w + 1) * (8j * w + 1))
    np.testing.assert_allclose(plant.frequency_response(np.array([w]))[0], expected,
                               rtol=IDENTITY_RTOL, atol=0.0)
