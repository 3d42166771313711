"""Residuals and exact Jacobians of Hammerstein OE and ARMAX models by sensitivity filters.

Kernels on plain arrays (STYLE B.14.2): a record is a sequence of segments, each a pair
``(y, ds)`` of deviation arrays, and each segment has its own initial state. They
replace the per-sample CasADi evaluation of `sysid.greybox` for the Hammerstein
structures of `sysid.hammerstein.model` (same parameter names and order), with
`scipy.signal.lfilter` doing every recursion.

Initial state
-------------
Every policy is written as a transient ``h`` of ``n = max(nf, nk + nb - 1)`` samples
(OE; ``max(na, nc, nk + nb - 1)`` for ARMAX) added to the filter input, which is what
any initial state of the observer form does to the output::

    OE:     F(q) yhat = B(q) f(ds) + h,        eps = y - yhat                   (eq. 26)
    ARMAX:  C(q) e    = A(q) y - B(q) f(ds) + g                                 (eq. 30)

with every signal zero before the segment. ``"estimate"`` makes ``h`` (``g``) free
parameters of each segment, as MATLAB's ``'estimate'`` does for the full state;
``"held"`` computes it from a past held at the first sample (``y_0``, ``ds_0``; past
prediction errors zero), the rule of `sysid.simulate`; ``"zero"`` sets it to zero (the
record starts at rest at the operating point).

Jacobians
---------
With ``w = f(ds) = sum_i d_i ds^i`` and ``beta`` the full ``B`` (``beta_nk = 1``),
``d yhat/d theta = (dS/d theta) / F`` where ``S = B w + h`` minus the ``F`` terms
on the past of ``yhat``: ``q^-j w`` for ``b_j``, ``B ds^i`` for ``d_i``, ``-q^-i yhat``
for ``f_i`` (all with a zero past), plus ``d h/d theta`` (held: ``w_0``, ``ds_0^i
sum_{j>k} beta_j``, ``-y_0``; estimate: unit pulses). ARMAX likewise through ``1/C``
with ``c_i = a_i + k_i`` (eq. 32), so ``d/d a_i`` adds the ``c_i`` column.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.signal import lfilter

from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.errors import IdentificationError
from sysid.polynomials import impulse_response

InitialState = Literal["estimate", "zero", "held"]
INITIAL_STATES: tuple[InitialState, ...] = ("estimate", "zero", "held")

Segment = tuple[FloatArray, FloatArray]
#: A segment's grid-voltage drive ``(v^2, o)``: the powers ``ds^i`` are scaled by ``v^2``
#: and the known input ``o = (v^2 - 1) W0`` is added, so the linear block sees
#: ``w_eff = v^2 f(ds) + (v^2 - 1) W0`` (`sysid.hammerstein.voltage`).
Drive = tuple[FloatArray, FloatArray]


@dataclass(frozen=True, slots=True, eq=False)
class _Prepared:
    """One segment ready for the kernels: output, input regressors and the known input."""

    y: FloatArray
    feats: FloatArray          # ds^i (times v^2 under a drive), shape (N, degree)
    off: FloatArray | None     # known input added to w, or None
    ds0: float                 # the first input deviation
    v20: float                 # the first v^2 (1.0 without a drive)


def check_initial_state(value: object, where: str) -> InitialState:
    """``value`` as an `InitialState`, or an `IdentificationError` naming the choices."""
    for choice in INITIAL_STATES:
        if value == choice:
            return choice
    raise IdentificationError(
        f"{where}: initial_state must be one of {list(INITIAL_STATES)}; got {value!r}"
    )


@dataclass(frozen=True, kw_only=True, slots=True)
class HammersteinOrders:
    """Orders of a Hammerstein model with an OE or ARMAX linear block.

    Parameters
    ----------
    block :
        ``"oe"`` (parameters ``b.., d.., f1..f_na``) or ``"armax"`` (``b.., d..,
        a1..a_na, k1..k_nc``), as `sysid.hammerstein.model`'s structures.
    degree, nb, na, nc, nk :
        Degree of ``f`` (no constant term); number of ``B`` coefficients including the
        normalized ``b_nk = 1``; order of ``F`` (OE) or ``A`` (ARMAX); order of ``C``
        (ARMAX; ignored for OE); delay [samples].
    """

    block: Literal["oe", "armax"]
    degree: int
    nb: int
    na: int
    nc: int
    nk: int

    def __post_init__(self) -> None:
        if self.block not in ("oe", "armax"):
            raise IdentificationError(
                f"HammersteinOrders: block must be 'oe' or 'armax'; got {self.block!r}"
            )
        for name, minimum in (("degree", 1), ("nb", 1), ("na", 0), ("nc", 0), ("nk", 0)):
            object.__setattr__(self, name, checked_int(getattr(self, name), minimum,
                                                       f"HammersteinOrders: {name}"))

    @property
    def n_model(self) -> int:
        """Number of model parameters (without initial states)."""
        extra = self.nc if self.block == "armax" else 0
        return self.nb - 1 + self.degree + self.na + extra

    @property
    def n_state(self) -> int:
        """Length of each segment's transient (the state dimension of the observer form)."""
        nc = self.nc if self.block == "armax" else 0
        return max(self.na, nc, self.nk + self.nb - 1)

    def parameter_names(self) -> tuple[str, ...]:
        """Model parameter names, in the order of the parameter vector."""
        names = tuple(f"b{j}" for j in range(self.nk + 1, self.nk + self.nb))
        names += tuple(f"d{i}" for i in range(1, self.degree + 1))
        if self.block == "oe":
            return names + tuple(f"f{i}" for i in range(1, self.na + 1))
        return names + tuple(f"a{i}" for i in range(1, self.na + 1)) + tuple(
            f"k{i}" for i in range(1, self.nc + 1))

    def polynomials(self, theta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(A or F, beta, C, input_poly)`` from the model parameters (first `n_model`)."""
        nb1 = self.nb - 1
        beta = np.concatenate([np.zeros(self.nk), [1.0], theta[:nb1]])
        poly = np.asarray(theta[nb1 : nb1 + self.degree], dtype=float)
        i0 = nb1 + self.degree
        a = np.concatenate([[1.0], theta[i0 : i0 + self.na]])
        if self.block == "oe":
            return a, beta, a, poly
        k = theta[i0 + self.na : i0 + self.na + self.nc]
        c = np.zeros(self.nc + 1)
        c[0] = 1.0
        for i in range(1, self.nc + 1):
            c[i] = (a[i] if i <= self.na else 0.0) + k[i - 1]
        return a, beta, c, poly


def _tail_sums(coef: FloatArray, n: int) -> FloatArray:
    """``s_k = sum_{j > k} coef_j`` for ``k = 0..n-1`` (``coef_j = 0`` beyond its end)."""
    padded = np.zeros(max(n + 1, coef.size))
    padded[: coef.size] = coef
    return np.array([float(np.sum(padded[k + 1 :])) for k in range(n)])


def _fir(coef: FloatArray, x: FloatArray) -> FloatArray:
    """``sum_j coef_j x[k - j]`` with a zero past, of a 1-D record.

    What ``lfilter(coef, [1.0], x)`` computes, by `numpy.convolve`: a tenth of its time
    on these records, and every residual evaluation has two.
    """
    out: FloatArray = np.convolve(x, coef)[: x.size]
    return out


#: A segment's Jacobian, made on request: ``[d r/d theta_model, d r/d transient]`` in one
#: column-major block (the transient's columns only under ``"estimate"``).
SegmentJacobian = Callable[[], FloatArray]


def _powers(ds: FloatArray, degree: int) -> FloatArray:
    """``(N, degree)``: column ``i`` is ``ds^(i+1)``, the regressors of ``f`` (eq. 22)."""
    return np.column_stack([ds**i for i in range(1, degree + 1)])


def _put_lag(out: FloatArray, col: int, x: FloatArray, lag: int, sign: float = 1.0) -> None:
    """``out[:, col] = sign * x[k - lag]`` with zeros before the start (all of a segment
    no longer than ``lag``)."""
    out[:lag, col] = 0.0
    if lag >= x.size:   # x[: size - lag] would count from the end
        return
    if sign == 1.0:
        out[lag:, col] = x[: x.size - lag]
    else:
        np.negative(x[: x.size - lag], out=out[lag:, col])


def _jacobian_block(n_samples: int, n_model: int, n_state: int,
                    initial_state: InitialState) -> FloatArray:
    return np.empty((n_samples, n_model + (n_state if initial_state == "estimate" else 0)),
                    order="F")


def _input_columns(out: FloatArray, w_f: FloatArray, feats_f: FloatArray, beta: FloatArray,
                   orders: HammersteinOrders) -> int:
    """The input block's columns of a segment's Jacobian; returns the next column.

    ``d eps/d b_j = -q^-j w_f`` (``j = nk+1 .. nk+nb-1``; ``b_nk`` is fixed by the gain
    normalisation) and ``d eps/d alpha_i = -B feats_f[:, i]``, with ``w_f`` and ``feats_f``
    the gain ``w`` and the input powers through the block's denominator (``F`` or ``C``).
    """
    col = 0
    for j in range(orders.nk + 1, orders.nk + orders.nb):
        _put_lag(out, col, w_f, j, -1.0)
        col += 1
    for i in range(orders.degree):
        np.negative(_fir(beta, feats_f[:, i]), out=out[:, col])
        col += 1
    return col


def _transient_columns(out: FloatArray, den: FloatArray, n_model: int, n_state: int,
                       initial_state: InitialState, d_state: list[FloatArray],
                       sign: float) -> None:
    """The transient's part of a segment's Jacobian, from one impulse response of ``1/den``.

    ``"estimate"``: its columns ``sign * q^-j h``. ``"held"``: the held past enters as the
    first ``n_state`` samples of the filter input, ``d_state[i]`` their derivatives by
    model parameter ``i``, so ``out[:, i] += sign * sum_j d_state[i][j] q^-j h``
    (``d_state`` is read under ``"held"`` only).
    """
    if initial_state == "zero" or n_state == 0:
        return
    h = impulse_response(den, out.shape[0])
    if initial_state == "estimate":
        for j in range(n_state):
            _put_lag(out, n_model + j, h, j, sign)
        return
    for i, dh in enumerate(d_state):
        for k in np.flatnonzero(dh).tolist():
            out[k:, i] += sign * float(dh[k]) * h[: h.size - k]


def _held_derivatives(orders: HammersteinOrders, beta: FloatArray, w0: float, ds0: float,
                      y0: float, v20: float = 1.0) -> list[FloatArray]:
    """``d h/d theta`` of the OE held-past transient ``h = w_0 S(beta) - y_0 S(f)`` by ``b, d, f``.

    ``v20``: the first sample's ``v^2`` under a voltage drive (``d w_0/d d_i = v20 ds0^i``).
    """
    n = orders.n_state
    k_idx = np.arange(n)
    tail_beta = _tail_sums(beta, n)
    out = [np.where(k_idx < j, w0, 0.0) for j in range(orders.nk + 1, orders.nk + orders.nb)]
    out += [v20 * ds0**i * tail_beta for i in range(1, orders.degree + 1)]
    return out + [np.where(k_idx < i, -y0, 0.0) for i in range(1, orders.na + 1)]


def _oe_segment(
    orders: HammersteinOrders, theta: FloatArray, h_free: FloatArray | None, seg: _Prepared,
    initial_state: InitialState,
) -> tuple[FloatArray, SegmentJacobian]:
    """Simulation errors of one segment and the maker of their Jacobian.

    The sensitivities are shifts and FIR sums of three filterings by ``1/F``: of the
    input powers ``ds^i`` (``q^-j w / F`` is the shift of their combination ``w/F``,
    ``B ds^i / F`` their FIR), of ``yhat`` (``q^-i yhat / F``) and of a unit pulse
    (the transient's columns, and the held past's first samples through them).
    A voltage drive adds its known input to ``w`` (and, filtered, to ``w/F``).
    """
    f, beta, _, poly = orders.polynomials(theta)
    n = orders.n_state
    y, feats, off = seg.y, seg.feats, seg.off
    w = feats @ poly
    if off is not None:
        w = w + off
    src = _fir(beta, w)
    w0, ds0, y0 = float(w[0]), seg.ds0, float(y[0])
    if initial_state == "estimate" and h_free is not None:
        h = h_free
    elif initial_state == "held":
        h = w0 * _tail_sums(beta, n) - y0 * _tail_sums(f, n)
    else:
        h = np.zeros(n)
    src[: min(n, src.size)] += h[: src.size]
    yhat = lfilter([1.0], f, src)

    def jacobian() -> FloatArray:
        # d eps/d theta = -(d yhat/d theta): every column written with its sign
        feats_f = lfilter([1.0], f, feats, axis=0)
        w_f = feats_f @ poly
        if off is not None:
            w_f = w_f + lfilter([1.0], f, off)
        yhat_f = lfilter([1.0], f, yhat)
        out = _jacobian_block(y.size, orders.n_model, n, initial_state)
        col = _input_columns(out, w_f, feats_f, beta, orders)
        for i in range(1, orders.na + 1):
            _put_lag(out, col, yhat_f, i)
            col += 1
        d_state = (_held_derivatives(orders, beta, w0, ds0, y0, seg.v20)
                   if initial_state == "held" else [])
        _transient_columns(out, f, orders.n_model, n, initial_state, d_state, -1.0)
        return out

    return y - yhat, jacobian


def _armax_segment(
    orders: HammersteinOrders, theta: FloatArray, g_free: FloatArray | None, seg: _Prepared,
    initial_state: InitialState,
) -> tuple[FloatArray, SegmentJacobian]:
    """One-step prediction errors of one segment and the maker of their Jacobian.

    As `_oe_segment` through ``1/C``: filterings of ``ds^i``, ``y``, ``e`` and a pulse.
    """
    a, beta, c, poly = orders.polynomials(theta)
    n, na, nc = orders.n_state, orders.na, orders.nc
    y, feats, off = seg.y, seg.feats, seg.off
    w = feats @ poly
    if off is not None:
        w = w + off
    v = _fir(a, y) - _fir(beta, w)
    w0, ds0, y0 = float(w[0]), seg.ds0, float(y[0])
    if initial_state == "estimate" and g_free is not None:
        g = g_free
    elif initial_state == "held":
        g = y0 * _tail_sums(a, n) - w0 * _tail_sums(beta, n)
    else:
        g = np.zeros(n)
    v[: min(n, v.size)] += g[: v.size]
    e = lfilter([1.0], c, v)

    def jacobian() -> FloatArray:
        feats_c = lfilter([1.0], c, feats, axis=0)
        w_c = feats_c @ poly
        if off is not None:
            w_c = w_c + lfilter([1.0], c, off)
        e_c = lfilter([1.0], c, e) if nc else e
        y_c = lfilter([1.0], c, y) if na else y
        out = _jacobian_block(y.size, orders.n_model, n, initial_state)
        col = _input_columns(out, w_c, feats_c, beta, orders)
        for i in range(1, na + 1):  # c_i = a_i + k_i: d/d a_i also moves C
            _put_lag(out, col, y_c, i)
            if i <= nc:
                out[i:, col] -= e_c[: y.size - i]
            col += 1
        for i in range(1, nc + 1):
            _put_lag(out, col, e_c, i, -1.0)
            col += 1
        d_state: list[FloatArray] = []
        if initial_state == "held":  # g = -h of OE's held past, nothing from the k_i
            d_state = [-d for d in _held_derivatives(orders, beta, w0, ds0, y0, seg.v20)
                       ] + [np.zeros(n)] * nc
        _transient_columns(out, c, orders.n_model, n, initial_state, d_state, 1.0)
        return out

    return e, jacobian


def _segment_terms(
    orders: HammersteinOrders, theta: FloatArray, prepared: Sequence[_Prepared],
    initial_state: InitialState,
) -> list[tuple[FloatArray, SegmentJacobian]]:
    """Each segment's residuals and Jacobian maker; ``theta`` as `segment_residuals`.

    ``prepared``: each segment from `_prepare`.
    """
    kernel = _oe_segment if orders.block == "oe" else _armax_segment
    p_model, n = orders.n_model, orders.n_state
    estimate = initial_state == "estimate"
    return [kernel(orders, theta[:p_model],
                   theta[p_model + s * n : p_model + (s + 1) * n] if estimate else None,
                   seg, initial_state)
            for s, seg in enumerate(prepared)]


def _prepare_one(orders: HammersteinOrders, y: FloatArray, ds: FloatArray,
                 drive: Drive | None) -> _Prepared:
    feats = _powers(ds, orders.degree)
    if drive is None:
        return _Prepared(y=y, feats=feats, off=None, ds0=float(feats[0, 0]), v20=1.0)
    v2, off = drive
    if v2.shape != y.shape or off.shape != y.shape:
        raise IdentificationError(
            f"a segment's voltage drive must have its {y.size} samples; got shapes "
            f"{v2.shape} and {off.shape}")
    return _Prepared(y=y, feats=feats * v2[:, None], off=off, ds0=float(feats[0, 0]),
                     v20=float(v2[0]))


def _prepare(orders: HammersteinOrders, segments: Sequence[Segment],
             drives: Sequence[Drive] | None = None) -> list[_Prepared]:
    """Each segment's regressors; `drives` (one per segment) applies a grid voltage."""
    if drives is None:
        return [_prepare_one(orders, y, ds, None) for y, ds in segments]
    if len(drives) != len(segments):
        raise IdentificationError(
            f"expected one voltage drive per segment ({len(segments)}); got {len(drives)}")
    return [_prepare_one(orders, y, ds, d) for (y, ds), d in zip(segments, drives, strict=True)]


def _stacked_jacobian(orders: HammersteinOrders, terms: list[tuple[FloatArray, SegmentJacobian]],
                      n_theta: int, initial_state: InitialState) -> FloatArray:
    """The Jacobian over all segments: shared model columns, each segment's own transient."""
    if len(terms) == 1:  # one segment: its block is the whole Jacobian
        return terms[0][1]()
    p_model, n = orders.n_model, orders.n_state
    jac = np.zeros((sum(r.size for r, _ in terms), n_theta), order="F")
    row = 0
    for s, (res, make) in enumerate(terms):
        block = make()
        jac[row : row + res.size, :p_model] = block[:, :p_model]
        if initial_state == "estimate":
            jac[row : row + res.size, p_model + s * n : p_model + (s + 1) * n] = block[:, p_model:]
        row += res.size
    return jac


def segment_residuals(
    orders: HammersteinOrders,
    theta: FloatArray,
    segments: Sequence[Segment],
    initial_state: InitialState,
    *,
    jacobian: bool = True,
    drives: Sequence[Drive] | None = None,
) -> tuple[FloatArray, FloatArray | None]:
    """Residuals over all segments (concatenated) and their Jacobian.

    Parameters
    ----------
    orders :
        The structure.
    theta :
        Model parameters (`HammersteinOrders.n_model`), followed, for ``"estimate"``,
        by ``n_state`` transient values per segment.
    segments :
        ``(y, ds)`` deviation arrays, each segment at least one sample long.
    initial_state :
        See the module docstring.
    jacobian :
        Also return the Jacobian ``d r/d theta``, shape ``(N_total, len(theta))``.
    drives :
        Each segment's grid-voltage `Drive`, or None (no voltage compensation).

    Returns
    -------
    tuple
        ``(r, J)`` with ``r`` the simulation errors (OE, V) or one-step prediction
        errors (ARMAX, W); ``J`` None when not asked for.
    """
    terms = _segment_terms(orders, theta, _prepare(orders, segments, drives), initial_state)
    r = np.concatenate([res for res, _ in terms])
    if not jacobian:
        return r, None
    return r, _stacked_jacobian(orders, terms, theta.size, initial_state)


def estimate_transients(
    orders: HammersteinOrders, theta_model: FloatArray, segments: Sequence[Segment],
    *, fit_samples: int | None = None, drives: Sequence[Drive] | None = None,
) -> FloatArray:
    """Least-squares initial transients of every segment for fixed model parameters.

    The residuals are affine in the transients, so one least-squares solve per segment
    gives the exact minimum of V (OE) or W (ARMAX) over the initial state. With
    ``fit_samples``, only each segment's first samples are fitted (a burn-in);
    ``drives`` as `segment_residuals`.

    Returns
    -------
    FloatArray
        ``n_state`` values per segment, concatenated, shape ``(n_segments * n_state,)``.
    """
    n = orders.n_state
    if n == 0:
        return np.zeros(0)
    oe = orders.block == "oe"
    kernel = _oe_segment if oe else _armax_segment
    den = orders.polynomials(theta_model)[2]  # F (OE) or C (ARMAX)
    out = []
    for seg in _prepare(orders, segments, drives):
        # r = r0 + P h is affine in h: h = argmin |r0 + P h|, P the Jacobian's transient columns
        y = seg.y
        r0, _ = kernel(orders, theta_model, np.zeros(n), seg, "estimate")
        pulses = np.empty((y.size, n), order="F")
        _transient_columns(pulses, den, 0, n, "estimate", [], -1.0 if oe else 1.0)
        m = y.size if fit_samples is None else fit_samples
        out.append(np.linalg.lstsq(pulses[:m], -r0[:m], rcond=None)[0])
    return np.concatenate(out)


def mean_square_criterion(
    orders: HammersteinOrders,
    theta_model: FloatArray,
    segments: Sequence[Segment],
    initial_state: InitialState,
    drives: Sequence[Drive] | None = None,
) -> float:
    """V (OE) or W (ARMAX) over all segments under an initial-state policy.

    ``"estimate"`` scores the model with each segment's initial state fitted by least
    squares (`estimate_transients`); ``drives`` as `segment_residuals`.
    """
    theta = np.asarray(theta_model, dtype=float)
    if initial_state == "estimate":
        theta = np.concatenate([theta, estimate_transients(orders, theta, segments,
                                                           drives=drives)])
    r, _ = segment_residuals(orders, theta, segments, initial_state, jacobian=False,
                             drives=drives)
    return float(np.mean(r**2))


def residual_function(
    orders: HammersteinOrders, segments: Sequence[Segment], initial_state: InitialState,
    drives: Sequence[Drive] | None = None,
) -> Callable[[FloatArray], tuple[FloatArray, Callable[[], FloatArray]]]:
    """``fun(theta) -> (r, J)`` for `sysid.optimize.levenberg_marquardt`, ``J`` made on request
    (``drives`` as `segment_residuals`)."""

    prepared = _prepare(orders, segments, drives)

    def fun(theta: FloatArray) -> tuple[FloatArray, Callable[[], FloatArray]]:
        terms = _segment_terms(orders, theta, prepared, initial_state)
        r = terms[0][0] if len(terms) == 1 else np.concatenate([res for res, _ in terms])
        return r, lambda: _stacked_jacobian(orders, terms, theta.size, initial_state)

    return fun


__all__ = [
    "Drive",
    "INITIAL_STATES",
    "HammersteinOrders",
    "InitialState",
    "Segment",
    "check_initial_state",
    "estimate_transients",
    "mean_square_criterion",
    "residual_function",
    "segment_residuals",
]
