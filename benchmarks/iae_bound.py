"""Noise-free lower bound on the IAE of any controller over a scenario: an LP over the model.

The value-case benchmark (`benchmarks.value_case`) checks with it that the MPC uses the
setpoint preview well: no controller, whatever it knows, tracks a scenario's setpoints
on the model plant with a smaller IAE than this bound.

The LP
------
Deviation variables about the model's operating point ``(s_nom, P_nom)``: ``w_k =
f(s_k - s_nom)`` [kW-equivalent], the nonlinearity's output the controller chooses at
sample ``k``; ``y_k`` [kW], the linear block's output ``A(q) y = B(q) w`` started in
steady state at the plant's initial input (``w_{k<0} = w_init``, ``y_{k<0} = G w_init``,
``G = B(1)/A(1)``). The plant's true power is ``P_k = g_k (P_nom + y_k) + o_k``, with
``g_k`` and ``o_k`` the scenario's grid-voltage factor squared and power shift acting on
sample ``k`` (`sim.model_plant.ModelPlant`: the exogenous value of step ``k - 1``)::

    minimise    Ts * sum_k t_k                     (k = 0 .. n-1; IAE in kW s)
    subject to  A(q) y = B(q) w                    (equalities, banded: sparse)
                -t_k <= P_k - r_k <= t_k
                f(s_min - s_nom) <= w_k <= f(s_max - s_nom)
                |w_k - w_{k-1}| <= max|f'| * delta  (k >= 0; w_{-1} = f(s_start - s_nom))

``[s_min, s_max]`` is the MPC's allowed TRIAC range (`OffsetFreeMPC.allowed_triac_range_pct`
with the run's settings), on which ``f`` is monotone, so the bounds on ``w`` are exact.
``delta`` is the rate limit [%/step]; the exact constraint ``|s_k - s_{k-1}| <= delta`` is
not linear in ``w``, and ``|f(s) - f(s')| <= max|f'| |s - s'|`` (the maximum over the
allowed range) makes the LP's rate constraint a *relaxation*: every input sequence a
rate-limited controller can apply is feasible, so the optimum stays a lower bound.

What the bound assumes (each makes it lower, never higher, than any real controller's
IAE on the model plant without noise): the whole reference and every disturbance are
known in advance (so it bounds controllers with any finite setpoint preview, and with
measured voltage); the model is the plant exactly; no noise; the plant's clamp of the
power at 0 kW is left out (it never binds on the allowed range of a sound model, whose
power stays far above 0 there). Sensor faults (spikes, missing samples) touch only what a
controller measures, not the true power, and are ignored.

Size: three variables per sample; one equality, two error rows and one row per rate cut
(2 with ``"max_slope"``, ``2 * TANGENT_POINTS`` = 16 with ``"tangents"``), all sparse
(a few nonzeros per row). HiGHS solves the 3,900-sample staircase in 1-3 s with the
max-slope cuts and 6-13 s with the tangents on a shared 2-core machine
(`IAEBound.solve_time_s`; the value-case section records each).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt
from numpy.typing import ArrayLike
from scipy import sparse
from scipy.optimize import linprog

from czmpc.campaigns.build import controller_settings
from czmpc.controller import OffsetFreeMPC
from czmpc.settings import MPCSettings
from sim.disturbances import exogenous_profile
from sim.model_plant import ModelPlant
from sim.scenario import Scenario
from sysid._typing import FloatArray
from sysid.model import HammersteinModel


class BoundError(ValueError):
    """The bound's LP is malformed (bad sizes, bounds, a non-monotone f) or not solved."""


@dataclass(frozen=True, kw_only=True)
class IAEBound:
    """The LP's optimum: the lower bound and the trajectory that attains it.

    Parameters
    ----------
    iae_kw_s :
        The bound: ``Ts * sum |P_k - r_k|`` at the optimum [kW s].
    power_kw :
        Optimal true power ``P_k`` [kW], shape ``(n,)``.
    w_kw :
        Optimal nonlinearity outputs ``w_k`` [kW-equivalent], shape ``(n,)``.
    solve_time_s :
        Wall time of building and solving the LP [s].
    n_variables, n_constraints :
        Size of the LP (equalities and inequalities).
    """

    iae_kw_s: float
    power_kw: FloatArray
    w_kw: FloatArray
    solve_time_s: float
    n_variables: int
    n_constraints: int


@dataclass(frozen=True, slots=True, kw_only=True)
class MoveCut:
    """One linear constraint on consecutive nonlinearity outputs, for every ``k >= 0``.

    ``side="upper"``: ``w_k <= slope * w_{k-1} + intercept_kw``; ``side="lower"``:
    ``w_k >= slope * w_{k-1} + intercept_kw``.

    Parameters
    ----------
    slope :
        Coefficient of ``w_{k-1}`` [-].
    intercept_kw :
        Constant [kW-equivalent].
    side :
        ``"upper"`` or ``"lower"``.
    """

    slope: float
    intercept_kw: float
    side: Literal["upper", "lower"]

    def __post_init__(self) -> None:
        if self.side not in ("upper", "lower"):
            raise BoundError(f"MoveCut.side: expected 'upper' or 'lower'; got {self.side!r}")
        if not (math.isfinite(self.slope) and math.isfinite(self.intercept_kw)):
            raise BoundError(f"MoveCut: expected a finite slope and intercept; got "
                             f"{self.slope!r}, {self.intercept_kw!r}")


def symmetric_move_cuts(max_move_kw: float) -> tuple[MoveCut, MoveCut]:
    """``|w_k - w_{k-1}| <= max_move_kw`` as two `MoveCut`.

    Raises
    ------
    BoundError
        ``max_move_kw`` negative or not finite.
    """
    if not (math.isfinite(max_move_kw) and max_move_kw >= 0):
        raise BoundError(f"symmetric_move_cuts: expected max_move_kw >= 0 [kW]; got {max_move_kw!r}")
    return (MoveCut(slope=1.0, intercept_kw=max_move_kw, side="upper"),
            MoveCut(slope=1.0, intercept_kw=-max_move_kw, side="lower"))


def _coefficients(values: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
        raise BoundError(f"iae_lower_bound: expected {name} as a non-empty 1-D array of finite "
                         f"numbers; got {values!r}")
    return arr


def _per_sample(values: ArrayLike | None, n: int, default: float, name: str) -> FloatArray:
    if values is None:
        return np.full(n, default)
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise BoundError(f"iae_lower_bound: expected {name} of shape ({n},), finite; got shape "
                         f"{arr.shape}")
    return arr


def iae_lower_bound(
    a: ArrayLike,
    b: ArrayLike,
    reference_kw: ArrayLike,
    *,
    ts_s: float,
    base_power_kw: float,
    w_bounds_kw: tuple[float, float] | None,
    move_cuts: Sequence[MoveCut] = (),
    w_initial_kw: float,
    w_previous_kw: float | None = None,
    power_scale: ArrayLike | None = None,
    power_offset_kw: ArrayLike | None = None,
) -> IAEBound:
    """Smallest IAE any input sequence achieves on ``A(q) y = B(q) w`` (module notes).

    Parameters
    ----------
    a :
        ``A(q)``, ascending powers of ``q^-1``, ``a[0] = 1``.
    b :
        ``B(q)``, ascending powers of ``q^-1``, ``b[0] = 0`` (a delay of at least one sample).
    reference_kw :
        Setpoint ``r_k`` [kW], shape ``(n,)``; known to the bound in full.
    ts_s :
        Sampling time [s] (IAE weight per sample).
    base_power_kw :
        ``P_nom`` [kW]: the power at ``y = 0``.
    w_bounds_kw :
        ``(w_min, w_max)`` [kW-equivalent], or None for no bounds.
    move_cuts :
        Linear constraints on consecutive ``w`` (`MoveCut`; `symmetric_move_cuts` for
        ``|w_k - w_{k-1}| <= M``); empty: no rate limit.
    w_initial_kw :
        ``w`` of the steady state the plant starts in (every ``w_{k<0}``).
    w_previous_kw :
        ``w_{-1}`` the first move's rate limit counts from; None: ``w_initial_kw``.
    power_scale, power_offset_kw :
        ``g_k`` [-] and ``o_k`` [kW] of ``P_k = g_k (P_nom + y_k) + o_k``, shape ``(n,)``;
        None: 1 and 0.

    Returns
    -------
    IAEBound
        The bound and its optimal trajectory.

    Raises
    ------
    BoundError
        Malformed coefficients or sizes, ``b[0] != 0``, ``a[0] != 1``, inverted bounds,
        or an LP HiGHS does not solve to optimality (e.g. infeasible cuts).
    """
    t0 = time.perf_counter()
    a_arr, b_arr = _coefficients(a, "a"), _coefficients(b, "b")
    if a_arr[0] != 1.0 or b_arr[0] != 0.0:
        raise BoundError(f"iae_lower_bound: expected a[0] = 1 and b[0] = 0 (a delay of one sample "
                         f"at least); got a[0] = {a_arr[0]!r}, b[0] = {b_arr[0]!r}")
    r = _coefficients(reference_kw, "reference_kw")
    n = r.size
    if not (math.isfinite(ts_s) and ts_s > 0):
        raise BoundError(f"iae_lower_bound: expected ts_s > 0 [s]; got {ts_s!r}")
    if w_bounds_kw is not None and not w_bounds_kw[0] <= w_bounds_kw[1]:
        raise BoundError(f"iae_lower_bound: expected w_bounds_kw (min, max) with min <= max; got "
                         f"{w_bounds_kw!r}")
    g = _per_sample(power_scale, n, 1.0, "power_scale")
    o = _per_sample(power_offset_kw, n, 0.0, "power_offset_kw")
    gain = float(b_arr.sum() / a_arr.sum())
    y_init = gain * w_initial_kw
    w_prev = w_initial_kw if w_previous_kw is None else float(w_previous_kw)

    # x = [w_0..w_{n-1}, y_0..y_{n-1}, t_0..t_{n-1}]
    iw, iy, it = 0, n, 2 * n
    k = np.arange(n)
    rows: list[npt.NDArray[np.intp]] = [k]
    cols: list[npt.NDArray[np.intp]] = [iy + k]
    vals: list[FloatArray] = [np.ones(n)]
    b_eq = np.zeros(n)
    # + a_i y_{k-i} and - b_j w_{k-j}; terms before sample 0 are the steady start, known
    terms = [(iy, i, ai, y_init) for i, ai in enumerate(a_arr[1:], start=1)]
    terms += [(iw, j, -bj, w_initial_kw) for j, bj in enumerate(b_arr[1:], start=1)]
    for offset, lag, coef, before in terms:
        inside = k >= lag
        rows.append(k[inside])
        cols.append(offset + k[inside] - lag)
        vals.append(np.full(int(inside.sum()), coef))
        b_eq[~inside] -= coef * before
    a_eq = sparse.csr_array((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                            shape=(n, 3 * n))

    # g_k y_k - t_k <= r_k - o_k - g_k P_nom and -g_k y_k - t_k <= -(r_k - o_k - g_k P_nom)
    slack = r - o - g * base_power_kw
    eye_t = sparse.eye_array(n, format="csr")
    gy = sparse.diags_array(g, format="csr")
    zeros = sparse.csr_array((n, n))
    blocks = [[zeros, gy, -eye_t], [zeros, -gy, -eye_t]]
    b_ub_parts = [slack, -slack]
    for cut in move_cuts:
        sign = 1.0 if cut.side == "upper" else -1.0   # sign (w_k - slope w_{k-1}) <= sign c
        move = sparse.diags_array([np.full(n, sign), np.full(n - 1, -sign * cut.slope)],
                                  offsets=[0, -1], format="csr")
        blocks.append([move, zeros, zeros])
        rhs = np.full(n, sign * cut.intercept_kw)
        rhs[0] += sign * cut.slope * w_prev
        b_ub_parts.append(rhs)
    a_ub = sparse.block_array(blocks, format="csr")
    b_ub = np.concatenate(b_ub_parts)

    w_lo, w_hi = (None, None) if w_bounds_kw is None else w_bounds_kw
    bounds = [(w_lo, w_hi)] * n + [(None, None)] * n + [(0.0, None)] * n
    c = np.concatenate([np.zeros(2 * n), np.full(n, float(ts_s))])
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq, bounds=bounds, method="highs")
    if res.status != 0 or res.x is None:
        raise BoundError(f"iae_lower_bound: expected HiGHS to solve the LP to optimality; got "
                         f"status {res.status}: {res.message}")
    x = np.asarray(res.x)
    power = g * (base_power_kw + x[iy:it]) + o
    return IAEBound(iae_kw_s=float(res.fun), power_kw=power, w_kw=x[iw:iy],
                    solve_time_s=time.perf_counter() - t0, n_variables=3 * n,
                    n_constraints=a_eq.shape[0] + a_ub.shape[0])


def max_abs_slope(model: HammersteinModel, triac_range_pct: tuple[float, float]) -> float:
    """``max |f'(s - s_nom)|`` over ``triac_range_pct`` [kW/%], exact for any polynomial f.

    The maximum of ``|f'|`` on an interval lies at an end or where ``f''`` vanishes.
    """
    s_nom = model.operating_point.triac_pct
    lo, hi = (v - s_nom for v in triac_range_pct)
    p = np.polynomial.Polynomial(np.concatenate([[0.0], model.input_poly]))
    d1 = p.deriv()
    candidates = [lo, hi]
    if d1.degree() >= 1:
        roots = np.asarray(d1.deriv().roots(), dtype=complex)
        real = roots.real[np.abs(roots.imag) < 1e-12]
        candidates += [float(z) for z in real if lo <= z <= hi]
    return float(max(abs(d1(v)) for v in candidates))


#: Tangent points per side of the tangent relaxation of the rate limit.
TANGENT_POINTS = 8
#: Rate-limit relaxations `rate_limit_cuts` builds.
RateRelaxation = Literal["tangents", "max_slope"]


def rate_limit_cuts(model: HammersteinModel, triac_range_pct: tuple[float, float],
                    max_move_pct: float, *, relaxation: RateRelaxation = "tangents",
                    n_points: int = TANGENT_POINTS) -> tuple[MoveCut, ...]:
    """Linear relaxations in ``w`` of ``|s_k - s_{k-1}| <= max_move_pct`` (module notes).

    ``"max_slope"``: ``|w_k - w_{k-1}| <= max|f'| * delta`` over ``triac_range_pct``.
    ``"tangents"`` (f of degree 2 at most, increasing on the range): the exact set is
    ``f(u - delta) <= w_k <= f(u + delta)`` with ``u = f^-1(w_{k-1})``. For a quadratic
    ``f``, ``h+(w) = f(f^-1(w) + delta)`` is concave in ``w`` (``h+'' = -4 d2^2 delta /
    f'(u)^3 <= 0``) and ``h-(w) = f(f^-1(w) - delta)`` convex, so each lies on one side
    of its tangents; ``n_points`` tangents of each, at inputs spread over the range, are
    implied by the exact limit: a relaxation as tight as the tangents are dense.

    Parameters
    ----------
    model :
        Supplies ``f``.
    triac_range_pct :
        Range the inputs stay in [%].
    max_move_pct :
        ``delta`` [%/step], > 0.
    relaxation :
        ``"tangents"`` or ``"max_slope"``.
    n_points :
        Tangent points per side (``"tangents"``), >= 1.

    Raises
    ------
    BoundError
        ``delta`` not > 0, ``"tangents"`` for an ``f`` of degree above 2, an unknown
        relaxation.
    """
    if not (math.isfinite(max_move_pct) and max_move_pct > 0):
        raise BoundError(f"rate_limit_cuts: expected max_move_pct > 0 [%/step]; got {max_move_pct!r}")
    if relaxation == "max_slope":
        return symmetric_move_cuts(max_abs_slope(model, triac_range_pct) * max_move_pct)
    if relaxation != "tangents":
        raise BoundError(f"rate_limit_cuts: expected relaxation 'tangents' or 'max_slope'; got "
                         f"{relaxation!r}")
    if model.input_degree > 2:
        raise BoundError(f"rate_limit_cuts: the tangent relaxation needs f of degree 2 at most "
                         f"(its h+ is then concave); got degree {model.input_degree}: use "
                         f"'max_slope'")
    if n_points < 1:
        raise BoundError(f"rate_limit_cuts: expected n_points >= 1; got {n_points!r}")
    s_nom = model.operating_point.triac_pct
    u = np.linspace(triac_range_pct[0], triac_range_pct[1], n_points) - s_nom

    def f(v: FloatArray) -> FloatArray:
        return np.asarray(model.input_nonlinearity(v), dtype=float)

    def df(v: FloatArray) -> FloatArray:
        return np.asarray(model.input_nonlinearity_slope(v), dtype=float)

    w = f(u)
    cuts: list[MoveCut] = []
    for side, step in (("upper", max_move_pct), ("lower", -max_move_pct)):
        slope = df(u + step) / df(u)                  # d h(w) / dw at w = f(u)
        intercept = f(u + step) - slope * w
        cuts += [MoveCut(slope=float(a), intercept_kw=float(c), side=side)  # type: ignore[arg-type]
                 for a, c in zip(slope, intercept, strict=True)]
    return tuple(cuts)


def scenario_iae_bound(model: HammersteinModel, scenario: Scenario, *,
                       settings: MPCSettings | None = None,
                       relaxation: RateRelaxation = "tangents") -> IAEBound:
    """The IAE lower bound of ``scenario`` on the model plant of ``model`` (module notes).

    The plant starts where `ModelPlant.for_scenario` starts it (the scenario's
    ``initial_triac_pct``, or the input whose steady state is the initial setpoint); the
    input range, rate limit and first move are those the MPC gets in
    `czmpc.campaigns.simulation.run_simulation` (`controller_settings`).

    Parameters
    ----------
    model :
        The plant's model (and the MPC's).
    scenario :
        Setpoints and disturbances (voltage factors and power shifts, known to the bound).
    settings :
        The MPC's base settings; None: `MPCSettings.default_for` ``(model)``.
    relaxation :
        How the rate limit enters the LP (`rate_limit_cuts`); ``"tangents"`` needs an
        ``f`` of degree 2 at most.

    Raises
    ------
    BoundError
        ``f`` is not increasing over the allowed range, or the LP is not solved.
    """
    model.check_ts(scenario.ts_s, what=f"scenario '{scenario.name}'")
    s0 = ModelPlant.for_scenario(model, scenario).initial_triac_pct
    used = controller_settings(model, scenario, initial_triac_pct=s0, settings=settings)
    allowed = OffsetFreeMPC(model, used).allowed_triac_range_pct
    s_nom = model.operating_point.triac_pct
    grid = np.linspace(allowed[0], allowed[1], 1001) - s_nom
    if np.any(model.input_nonlinearity_slope(grid) <= 0):
        raise BoundError(f"scenario_iae_bound: expected f increasing over the allowed range "
                         f"{allowed[0]:g}..{allowed[1]:g} %; it is not (model {model.input_poly})")

    def f(s: float) -> float:
        return float(model.input_nonlinearity(s - s_nom))

    move = used.max_move_pct_per_step
    start = used.initial_triac_pct if used.initial_triac_pct is not None else s0
    n = scenario.n_steps
    exo = exogenous_profile(scenario.disturbances, n_steps=n, ts_s=scenario.ts_s)
    scale, offset = np.ones(n), np.zeros(n)        # sample k feels step k-1's exogenous value
    scale[1:] = np.square(exo.grid_voltage_factor[:-1])
    offset[1:] = exo.power_offset_kw[:-1]
    return iae_lower_bound(
        model.a, model.b, scenario.setpoint_profile_kw(), ts_s=scenario.ts_s,
        base_power_kw=model.operating_point.power_kw, w_bounds_kw=(f(allowed[0]), f(allowed[1])),
        move_cuts=() if move is None else rate_limit_cuts(model, allowed, move,
                                                          relaxation=relaxation),
        w_initial_kw=f(s0), w_previous_kw=f(start), power_scale=scale, power_offset_kw=offset)


__all__ = ["TANGENT_POINTS", "BoundError", "IAEBound", "MoveCut", "RateRelaxation", "iae_lower_bound",
           "max_abs_slope", "rate_limit_cuts", "scenario_iae_bound", "symmetric_move_cuts"]
