"""Matrix-vector products summed in one fixed order, the generated C step's (issue 42).

``y_i = (...((M_i0 v_0 + M_i1 v_1) + M_i2 v_2) + ...)``: every term ``M_ij v_j``
rounded on its own (an elementwise multiply, never fused into a multiply-add), then
the terms added in column order, starting from the first.

Why not ``M @ v``: numpy hands it to BLAS, whose summation order (blocking, fused
multiply-adds) belongs to the library and to the kernel it picks for the CPU at run
time (OpenBLAS's DYNAMIC_ARCH chose "Haswell" on the AMD EPYC this was measured on;
numpy on macOS uses Accelerate). One ulp in the QP's linear cost changes OSQP's
iterates and, over a closed-loop run, its iteration counts: with BLAS products, 5 of 8
fuzzed controllers drifted from their generated C step (`czmpc.codegen`) by up to
1e-3 % within 100 samples; with this order all 8 were bit-equal over 2,500 samples.
A C step cannot equal a sum whose order is chosen at run time; it can equal this one.

How: the terms are formed in a Fortran-ordered work array and reduced over the
columns by ``np.add.reduce``. Over an axis that is not the fast one in memory numpy
adds the slices one after the other (pairwise summation is used only along the fast
axis: the notes of `numpy.sum`), which is this order; a one-row product is summed in
Python (numpy would sum it pairwise). Measured cost: 2.3 to 6 us per product of the
controller's sizes, against 0.5 to 0.7 us for BLAS.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from sysid._typing import FloatArray


def ordered_dot(a: Iterable[float], b: Iterable[float]) -> float:
    """``sum_j a_j b_j`` in index order from 0 (module notes), as a Python float."""
    acc = 0.0
    for x, y in zip(a, b, strict=True):
        acc += x * y
    return acc


class OrderedProduct:
    """``y = M v`` in the fixed order of the module notes, with its work array kept.

    Parameters
    ----------
    matrix :
        (m, n) ``M`` (copied).

    Raises
    ------
    ValueError
        If ``matrix`` is not 2-d or has no column.
    """

    __slots__ = ("_m", "_rows", "_terms")

    def __init__(self, matrix: FloatArray) -> None:
        m = np.array(matrix, dtype=float, order="F")
        if m.ndim != 2 or m.shape[1] == 0:
            raise ValueError(f"OrderedProduct: matrix must be 2-d with at least one column; "
                             f"got shape {m.shape}")
        m.flags.writeable = False
        self._m = m
        self._terms = np.empty(m.shape, order="F")
        self._rows = m.tolist() if m.shape[0] == 1 else None

    @property
    def matrix(self) -> FloatArray:
        """(m, n) ``M`` (read-only)."""
        return self._m

    def __call__(self, v: FloatArray, out: FloatArray | None = None) -> FloatArray:
        """Return ``M v`` ((m,) from (n,) ``v``), into ``out`` if given."""
        if self._rows is not None:
            y = ordered_dot(self._rows[0], np.asarray(v, dtype=float).tolist())
            if out is None:
                return np.array([y])
            out[0] = y
            return out
        np.multiply(self._m, v, out=self._terms)
        return np.add.reduce(self._terms, axis=1, out=out)


__all__ = ["OrderedProduct", "ordered_dot"]
