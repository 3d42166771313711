"""Steady-state target (x_s, w_s) for the current disturbance.

Notation
--------
``r`` [kW] setpoint deviation ``P_ref - P_nom``; ``d`` the disturbance estimate;
``w`` [kW-equivalent] nonlinearity output; ``x`` the linear block's state;
``xw = (I - A)^-1 B`` the steady state per unit of constant input, ``g = C xw`` the
static gain ``B(1)/A(1)``.

``docs/theory.rst``, C4: the steady state with ``y_s = r`` for the current ``d``::

    input disturbance:   x_s = xw (w_s + d),  y_s = g (w_s + d) = r  ->  w_s = r/g - d
    output disturbance:  x_s = xw w_s,        y_s = g w_s + d = r    ->  w_s = (r - d)/g

``w_s`` is clipped to ``[w_min, w_max]`` (with a scalar input: the reachable output
closest to ``r``); the target then reports the setpoint unreachable, with that ``y_s``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from czmpc._records import record_from_fields
from czmpc.errors import DesignError
from czmpc.inversion import clamp
from czmpc.realization import InnovationsForm
from czmpc.settings import DisturbanceModel
from sysid._typing import FloatArray

#: |B(1)/A(1)| below this leaves no usable steady-state gain [kW per kW-equivalent].
MIN_STATIC_GAIN = 1e-6


@dataclass(frozen=True, eq=False, kw_only=True)
class SteadyStateMap:
    """What a target needs from the model, computed once.

    Parameters
    ----------
    xw :
        (n,) ``(I - A)^-1 B``: steady state per unit of constant input.
    static_gain :
        ``g = C xw = B(1)/A(1)`` [kW per kW-equivalent].
    disturbance_model :
        ``"input"`` or ``"output"``.
    """

    xw: FloatArray
    static_gain: float
    disturbance_model: DisturbanceModel


@dataclass(frozen=True, eq=False, kw_only=True)
class Target:
    """A steady-state target (module notes).

    Parameters
    ----------
    x_s :
        (n,) target state of the linear block.
    w_s :
        Target input [kW-equivalent], inside ``[w_min, w_max]``.
    y_s :
        Output the target reaches [kW deviation]; equals ``r`` when reachable.
    is_reachable :
        False if ``w_s`` had to be clipped, i.e. no allowed input holds ``y = r``.
    w_unclipped :
        The ``w_s`` that would hold ``y = r`` [kW-equivalent].
    """

    x_s: FloatArray
    w_s: float
    y_s: float
    is_reachable: bool
    w_unclipped: float


def steady_state_map(base: InnovationsForm, disturbance_model: DisturbanceModel) -> SteadyStateMap:
    """Precompute ``xw`` and the static gain of ``base``.

    Parameters
    ----------
    base :
        The innovations form (stable ``A``).
    disturbance_model :
        ``"input"`` or ``"output"``.

    Raises
    ------
    DesignError
        If ``|B(1)/A(1)| < MIN_STATIC_GAIN``: no steady state can track a setpoint.
    """
    n = base.n_states
    xw: FloatArray = np.asarray(np.linalg.solve(np.eye(n) - base.A, base.B), dtype=float)
    gain = float(base.C @ xw)
    if not abs(gain) >= MIN_STATIC_GAIN:
        raise DesignError(
            f"target: the static gain B(1)/A(1) must be nonzero (|g| >= {MIN_STATIC_GAIN:g}); "
            f"got {gain:.3g}"
        )
    xw.setflags(write=False)
    return SteadyStateMap(xw=xw, static_gain=gain, disturbance_model=disturbance_model)


def compute_target(
    ssm: SteadyStateMap, *, setpoint: float, disturbance: float, w_min: float, w_max: float
) -> Target:
    """Return the steady-state target for setpoint ``r`` and disturbance ``d``.

    Parameters
    ----------
    ssm :
        From `steady_state_map`.
    setpoint :
        ``r`` [kW deviation], finite.
    disturbance :
        ``d`` estimate, finite ([kW-equivalent] input, [kW] output disturbance).
    w_min, w_max :
        Input bounds [kW-equivalent], ``w_min < w_max``.
    """
    g = ssm.static_gain
    is_input = ssm.disturbance_model == "input"
    if is_input:
        w_free = setpoint / g - disturbance
    else:
        w_free = (setpoint - disturbance) / g
    w_s = clamp(w_free, w_min, w_max)
    if is_input:
        x_s = ssm.xw * (w_s + disturbance)
        y_s = g * (w_s + disturbance)
    else:
        x_s = ssm.xw * w_s
        y_s = g * w_s + disturbance
    reachable = w_s == w_free
    if reachable:
        y_s = setpoint
    return record_from_fields(Target, {"x_s": x_s, "w_s": w_s, "y_s": y_s,
                                       "is_reachable": reachable, "w_unclipped": w_free})


__all__ = [
    "MIN_STATIC_GAIN",
    "SteadyStateMap",
    "Target",
    "compute_target",
    "steady_state_map",
]
