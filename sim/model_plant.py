"""ModelPlant: a plant that runs an identified HammersteinModel's own difference equation.

Notation
--------
Deviation variables about the model's operating point ``(s_nom, P_nom)``:
``ds = s - s_nom`` [%], ``w = f(ds)`` [kW-equivalent], ``y = P - P_nom`` [kW]. The model
(docs/reference/model_file.rst; paper eq. 30 for ARMAX, eq. 27 for OE with ``C = A``) is::

    A(q) y_k = B(q) w_k + C(q) e_k,        e_k ~ N(0, noise_std_kw^2) white

The plant splits ``y = y_det + v`` exactly: ``A y_det = B w`` gives the true power,
``A v = C e`` the noise, and their sum satisfies the model's equation, so the model's
one-step predictor on the plant's data returns the injected ``e``. ``step(s_k)``
applies ``s_k`` over ``[t_k, t_{k+1})`` and returns the power measured at ``t_{k+1}``
(causal: the input delay ``nk >= 1``).

Approximations:

* **Negative power.** ``f`` predicts negative power near ``s = 0``: the true power is
  clamped at 0 kW (the output only, not the model's state).
* **Grid voltage.** The absolute noise-free power is multiplied by
  ``grid_voltage_factor^2`` at that sample; the voltage does not enter the dynamics
  (no sag after a voltage change).
* **Power offset.** ``power_offset_kw`` is added after the voltage scaling (a level
  shift such as the paper's +0.15 kW grid event, sec. 5.2).
* **Actuator.** Inputs are saturated to ``triac_limits_pct`` (default 0..100 %).
"""

from __future__ import annotations

import math
from operator import mul

import numpy as np

from sim.errors import PlantError
from sim.protocols import NOMINAL, Exogenous
from sim.scenario import Scenario
from sysid.model import HammersteinModel

#: Standard normals per refill of the noise buffer (fixed: runs reproduce bit for bit).
NOISE_BLOCK_STEPS = 4096


def steady_state_triac_pct(
    model: HammersteinModel,
    power_kw: float,
    *,
    triac_limits_pct: tuple[float, float] = (0.0, 100.0),
) -> float:
    """Return the TRIAC input [%] whose steady-state power is ``power_kw`` [kW].

    Solves ``P_nom + B(1)/A(1) f(s - s_nom) = power_kw`` for ``s`` inside
    ``triac_limits_pct``; of several roots the one closest to ``s_nom`` (the monotone
    branch of ``f`` around the operating point) is returned.

    Parameters
    ----------
    model :
        The model whose steady state is used.
    power_kw :
        Desired steady-state power [kW].
    triac_limits_pct :
        Range the answer must lie in [%].

    Raises
    ------
    PlantError
        No input in ``triac_limits_pct`` gives ``power_kw`` in steady state.
    """
    gain = model.linear_static_gain
    s_nom = model.operating_point.triac_pct
    target = (power_kw - model.operating_point.power_kw) / gain if gain != 0 else math.nan
    # f(ds) - target = 0, coefficients in descending powers of ds
    coeffs = [*model.input_poly[::-1].tolist(), -target]
    lo, hi = triac_limits_pct
    candidates = []
    if math.isfinite(target):
        for root in np.roots(coeffs):
            if abs(root.imag) <= 1e-9 * max(1.0, abs(root.real)):
                s = float(root.real) + s_nom
                if lo - 1e-9 <= s <= hi + 1e-9:
                    candidates.append(min(max(s, lo), hi))
    if not candidates:
        raise PlantError(f"steady_state_triac_pct: expected a power the model reaches in steady state with "
                         f"{lo:g}..{hi:g} % TRIAC input; got {power_kw:g} kW")
    return min(candidates, key=lambda s: abs(s - s_nom))


class ModelPlant:
    """A plant driven by an identified `HammersteinModel` (the model as the true process).

    Parameters
    ----------
    model :
        The model; its input delay must be at least one sample.
    noise :
        Inject the model's innovations ``e ~ N(0, noise_std_kw^2)`` through its noise
        model ``C/A`` (True), or run the noise-free plant (False).
    initial_triac_pct :
        The plant starts in steady state at this TRIAC input [%]; None: the model's
        operating point.
    triac_limits_pct :
        Physical range of the TRIAC input [%]; inputs are saturated to it.

    Raises
    ------
    PlantError
        A model without input delay, an initial input outside ``triac_limits_pct``, or
        inverted limits.

    Examples
    --------
    >>> from sysid.model import HammersteinModel, OperatingPoint
    >>> m = HammersteinModel(kind="hammerstein", linear_block="oe", ts_s=2.0,
    ...     operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
    ...     a=[1.0, -0.99], b=[0.0, 1.0, -0.991], c=[1.0, -0.99],
    ...     input_poly=[1.35, -0.0065], noise_std_kw=0.0134, input_range_pct=(10.0, 70.0))
    >>> plant = ModelPlant(m, noise=False)
    >>> plant.reset(0)
    45.0
    >>> round(plant.step(50.0), 4)     # the instantaneous response f(5) = 6.5875 kW
    51.5875
    """

    def __init__(
        self,
        model: HammersteinModel,
        *,
        noise: bool = True,
        initial_triac_pct: float | None = None,
        triac_limits_pct: tuple[float, float] = (0.0, 100.0),
    ) -> None:
        if model.delay_steps < 1:
            raise PlantError("ModelPlant: expected a model with an input delay of at least 1 sample "
                             f"(B(q) starting with 0); got delay {model.delay_steps}")
        lo, hi = (float(v) for v in triac_limits_pct)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise PlantError(
                f"ModelPlant.triac_limits_pct: expected finite min < max [%]; got {triac_limits_pct!r}")
        op = model.operating_point
        s0 = op.triac_pct if initial_triac_pct is None else float(initial_triac_pct)
        if not (math.isfinite(s0) and lo <= s0 <= hi):
            raise PlantError(f"ModelPlant.initial_triac_pct: expected a number in {lo:g}..{hi:g} %; "
                             f"got {initial_triac_pct!r}")
        self._use(model)
        self.ts_s = model.ts_s
        self.noise = bool(noise)
        self.initial_triac_pct = s0
        self.triac_limits_pct = (lo, hi)
        self._s_nom = op.triac_pct
        self._p_nom = op.power_kw
        self._sigma = model.noise_std_kw if self.noise else 0.0
        self._rng: np.random.Generator | None = None
        self._z: list[float] = []
        self._iz = 0
        self._true_kw = math.nan
        self._voltage = 1.0
        self._e = 0.0
        self._y: list[float] = []
        self._w: list[float] = []
        self._v: list[float] = []
        self._eh: list[float] = []

    @classmethod
    def for_scenario(cls, model: HammersteinModel, scenario: Scenario) -> ModelPlant:
        """Build the plant a scenario recommends: its noise setting and initial state.

        Parameters
        ----------
        model :
            The model to run as the plant.
        scenario :
            Supplies ``plant_noise`` and ``initial_triac_pct`` (None: the input whose
            steady-state power is ``initial_setpoint_kw``); its ``ts_s`` must match.

        Raises
        ------
        SamplingTimeError
            The scenario's sampling time differs from the model's.
        PlantError
            The initial setpoint is not reachable in steady state.
        """
        model.check_ts(scenario.ts_s, what=f"scenario '{scenario.name}'")
        s0 = scenario.initial_triac_pct
        if s0 is None:
            s0 = steady_state_triac_pct(model, scenario.initial_setpoint_kw)
        return cls(model, noise=scenario.plant_noise, initial_triac_pct=s0)

    def set_model(self, model: HammersteinModel) -> None:
        """Run on with another model's coefficients, keeping the plant's state (a drift).

        Parameters
        ----------
        model :
            Same sampling time, operating point, delay and polynomial lengths (the
            histories carry over), e.g. from `sim.perturbed.perturb_model`.

        Raises
        ------
        PlantError
            A model of another shape.
        """
        old = self.model
        same = (model.ts_s == old.ts_s and model.operating_point == old.operating_point
                and model.delay_steps == old.delay_steps and len(model.a) == len(old.a)
                and len(model.b) == len(old.b) and len(model.c) == len(old.c)
                and len(model.input_poly) == len(old.input_poly))
        if not same:
            raise PlantError(
                "ModelPlant.set_model: expected a model with the same Ts, operating point, delay "
                f"and polynomial lengths; got A {len(model.a)}, B {len(model.b)}, C "
                f"{len(model.c)} coefficients, delay {model.delay_steps} for A {len(old.a)}, "
                f"B {len(old.b)}, C {len(old.c)}, delay {old.delay_steps}")
        self._use(model)

    def _use(self, model: HammersteinModel) -> None:
        self.model = model
        self._neg_a = tuple(-float(v) for v in model.a[1:])      # -a_1 .. -a_na
        self._b = tuple(float(v) for v in model.b[1:])            # b_1 .. b_nb (b_0 = 0)
        self._c = tuple(float(v) for v in model.c[1:])            # c_1 .. c_nc
        self._poly_desc = tuple(float(v) for v in model.input_poly[::-1])  # p_n .. p_1

    def _f(self, ds_pct: float) -> float:
        out = 0.0
        for coef in self._poly_desc:
            out = (out + coef) * ds_pct
        return out

    def _draw(self) -> float:
        if self._iz >= len(self._z):
            if self._rng is None:
                raise PlantError("ModelPlant.step: call reset(rng) before the first step")
            self._z = self._rng.standard_normal(NOISE_BLOCK_STEPS).tolist()
            self._iz = 0
        z = self._z[self._iz]
        self._iz += 1
        return self._sigma * z

    def _output(self, y_det: float, v: float, exogenous: Exogenous) -> float:
        p_model = self._p_nom + y_det
        if p_model < 0.0:
            p_model = 0.0
        factor = self._voltage = exogenous.grid_voltage_factor
        true_kw = factor * factor * p_model + exogenous.power_offset_kw
        if true_kw < 0.0:
            true_kw = 0.0
        self._true_kw = true_kw
        return true_kw + v

    def reset(self, rng: np.random.Generator | int | None = None) -> float:
        """Start a new run in steady state at ``initial_triac_pct``.

        Parameters
        ----------
        rng :
            Seed or generator of the noise stream (unused when ``noise`` is False).

        Returns
        -------
        float
            The first measured power [kW] (steady-state power plus ``e_0``).
        """
        self._rng = np.random.default_rng(rng)
        self._z, self._iz = [], 0
        w_ss = self._f(self.initial_triac_pct - self._s_nom)
        y_ss = self.model.linear_static_gain * w_ss
        self._y = [y_ss] * len(self._neg_a)
        self._w = [w_ss] * len(self._b)
        e0 = self._draw() if self.noise else 0.0
        self._e = e0
        self._v = [0.0] * len(self._neg_a)
        self._eh = [0.0] * len(self._c)
        if self._v:
            self._v[0] = e0
        if self._eh:
            self._eh[0] = e0
        return self._output(y_ss, e0, NOMINAL)

    def step(self, triac_pct: float, exogenous: Exogenous = NOMINAL) -> float:
        """Apply ``triac_pct`` for one sample under ``exogenous``; return the next measured power.

        Parameters
        ----------
        triac_pct :
            TRIAC input [%] held over this sample; saturated to ``triac_limits_pct``.
        exogenous :
            Grid voltage factor and power offset acting on the returned sample.

        Returns
        -------
        float
            Measured power [kW] at the next sample: true power plus the noise ``v``.

        Raises
        ------
        PlantError
            A non-finite input, or no `reset` yet.
        """
        if not math.isfinite(triac_pct):
            raise PlantError(f"ModelPlant.step: expected a finite triac_pct [%]; got {triac_pct!r}")
        if self._rng is None:
            raise PlantError("ModelPlant.step: call reset(rng) before the first step")
        lo, hi = self.triac_limits_pct
        s = lo if triac_pct < lo else hi if triac_pct > hi else triac_pct
        # w_k enters y_{k+1} through b_1 (delay >= 1): shift the input history first
        w_hist = self._w
        w_hist.insert(0, self._f(s - self._s_nom))
        w_hist.pop()
        y_hist = self._y
        y_det = sum(map(mul, self._neg_a, y_hist)) + sum(map(mul, self._b, w_hist))
        if y_hist:
            y_hist.insert(0, y_det)
            y_hist.pop()
        if self.noise:
            e = self._draw()
            v_hist = self._v
            v = sum(map(mul, self._neg_a, v_hist)) + e + sum(map(mul, self._c, self._eh))
            if v_hist:
                v_hist.insert(0, v)
                v_hist.pop()
            if self._eh:
                self._eh.insert(0, e)
                self._eh.pop()
            self._e = e
        else:
            v = 0.0
        return self._output(y_det, v, exogenous)

    @property
    def true_power_kw(self) -> float:
        """Noise-free heater power [kW] at the latest sample (after exogenous effects)."""
        return self._true_kw

    @property
    def grid_voltage_factor(self) -> float:
        """Grid voltage relative to nominal [-] of the latest sample (1 after `reset`)."""
        return self._voltage

    @property
    def innovation_kw(self) -> float:
        """The innovation ``e`` [kW] injected at the latest sample (0 without noise)."""
        return self._e


__all__ = ["NOISE_BLOCK_STEPS", "ModelPlant", "steady_state_triac_pct"]
