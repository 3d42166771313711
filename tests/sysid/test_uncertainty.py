"""sysid.uncertainty: parameter names onto coefficients and back, and its refusals."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sysid.model import HammersteinModel
from sysid.uncertainty import ParameterError, model_parameters, model_with_parameters


def test_every_kind_of_name_maps_to_its_coefficient_and_back(
        paper_armax_model: HammersteinModel) -> None:
    m = paper_armax_model
    names = ("b2", "d1", "d2", "a1", "k1")
    theta = model_parameters(m, names)
    np.testing.assert_array_equal(theta, [m.b[2], m.input_poly[0], m.input_poly[1], m.a[1],
                                          m.c[1] - m.a[1]])
    moved = model_with_parameters(m, names, theta + np.array([0.0, 0.1, 0.0, -0.001, 0.01]))
    assert moved.input_poly[0] == pytest.approx(m.input_poly[0] + 0.1, abs=1e-15)
    assert moved.a[1] == pytest.approx(m.a[1] - 0.001, abs=1e-15)
    # k1 = C[1] - A[1]: C moves with A and by k1's own step
    assert moved.c[1] == pytest.approx(m.c[1] - 0.001 + 0.01, abs=1e-15)
    assert moved.covariance is None
    set_c = model_with_parameters(m, ("c1",), np.array([-0.5]))
    assert set_c.c[1] == -0.5 and set_c.a[1] == m.a[1]


def test_names_the_model_has_not_are_refused(paper_armax_model: HammersteinModel) -> None:
    with pytest.raises(ParameterError, match="parameter 'b9' does not exist"):
        model_parameters(paper_armax_model, ("b9",))
    with pytest.raises(ParameterError, match="cannot map parameter 'x'"):
        model_with_parameters(paper_armax_model, ("x",), np.array([1.0]))
    oe = dataclasses.replace(paper_armax_model, linear_block="oe", c=paper_armax_model.a)
    with pytest.raises(ParameterError, match="parameter 'k1' needs an ARMAX model"):
        model_parameters(oe, ("k1",))
