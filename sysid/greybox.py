"""Grey-box prediction-error method: fit named parameters of a state-space model.

MATLAB's ``idgrey`` + ``pem`` of the paper (sec. 7.5-7.6): a discrete state-space model
whose matrices are CasADi expressions of named parameters, some free, and a fixed map
from the measured input to the model input; `fit_greybox` minimizes ``V`` (eq. 9) or
``W`` (eq. 10) by Levenberg-Marquardt. The one-step map and its forward sensitivities
are one CasADi function run over the record by ``mapaccum``, so one pass gives the
residuals and their exact Jacobian (measured: about 10 ms for 12,000 samples and 4
parameters).

Notation
--------
The model is in innovations form (Ljung 1999, sec. 4.3)::

    x_{k+1} = A(theta) x_k + B(theta) u_k + K(theta) e_k
    y_k     = C(theta) x_k + D(theta) u_k + e_k

* ``y`` : measured output as deviation from the operating point (``dP`` [kW]).
* ``u`` : model input vector, formed from the measured input by a fixed map (for
  eq. 26: ``u = [ds^2, ds]`` with ``ds`` the TRIAC deviation [%]).
* ``e`` : innovation (one-step-ahead prediction error) [kW].
* ``theta`` : the named parameters, free or fixed.

Criteria: ``"ballistic"`` ignores ``K`` and simulates ``x_{k+1} = A x_k + B u_k``,
residual ``eps_k = y_k - C x_k - D u_k`` (eq. 9); ``"one_step"`` runs the predictor
``x_{k+1} = A x_k + B u_k + K (y_k - C x_k - D u_k)``, residual ``e_k`` (eq. 10).
The minimized cost is the mean square of the residuals.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import casadi as ca
import numpy as np

from sysid._arrays import readonly_array
from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.errors import IdentificationError, IdentificationWarning
from sysid.optimize import LMResult, levenberg_marquardt, parameter_std_errors

GreyBoxCriterion = Literal["ballistic", "one_step"]
InitialState = Literal["held_past", "steady", "estimate"]

#: ``matrices(p)`` returns ``(A, B, C, D, K)``; ``D`` and ``K`` may be None (zero).
MatrixBuilder = Callable[[Mapping[str, Any]], tuple[Any, Any, Any, Any, Any]]
#: ``input_map(measured)`` returns the model input, shape ``(n_samples, n_inputs)``.
InputMap = Callable[[FloatArray], FloatArray]
#: ``project(theta_all)`` returns admissible parameter values (same shape).
Projection = Callable[[FloatArray], FloatArray]


def _as_tuple(values: Sequence[Any] | None, n: int, fill: Any, name: str) -> tuple[Any, ...]:
    if values is None:
        return (fill,) * n
    out = tuple(values)
    if len(out) != n:
        raise IdentificationError(
            f"GreyBoxStructure.{name} must have one entry per parameter ({n}); got {len(out)}")
    return out


@dataclass(frozen=True, kw_only=True)
class GreyBoxStructure:
    """A parameterized state-space model in innovations form (the ``idgrey`` of MATLAB).

    Parameters
    ----------
    parameter_names :
        Unique names of all parameters, fixed and free, in a fixed order.
    initial_values :
        Initial (or, for fixed parameters, the fixed) values, one per name.
    free :
        Which parameters the fit may change; default: all.
    lower, upper :
        Bounds per parameter (``-inf``/``inf`` for none); default: unbounded.
    matrices :
        ``matrices(p) -> (A, B, C, D, K)``, ``p`` mapping each name to a CasADi scalar
        symbol, in CasADi operations. Shapes: ``A`` (n_x, n_x), ``B`` (n_x, n_u), ``C``
        (1, n_x), ``D`` (1, n_u) or None, ``K`` (n_x, 1) or None.
    input_map :
        Maps the measured input ``(n_samples,)`` to the model input ``(n_samples, n_u)``,
        independent of the parameters; default the input itself. For eq. 26:
        ``lambda ds: np.column_stack([ds**2, ds])``.
    project :
        Optional map from all parameter values to admissible ones (for example
        mirroring unstable roots), applied to every trial point.
    name :
        Label used in messages.

    Raises
    ------
    IdentificationError
        Duplicate or missing names, lengths that do not match, non-finite initial
        values, inverted bounds, or initial values outside the bounds.

    Examples
    --------
    A first-order output-error model ``y = b q^-1 / (1 + f q^-1) u``:

    >>> import casadi as ca
    >>> s = GreyBoxStructure(parameter_names=("f", "b"), initial_values=(-0.5, 1.0),
    ...     matrices=lambda p: (ca.reshape(-p["f"], 1, 1), ca.reshape(p["b"], 1, 1),
    ...                         ca.DM.ones(1, 1), None, None))
    >>> s.n_free
    2
    """

    parameter_names: tuple[str, ...]
    initial_values: tuple[float, ...]
    matrices: MatrixBuilder = field(repr=False)
    free: tuple[bool, ...] | None = None
    lower: tuple[float, ...] | None = None
    upper: tuple[float, ...] | None = None
    input_map: InputMap | None = field(default=None, repr=False)
    project: Projection | None = field(default=None, repr=False)
    name: str = "grey-box"

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.parameter_names)
        n = len(names)
        if n == 0:
            raise IdentificationError("GreyBoxStructure.parameter_names must not be empty")
        if len(set(names)) != n:
            dup = next(x for x in names if names.count(x) > 1)
            raise IdentificationError(f"GreyBoxStructure.parameter_names must be unique; got {dup!r} twice")
        values = tuple(float(v) for v in _as_tuple(self.initial_values, n, 0.0, "initial_values"))
        free = tuple(bool(v) for v in _as_tuple(self.free, n, True, "free"))
        lower = tuple(float(v) for v in _as_tuple(self.lower, n, -math.inf, "lower"))
        upper = tuple(float(v) for v in _as_tuple(self.upper, n, math.inf, "upper"))
        for name, v, lo, hi in zip(names, values, lower, upper, strict=True):
            if not math.isfinite(v):
                raise IdentificationError(
                    f"GreyBoxStructure: initial value of {name!r} must be finite; got {v}")
            if not lo < hi:
                raise IdentificationError(
                    f"GreyBoxStructure: bounds of {name!r} must satisfy lower < upper; "
                    f"got [{lo}, {hi}]")
            if not lo <= v <= hi:
                raise IdentificationError(
                    f"GreyBoxStructure: initial value of {name!r} must lie in [{lo}, {hi}]; got {v}")
        if not callable(self.matrices):
            raise IdentificationError(
                f"GreyBoxStructure.matrices must be callable; got {type(self.matrices).__name__}")
        object.__setattr__(self, "parameter_names", names)
        object.__setattr__(self, "initial_values", values)
        object.__setattr__(self, "free", free)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @property
    def n_parameters(self) -> int:
        """Number of parameters, fixed and free."""
        return len(self.parameter_names)

    @property
    def free_mask(self) -> tuple[bool, ...]:
        """Which parameters are free (normalized `free`)."""
        return self.free if self.free is not None else (True,) * self.n_parameters

    @property
    def n_free(self) -> int:
        """Number of free parameters."""
        return sum(self.free_mask)

    def with_initial_values(self, values: Mapping[str, float]) -> GreyBoxStructure:
        """Return a copy with some initial (or fixed) values replaced, by name."""
        self._check_names(values)
        return replace(self, initial_values=tuple(
            float(values.get(n, v)) for n, v in zip(self.parameter_names, self.initial_values,
                                                    strict=True)))

    def with_free(self, names: Sequence[str]) -> GreyBoxStructure:
        """Return a copy where exactly the named parameters are free (the rest fixed)."""
        self._check_names(names)
        return replace(self, free=tuple(n in names for n in self.parameter_names))

    def _check_names(self, names: Iterable[str]) -> None:
        unknown = set(names) - set(self.parameter_names)
        if unknown:
            raise IdentificationError(f"{self.name}: unknown parameter name(s) {sorted(unknown)}; "
                                      f"expected some of {list(self.parameter_names)}")


@dataclass(frozen=True, kw_only=True, eq=False)
class GreyBoxResult:
    """Outcome of `fit_greybox`.

    Parameters
    ----------
    structure :
        The structure that was fitted (with its initial values).
    criterion :
        ``"ballistic"`` (V, eq. 9) or ``"one_step"`` (W, eq. 10).
    parameter_names :
        All parameter names, as in the structure.
    parameters :
        Final values of all parameters (fixed ones unchanged).
    std_errors :
        ``sqrt(diag(s^2 (J'J)^-1))``; 0.0 for fixed parameters, ``inf`` for free ones
        the data cannot determine.
    free :
        Which parameters were free.
    initial_state :
        The initial state used at the final parameters, shape ``(n_x,)``.
    residuals :
        Final residual sequence ``eps_k`` or ``e_k``, shape ``(n_samples,)``.
    criterion_value :
        Mean square of `residuals` (the V or W of the fit).
    n_iterations :
        Levenberg-Marquardt iterations used.
    converged :
        Whether the optimizer met its convergence test.
    message :
        The optimizer's reason for stopping.
    raw :
        The optimizer's own result, for experts.
    """

    structure: GreyBoxStructure = field(repr=False)
    criterion: GreyBoxCriterion
    parameter_names: tuple[str, ...]
    parameters: FloatArray
    std_errors: FloatArray
    free: tuple[bool, ...]
    initial_state: FloatArray
    residuals: FloatArray = field(repr=False)
    criterion_value: float
    n_iterations: int
    converged: bool
    message: str
    raw: LMResult | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        for name in ("parameters", "std_errors", "initial_state", "residuals"):
            object.__setattr__(self, name, readonly_array(getattr(self, name)))

    def value(self, name: str) -> float:
        """Final value of the parameter called ``name``."""
        return float(self.parameters[self.parameter_names.index(name)])

    def std_error(self, name: str) -> float:
        """Standard error of the parameter called ``name`` (0.0 if it was fixed)."""
        return float(self.std_errors[self.parameter_names.index(name)])

    def as_dict(self) -> dict[str, float]:
        """``{name: value}`` of all parameters."""
        return {n: float(v) for n, v in zip(self.parameter_names, self.parameters, strict=True)}


# --------------------------------------------------------------------------- building
def _to_sx(value: Any, shape: tuple[int, int], what: str, structure: GreyBoxStructure) -> ca.SX:
    if value is None:
        return ca.SX.zeros(*shape)
    if isinstance(value, (ca.SX, ca.DM)):
        sx = ca.SX(value)
    else:
        arr = np.asarray(value, dtype=object)
        if arr.ndim == 0:
            arr = arr.reshape(1, 1)
        if arr.ndim == 1:
            arr = arr.reshape(shape) if arr.size == shape[0] * shape[1] else arr.reshape(1, -1)
        rows = [ca.horzcat(*[ca.SX(v) for v in row]) for row in arr]
        sx = ca.vertcat(*rows)
    if sx.shape != shape:
        raise IdentificationError(
            f"{structure.name}: matrices() returned {what} of shape {sx.shape}; expected {shape}")
    return sx


def _symbolic_matrices(structure: GreyBoxStructure, n_inputs: int) -> tuple[list[ca.SX], ca.SX]:
    """``[A, B, C, D, K]`` of the user's ``matrices`` on the symbols ``theta``, and ``theta``."""
    theta = ca.SX.sym("theta", structure.n_parameters)
    p = {n: theta[i] for i, n in enumerate(structure.parameter_names)}
    try:
        out = structure.matrices(p)
    except IdentificationError:
        raise
    except Exception as exc:  # the user's code: report where it failed
        raise IdentificationError(
            f"{structure.name}: matrices() failed on symbolic parameters: {exc}"
        ) from exc
    if not isinstance(out, tuple) or len(out) != 5:
        raise IdentificationError(
            f"{structure.name}: matrices() must return (A, B, C, D, K); got {type(out).__name__}")
    A_raw = out[0]
    a_shape = ca.SX(A_raw).shape if isinstance(A_raw, (ca.SX, ca.DM)) else np.shape(A_raw)
    if len(a_shape) != 2 or a_shape[0] != a_shape[1] or a_shape[0] < 1:
        raise IdentificationError(f"{structure.name}: A must be a square matrix; got shape {tuple(a_shape)}")
    n_x = int(a_shape[0])
    shapes = {"A": (n_x, n_x), "B": (n_x, n_inputs), "C": (1, n_x), "D": (1, n_inputs), "K": (n_x, 1)}
    return [_to_sx(mat, shape, what, structure)
            for mat, (what, shape) in zip(out, shapes.items(), strict=True)], theta


#: Samples per CasADi ``mapaccum`` block: building one grows faster than linearly in its
#: length (measured: 5 ms at 1000 samples, 100 ms at 12000) while the per-sample cost is
#: flat from a few hundred on, so long records run as a loop over blocks.
_BLOCK_SAMPLES = 1000


class _BlockRunner:
    """Run a step ``(z, u, y, *params) -> (z_next, out)`` over a record, `_BLOCK_SAMPLES`
    per ``mapaccum`` call; returns the outputs, shape ``(n_out, N)``."""

    def __init__(self, step: ca.Function, n_samples: int) -> None:
        self._block = min(_BLOCK_SAMPLES, n_samples)
        self._full = step.mapaccum("block", self._block)
        tail = n_samples % self._block
        # with no tail every block is full, so the tail is never called
        self._tail = step.mapaccum("tail", tail) if tail else self._full
        self._n_samples = n_samples

    def __call__(self, z0: FloatArray, U: FloatArray, Y: FloatArray, *params: FloatArray) -> FloatArray:
        chunks = []
        z = z0
        for start in range(0, self._n_samples, self._block):
            stop = min(start + self._block, self._n_samples)
            fun = self._full if stop - start == self._block else self._tail
            states, out = fun(z, U[:, start:stop], Y[:, start:stop], *params)
            chunks.append(np.asarray(out, dtype=float))
            z = np.asarray(states[:, -1], dtype=float).ravel()
        return np.hstack(chunks)


@dataclass(frozen=True, kw_only=True, eq=False)
class _Evaluator:
    """Residuals and exact Jacobian of one structure on one record.

    ``theta``: the free parameters, then the estimated initial state (if any).
    ``run_with_sensitivities`` carries ``(x, S = dx/dtheta)`` and outputs
    ``[r_k, dr_k/dtheta]`` per sample.
    """

    run: _BlockRunner                     # (x0, U, Y, theta_free, theta_fixed) -> R
    run_with_sensitivities: _BlockRunner  # (z0, U, Y, theta_free, theta_fixed) -> [R; dR]
    start: ca.Function                    # (theta, theta_fixed, u0, y0) -> (x0, S0)
    guess: ca.Function                    # (theta_free, theta_fixed, u0, y0) -> x_held
    U: FloatArray
    Y: FloatArray
    theta_fixed: FloatArray
    free: tuple[bool, ...]
    n_states: int
    n_estimated_states: int

    def initial(self, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Initial state ``x0`` (n_x,) and its sensitivity ``dx0/dtheta`` (n_x, q)."""
        x0, s0 = self.start(theta, self.theta_fixed, self.U[:, 0], self.Y[0, 0])
        return np.asarray(x0, dtype=float).ravel(), np.asarray(s0, dtype=float)

    def held_past_state(self, theta_free: FloatArray) -> FloatArray:
        """Held-past initial state at the given free parameter values."""
        x0 = self.guess(theta_free, self.theta_fixed, self.U[:, 0], self.Y[0, 0])
        return np.asarray(x0, dtype=float).ravel()

    def residuals(self, theta: FloatArray) -> FloatArray:
        """Residual sequence ``(N,)`` at the search vector ``theta``."""
        x0, _ = self.initial(theta)
        r = self.run(x0, self.U, self.Y, theta[: sum(self.free)], self.theta_fixed)
        return np.asarray(r, dtype=float).ravel()

    def residuals_and_jacobian(self, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Residuals ``(N,)`` and their exact Jacobian ``(N, q)`` at ``theta``."""
        x0, s0 = self.initial(theta)
        z0 = np.concatenate([x0, s0.ravel(order="F")])
        rows = np.asarray(self.run_with_sensitivities(
            z0, self.U, self.Y, theta[: sum(self.free)], self.theta_fixed), dtype=float)
        return rows[0].copy(), np.ascontiguousarray(rows[1:].T)


def _held_past_state(A: ca.SX, B: ca.SX, C: ca.SX, D: ca.SX, u0: ca.SX, y0: ca.SX) -> ca.SX:
    """State ``x_0`` of a model whose past inputs were ``u0`` and past outputs ``y0``.

    Solves for ``z = x_{-n}`` whose free run under ``u0`` outputs ``y0`` at ``j = -n ..
    -1`` (an invertible observability matrix), then steps to ``x_0``: for a polynomial
    model in observer form, the held-past rule of `sysid.simulate`.
    """
    n_x = A.shape[0]
    rows = []
    forced = []
    power = ca.SX.eye(n_x)
    acc = ca.SX.zeros(n_x, 1)          # state reached from z = 0 by j steps of u0
    for _ in range(n_x):
        rows.append(C @ power)
        forced.append(C @ acc + D @ u0)
        acc = A @ acc + B @ u0
        power = A @ power
    obs = ca.vertcat(*rows)
    z = ca.solve(obs, y0 - ca.vertcat(*forced))
    return power @ z + acc


def _build_evaluator(structure: GreyBoxStructure, *, U: FloatArray, Y: FloatArray,
                     criterion: GreyBoxCriterion, initial_state: InitialState) -> _Evaluator:
    n_inputs, n_samples = U.shape
    matrices, theta_sym = _symbolic_matrices(structure, n_inputs)
    n_x = matrices[0].shape[0]
    free = structure.free_mask
    n_par = sum(free)
    n_est = n_x if initial_state == "estimate" else 0
    q = n_par + n_est

    # the parameters as (free, fixed) symbols, substituted into the user's matrices
    th_free = ca.SX.sym("theta_free", n_par)
    th_fixed = ca.SX.sym("theta_fixed", len(free) - n_par)
    free_at, fixed_at = np.cumsum(free) - 1, np.cumsum(np.logical_not(free)) - 1
    theta_all = ca.vertcat(*(th_free[int(free_at[i])] if is_free else th_fixed[int(fixed_at[i])]
                             for i, is_free in enumerate(free)))
    A, B, C, D, K = (ca.substitute(mat, theta_sym, theta_all) for mat in matrices)

    x = ca.SX.sym("x", n_x)
    u = ca.SX.sym("u", n_inputs)
    y = ca.SX.sym("y", 1)
    residual = y - C @ x - D @ u
    if criterion == "ballistic":
        x_next = A @ x + B @ u
        # steady state of x = A x + B u0 (the input held at its first value)
        x_ss = ca.solve(ca.SX.eye(n_x) - A, B @ u)
    else:
        x_next = A @ x + B @ u + K @ residual
        # steady state of the predictor with (u0, y0) held
        x_ss = ca.solve(ca.SX.eye(n_x) - A + K @ C, (B - K @ D) @ u + K @ y)
    x_held = _held_past_state(A, B, C, D, u, y)

    # forward sensitivities S = dx/dtheta (n_x, q), carried with the state
    S = ca.SX.sym("S", n_x, q)
    pad = ca.SX.zeros(1, n_est)
    S_next = ca.jacobian(x_next, x) @ S + ca.horzcat(ca.jacobian(x_next, th_free), ca.SX.zeros(n_x, n_est))
    d_residual = ca.jacobian(residual, x) @ S + ca.horzcat(ca.jacobian(residual, th_free), pad)
    z = ca.vertcat(x, ca.vec(S))
    step_sens = ca.Function(
        "step_sens",
        [z, u, y, th_free, th_fixed],
        [ca.vertcat(x_next, ca.vec(S_next)), ca.vertcat(residual, ca.transpose(d_residual))])
    step = ca.Function("step", [x, u, y, th_free, th_fixed], [x_next, residual])

    if initial_state == "estimate":
        th_est = ca.SX.sym("x0", n_est)
        start = ca.Function(
            "start",
            [ca.vertcat(th_free, th_est), th_fixed, u, y],
            [th_est, ca.horzcat(ca.SX.zeros(n_x, n_par), ca.SX.eye(n_x))])
    else:
        x_start = x_ss if initial_state == "steady" else x_held
        start = ca.Function("start", [th_free, th_fixed, u, y], [x_start, ca.jacobian(x_start, th_free)])
    return _Evaluator(
        run=_BlockRunner(step, n_samples), run_with_sensitivities=_BlockRunner(step_sens, n_samples),
        start=start, guess=ca.Function("guess", [th_free, th_fixed, u, y], [x_held]), U=U, Y=Y,
        theta_fixed=np.asarray(structure.initial_values)[~np.asarray(free)], free=free,
        n_states=n_x, n_estimated_states=n_est)


# --------------------------------------------------------------------------- inputs
def _model_inputs(structure: GreyBoxStructure, u: FloatArray) -> FloatArray:
    if structure.input_map is None:
        features = u.reshape(-1, 1) if u.ndim == 1 else u
    else:
        features = np.asarray(structure.input_map(u), dtype=float)
        if features.ndim == 1:
            features = features.reshape(-1, 1)
    if features.ndim != 2 or features.shape[0] != u.shape[0]:
        raise IdentificationError(
            f"{structure.name}: input_map must return shape (n_samples, n_inputs) = "
            f"({u.shape[0]}, n_u); got {features.shape}")
    if not np.all(np.isfinite(features)):
        raise IdentificationError(f"{structure.name}: input_map returned non-finite values")
    return np.ascontiguousarray(features, dtype=float)


# --------------------------------------------------------------------------- public API
def _prepare(structure: GreyBoxStructure, y: Any, u: Any, criterion: str, initial_state: str
             ) -> _Evaluator:
    """Check the options and signals and build the structure's `_Evaluator` on them."""
    if criterion not in ("ballistic", "one_step"):
        raise IdentificationError(
            f"fit_greybox: criterion must be 'ballistic' or 'one_step'; got {criterion!r}")
    if initial_state not in ("held_past", "steady", "estimate"):
        raise IdentificationError(
            "fit_greybox: initial_state must be 'held_past', 'steady' or 'estimate'; "
            f"got {initial_state!r}")
    y_arr = np.asarray(y, dtype=float)
    u_arr = np.asarray(u, dtype=float)
    if y_arr.ndim != 1:
        raise IdentificationError(f"fit_greybox: y must be 1-D (n_samples,); got shape {y_arr.shape}")
    if u_arr.ndim not in (1, 2) or u_arr.shape[0] != y_arr.shape[0]:
        raise IdentificationError(
            f"fit_greybox: u must have shape ({y_arr.shape[0]},) or ({y_arr.shape[0]}, m) like y; "
            f"got {u_arr.shape}")
    if not (np.all(np.isfinite(y_arr)) and np.all(np.isfinite(u_arr))):
        raise IdentificationError(
            "fit_greybox: y and u must be finite (repair missing samples before fitting)")
    features = _model_inputs(structure, u_arr)
    return _build_evaluator(
        structure,
        U=np.ascontiguousarray(features.T),
        Y=y_arr.reshape(1, -1).copy(),
        criterion=criterion,  # type: ignore[arg-type]
        initial_state=initial_state,  # type: ignore[arg-type]
    )


def greybox_residuals(
    structure: GreyBoxStructure,
    y: FloatArray,
    u: FloatArray,
    *,
    criterion: GreyBoxCriterion = "ballistic",
    initial_state: Literal["held_past", "steady"] = "held_past",
) -> FloatArray:
    """Residuals of a structure at its initial values (no fitting).

    Parameters
    ----------
    structure :
        The model; every parameter is taken at its initial value.
    y :
        Measured output (deviation) [kW], shape ``(n_samples,)``.
    u :
        Measured input (deviation), shape ``(n_samples,)`` or ``(n_samples, m)``.
    criterion :
        ``"ballistic"`` (simulation error, eq. 9) or ``"one_step"`` (innovations, eq. 10).
    initial_state :
        ``"held_past"`` or ``"steady"``, as in `fit_greybox`.

    Returns
    -------
    FloatArray
        Residual sequence, shape ``(n_samples,)``.

    Raises
    ------
    IdentificationError
        As `fit_greybox` for malformed signals, options or structures.
    """
    evaluator = _prepare(structure, y, u, criterion, initial_state)
    values = np.asarray(structure.initial_values)
    return evaluator.residuals(values[np.asarray(structure.free_mask)])


def fit_greybox(
    structure: GreyBoxStructure,
    y: FloatArray,
    u: FloatArray,
    *,
    criterion: GreyBoxCriterion = "ballistic",
    initial_state: InitialState = "held_past",
    max_iterations: int = 100,
    xtol: float = 1e-10,
    ftol: float = 1e-12,
    gtol: float = 1e-10,
    warn: bool = True,
) -> GreyBoxResult:
    """Fit the free parameters of a grey-box structure by the prediction-error method.

    Parameters
    ----------
    structure :
        The parameterized model; its initial values start the search.
    y :
        Measured output as deviation from the operating point [kW], ``(n_samples,)``.
    u :
        Measured input as deviation (``ds`` [%]), ``(n_samples,)`` or
        ``(n_samples, m)``; `GreyBoxStructure.input_map` turns it into the model input.
    criterion :
        ``"ballistic"``: minimize ``V`` (eq. 9), ``K`` ignored. ``"one_step"``:
        minimize ``W`` (eq. 10) with the innovations predictor.
    initial_state :
        ``"held_past"``: ``x_0`` of a model whose past inputs were ``u_0`` and past
        outputs ``y_0`` (the rule of `sysid.simulate`, so V and W agree with
        `sysid.criteria`; needs an observable ``(A, C)``). ``"steady"``: the steady state
        of the model (or predictor) at the first sample. Both are differentiated with the
        parameters. ``"estimate"``: ``n_x`` extra free parameters, started held-past.
    max_iterations :
        Most Levenberg-Marquardt iterations.
    xtol, ftol, gtol :
        Tolerances on the step, the relative cost decrease and the gradient
        (`sysid.optimize.levenberg_marquardt`).
    warn :
        Emit an `IdentificationWarning` if the search did not converge.

    Returns
    -------
    GreyBoxResult
        The best iterate found, its standard errors and residuals.

    Raises
    ------
    IdentificationError
        Bad options; ``y``/``u`` of wrong shape or non-finite; fewer samples than
        free parameters plus one; a constant input (nothing to identify); a
        structure whose ``matrices`` or ``input_map`` fail or return wrong shapes.

    Warns
    -----
    IdentificationWarning
        The search stopped before converging (the best iterate is returned, with
        ``converged=False``).

    Notes
    -----
    The residuals are a CasADi ``mapaccum`` of ``(x_k, S_k, u_k, y_k) -> (x_{k+1},
    S_{k+1}, r_k, dr_k/dtheta)`` with ``S = dx/dtheta``: an exact Jacobian. Standard
    errors assume white residuals (optimistic for V on coloured noise).
    """
    max_iterations = checked_int(max_iterations, 1, "fit_greybox: max_iterations")
    for tol_name, tol in (("xtol", xtol), ("ftol", ftol), ("gtol", gtol)):
        if not (math.isfinite(tol) and tol >= 0):
            raise IdentificationError(f"fit_greybox: {tol_name} must be finite and >= 0; got {tol}")
    evaluator = _prepare(structure, y, u, criterion, initial_state)
    n_samples = evaluator.Y.shape[1]
    n_est = evaluator.n_estimated_states
    n_unknown = structure.n_free + n_est
    if n_unknown == 0:
        raise IdentificationError(f"{structure.name}: no free parameter to fit")
    if n_samples <= n_unknown:
        raise IdentificationError(
            f"fit_greybox: need more samples than free parameters ({n_unknown}); got {n_samples}")
    if np.all(np.ptp(evaluator.U, axis=1) == 0.0):
        raise IdentificationError(
            "fit_greybox: the input never changes over the record; expected an exciting "
            "input (steps or noise) to identify dynamics from")

    free = np.asarray(structure.free_mask)
    values = np.asarray(structure.initial_values)
    lower = np.asarray(structure.lower)[free]
    upper = np.asarray(structure.upper)[free]
    theta0 = values[free]
    if n_est:
        theta0 = np.concatenate([theta0, evaluator.held_past_state(theta0)])
        lower = np.concatenate([lower, np.full(n_est, -np.inf)])
        upper = np.concatenate([upper, np.full(n_est, np.inf)])
    n_par_free = structure.n_free

    def full_values(theta: FloatArray) -> FloatArray:
        out = values.copy()
        out[free] = theta[:n_par_free]
        return out

    project = None
    if structure.project is not None:
        user_project = structure.project

        def project(theta: FloatArray) -> FloatArray:
            projected = np.asarray(user_project(full_values(theta)), dtype=float)
            out = theta.copy()
            out[:n_par_free] = projected[free]
            return out

        theta0 = project(theta0)

    lm = levenberg_marquardt(
        evaluator.residuals_and_jacobian, theta0,
        lower=None if np.all(np.isinf(lower)) else lower,
        upper=None if np.all(np.isinf(upper)) else upper,
        project=project, max_iterations=max_iterations, xtol=xtol, ftol=ftol, gtol=gtol)
    theta = np.asarray(lm.theta, dtype=float)
    x0, _ = evaluator.initial(theta)
    std_errors = np.zeros(structure.n_parameters)
    std_errors[free] = parameter_std_errors(lm.jacobian, lm.residuals)[:n_par_free]
    residuals = np.asarray(lm.residuals, dtype=float)
    if warn and not lm.converged:
        warnings.warn(
            f"{structure.name}: the prediction-error search did not converge after "
            f"{lm.n_iterations} iterations ({lm.message}); the best iterate is kept",
            IdentificationWarning,
            stacklevel=2)
    return GreyBoxResult(
        structure=structure, criterion=criterion, parameter_names=structure.parameter_names,
        parameters=full_values(theta), std_errors=std_errors, free=structure.free_mask,
        initial_state=x0, residuals=residuals, criterion_value=float(np.mean(residuals**2)),
        n_iterations=int(lm.n_iterations), converged=bool(lm.converged),
        message=str(lm.message), raw=lm)


__all__ = [
    "GreyBoxCriterion", "GreyBoxResult", "GreyBoxStructure", "InitialState", "fit_greybox",
    "greybox_residuals"
]
