"""Fuzz set sized for CI: random models, settings and fault streams (`tests.codegen.fuzz`).

1e6 steps: ``python -m tests.codegen.fuzz --cases 400 --steps 2500``.
"""

from __future__ import annotations

import pytest

from tests.codegen.fuzz import fuzz
from tests.codegen.replay import StepBuilder


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "issue 42, open: on random settings the C and Python plans drift apart (seed 20261129: "
    "5 of 8 cases, first at k = 25..376, by 2e-5 % at equal iteration counts or by "
    "OSQP iteration counts); not yet told apart from BLAS summation order"))
def test_fuzzed_c_steps_equal_python(step_builder: StepBuilder) -> None:
    result = fuzz(step_builder, n_cases=8, n_steps=2500, seed=20261129)
    print(f"fuzz: {result.summary()}")
    assert result.total.n_steps == 20_000
    assert result.n_bad == 0 and result.n_diverged == 0, result.bad
