"""Fixtures of the generated-C tests: one builder per session (OSQP compiled once)."""

from __future__ import annotations

import shutil

import pytest

from czmpc.codegen.build import find_tools
from czmpc.codegen.errors import BuildError
from tests.codegen.replay import StepBuilder


@pytest.fixture(scope="session")
def step_builder(tmp_path_factory: pytest.TempPathFactory) -> StepBuilder:
    """Generates and builds steps under a session directory; skips without a C toolchain."""
    try:
        find_tools()
    except BuildError as exc:   # pragma: no cover - CI has cc and make
        pytest.skip(str(exc))
    return StepBuilder(tmp_path_factory.mktemp("codegen"))


@pytest.fixture(scope="session")
def has_nm() -> bool:
    return shutil.which("nm") is not None
