"""Perturbed plants: gain, slow time constant and delay move exactly as documented."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.signal import lfilter

from sim.errors import PlantError
from sim.model_plant import ModelPlant
from sim.perturbed import perturb_model, scale_slow_time_constant, slow_pole
from sysid.model import HammersteinModel, OperatingPoint
from tests.tolerances import IDENTITY_RTOL

TS_S = 2.0


def _model(a: list[float], b: list[float], *, block: str = "armax",
           c: list[float] | None = None) -> HammersteinModel:
    return HammersteinModel(
        kind="hammerstein", linear_block=block,  # type: ignore[arg-type]
        ts_s=TS_S, operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
        a=a, b=b, c=(a if block == "oe" else (c or [1.0, -0.9])),
        input_poly=[1.35, -0.0065], noise_std_kw=0.0134, input_range_pct=(20.0, 70.0),
    )


def _step_response(model: HammersteinModel, n: int, ds_pct: float = 5.0) -> np.ndarray:
    """Noise-free ModelPlant power deviations after an input step of ``ds_pct`` at k = 0."""
    plant = ModelPlant(model, noise=False)
    p0 = plant.reset(0)
    s = model.operating_point.triac_pct + ds_pct
    return np.array([plant.step(s) for _ in range(n)]) - p0


def test_default_arguments_return_the_same_coefficients(paper_armax_model: HammersteinModel) -> None:
    p = perturb_model(paper_armax_model)
    for name in ("a", "b", "c", "input_poly"):
        np.testing.assert_array_equal(getattr(p, name), getattr(paper_armax_model, name))


def test_first_order_pole_follows_the_time_constant_formula(paper_oe_model: HammersteinModel) -> None:
    a1 = paper_oe_model.a[1]
    tau_s = -TS_S / math.log(-a1)
    for factor in (0.5, 0.8, 1.5, 2.0):
        p = perturb_model(paper_oe_model, time_constant_factor=factor)
        # independent: a1' = -exp(-Ts / tau'), tau' = factor * tau
        assert_allclose(p.a[1], -math.exp(-TS_S / (factor * tau_s)), rtol=IDENTITY_RTOL, atol=0,
                        err_msg="closed form of the first-order pole; only rounding differs")
        assert_allclose(-TS_S / math.log(-p.a[1]), factor * tau_s, rtol=1e-9, atol=0,
                        err_msg="tau recovered from a1' (log of a number near 1 loses digits)")


@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_time_constant_holds_instant_response_static_gain_and_scales_the_sag(
    paper_armax_model: HammersteinModel, factor: float
) -> None:
    m = paper_armax_model
    p = perturb_model(m, time_constant_factor=factor)
    assert p.b[1] == 1.0 and p.delay_steps == m.delay_steps
    assert_allclose(p.linear_static_gain, m.linear_static_gain, rtol=1e-12, atol=0,
                    err_msg="B(1)/A(1) is held by construction; rounding of A'(1) only")
    np.testing.assert_array_equal(p.c, m.c)          # ARMAX keeps its noise zeros
    # independent reference: lfilter of B'/A' applied to w = f(5 %) from k = 0
    n = 4000
    w = np.full(n + 1, float(m.input_nonlinearity(5.0)))
    y_ref = lfilter(p.b, p.a, w)[1:]          # the plant returns the power one sample later
    y = _step_response(p, n)
    assert_allclose(y, y_ref, rtol=1e-9, atol=1e-9,
                    err_msg="plant recursion vs lfilter, rounding only")
    assert_allclose(y[0], w[0], rtol=1e-12, atol=0, err_msg="instantaneous jump f(ds) is held")
    y_ss = m.linear_static_gain * w[0]
    # the sag decays as p'^k: successive distances to the steady state shrink by p'
    ratios = (y[11:200] - y_ss) / (y[10:199] - y_ss)
    assert_allclose(ratios, -p.a[1], rtol=1e-7, atol=0,
                    err_msg="pure first-order decay; the distance to y_ss stays >> rounding")


def test_second_order_moves_only_the_slow_root() -> None:
    a = np.polymul([1.0, -0.99], [1.0, -0.5])     # poles 0.99 (slow) and 0.5
    m = _model(a.tolist(), [0.0, 1.0, -0.7, -0.285])
    pole, tau_s = slow_pole(m.a, ts_s=TS_S)
    assert_allclose(pole, 0.99, rtol=1e-12, atol=0, err_msg="numpy roots of an exact product")
    p = perturb_model(m, time_constant_factor=2.0)
    roots = np.sort(np.roots(p.a).real)
    assert_allclose(roots, [0.5, math.exp(-TS_S / (2.0 * tau_s))], rtol=1e-10, atol=0,
                    err_msg="deflate/multiply of exact roots, rounding only")
    assert_allclose(p.linear_static_gain, m.linear_static_gain, rtol=1e-12, atol=0,
                    err_msg="static gain held by scaling B's tail")
    tail_ratio = p.b[2:] / m.b[2:]
    assert_allclose(tail_ratio, tail_ratio[0], rtol=1e-12, atol=0,
                    err_msg="one common factor on B's tail")


def test_oe_model_keeps_c_equal_to_the_new_a(paper_oe_model: HammersteinModel) -> None:
    p = perturb_model(paper_oe_model, time_constant_factor=0.5)
    np.testing.assert_array_equal(p.c, p.a)
    assert p.a[1] != paper_oe_model.a[1]


def test_gain_factor_scales_the_whole_response(paper_armax_model: HammersteinModel) -> None:
    nominal = _step_response(paper_armax_model, 300)
    scaled = _step_response(perturb_model(paper_armax_model, gain_factor=0.7), 300)
    assert_allclose(scaled, 0.7 * nominal, rtol=1e-12, atol=1e-12,
                    err_msg="f scaled by 0.7, the linear block is linear")


def test_extra_delay_shifts_the_response_by_whole_samples(paper_armax_model: HammersteinModel) -> None:
    nominal = _step_response(paper_armax_model, 300)
    delayed = _step_response(perturb_model(paper_armax_model, extra_delay_steps=2), 302)
    assert delayed[0] == 0.0 and delayed[1] == 0.0
    assert_allclose(delayed[2:], nominal, rtol=0, atol=1e-12,
                    err_msg="same recursion two samples later; identical arithmetic")


def test_perturbations_are_recorded_in_the_provenance(paper_armax_model: HammersteinModel) -> None:
    p = perturb_model(paper_armax_model, gain_factor=1.3, time_constant_factor=0.5,
                      extra_delay_steps=1)
    assert p.provenance.extra["perturbation"] == {
        "gain_factor": 1.3, "time_constant_factor": 0.5, "extra_delay_steps": 1,
    }


def test_shipped_model_slow_time_constant_is_about_four_minutes(shipped_model: HammersteinModel) -> None:
    _, tau_s = slow_pole(shipped_model.a, ts_s=shipped_model.ts_s)
    assert 200.0 < tau_s < 300.0


@pytest.mark.parametrize(
    ("a", "what"),
    [([1.0, 0.5], "negative real pole"),
     ([1.0, -1.6, 0.8], "complex pair is the slowest")],
)
def test_a_without_a_real_positive_slow_pole_is_refused(a: list[float], what: str) -> None:
    m = _model(a, [0.0, 1.0, -0.5])
    with pytest.raises(PlantError, match="real in \\(0, 1\\)"):
        perturb_model(m, time_constant_factor=2.0)
    assert perturb_model(m, gain_factor=2.0).input_poly[0] == 2.7   # others still work


def test_b_without_a_tail_cannot_hold_the_static_gain() -> None:
    m = _model([1.0, -0.9], [0.0, 1.0])
    with pytest.raises(PlantError, match="static gain"):
        scale_slow_time_constant(m.a, m.b, ts_s=TS_S, factor=2.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"gain_factor": 0.0}, "gain_factor"), ({"gain_factor": math.nan}, "gain_factor"),
     ({"gain_factor": True}, "gain_factor"), ({"time_constant_factor": -1.0}, "time_constant"),
     ({"extra_delay_steps": -1}, "extra_delay"), ({"extra_delay_steps": 1.0}, "extra_delay")],
)
def test_invalid_arguments_raise_plant_error(
    paper_armax_model: HammersteinModel, kwargs: dict[str, object], match: str
) -> None:
    with pytest.raises(PlantError, match=match):
        perturb_model(paper_armax_model, **kwargs)  # type: ignore[arg-type]
