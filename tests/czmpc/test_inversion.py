"""f, its inverse on the monotone branch, branch limits, w-bounds and slope bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from czmpc.errors import DesignError
from czmpc.inversion import (
    InputMap,
    allowed_triac_range,
    build_input_map,
    clamp,
    evaluate,
    min_slope,
    monotone_branch,
    slope,
)
from sysid.model import HammersteinModel
from tests.tolerances import IDENTITY_RTOL

#: f(f^-1(w)) = w: the root formula loses at most a few ulps of w's scale (|w| <= 100).
ROUNDTRIP_ATOL_KW = 1e-12
#: Newton/bisection stops at a bracket of 1e-13 relative; f' <= 2 kW/% keeps w within this.
NEWTON_ATOL_KW = 1e-11


def _paper_map(model: HammersteinModel) -> InputMap:
    return build_input_map(model, triac_min_pct=0.0, triac_max_pct=100.0,
                           validity_margin_pct=5.0)


@pytest.fixture(scope="session")
def cubic_model(paper_armax_model: HammersteinModel) -> HammersteinModel:
    # f' = 1.35 - 0.013 ds + 3e-4 ds^2 has its minimum at ds = 21.7, inside (-30, 30).
    return paper_armax_model.with_updates(input_poly=[1.35, -0.0065, 1e-4])


def test_f_matches_the_model_polynomial(paper_armax_model: HammersteinModel) -> None:
    ds = np.linspace(-40.0, 30.0, 71)
    ours = np.array([evaluate(tuple(paper_armax_model.input_poly), v) for v in ds])
    np.testing.assert_allclose(ours, paper_armax_model.input_nonlinearity(ds),
                               rtol=IDENTITY_RTOL, atol=0.0)  # same Horner arithmetic


def test_paper_map_spans_the_identified_range_plus_margin(
    paper_armax_model: HammersteinModel,
) -> None:
    im = _paper_map(paper_armax_model)
    assert (im.ds_min_pct, im.ds_max_pct) == (15.0 - 45.0, 75.0 - 45.0)
    assert im.w_min == evaluate(im.coefficients, -30.0)
    assert im.w_max == evaluate(im.coefficients, 30.0)


@settings(max_examples=200, deadline=None)
@given(fraction=st.floats(min_value=0.0, max_value=1.0))
def test_f_of_inverse_is_identity_across_the_allowed_range(
    fraction: float, paper_armax_model: HammersteinModel
) -> None:
    im = _paper_map(paper_armax_model)
    w = im.w_min + fraction * (im.w_max - im.w_min)
    ds = im.inverse(w)
    assert im.ds_min_pct <= ds <= im.ds_max_pct
    assert abs(im.f(ds) - w) <= ROUNDTRIP_ATOL_KW


@settings(max_examples=100, deadline=None)
@given(ds=st.floats(min_value=-30.0, max_value=30.0))
def test_inverse_of_f_is_identity_on_the_branch(
    ds: float, paper_oe_model: HammersteinModel
) -> None:
    im = _paper_map(paper_oe_model)
    # ds = f^-1(f(ds)) up to the conditioning 1/f' (f' >= 0.96 kW/% here).
    assert abs(im.inverse(im.f(ds)) - ds) <= 2.0 * ROUNDTRIP_ATOL_KW


@settings(max_examples=100, deadline=None)
@given(fraction=st.floats(min_value=0.0, max_value=1.0))
def test_newton_inverse_of_a_cubic_is_identity(
    fraction: float, cubic_model: HammersteinModel
) -> None:
    im = _paper_map(cubic_model)
    w = im.w_min + fraction * (im.w_max - im.w_min)
    ds = im.inverse(w)
    assert abs(im.f(ds) - w) <= NEWTON_ATOL_KW


def test_inverse_clips_outside_the_allowed_w_range(paper_armax_model: HammersteinModel) -> None:
    im = _paper_map(paper_armax_model)
    assert im.inverse(im.w_max + 5.0) == im.ds_max_pct
    assert im.inverse(im.w_min - 5.0) == im.ds_min_pct
    assert math.isnan(im.inverse(math.nan))


def test_inverse_handles_zero_d2_and_a_linear_model(paper_oe_model: HammersteinModel) -> None:
    flat = _paper_map(paper_oe_model.with_updates(input_poly=[1.2, 0.0]))
    linear = _paper_map(paper_oe_model.with_updates(kind="linear", input_poly=[1.2]))
    for im in (flat, linear):
        assert im.inverse(6.0) == pytest.approx(5.0, rel=IDENTITY_RTOL, abs=0.0)


def test_root_formula_is_stable_for_tiny_d2(paper_oe_model: HammersteinModel) -> None:
    d1, d2, w = 1.3, -1e-13, 10.0
    im = _paper_map(paper_oe_model.with_updates(input_poly=[d1, d2]))
    ds = im.inverse(w)
    # Reference: the series w/d1 - d2 w^2/d1^3 + 2 d2^2 w^3/d1^5 (next term ~1e-37).
    reference = w / d1 - d2 * w**2 / d1**3 + 2 * d2**2 * w**3 / d1**5
    naive = (-d1 + math.sqrt(d1 * d1 + 4 * d2 * w)) / (2 * d2)
    assert abs(ds - reference) <= 1e-14 * abs(reference)
    assert abs(naive - reference) > 1e-6 * abs(reference)  # the textbook formula cancels


def test_monotone_branch_of_a_concave_quadratic_ends_at_its_vertex() -> None:
    d1, d2 = 1.35, -0.0065
    assert monotone_branch((d1, d2)) == (-math.inf, pytest.approx(-d1 / (2 * d2)))


def test_monotone_branch_of_a_convex_quadratic_starts_at_its_vertex() -> None:
    d1, d2 = 1.35, 0.01
    assert monotone_branch((d1, d2)) == (pytest.approx(-d1 / (2 * d2)), math.inf)


def test_monotone_branch_of_a_line_is_everything() -> None:
    assert monotone_branch((1.2,)) == (-math.inf, math.inf)


def test_decreasing_f_at_the_operating_point_is_a_design_error() -> None:
    with pytest.raises(DesignError, match=r"expected f'\(0\) = p_1 > 0.*got p_1 = -1\.0"):
        monotone_branch((-1.0, 0.01))


def test_allowed_range_past_the_vertex_is_a_design_error(
    paper_oe_model: HammersteinModel,
) -> None:
    steep = paper_oe_model.with_updates(input_poly=[1.35, -0.03])  # vertex at s = 67.5 %
    with pytest.raises(DesignError, match=r"must lie on the monotone branch.*67\.5"):
        _paper_map(steep)


def test_allowed_range_shrinks_to_triac_limits_and_refuses_empty(
    paper_oe_model: HammersteinModel,
) -> None:
    assert allowed_triac_range(paper_oe_model, triac_min_pct=20.0, triac_max_pct=60.0,
                               validity_margin_pct=5.0) == (20.0, 60.0)
    with pytest.raises(DesignError, match="empty intersection"):
        allowed_triac_range(paper_oe_model, triac_min_pct=80.0, triac_max_pct=90.0,
                            validity_margin_pct=5.0)


def test_min_slope_of_a_quadratic_is_at_the_upper_end() -> None:
    c = (1.35, -0.0065)
    assert min_slope(c, -10.0, 20.0) == slope(c, 20.0)


def test_min_slope_finds_an_interior_minimum(cubic_model: HammersteinModel) -> None:
    c = tuple(float(v) for v in cubic_model.input_poly)
    grid = np.linspace(-30.0, 30.0, 200001)
    reference = float(np.min(1.35 - 2 * 0.0065 * grid + 3e-4 * grid**2))
    # Dense grid: the grid minimum is within (spacing/2)^2 |f'''|/2 (< 1e-10) of the true one.
    assert min_slope(c, -30.0, 30.0) == pytest.approx(reference, abs=1e-9)
    assert min_slope(c, -30.0, 30.0) < min(slope(c, -30.0), slope(c, 30.0))


def test_clamp_is_min_of_max_exactly() -> None:
    # NaN, infinities and signed zeros included: the same value, bit for bit, in every order
    values = [math.nan, -math.inf, -1.0, -0.0, 0.0, 0.5, 1.0, math.inf]
    for v in values:
        for lo in values:
            for hi in values:
                assert repr(clamp(v, lo, hi)) == repr(min(hi, max(lo, v)))
                assert math.copysign(1.0, clamp(v, lo, hi)) == math.copysign(1.0, min(hi, max(lo, v)))
