"""How a PID block samples the ISA law: forward, backward or trapezoidal integration, as a transfer function.

A table of ISA parameters ``Kc, Ti, Td, Tf`` is not yet a sampled controller: each block
runs it through its own difference equation, and when ``Ti`` is near the sampling time
``Ts`` those equations are different controllers. The three forms here are the ones
velocity-form blocks use; each is exact as written below, in the notation of
`czmpc.pid.controller` (``e_k = r_k - y_k``, ``p_k = b r_k - y_k``, ``d_k`` the filtered
``-Td dy/dt``, ``r = Ts/Ti``)::

    forward   du_k = Kc [p_k - p_{k-1} + d_k - d_{k-1} + r e_{k-1}]
    backward  du_k = Kc [p_k - p_{k-1} + d_k - d_{k-1} + r e_k]
    tustin    du_k = Kc [p_k - p_{k-1} + d_k - d_{k-1} + r (e_k + e_{k-1})/2]

The derivative filter ``Tf dd/dt + d = -Td dy/dt`` is sampled by backward Euler in the
forward and backward forms (stable for every ``Tf``; `czmpc.pid.controller.ScheduledPID`
runs ``forward``) and by the trapezoidal rule in ``tustin``::

    backward Euler  d_k = (Tf d_{k-1} - Td (y_k - y_{k-1})) / (Tf + Ts)
    trapezoidal     d_k = ((2 Tf - Ts) d_{k-1} - 2 Td (y_k - y_{k-1})) / (2 Tf + Ts)

As transfer functions from ``-y`` to ``u`` (`controller_polynomials`)::

    C(z) = Kc [1 + I(z) + D(z)]
    I(z) = r z^-1/(1 - z^-1),  r/(1 - z^-1),  (r/2)(1 + z^-1)/(1 - z^-1)
    D(z) = Td (1 - z^-1)/(Tf + Ts - Tf z^-1)   or   2 Td (1 - z^-1)/(2 Tf + Ts - (2 Tf - Ts) z^-1)

A *discretization* a table is designed for is one form or ``worst``: all three, every
margin the worst of them. Every form's PI is ``(q0 + q1 z^-1)/(1 - z^-1)`` with the same
integral gain ``q0 + q1 = Kc Ts/Ti``; they differ by ``Kc Ts/(2 Ti)`` at the Nyquist
frequency, which is small for ``Ti >> Ts`` and decides the loop for ``Ti < Ts``.
"""

from __future__ import annotations

from typing import Literal, cast

import numpy as np

from czmpc.pid.errors import PIDTuningError
from czmpc.pid.rules import PIDTuning
from sysid._typing import FloatArray

IntegralForm = Literal["forward", "backward", "tustin"]
Discretization = Literal["forward", "backward", "tustin", "worst"]
#: The sampled forms of the integral (module notes), in report order.
INTEGRAL_FORMS: tuple[IntegralForm, ...] = ("forward", "backward", "tustin")
#: What a table can be designed for: one form, or ``worst`` (all three).
DISCRETIZATIONS: tuple[Discretization, ...] = ("forward", "backward", "tustin", "worst")
#: The discretization a table is designed for unless told otherwise.
DEFAULT_DISCRETIZATION: Discretization = "worst"

#: One line per form: the integral's rule and the derivative filter's.
FORM_DESCRIPTIONS: dict[IntegralForm, str] = {
    "forward": "forward Euler integral du_I = Kc (Ts/Ti) e_{k-1}, derivative filter by "
               "backward Euler (czmpc.pid.ScheduledPID's law)",
    "backward": "backward Euler integral du_I = Kc (Ts/Ti) e_k, derivative filter by "
                "backward Euler",
    "tustin": "trapezoidal integral du_I = Kc (Ts/Ti) (e_k + e_{k-1})/2, derivative filter "
              "by the trapezoidal rule",
}


def checked_discretization(name: str) -> Discretization:
    """``name`` as a `Discretization`, or `PIDTuningError` naming the choices."""
    if name not in DISCRETIZATIONS:
        raise PIDTuningError(
            f"discretization: expected one of {', '.join(DISCRETIZATIONS)}; got {name!r}")
    return name


def forms_of(discretization: Discretization) -> tuple[IntegralForm, ...]:
    """The integral forms a discretization stands for: all three for ``worst``."""
    if checked_discretization(discretization) == "worst":
        return INTEGRAL_FORMS
    return (cast(IntegralForm, discretization),)


def covering(*discretizations: Discretization) -> Discretization:
    """The discretization whose forms include those of all ``discretizations``.

    One form when they all name the same form, else ``worst`` (the only one covering two).

    Raises
    ------
    PIDTuningError
        None given, or an unknown name.
    """
    forms = {f for d in discretizations for f in forms_of(d)}
    if not forms:
        raise PIDTuningError("covering: expected at least one discretization; got none")
    return cast(Discretization, forms.pop()) if len(forms) == 1 else "worst"


def describe(discretization: Discretization) -> str:
    """One sentence for tables and reports: which forms, and how their margins combine."""
    if checked_discretization(discretization) == "worst":
        return ("worst case over forward, backward and trapezoidal (Tustin) integration: "
                "every margin is the worst of the three, and a bound holds for all three")
    return FORM_DESCRIPTIONS[cast(IntegralForm, discretization)]


def controller_polynomials(tuning: PIDTuning, ts_s: float,
                           form: IntegralForm) -> tuple[FloatArray, FloatArray]:
    """``C(z) = num/den`` from ``-y`` to ``u`` [%/kW], ascending powers of ``z^-1``.

    ``num = Kc [(1 - z^-1 + N_I) F + c Td (1 - z^-1)^2]``, ``den = (1 - z^-1) F`` with
    ``N_I`` the integral's numerator (``I = N_I/(1 - z^-1)``, module notes), ``F`` the
    derivative filter's denominator and ``c = 1`` (backward Euler) or 2 (trapezoidal);
    ``F = 1`` for a PI.

    Parameters
    ----------
    tuning :
        The tuning.
    ts_s :
        Sampling time [s], > 0.
    form :
        One of `INTEGRAL_FORMS`.

    Raises
    ------
    PIDTuningError
        An unknown form.
    """
    r = ts_s / tuning.ti_s
    integral = {"forward": [0.0, r], "backward": [r, 0.0], "tustin": [r / 2.0, r / 2.0]}.get(form)
    if integral is None:
        raise PIDTuningError(
            f"integral form: expected one of {', '.join(INTEGRAL_FORMS)}; got {form!r}")
    diff = np.array([1.0, -1.0])
    proportional_integral = diff + np.array(integral)
    if tuning.td_s > 0:
        tf = tuning.td_filter_s
        if form == "tustin":
            filt, c = np.array([2.0 * tf + ts_s, -(2.0 * tf - ts_s)]), 2.0
        else:
            filt, c = np.array([tf + ts_s, -tf]), 1.0
        num = (np.convolve(proportional_integral, filt)
               + c * tuning.td_s * np.array([1.0, -2.0, 1.0]))
        den = np.convolve(diff, filt)
    else:
        num, den = proportional_integral, diff
    return tuning.kc_pct_per_kw * num, den


def controller_frequency_response(tuning: PIDTuning, ts_s: float, w_rad_per_s: FloatArray,
                                  form: IntegralForm) -> FloatArray:
    """``C(e^{j w Ts})`` [%/kW] of ``form`` (module notes) from ``-y`` to ``u``.

    Parameters
    ----------
    tuning :
        The tuning in force.
    ts_s :
        Sampling time [s].
    w_rad_per_s :
        Angular frequencies [rad/s], below ``pi/ts_s``.
    form :
        One of `INTEGRAL_FORMS`.
    """
    if form not in INTEGRAL_FORMS:
        raise PIDTuningError(
            f"integral form: expected one of {', '.join(INTEGRAL_FORMS)}; got {form!r}")
    zinv = np.exp(-1j * np.asarray(w_rad_per_s, dtype=float) * ts_s)
    r = ts_s / tuning.ti_s
    if form == "forward":
        out = 1.0 + r * zinv / (1.0 - zinv)
    elif form == "backward":
        out = 1.0 + r / (1.0 - zinv)
    else:
        out = 1.0 + 0.5 * r * (1.0 + zinv) / (1.0 - zinv)
    if tuning.td_s > 0:
        tf = tuning.td_filter_s
        if form == "tustin":
            out = out + 2.0 * tuning.td_s * (1.0 - zinv) / (2.0 * tf + ts_s - (2.0 * tf - ts_s) * zinv)
        else:
            out = out + tuning.td_s * (1.0 - zinv) / (tf + ts_s - tf * zinv)
    return np.asarray(tuning.kc_pct_per_kw * out)


__all__ = ["DEFAULT_DISCRETIZATION", "DISCRETIZATIONS", "FORM_DESCRIPTIONS", "INTEGRAL_FORMS",
           "Discretization", "IntegralForm", "checked_discretization", "controller_frequency_response",
           "controller_polynomials", "covering", "describe", "forms_of"]
