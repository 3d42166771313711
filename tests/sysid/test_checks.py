"""Whole-number options: one rule (`sysid._checks.checked_int`) for every sysid function.

Before the rule was one function, four copies accepted numpy integers and eleven refused
them, so ``orders = np.arange(1, 4)`` worked for ``fit_oe`` and failed for
``HammersteinOrders`` and ``levenberg_marquardt``; the messages stay as they were.
"""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np
import pytest

from sysid._checks import checked_int
from sysid.errors import DataFileError, IdentificationError
from sysid.hammerstein.filtering import HammersteinOrders
from sysid.historian import LoadPolicy
from sysid.optimize import levenberg_marquardt


@pytest.mark.parametrize("value", [3, np.int64(3), np.int32(3), np.uint8(3)])
def test_whole_numbers_of_python_and_numpy_come_back_as_int(value: object) -> None:
    out = checked_int(value, 1, "f: n")
    assert out == 3 and type(out) is int


@pytest.mark.parametrize("value", [True, 3.0, "3", None, 0, np.int64(0)])
def test_anything_else_is_refused_naming_what_and_the_value(value: object) -> None:
    with pytest.raises(IdentificationError, match=r"^f: n must be an int >= 1; got "):
        checked_int(value, 1, "f: n")


def test_the_error_class_is_the_callers() -> None:
    with pytest.raises(DataFileError, match=r"^fill_max_samples must be an int >= 1; got 0$"):
        LoadPolicy(fill_max_samples=0)


def test_numpy_orders_make_the_same_frozen_values_as_python_ints() -> None:
    a = HammersteinOrders(block="oe", degree=np.int64(2), nb=np.int64(2), na=np.int64(1),
                          nc=np.int64(0), nk=np.int64(1))
    b = HammersteinOrders(block="oe", degree=2, nb=2, na=1, nc=0, nk=1)
    assert a == b and all(type(getattr(a, n)) is int for n in ("degree", "nb", "na", "nc", "nk"))
    policy = LoadPolicy(fill_max_samples=np.int64(4))
    assert type(policy.fill_max_samples) is int
    json.dumps(asdict(policy))          # what a model file's provenance records


def test_the_optimizer_takes_a_numpy_iteration_cap() -> None:
    x = np.linspace(0.0, 1.0, 5)

    def line(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return theta[0] + theta[1] * x - (1.0 + 2.0 * x), np.column_stack([np.ones(5), x])

    out = levenberg_marquardt(line, np.zeros(2), max_iterations=np.int64(20))
    np.testing.assert_allclose(out.theta, [1.0, 2.0], atol=1e-10)
    with pytest.raises(IdentificationError, match=r"^levenberg_marquardt: max_iterations must be "
                                                  r"an int >= 1; got 0$"):
        levenberg_marquardt(line, np.zeros(2), max_iterations=0)
