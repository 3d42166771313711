"""Innovations-form state space from A, B, C; disturbance augmentation.

Notation
--------
``y`` [kW]
    Power deviation ``dP = P - P_nom`` (paper sec. 5.1).
``w`` [kW-equivalent]
    Nonlinearity output ``f(ds)`` (paper eq. 28), the linear block's input.
``e`` [kW]
    Innovation, white with standard deviation ``noise_std_kw``.
``x``
    State of the linear block (observer canonical form, below); ``d`` the integrating
    disturbance of the offset-free MPC.

The polynomial model ``A(q) y = B(q) w + C(q) e`` (the model file's form,
docs/reference/model_file.rst; paper eqs. 27 and 30) is realized in innovations form
(docs/theory.rst, C1)::

    x+ = A x + B w + K e,     y = C x + e

with the observer canonical form of order ``n = max(na, nb, nc)`` (``nb`` counting
``B``'s leading zeros, so the delay becomes states)::

    A = [[-a1, 1, 0, ...], [-a2, 0, 1, ...], ..., [-an, 0, ..., 0]]
    B = [b1, ..., bn]^T,   K = [c1 - a1, ..., cn - an]^T,   C = [1, 0, ..., 0]

which gives ``y = (B(q)/A(q)) w + (C(q)/A(q)) e`` exactly. ``b0`` must be 0 (at least
one sample of delay): the MPC measures ``y_k`` before it chooses ``w_k``.

Augmentation (docs/theory.rst, C2), state ``z = [x; d]``::

    input:   x+ = A x + B (w + d),   y = C x + e
    output:  x+ = A x + B w,         y = C x + d + e
    both:    d+ = d + xi  (random walk)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from czmpc.errors import DesignError
from czmpc.settings import DisturbanceModel
from sysid._arrays import readonly_array as _readonly
from sysid._typing import FloatArray
from sysid.model import HammersteinModel

#: PBH rank test: a smallest singular value below this, relative to the largest, is rank
#: loss (far above round-off, far below any real model's margin).
PBH_RTOL = 1e-9


@dataclass(frozen=True, eq=False, kw_only=True)
class InnovationsForm:
    """``x+ = A x + B w + K e``, ``y = C x + e`` (module notes).

    Parameters
    ----------
    A :
        (n, n) state matrix.
    B :
        (n,) input vector (input ``w`` [kW-equivalent]).
    C :
        (n,) output row (output ``y`` [kW]).
    K :
        (n,) innovation gain.
    ts_s :
        Sampling time [s].
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    K: FloatArray
    ts_s: float

    @property
    def n_states(self) -> int:
        """State dimension ``n``."""
        return int(self.B.size)

    @property
    def static_gain(self) -> float:
        """``C (I - A)^-1 B = B(1)/A(1)``: steady-state gain from ``w`` to ``y``."""
        return float(self.C @ np.linalg.solve(np.eye(self.n_states) - self.A, self.B))


@dataclass(frozen=True, eq=False, kw_only=True)
class AugmentedModel:
    """The innovations form augmented with an integrating disturbance (module notes).

    Parameters
    ----------
    base :
        The model without augmentation.
    disturbance_model :
        ``"input"`` (``w + d``) or ``"output"`` (``y + d``).
    A :
        (n+1, n+1) augmented state matrix; the last state is ``d``.
    B :
        (n+1,) input vector.
    C :
        (n+1,) output row.
    K :
        (n+1,) innovation gain (``[K; 0]``: ``e`` does not drive ``d``).
    """

    base: InnovationsForm
    disturbance_model: DisturbanceModel
    A: FloatArray
    B: FloatArray
    C: FloatArray
    K: FloatArray

    @property
    def n_states(self) -> int:
        """Augmented state dimension ``n + 1``."""
        return int(self.B.size)

    @property
    def disturbance_power_gain(self) -> float:
        """Steady-state power change [kW] per unit of ``d`` (``B(1)/A(1)`` or 1)."""
        return self.base.static_gain if self.disturbance_model == "input" else 1.0


def innovations_form(model: HammersteinModel) -> InnovationsForm:
    """Realize ``A(q) y = B(q) w + C(q) e`` in innovations form (module notes).

    Parameters
    ----------
    model :
        Any orders ``na``, ``nb``, ``nc`` and delay ``nk >= 1``.

    Raises
    ------
    DesignError
        If ``nk = 0`` (direct feedthrough from ``w`` to ``y``).
    """
    if model.delay_steps < 1:
        raise DesignError(
            "realization: the MPC needs at least one sample of input delay (b[0] = 0); "
            f"got b = {model.b.tolist()}"
        )
    n = max(model.a.size, model.b.size, model.c.size) - 1
    a, b, c = (np.pad(np.asarray(p, dtype=float), (0, n + 1 - p.size)) for p in (model.a, model.b, model.c))
    A = np.zeros((n, n))
    A[:, 0] = -a[1:]
    A[: n - 1, 1:] = np.eye(n - 1)
    C = np.zeros(n)
    C[0] = 1.0
    return InnovationsForm(
        A=_readonly(A), B=_readonly(b[1:]), C=_readonly(C), K=_readonly(c[1:] - a[1:]),
        ts_s=model.ts_s,
    )


def augment(base: InnovationsForm, disturbance_model: DisturbanceModel) -> AugmentedModel:
    """Augment ``base`` with an integrating disturbance and check detectability.

    Parameters
    ----------
    base :
        The innovations form of the model.
    disturbance_model :
        ``"input"`` or ``"output"``.

    Raises
    ------
    DesignError
        If the augmented pair ``(A, C)`` is not detectable (`check_detectable`).
    """
    n = base.n_states
    A = np.zeros((n + 1, n + 1))
    A[:n, :n] = base.A
    A[n, n] = 1.0
    C = np.zeros(n + 1)
    C[:n] = base.C
    if disturbance_model == "input":
        A[:n, n] = base.B
    else:
        C[n] = 1.0
    B, K = np.append(base.B, 0.0), np.append(base.K, 0.0)
    check_detectable(A, C, what=f"{disturbance_model} disturbance augmentation")
    return AugmentedModel(
        base=base, disturbance_model=disturbance_model, A=_readonly(A), B=_readonly(B),
        C=_readonly(C), K=_readonly(K),
    )


def check_detectable(A: FloatArray, C: FloatArray, *, what: str) -> None:
    """Raise `DesignError` unless ``(A, C)`` is detectable (PBH test).

    Every eigenvalue ``lambda`` of ``A`` with ``|lambda| >= 1`` must satisfy
    ``rank [lambda I - A; C] = n``; an input disturbance fails at ``z = 1`` exactly when
    ``B(1) = 0`` (no steady effect on the output).

    Parameters
    ----------
    A :
        (n, n) state matrix.
    C :
        (n,) output row.
    what :
        Names the pair in the error message.

    Raises
    ------
    DesignError
        If some unstable or marginal mode is unobservable.
    """
    n = A.shape[0]
    for lam in np.linalg.eigvals(A):
        if abs(lam) < 1.0 - 1e-12:
            continue
        pencil = np.vstack([lam * np.eye(n) - A, C.reshape(1, n)])
        sv = np.linalg.svd(pencil, compute_uv=False)
        if sv[-1] <= PBH_RTOL * max(1.0, sv[0]):
            raise DesignError(
                f"{what}: the augmented pair (A, C) must be detectable; the mode at "
                f"z = {complex(lam):.6g} is unobservable (PBH test, smallest singular "
                f"value {sv[-1]:.3g}). With an input disturbance this means B(1) = 0; "
                "use the output disturbance model"
            )


__all__ = ["AugmentedModel", "InnovationsForm", "augment", "check_detectable", "innovations_form"]
