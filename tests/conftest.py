"""Shared fixtures: a seeded rng, the paper's final models, the shipped experiment."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from sysid import HammersteinModel, OperatingPoint

# No per-example deadline: `make test` runs the suite on two workers on a shared 2-core
# machine, where an example's wall time says nothing about the code (speed goals live
# in the benchmarks, never in assertions).
settings.register_profile("czmpc", deadline=None)
settings.load_profile("czmpc")

REPO = Path(__file__).resolve().parents[1]
SHIPPED_EXPERIMENT = REPO / "data" / "cz_heater_experiment.csv"


#: Test files whose tests `make test`'s workers share out by the log they identify (a
#: test id's parameters, ``[exchanger]``) instead of taking the whole file at once: the
#: real-log identifications are the suite's heaviest file, and the runs of one log share
#: a module-level cache, so a log's tests stay together (`_scope`).
SPLIT_BY_LOG = frozenset({"tests/czmpc/cli/test_identify_real_logs.py"})


def _scope(nodeid: str) -> str:
    """The unit ``--dist loadfile`` hands a worker: a test file, or for `SPLIT_BY_LOG`
    the file and the test's parameters (its function without any)."""
    path, _, rest = nodeid.partition("::")
    if path not in SPLIT_BY_LOG:
        return path
    function, _, params = rest.partition("[")
    return f"{path}[{params}" if params else f"{path}::{function}"


def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """``--dist loadfile`` (`tools/run_suite.sh`) by `_scope` rather than by file only.

    (``--dist loadgroup`` cannot do it: xdist 3.8 renames the node ids that pytest 9 no
    longer reads, so its groups are ignored.)"""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class _ScopeScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _scope(nodeid)

    return _ScopeScheduling(config, log)  # type: ignore[arg-type]


@pytest.fixture(scope="session")
def shipped_model() -> HammersteinModel:
    """The shipped model of the paper's heater (`czmpc.shipped.HAMMERSTEIN_MODEL_JSON`)."""
    from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
    from sysid.modelfile import load_model

    return load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)


def _paper_model(block: str) -> HammersteinModel:
    # Paper-like values (eq. 27 / eq. 30 shape): slow pole near 0.99, b2 near a1,
    # f'(0) about 1.35 kW/% and falling with ds (Table 3); static gain
    # (1 + b2)/(1 + a1) = 0.9: the power sags about 10 % after a step (DESIGN.md).
    a1, b2, c1 = -0.99, -0.991, -0.9
    return HammersteinModel(
        kind="hammerstein",
        linear_block=block,  # type: ignore[arg-type]
        ts_s=2.0,
        operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
        a=[1.0, a1],
        b=[0.0, 1.0, b2],
        c=[1.0, a1] if block == "oe" else [1.0, c1],
        input_poly=[1.35, -0.0065],
        noise_std_kw=0.0134,
        input_range_pct=(20.0, 70.0),
    )


@pytest.fixture(scope="session")
def paper_oe_model() -> HammersteinModel:
    return _paper_model("oe")


@pytest.fixture(scope="session")
def paper_armax_model() -> HammersteinModel:
    return _paper_model("armax")
