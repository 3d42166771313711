"""Simulation and one-step prediction against lfilter and explicit recursions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter, lfiltic

from sysid.data import Dataset
from sysid.errors import SamplingTimeError
from sysid.model import HammersteinModel
from sysid.simulate import (
    equation_errors,
    filter_state,
    predict_one_step,
    predict_one_step_arrays,
    prediction_errors_arrays,
    simulate,
    simulate_arrays,
)

#: simulate and a test-side lfilter with the same initial state do the same arithmetic.
LFILTER_ATOL_KW = 1e-12
#: A direct-form Python recursion rounds differently from lfilter's transposed form; with
#: a pole at 0.99 rounding accumulates over ~100 samples: 1e-10 kW on outputs of ~30 kW.
RECURSION_ATOL_KW = 1e-10


def _record(rng: np.random.Generator, n: int = 1500, start_pct: float = 45.0) -> Dataset:
    levels = np.concatenate([[start_pct], rng.uniform(20.0, 70.0, n // 100)])
    triac = np.repeat(levels, 100)[:n]
    power = 45.0 + 0.3 * rng.standard_normal(n) + 1.2 * (triac - 45.0)
    return Dataset(time_s=2.0 * np.arange(n), triac_pct=triac, power_kw=power, ts_s=2.0)


def _held_recursion_sim(
    a: np.ndarray, b: np.ndarray, u: np.ndarray, y0: float
) -> np.ndarray:
    """A yhat = B u, sample by sample; yhat_{k<0} = y0, u_{k<0} = u[0]."""
    n = u.size
    yhat = np.empty(n)
    for k in range(n):
        acc = 0.0
        for j, bj in enumerate(b):
            acc += bj * (u[k - j] if k - j >= 0 else u[0])
        for i in range(1, a.size):
            acc -= a[i] * (yhat[k - i] if k - i >= 0 else y0)
        yhat[k] = acc
    return yhat


def _held_recursion_errors(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, y: np.ndarray, u: np.ndarray,
    e_past: np.ndarray,
) -> np.ndarray:
    """C e = A y - B u, sample by sample; y, u held before k = 0, e_{-j} = e_past[j-1]."""
    n = y.size
    e = np.empty(n)
    for k in range(n):
        acc = 0.0
        for i, ai in enumerate(a):
            acc += ai * (y[k - i] if k - i >= 0 else y[0])
        for j, bj in enumerate(b):
            acc -= bj * (u[k - j] if k - j >= 0 else u[0])
        for i in range(1, c.size):
            acc -= c[i] * (e[k - i] if k - i >= 0 else e_past[i - k - 1])
        e[k] = acc
    return e


def test_simulate_equals_lfilter_with_held_initial_state(
    paper_oe_model: HammersteinModel, rng: np.random.Generator
) -> None:
    data = _record(rng)
    op = paper_oe_model.operating_point
    w = paper_oe_model.input_nonlinearity(data.triac_pct - op.triac_pct)
    dp0 = data.power_kw[0] - op.power_kw
    zi = lfiltic(paper_oe_model.b, paper_oe_model.a, [dp0], [w[0], w[0]])
    expected = op.power_kw + lfilter(paper_oe_model.b, paper_oe_model.a, w, zi=zi)[0]
    np.testing.assert_allclose(
        simulate(paper_oe_model, data), expected, rtol=0, atol=LFILTER_ATOL_KW
    )
    np.testing.assert_allclose(
        simulate(paper_oe_model, data) - op.power_kw,
        _held_recursion_sim(paper_oe_model.a, paper_oe_model.b, w, dp0),
        rtol=0, atol=RECURSION_ATOL_KW,
    )


def test_simulate_from_rest_has_no_start_up_transient(paper_oe_model: HammersteinModel) -> None:
    # Constant input and the output at the model's steady state: the simulation must stay
    # there (a zero-started filter would rise from 0 over ~100 samples instead).
    n = 50
    triac = np.full(n, 55.0)
    power = np.full(n, float(paper_oe_model.steady_state_power_kw(55.0)))
    data = Dataset(time_s=2.0 * np.arange(n), triac_pct=triac, power_kw=power, ts_s=2.0)
    np.testing.assert_allclose(simulate(paper_oe_model, data), power, rtol=0, atol=1e-11)


def test_armax_one_step_prediction_equals_explicit_predictor(
    paper_armax_model: HammersteinModel, rng: np.random.Generator
) -> None:
    data = _record(rng)
    m = paper_armax_model
    op = m.operating_point
    y = data.power_kw - op.power_kw
    w = m.input_nonlinearity(data.triac_pct - op.triac_pct)
    e = _held_recursion_errors(m.a, m.b, m.c, y, w, np.zeros(1))
    np.testing.assert_allclose(
        predict_one_step(m, data), data.power_kw - e, rtol=0, atol=RECURSION_ATOL_KW
    )


def test_prediction_errors_take_explicit_past_errors(rng: np.random.Generator) -> None:
    a, b, c = np.array([1.0, -0.9, 0.1]), np.array([0.0, 1.0, 0.4]), np.array([1.0, -0.5, 0.2])
    y, u = rng.standard_normal(300), rng.standard_normal(300)
    e_past = np.array([0.3, -0.7])
    np.testing.assert_allclose(
        prediction_errors_arrays(a, b, c, y, u, e_past=e_past),
        _held_recursion_errors(a, b, c, y, u, e_past), rtol=0, atol=1e-12,
    )
    np.testing.assert_allclose(
        predict_one_step_arrays(a, b, c, y, u),
        y - _held_recursion_errors(a, b, c, y, u, np.zeros(2)), rtol=0, atol=1e-12,
    )


def test_oe_prediction_is_the_simulation(
    paper_oe_model: HammersteinModel, rng: np.random.Generator
) -> None:
    data = _record(rng)
    np.testing.assert_array_equal(predict_one_step(paper_oe_model, data),
                                  simulate(paper_oe_model, data))
    # ... and the general predictor with C = A gives the same up to rounding.
    op = paper_oe_model.operating_point
    w = paper_oe_model.input_nonlinearity(data.triac_pct - op.triac_pct)
    general = op.power_kw + predict_one_step_arrays(
        paper_oe_model.a, paper_oe_model.b, paper_oe_model.a, data.power_kw - op.power_kw, w
    )
    np.testing.assert_allclose(general, simulate(paper_oe_model, data), rtol=0, atol=1e-9)


def test_arx_prediction_uses_c_equal_one(
    paper_oe_model: HammersteinModel, rng: np.random.Generator
) -> None:
    arx = paper_oe_model.with_updates(linear_block="arx", c=[1.0])
    data = _record(rng)
    op = arx.operating_point
    y = data.power_kw - op.power_kw
    w = arx.input_nonlinearity(data.triac_pct - op.triac_pct)
    y_prev = np.concatenate([[y[0]], y[:-1]])
    w1 = np.concatenate([[w[0]], w[:-1]])
    w2 = np.concatenate([[w[0], w[0]], w[:-2]])
    expected = op.power_kw - arx.a[1] * y_prev + arx.b[1] * w1 + arx.b[2] * w2
    np.testing.assert_allclose(predict_one_step(arx, data), expected, rtol=0, atol=1e-12)


def test_simulate_arrays_accepts_explicit_past_outputs(rng: np.random.Generator) -> None:
    b, f = np.array([0.0, 0.5, 0.2]), np.array([1.0, -1.2, 0.5])
    u = rng.standard_normal(200)
    zi = lfiltic(b, f, [2.0, -1.0], [u[0], u[0]])
    np.testing.assert_allclose(
        simulate_arrays(b, f, u, y_past=np.array([2.0, -1.0])),
        lfilter(b, f, u, zi=zi)[0], rtol=0, atol=1e-14,
    )


@pytest.mark.parametrize("fn", [simulate, predict_one_step], ids=["simulate", "predict"])
def test_mismatched_sampling_time_is_refused(
    fn: object, paper_armax_model: HammersteinModel, rng: np.random.Generator
) -> None:
    data = _record(rng)
    data_1s = Dataset(time_s=data.time_s / 2.0, triac_pct=data.triac_pct,
                      power_kw=data.power_kw, ts_s=1.0)
    with pytest.raises(SamplingTimeError, match="sampling time 1.0 s but the model has 2.0 s"):
        fn(paper_armax_model, data_1s)  # type: ignore[operator]


#: Convolution and lfilter sum the same few products in another order.
FIR_ATOL = 1e-12


@pytest.mark.parametrize(("a", "b"), [([1.0], [0.0, 1.0]), ([1.0, -1.5, 0.7], [0.0, 0.0, 1.0, 0.3]),
                                      ([1.0, -0.9], [2.0])])
def test_equation_errors_equal_lfilter_with_the_held_past(
    rng: np.random.Generator, a: list[float], b: list[float],
) -> None:
    y = 3.0 + rng.standard_normal(300)
    u = -2.0 + rng.standard_normal(300)
    zy = lfiltic(a, [1.0], [], np.full(len(a) - 1, y[0]))
    zu = lfiltic(b, [1.0], [], np.full(len(b) - 1, u[0]))
    ref = lfilter(a, [1.0], y, zi=zy)[0] - lfilter(b, [1.0], u, zi=zu)[0]
    np.testing.assert_allclose(equation_errors(np.array(a), np.array(b), y, u), ref,
                               rtol=0, atol=FIR_ATOL)


@pytest.mark.parametrize(("b", "a", "y_past", "x_past"), [
    ([0.0, 1.2, 0.3], [1.0, -0.9], [1.5], [2.0, 2.0]),
    ([1.0], [1.0, -1.5, 0.7], [0.4, -0.2], None),
    ([0.5, 0.1, 0.0, 0.2], [2.0, -1.0], [1.0, 9.0], [1.0]),   # a0 != 1, pasts too long/short
    ([1.0, 0.4], [1.0], [], [3.0]),
])
def test_filter_state_equals_lfiltic(b: list[float], a: list[float], y_past: list[float],
                                     x_past: list[float] | None) -> None:
    np.testing.assert_allclose(
        filter_state(np.array(b), np.array(a), np.array(y_past),
                     None if x_past is None else np.array(x_past)),
        lfiltic(b, a, y_past, x_past), rtol=0, atol=FIR_ATOL)
