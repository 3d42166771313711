"""Fixed-pole starts of the final Hammerstein-OE fit (`sysid.hammerstein.route`)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.signal import lfilter

from sysid.errors import IdentificationError
from sysid.hammerstein import route, run_hammerstein_route
from sysid.hammerstein.route import _catch_up_watch, fixed_pole_starts, pole_start_time_constants
from sysid.model import OperatingPoint
from sysid.optimize import PROGRESS_WINDOW

#: B is an exact least-squares solution when F is the truth and there is no noise.
EXACT_ATOL = 1e-9


def _record(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    ds = np.repeat(rng.uniform(-10.0, 10.0, n // 40 + 1), 40)[:n]
    return ds, 1.2 * ds - 0.02 * ds**2


def test_time_constants_run_geometrically_from_one_sample_to_a_tenth_of_the_record() -> None:
    taus = pole_start_time_constants(1000, 8)
    np.testing.assert_allclose(taus[[0, -1]], [1.0, 100.0])
    np.testing.assert_allclose(taus[1:] / taus[:-1], 100.0 ** (1 / 7))
    with pytest.raises(IdentificationError, match="n_starts must be an int >= 1; got 0"):
        pole_start_time_constants(1000, 0)


def test_fixed_pole_start_at_the_true_poles_is_the_true_b(rng: np.random.Generator) -> None:
    ds, _ = _record(rng, 800)
    pole = 0.9
    y = lfilter([0.0, 0.0, 0.5, 0.25], np.poly([pole, pole]), ds)
    tau = -1.0 / np.log(pole)
    far, true = fixed_pole_starts(y, ds, nb=2, nf=2, nk=2, time_constants_samples=[2.0, tau])
    assert true.keys() == {"d1", "b3", "f1", "f2"}
    for name, value in {"d1": 0.5, "b3": 0.5, "f1": -1.8, "f2": 0.81}.items():
        assert true[name] == pytest.approx(value, abs=EXACT_ATOL), name
    # a wrong pole gives a B that is not the truth (the start is only a start)
    assert abs(far["d1"] - 0.5) > 0.01
    assert len(fixed_pole_starts(y, ds, nb=2, nf=0, nk=2, time_constants_samples=[2.0, tau])) == 1
    with pytest.raises(IdentificationError, match=r"finite numbers > 0; got \[5.0, -1.0\]"):
        fixed_pole_starts(y, ds, nb=2, nf=2, nk=2, time_constants_samples=[5.0, -1.0])


def test_multistart_keeps_the_routes_own_fit_at_an_equal_minimum_and_finds_the_truth(
    rng: np.random.Generator,
) -> None:
    ds, w = _record(rng, 2400)
    y = lfilter([0.0, 1.0, -0.5], [1.0, -0.9], w) + 0.05 * rng.standard_normal(ds.size)
    op = OperatingPoint(triac_pct=50.0, power_kw=10.0)
    plain = run_hammerstein_route(y, ds, steps=(), operating_point=op, noise_model=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # the losing starts' warnings are not issued
        multi = run_hammerstein_route(y, ds, steps=(), operating_point=op, noise_model=False,
                                      pole_starts=6)
    assert multi.final_oe.n_iterations == plain.final_oe.n_iterations
    assert multi.final_oe.cost == plain.final_oe.cost
    values = multi.final_oe.values()
    # truth: f(ds) = 1.2 ds - 0.02 ds^2, B = q^-1 (1 - 0.5 q^-1), F = 1 - 0.9 q^-1
    assert values["d1"] == pytest.approx(1.2, rel=0.02)
    assert values["d2"] == pytest.approx(-0.02, rel=0.05)
    assert values["b2"] == pytest.approx(-0.5, abs=0.01)
    assert values["f1"] == pytest.approx(-0.9, abs=0.002)


def _watched(costs: list[float], target: float, cap: int = 1000) -> tuple[list[float], int]:
    """Feed ``costs`` as iterations 1, 2, ... to a catch-up watch; return what it passed
    on and the iteration it abandoned at (0: never)."""
    seen: list[float] = []
    watch = _catch_up_watch(target, cap, lambda _, cost: seen.append(cost))
    for k, cost in enumerate(costs, start=1):
        try:
            watch(k, cost)
        except IdentificationError as exc:
            assert f"cannot reach {target:.6g} within {cap} iterations" in str(exc)
            return seen, k
    return seen, 0


def test_a_search_that_cannot_catch_up_is_abandoned_once_its_window_is_full() -> None:
    # the exchanger log at 4x its rate: V 0.2597 falling by about 2.3e-7 per iteration
    # against an incumbent of 0.1906; at 10 times that fall it would need 3e4 iterations
    crawl = [0.2600 - 2.3e-7 * k for k in range(1, 900)]
    seen, at = _watched(crawl, 0.1906)
    assert at == PROGRESS_WINDOW + 1 and seen == crawl[:at]   # the progress still shown
    # the same crawl 0.0001 above the incumbent: at 10 times its fall it would reach it
    # in time (and it does, at iteration 435)
    assert _watched([0.1907 - 2.3e-7 * k for k in range(1, 900)], 0.1906)[1] == 0
    # 0.0005 above: at 10 times its fall it would, until the cap comes too near
    assert _watched([0.1911 - 2.3e-7 * k for k in range(1, 900)], 0.1906)[1] == 870
    # a fast fall is never abandoned, nor a search below the target
    assert _watched([1.0 * 0.99 ** k for k in range(1, 300)], 0.1906)[1] == 0
    assert _watched([0.1 + 1e-12 * (900 - k) for k in range(1, 900)], 0.1906)[1] == 0
    # a new search (iteration 1 again) starts its window afresh: the voltage refits
    watch = _catch_up_watch(0.1906, 1000, None)
    for k in range(1, PROGRESS_WINDOW + 1):
        watch(k, 0.26)
    watch(1, 0.26)            # a full window of the first search would abandon here
    for k in range(2, PROGRESS_WINDOW + 1):
        watch(k, 0.26)
    with pytest.raises(IdentificationError):
        watch(PROGRESS_WINDOW + 1, 0.26)


def test_abandoned_starts_leave_the_multistart_fit_as_it_was(rng: np.random.Generator) -> None:
    ds, w = _record(rng, 2400)
    y = lfilter([0.0, 1.0, -0.5], [1.0, -0.9], w) + 0.05 * rng.standard_normal(ds.size)
    op = OperatingPoint(triac_pct=50.0, power_kw=10.0)
    kept = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(route, "ABANDON_RATE_FACTOR", float("inf"))   # never abandon
        never = run_hammerstein_route(y, ds, steps=(), operating_point=op, noise_model=False,
                                      pole_starts=6, progress=lambda stage, k, v: kept.append(k))
    seen = []
    now = run_hammerstein_route(y, ds, steps=(), operating_point=op, noise_model=False,
                                pole_starts=6, progress=lambda stage, k, v: seen.append(k))
    assert now.final_oe.cost == never.final_oe.cost
    np.testing.assert_array_equal(now.final_oe.parameters, never.final_oe.parameters)
    assert len(seen) < len(kept)
