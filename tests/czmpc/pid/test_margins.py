"""czmpc.pid.margins against MATLAB's documented example and python-control's stability_margins."""

from __future__ import annotations

import math

import numpy as np
import pytest

from czmpc.pid.design import closed_loop_stable
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.margins import loop_margins, sampled_margins
from czmpc.pid.plant import local_plant
from czmpc.pid.rules import PIDTuning
from sysid.model import HammersteinModel
from tests.tolerances import MARGIN_REFERENCE_RTOL


def test_reproduces_matlabs_pidtune_example() -> None:
    # MATLAB's documentation (pidtune / margin): PI Kp = 1.14, Ki = 0.454 on 1/(s + 1)^3 has
    # its gain crossover at 0.5205 rad/s and a phase margin of 60.0 deg
    def loop(w: np.ndarray) -> np.ndarray:
        s = 1j * w
        return (1.14 + 0.454 / s) / (s + 1) ** 3

    m = loop_margins(loop, w_min_rad_per_s=1e-3, w_max_rad_per_s=1e2)
    assert m.crossover_rad_per_s == pytest.approx(0.5205, rel=MARGIN_REFERENCE_RTOL)
    assert m.phase_margin_deg == pytest.approx(60.0, rel=MARGIN_REFERENCE_RTOL)
    # analytic checks of the same loop: |L(j wc)| = 1 and the phase crossover's Im L = 0
    assert abs(loop(np.array([m.crossover_rad_per_s]))[0]) == pytest.approx(1.0, rel=1e-9)
    assert loop(np.array([m.phase_crossover_rad_per_s]))[0].imag == pytest.approx(0.0, abs=1e-9)


def _discrete_loop_tf(tuning: PIDTuning, model: HammersteinModel, s_pct: float):  # type: ignore[no-untyped-def]
    """L(z) = C(z) g B/A as a python-control transfer function (written from the law)."""
    control = pytest.importorskip("control")
    ts = model.ts_s
    g = float(np.polynomial.polynomial.polyval(
        s_pct - model.operating_point.triac_pct,
        np.polynomial.polynomial.polyder(np.concatenate([[0.0], model.input_poly]))))
    # forward-Euler PI: C = Kc [1 + (Ts/Ti) z^-1 / (1 - z^-1)] = Kc [(1 - z^-1) + r z^-1]/(1 - z^-1)
    r = ts / tuning.ti_s
    c_num = tuning.kc_pct_per_kw * np.array([1.0, r - 1.0])
    c_den = np.array([1.0, -1.0])
    num = np.convolve(c_num, g * np.asarray(model.b))
    den = np.convolve(c_den, np.asarray(model.a))
    n = max(num.size, den.size)  # polynomials in z^-1 -> descending powers of z
    return control.tf(np.pad(num, (0, n - num.size)), np.pad(den, (0, n - den.size)), ts)


@pytest.mark.parametrize("s_pct, tuning", [
    (45.0, PIDTuning(kc_pct_per_kw=0.15, ti_s=1.0)),
    (30.0, PIDTuning(kc_pct_per_kw=0.42, ti_s=1.8)),
    (65.0, PIDTuning(kc_pct_per_kw=0.3, ti_s=6.0)),
], ids=["simc-45", "ms-30", "slow-65"])
def test_sampled_margins_agree_with_python_control(
    paper_armax_model: HammersteinModel, s_pct: float, tuning: PIDTuning,
) -> None:
    control = pytest.importorskip("control")
    gms, pms, sms, wpcs, wgcs, wmss = control.stability_margins(
        _discrete_loop_tf(tuning, paper_armax_model, s_pct), returnall=True)
    # python-control lists w = 0 as a phase crossover (the integrator's pole at z = 1 makes
    # L infinite there, "gain margin" ~1e-14); the crossings that are one are at w > 0
    real = [(g, w) for g, w in zip(gms, wpcs, strict=True) if w > 0]
    gm, wpc = min(real) if real else (math.inf, math.nan)
    (pm,), (wgc,), sm = pms, wgcs, min(sms)
    ours = sampled_margins(tuning, local_plant(paper_armax_model, s_pct))
    rtol = MARGIN_REFERENCE_RTOL
    assert ours.phase_margin_deg == pytest.approx(pm, rel=rtol)
    assert ours.crossover_rad_per_s == pytest.approx(wgc, rel=rtol)
    assert 1.0 / ours.ms == pytest.approx(sm, rel=rtol)
    plant = local_plant(paper_armax_model, s_pct)
    if math.isfinite(gm):
        assert ours.gain_margin == pytest.approx(gm, rel=rtol)
        assert ours.phase_crossover_rad_per_s == pytest.approx(wpc, rel=rtol)
    else:
        # python-control does not count z = -1 (the Nyquist frequency, where L is real) as
        # a phase crossover; the closed loop says it is one: stable just below the margin,
        # unstable just above
        assert ours.phase_crossover_rad_per_s == pytest.approx(math.pi / plant.ts_s, rel=1e-12)
    assert closed_loop_stable(tuning.scaled(ours.gain_margin * (1 - rtol)), plant)
    assert not closed_loop_stable(tuning.scaled(ours.gain_margin * (1 + rtol)), plant)


def test_a_loop_that_never_crosses_has_infinite_gain_margin_and_no_phase_margin() -> None:
    m = loop_margins(lambda w: 0.5 / (1j * w + 1), w_min_rad_per_s=1e-3, w_max_rad_per_s=1e3)
    assert m.gain_margin == math.inf and math.isnan(m.phase_margin_deg)
    # |S| = |1 + jw| / |1.5 + jw| rises from 2/3 to 1 as w grows: its peak is at the top end
    assert m.ms == pytest.approx(abs((1 + 1e3j) / (1.5 + 1e3j)), rel=1e-9)
    with pytest.raises(PIDTuningError, match="expected 0 < w_min < w_max"):
        loop_margins(lambda w: w, w_min_rad_per_s=1.0, w_max_rad_per_s=0.5)
