"""Steady-state Kalman gains (DARE) and the one estimator object every controller uses.

Notation
--------
``z`` the (augmented) state, ``y`` [kW] the measured power deviation, ``w``
[kW-equivalent] the applied nonlinearity output, ``eps`` [kW] the innovation
``y - C z_{k|k-1}``. The noise model (``docs/theory.rst``, C1-C3)::

    z+ = A z + B w + v,    y = C z + e,
    cov(v) = Q,  cov(e) = R,  cov(v, e) = S

For the innovations form ``v = K e`` plus the disturbance increment ``xi``:
``Q = s2 (K K^T + rho E_d E_d^T)``, ``S = s2 K``, ``R = s2``, ``s2 = sigma_e^2``, ``rho``
the settings' ``disturbance_noise``. The gains do not depend on ``s2``: it is set to 1.

``P`` solves the filter DARE with correlated noise
``P = A P A^T + Q - (A P C^T + S) Re^-1 (A P C^T + S)^T`` with ``Re = C P C^T + R``;
the updates are::

    measurement:  z_{k|k}   = z_{k|k-1} + M eps_k,          M = P C^T / Re
    time:         z_{k+1|k} = A z_{k|k} + B w_k + G eps_k,   G = S / Re

so that the one-step predictor gain is ``L = A M + G``. With no augmentation ``P = 0``
and ``L = K``: the model's own innovations form is its Kalman filter.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from czmpc.errors import DesignError
from czmpc.ordered import OrderedProduct, ordered_dot
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


def innovation_variance_after_gap(
    model: AugmentedModel, kf: SteadyStateKalman, disturbance_noise: float, max_gap: int
) -> FloatArray:
    """Predicted innovation variance after ``m = 0..max_gap`` skipped measurement updates.

    ``C P_m C^T + R`` with ``P_{m+1} = A P_m A^T + Q`` from the stationary ``P_0 = P``
    (units of ``s2``); the spike gate (`czmpc.validation`) widens with it.

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


#: An innovation beyond this [kW] is no heater power: `Estimator.update` skips it, so
#: absurd values such as 1e300 cannot overflow the estimator.
MAX_INNOVATION_KW = 1e6


#: One past sample, kept to roll back: ``(z_{j|j}, eps_j [kW] or 0, w_j [kW-equivalent])``.
#: A plain tuple: a NamedTuple cost 0.3 us a step.
_Trace = tuple[FloatArray, float, float]


class Estimator:
    """The steady-state Kalman filter with its state: predict, update, roll back.

    ``z`` is ``z_{k|k-1}`` until `update` makes it ``z_{k|k}``; `predict` then gives
    ``z_{k+1|k}`` with the ``w`` applied. A trace lets `roll_back` undo updates.

    Parameters
    ----------
    model :
        The augmented model.
    disturbance_noise :
        ``rho`` > 0, see `noise_covariances`.
    noise_std_kw :
        ``sigma_e`` [kW]: scales `innovation_std_kw`.
    max_gap :
        Longest gap [samples] `innovation_std_kw` grows over (then it stays).
    history_samples :
        Past samples kept for `roll_back`.

    Attributes
    ----------
    gains :
        The steady-state gains (`design_estimator`).
    eps :
        This sample's innovation [kW] once `update` used it, else 0.
    gap :
        Samples without a measurement update, this one included once skipped.

    Raises
    ------
    DesignError
        If the DARE has no stabilizing solution.
    """

    def __init__(self, model: AugmentedModel, disturbance_noise: float, *, noise_std_kw: float,
                 max_gap: int = 0, history_samples: int = 1) -> None:
        self.model = model
        self.gains = design_estimator(model, disturbance_noise)
        var = innovation_variance_after_gap(model, self.gains, disturbance_noise, max_gap)
        self._std_kw = [noise_std_kw * math.sqrt(v) for v in var.tolist()]
        self._A, self._B, self._C = np.array(model.A), np.array(model.B), np.array(model.C)
        self._M, self._G = np.array(self.gains.M), np.array(self.gains.G)
        # [z+; C z+] = [[A, B, G]; C [A, B, G]] [z; w; eps]: one product per step.
        ABG = np.column_stack([self._A, self._B, self._G])
        self._ABG_C = np.vstack([ABG, self._C @ ABG])
        # The step's products in one fixed order (`czmpc.ordered`): the generated C's.
        self._predict_product = OrderedProduct(self._ABG_C)
        self._a_product = OrderedProduct(self._A)
        self._c_list = self._C.tolist()
        self._cm = ordered_dot(self._c_list, self._M.tolist())  # C M: the update's share
        self._v = np.empty(model.n_states + 2)
        self._v_z = self._v[:-2]  # a view, taken once
        self._eps = np.array(0.0)  # eps as a 0-d array: numpy converts a float on every call
        self._history: deque[_Trace] = deque(maxlen=history_samples)
        self.restart(np.zeros(model.n_states))

    def restart(self, z: FloatArray) -> None:
        """Start again from state ``z`` with no gap and no trace."""
        self._set(np.array(z, dtype=float))
        self.eps = 0.0
        self.gap = 0
        self._history.clear()

    def _set(self, z: FloatArray) -> None:
        z.setflags(write=False)  # handed out in diagnostics
        self._z = z
        self._z_shared = True
        self._y_pred = ordered_dot(self._c_list, z.tolist())

    @property
    def z(self) -> FloatArray:
        """(n,) the state now (read-only): ``z_{k|k-1}``, or ``z_{k|k}`` after `update`."""
        if not self._z_shared:  # made read-only when first handed out: most are replaced first
            self._z.setflags(write=False)
            self._z_shared = True
        return self._z

    @property
    def predicted_output(self) -> float:
        """``C z_{k|k-1}`` [kW deviation] (before `update`)."""
        return self._y_pred

    @property
    def innovation_std_kw(self) -> float:
        """Predicted std [kW] of this sample's innovation after `gap` samples without update."""
        std, gap = self._std_kw, self.gap
        return std[gap] if gap < len(std) else std[-1]  # std[min(gap, len - 1)], no min() call

    @property
    def sigma_kw(self) -> float:
        """Stationary innovation std [kW] (no gap)."""
        return self._std_kw[0]

    def update(self, y: float) -> bool:
        """Measurement update with ``y_k`` [kW deviation]; False (skipped as by `skip`)
        if the innovation is not finite or beyond `MAX_INNOVATION_KW`."""
        eps = y - self._y_pred
        if not abs(eps) <= MAX_INNOVATION_KW:
            self.gap += 1
            return False
        e = self._eps
        e[()] = eps
        z = np.multiply(self._M, e)
        z += self._z  # = z + M eps, in place
        self._z = z
        self._z_shared = False
        self.eps = eps
        self.gap = 0
        return True

    def absorb_level_change(self) -> bool:
        """After `update`: move an output disturbance ``d`` so that ``C z = y`` for this
        sample (the whole innovation left after the update taken as a level change).

        Returns False, changing nothing, when ``d`` does not act on the output at once
        (an input disturbance) or no measurement was used."""
        c_d = float(self._C[-1])
        if c_d == 0.0 or self.gap or self.eps == 0.0:
            return False
        residual = self.eps * (1.0 - self._cm)
        z = self._z.copy()
        z[-1] += residual / c_d
        self._z = z
        self._z_shared = False
        return True

    def skip(self) -> None:
        """No measurement this sample: ``z_{k|k} = z_{k|k-1}``, ``eps = 0``."""
        self.gap += 1

    def predict(self, w: float) -> None:
        """Time update ``z+ = A z + B w + G eps`` with the ``w`` applied (a non-finite result keeps ``z``)."""
        z = self.z  # read-only: the trace keeps it
        self._history.append((z, self.eps, w))
        v = self._v
        self._v_z[...] = z
        v[-2] = w
        v[-1] = self.eps
        out = self._predict_product(v)
        values = out.tolist()  # math.isfinite on n + 1 floats beats np.isfinite on a tiny array
        if all(map(math.isfinite, values)):
            self._z = out[:-1]
            self._z_shared = False
            self._y_pred = values[-1]
        else:
            self._set(z.copy())
        self.eps = 0.0

    def correct_input(self, w_assumed: float, w_applied: float) -> None:
        """The last `predict` assumed ``w_assumed``; ``w_applied`` was applied (linear in ``w``)."""
        z = self._z + self._B * (w_applied - w_assumed)
        if np.isfinite(z).all():
            self._set(z)
            if self._history:
                z_post, eps, _ = self._history[-1]
                self._history[-1] = (z_post, eps, w_applied)

    def roll_back(self, samples: int) -> int:
        """Undo the updates of the last ``samples`` samples, as if they had been skipped.

        Returns the number undone (0 if the trace is too short or the result not finite).
        """
        steps_back = min(samples + 1, len(self._history))
        if steps_back < 1:
            return 0
        traces = list(self._history)[-steps_back:]
        z_post, eps, w = traces[0]
        z = self._a_product(z_post) + self._B * w + self._G * eps
        for _, _, w in traces[1:]:
            z = self._a_product(z) + self._B * w
        if not np.isfinite(z).all():
            return 0
        self._set(z)
        frozen = steps_back - 1
        self.gap = max(self.gap, frozen)
        return frozen


class LevelChangeRule:
    """A level change told from a spike: two used samples in a row whose innovations
    exceed ``k_sigma`` predicted standard deviations, with one sign.

    At the second, an output disturbance takes the whole innovation left after the
    update (`Estimator.absorb_level_change`) instead of the filter's share: a grid sag
    without a voltage reading is taken at once. A lone spike moves the estimate by the
    filter's share only. Every controller with an `Estimator` runs it the same way
    (`czmpc.settings.ReliabilitySettings.level_change_k_sigma`).

    Parameters
    ----------
    k_sigma :
        The threshold [predicted standard deviations]; None never takes a level change
        (the textbook filter).
    """

    __slots__ = ("_sign", "k_sigma")

    def __init__(self, k_sigma: float | None) -> None:
        self.k_sigma = k_sigma
        self._sign = 0

    def reset(self) -> None:
        """Forget the last innovation's sign."""
        self._sign = 0

    def observe(self, est: Estimator, std_kw: float, used: bool) -> bool:
        """After this sample's measurement update: take a level change if this is the second.

        Parameters
        ----------
        est :
            The estimator, its `Estimator.update` just run (or not).
        std_kw :
            The innovation's predicted standard deviation before the update [kW].
        used :
            Whether the update ran with a measurement; a sample without one ends a run.

        Returns
        -------
        bool
            True when the estimate was moved as a level change.
        """
        k_sigma = self.k_sigma
        if not used or k_sigma is None:
            self._sign = 0
            return False
        eps = est.eps
        sign = 0 if not abs(eps) > k_sigma * std_kw else 1 if eps > 0 else -1
        if sign and sign == self._sign:
            self._sign = 0
            return est.absorb_level_change()
        self._sign = sign
        return False


__all__ = [
    "MAX_INNOVATION_KW",
    "Estimator",
    "LevelChangeRule",
    "SteadyStateKalman",
    "design_estimator",
    "innovation_variance_after_gap",
    "noise_covariances",
    "steady_state_kalman",
]
