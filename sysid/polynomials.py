"""Polynomials in the backward shift q^-1: roots, stability, normalization.

Notation
--------
A polynomial ``p = [p0, p1, ..., pn]`` holds ascending powers of q^-1, so
``p(q) = p0 + p1 q^-1 + ... + pn q^-n`` (paper eqs. 1-4). Its roots in the z-plane are
the roots of ``p0 z^n + p1 z^(n-1) + ... + pn``, which is what `numpy.roots` computes
from the same coefficient list.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from sysid._typing import FloatArray


def roots_z(poly: FloatArray) -> npt.NDArray[np.complex128]:
    """Return the z-plane roots of a q^-1 polynomial (complex array, possibly empty)."""
    p = np.trim_zeros(np.asarray(poly, dtype=float), trim="b")
    if p.size <= 1:
        return np.zeros(0, dtype=complex)
    return np.asarray(np.roots(p), dtype=complex)


def max_root_modulus(poly: FloatArray) -> float:
    """Largest |z| among the roots of a monic q^-1 polynomial; 0.0 for a constant."""
    r = roots_z(poly)
    return float(np.max(np.abs(r))) if r.size else 0.0


def slowest_time_constant_samples(poly: FloatArray) -> float:
    """``-1 / ln|z|`` of the largest root of a q^-1 polynomial [samples].

    ``inf`` for a root on or outside the unit circle (an integrator or worse), 0.0 for a
    constant or roots only at ``z = 0``.
    """
    radius = max_root_modulus(poly)
    if radius >= 1.0:
        return float("inf")
    return 0.0 if radius == 0.0 else -1.0 / float(np.log(radius))


def is_stable(poly: FloatArray) -> bool:
    """True if every root of the q^-1 polynomial ``poly`` lies strictly inside |z| < 1.

    The Schur-Cohn step-down recursion: the last coefficient of each monic polynomial
    is a reflection coefficient, all of which must have modulus below one (Astrom and
    Wittenmark, Computer-Controlled Systems, sec. 3.3). The prediction-error searches
    test every trial point with it, so it runs on Python floats (a tenth of the time on
    numpy arrays; the roots would cost an eigenvalue problem).
    """
    a: list[float] = np.asarray(poly, dtype=float).reshape(-1).tolist()
    while a and a[-1] == 0.0:  # trailing zeros: roots at z = 0
        a.pop()
    if not a or a[0] == 0.0 or not all(math.isfinite(v) for v in a):
        return False
    a = [v / a[0] for v in a]
    for n in range(len(a) - 1, 0, -1):
        k = a[n]
        if not abs(k) < 1.0:
            return False
        a = [(a[i] - k * a[n - i]) / (1.0 - k * k) for i in range(n)]
    return True


def impulse_response(den: FloatArray, n_samples: int) -> FloatArray:
    """First ``n_samples`` of the impulse response of ``1/den`` (a monic ``den``).

    Every initial-state column of the sensitivity filters is it, delayed. A first-order
    ``den = [1, a1]`` gives the powers of ``-a1`` by `numpy.cumprod`: lfilter's products,
    bit for bit, at two thirds of its time.
    """
    den = np.asarray(den, dtype=float)
    if den.size == 2 and den[0] == 1.0:
        powers = np.full(n_samples, -float(den[1]))
        powers[:1] = 1.0
        out: FloatArray = np.cumprod(powers)
        return out
    pulse = np.zeros(n_samples)
    pulse[:1] = 1.0
    out = lfilter([1.0], den, pulse)
    return out


def reflect_unstable_roots(poly: FloatArray) -> FloatArray:
    """Mirror roots outside the unit circle to 1/conj(z) and return the monic polynomial.

    Used by the prediction-error searches to keep F(q) and C(q) stable: mirroring a root
    keeps the magnitude response up to a constant, the classical projection of
    Ljung (1999, sec. 10.1).
    """
    p = np.asarray(poly, dtype=float)
    if is_stable(p):
        return p.copy()
    r = roots_z(p)
    big = np.abs(r) >= 1.0
    if not np.any(big):  # also a constant, which has no roots
        return p.copy()
    r[big] = 1.0 / np.conj(r[big])
    # keep strictly inside: a root exactly on the circle is pulled in slightly
    on = np.abs(r) >= 1.0 - 1e-9
    r[on] *= (1.0 - 1e-6) / np.abs(r[on])
    out = np.real(np.poly(r))
    return np.asarray(out, dtype=float)


__all__ = ["impulse_response", "is_stable", "max_root_modulus", "reflect_unstable_roots", "roots_z"]
