"""The golden-set helpers of czmpc.campaigns.golden (tolerance rule, comparison, file format).

The project's golden set itself is checked through czmpc.testing in
tests/czmpc/testing/test_project_golden.py.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from czmpc.campaigns.golden import (
    FLOAT_ATOL,
    FLOAT_RTOL,
    GOLDEN_METRICS,
    SOLVER_SAFETY,
    GoldenError,
    compare,
    load_golden,
    tolerances,
)


def test_compare_flags_values_outside_tolerance_and_missing_metrics() -> None:
    golden = {"a": {"value": 1.0, "tol": 0.1}, "b": {"value": None, "tol": 0.0},
              "c": {"value": 2.0, "tol": 0.0}}
    assert compare("x", golden, {"a": 1.05, "b": math.nan, "c": 2.0}) == ()
    bad = compare("x", golden, {"a": 1.2, "b": 0.0})
    assert [m.metric for m in bad] == ["a", "b", "c"]
    assert math.isnan(bad[2].actual)


def test_tolerances_are_the_larger_of_solver_and_float_allowances() -> None:
    nominal = dict.fromkeys(GOLDEN_METRICS, 100.0)
    tight = dict(nominal, iae_kw_s=100.5)
    tol = tolerances(nominal, tight)
    assert tol["iae_kw_s"] == pytest.approx(SOLVER_SAFETY * 0.5, rel=1e-12)
    assert tol["ise_kw2_s"] == pytest.approx(FLOAT_RTOL * 100.0, rel=1e-12)
    assert tol["n_solver_failures"] == 0.0
    assert tolerances(dict(nominal, ise_kw2_s=0.0), dict(tight, ise_kw2_s=0.0))["ise_kw2_s"] \
        == FLOAT_ATOL


def test_unreadable_golden_files_are_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "other"}), encoding="utf-8")
    with pytest.raises(GoldenError, match="expected format 'czmpc-golden/1'"):
        load_golden(bad)
    with pytest.raises(GoldenError, match="readable JSON"):
        load_golden(tmp_path / "missing.json")
