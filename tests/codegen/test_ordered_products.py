"""`czmpc.ordered`: the Python controller's products sum in the generated C's order.

The reference is the C's loop written out in Python (``acc = 0; acc += M_ij v_j`` for j
in order), on every shape the controller uses and beyond, with entries spread over 16
decades so that any other order shows in the last bits.
"""

from __future__ import annotations

import numpy as np
import pytest

from czmpc.ordered import OrderedProduct, ordered_dot


def _c_loop(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = []
    for row in m.tolist():
        acc = 0.0
        for a, b in zip(row, v.tolist(), strict=True):
            acc += a * b
        out.append(acc)
    return np.array(out)


def test_products_equal_the_c_loop_bit_for_bit() -> None:
    rng = np.random.default_rng(42)
    n_other = 0
    for rows in range(1, 46):
        for cols in range(1, 91, 4):
            m = rng.standard_normal((rows, cols)) * 10.0 ** rng.uniform(-8, 8, (rows, cols))
            v = rng.standard_normal(cols) * 10.0 ** rng.uniform(-4, 4, cols)
            want = _c_loop(m, v)
            product = OrderedProduct(m)
            assert np.array_equal(product(v), want), (rows, cols)
            out = np.empty(rows)
            assert product(v, out=out) is out and np.array_equal(out, want)
            n_other += not np.array_equal(m @ v, want)
    # the reference tells orders apart: BLAS's differs on many of these shapes
    assert n_other > 100


def test_ordered_dot_is_the_c_loop() -> None:
    a, b = [1e16, 1.0, -1e16, 1.0], [1.0, 1.0, 1.0, 1.0]
    assert ordered_dot(a, b) == ((1e16 + 1.0) - 1e16) + 1.0 == 1.0
    with pytest.raises(ValueError):
        ordered_dot([1.0], [1.0, 2.0])


def test_a_product_needs_a_matrix_with_columns() -> None:
    with pytest.raises(ValueError, match="2-d"):
        OrderedProduct(np.ones(3))
    with pytest.raises(ValueError, match="2-d"):
        OrderedProduct(np.ones((3, 0)))
