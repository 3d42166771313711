"""Measurement/time updates and steady-state gain (DARE).

Notation
--------
``z`` the (augmented) state, ``y`` [kW] the measured power deviation, ``w``
[kW-equivalent] the applied nonlinearity output, ``eps`` [kW] the innovation
``y - C z_{k|k-1}``. The noise model (DESIGN.md items 1-2)::

    z+ = A z + B w + v,    y = C z + e,
    cov(v) = Q,  cov(e) = R,  cov(v, e) = S

For the innovations form ``v = K e`` (plus the disturbance's random-walk increment
``xi``), so ``Q = s2 (K K^T + rho E_d E_d^T)``, ``S = s2 K``, ``R = s2`` with
``s2 = sigma_e^2`` and ``rho`` the settings' ``disturbance_noise``. The gains do not
depend on ``s2``, so it is set to 1.

Steady-state filter with correlated noise: ``P`` solves the filter DARE
``P = A P A^T + Q - (A P C^T + S) Re^-1 (A P C^T + S)^T`` with ``Re = C P C^T + R``;
the updates are::

    measurement:  z_{k|k}   = z_{k|k-1} + M eps_k,          M = P C^T / Re
    time:         z_{k+1|k} = A z_{k|k} + B w_k + G eps_k,   G = S / Re

so that the one-step predictor gain is ``L = A M + G``. With no augmentation ``P = 0``
and ``L = K``: the model's own innovations form is its Kalman filter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from czmpc.errors import DesignError
from czmpc.realization import AugmentedModel
from sysid._arrays import readonly_array as _readonly
from sysid._typing import FloatArray


@dataclass(frozen=True, eq=False, kw_only=True)
class SteadyStateKalman:
    """Steady-state Kalman gains for one noise model (module notes).

    Parameters
    ----------
    P :
        (n, n) stationary one-step prediction error covariance (units of ``s2``).
    innovation_variance :
        ``Re = C P C^T + R`` (units of ``s2``).
    M :
        (n,) measurement-update gain.
    G :
        (n,) correlated-noise gain of the time update.
    L :
        (n,) one-step predictor gain ``A M + G``.
    """

    P: FloatArray
    innovation_variance: float
    M: FloatArray
    G: FloatArray
    L: FloatArray


def steady_state_kalman(
    A: FloatArray, C: FloatArray, Q: FloatArray, R: float, S: FloatArray
) -> SteadyStateKalman:
    """Solve the filter DARE with correlated noise and return the gains.

    Parameters
    ----------
    A :
        (n, n) state matrix.
    C :
        (n,) output row.
    Q :
        (n, n) process noise covariance.
    R :
        Measurement noise variance, > 0.
    S :
        (n,) cross covariance of process and measurement noise.

    Raises
    ------
    DesignError
        If the DARE has no stabilizing solution (scipy's solver fails).
    """
    n = A.shape[0]
    Cm = C.reshape(1, n)
    Sm = S.reshape(n, 1)
    try:
        P = scipy.linalg.solve_discrete_are(A.T, Cm.T, Q, np.array([[R]]), s=Sm)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise DesignError(
            f"Kalman filter: the filter DARE must have a stabilizing solution; got: {exc}"
        ) from exc
    P = 0.5 * (P + P.T)
    re = float(C @ P @ C) + R
    M = (P @ C) / re
    G = S / re
    L = A @ M + G
    return SteadyStateKalman(
        P=_readonly(P), innovation_variance=re, M=_readonly(M), G=_readonly(G),
        L=_readonly(L),
    )


def noise_covariances(
    model: AugmentedModel, disturbance_noise: float
) -> tuple[FloatArray, float, FloatArray]:
    """Return ``(Q, R, S)`` of the augmented model with ``s2 = 1`` (module notes).

    Parameters
    ----------
    model :
        The augmented model; its ``K`` carries the innovation's effect on ``x``.
    disturbance_noise :
        ``rho``: variance of the disturbance increment relative to ``s2``.
    """
    n = model.n_states
    K = model.K
    Q = np.outer(K, K)
    Q[n - 1, n - 1] += disturbance_noise
    return Q, 1.0, K.copy()


def design_estimator(model: AugmentedModel, disturbance_noise: float) -> SteadyStateKalman:
    """Steady-state Kalman gains of the offset-free estimator.

    Parameters
    ----------
    model :
        The augmented model.
    disturbance_noise :
        ``rho`` > 0, see `noise_covariances`.

    Raises
    ------
    DesignError
        If the DARE has no stabilizing solution.
    """
    Q, R, S = noise_covariances(model, disturbance_noise)
    return steady_state_kalman(model.A, model.C, Q, R, S)


def measurement_update(
    z_pred: FloatArray, y: float, C: FloatArray, M: FloatArray
) -> tuple[FloatArray, float]:
    """Return ``(z_{k|k}, eps_k)`` from the prediction and a finite measurement.

    Parameters
    ----------
    z_pred :
        (n,) ``z_{k|k-1}``.
    y :
        Measured output deviation [kW]; must be finite (a missing sample skips this
        update: ``z_{k|k} = z_{k|k-1}``, ``eps_k = 0``).
    C :
        (n,) output row.
    M :
        (n,) measurement-update gain.
    """
    eps = y - float(C @ z_pred)
    return z_pred + M * eps, eps


def time_update(
    z_filt: FloatArray, w: float, eps: float, A: FloatArray, B: FloatArray, G: FloatArray
) -> FloatArray:
    """Return ``z_{k+1|k} = A z_{k|k} + B w + G eps`` with the ``w`` actually applied.

    Parameters
    ----------
    z_filt :
        (n,) ``z_{k|k}``.
    w :
        Applied nonlinearity output [kW-equivalent].
    eps :
        This sample's innovation [kW] (0 if the measurement was missing).
    A, B, G :
        State matrix, input vector, correlated-noise gain.
    """
    return A @ z_filt + B * w + G * eps


def innovation_variance_after_gap(
    model: AugmentedModel, kf: SteadyStateKalman, disturbance_noise: float, max_gap: int
) -> FloatArray:
    """Predicted innovation variance after ``m = 0..max_gap`` skipped measurement updates.

    Without an update the one-step prediction error grows as
    ``P_{m+1} = A P_m A^T + Q`` from the stationary ``P_0 = P``, so the next innovation
    has variance ``C P_m C^T + R`` (units of ``s2``, see the module notes; multiply by
    ``sigma_e^2``). The spike gate (`czmpc.validation`) widens with it after an outage.

    Parameters
    ----------
    model :
        The augmented model.
    kf :
        Its steady-state gains (``kf.P`` is ``P_0``).
    disturbance_noise :
        ``rho``, as given to `design_estimator`.
    max_gap :
        Largest gap [samples] to tabulate, >= 0.

    Returns
    -------
    FloatArray
        (max_gap + 1,) variances, read-only; element 0 is ``kf.innovation_variance``.
    """
    Q, R, _ = noise_covariances(model, disturbance_noise)
    A = model.A
    C = model.C
    P = np.array(kf.P, dtype=float)
    out = np.empty(max_gap + 1)
    for m in range(max_gap + 1):
        out[m] = float(C @ P @ C) + R
        P = A @ P @ A.T + Q
    return _readonly(out)


__all__ = [
    "SteadyStateKalman",
    "design_estimator",
    "innovation_variance_after_gap",
    "measurement_update",
    "noise_covariances",
    "steady_state_kalman",
    "time_update",
]
