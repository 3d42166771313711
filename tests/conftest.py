"""Shared fixtures: a seeded rng, the paper's final models, the shipped experiment."""

from __future__ import annotations

import contextlib
import fcntl
import io
import pickle
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np
import pytest
from hypothesis import settings

from sysid import HammersteinModel, OperatingPoint

if TYPE_CHECKING:
    from sysid.pipeline import PipelineResult

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


#: The test files that keep a worker longest, longest first (worker-seconds in a clean
#: `make test`, 2026-11-29). `--dist loadfile` hands files out in collection order,
#: and these came late: the last 3 % of the tests took 375 of the workers' 1,110 s, one
#: worker finishing a long file while the other had nothing left. Handed out first, they
#: leave the short files for the end. A stale list costs balance, never a result.
HEAVY_FIRST = (
    "tests/czmpc/cli/test_identify_real_logs.py",
    "tests/czmpc/cli/test_identify_cli.py",
    "tests/packaging/test_wheel.py",
    "tests/czmpc/cli/test_identify_voltage.py",
    "tests/benchmarks/test_commission_length.py",
    "tests/czmpc/cli/test_identify_identifiability.py",
    "tests/codegen/test_codegen_daqp.py",
    "tests/sim/test_thermal_plant.py",
    "tests/czmpc/cli/test_identify_historian.py",
    "tests/czmpc/campaigns/test_project_golden.py",
    "tests/sysid/test_structure.py",
    "tests/codegen/test_codegen_fuzz.py",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """`HEAVY_FIRST`'s files first, in its order; the rest after them as collected."""
    rank = {path: i for i, path in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.partition("::")[0], len(rank)))


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


#: A CLI run's exit code and stderr (`run_cli`).
RunResult = tuple[int, str]
Kept = TypeVar("Kept")


def once_per_run(tmp_path_factory: pytest.TempPathFactory, worker_id: str, key: str,
                 job: Callable[[Path], Kept]) -> tuple[Kept, Path]:
    """``job(folder)`` once per run of the suite, whichever worker asks first.

    The workers of `make test` share the run's base folder: the first to ask for ``key``
    runs the job in ``folder`` (its output files there) under a lock on ``key`` and
    keeps what it returns (pickled: this run's own file), and every later ask, on either
    worker, waits for it and reads that. For jobs that several test files or groups need
    whole (a ``czmpc identify``, the paper's pipeline), as `--dist loadfile` may hand
    them to both workers. Returns ``(job's value, folder)``.
    """
    root = tmp_path_factory.getbasetemp()
    folder = (root if worker_id == "master" else root.parent) / "once" / key
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "lock", "w", encoding="utf-8") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)     # released when the file closes
        kept = folder / "kept.pickle"
        if not kept.exists():
            kept.write_bytes(pickle.dumps(job(folder)))
        value: Kept = pickle.loads(kept.read_bytes())
    return value, folder


def run_cli(argv: list[str]) -> RunResult:
    """``czmpc ARGV`` in this process: its exit code and stderr (stdout let through)."""
    from czmpc.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(argv)
    return code, err.getvalue()


@pytest.fixture(scope="session")
def shipped_identified(tmp_path_factory: pytest.TempPathFactory,
                       worker_id: str) -> tuple[int, str, Path]:
    """``czmpc identify`` of the shipped experiment with default options, once per run:
    ``(code, stderr, out)``, the output folder read-only to its users."""
    (code, err), folder = once_per_run(
        tmp_path_factory, worker_id, "shipped_experiment",
        lambda folder: run_cli(["identify", str(SHIPPED_EXPERIMENT), "--out",
                                str(folder / "out")]))
    return code, err, folder / "out"


@pytest.fixture(scope="session")
def shipped_pipeline(tmp_path_factory: pytest.TempPathFactory, worker_id: str) -> PipelineResult:
    """`sysid.pipeline.run_paper_pipeline` of the shipped experiment with ``orders="auto"``
    (the CLI's default), once per run; its warnings (non-convergence, reported in the
    result) silenced."""
    def job(_: Path) -> PipelineResult:
        from sysid.data import read_csv
        from sysid.pipeline import run_paper_pipeline

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return run_paper_pipeline(read_csv(SHIPPED_EXPERIMENT), orders="auto")
    return once_per_run(tmp_path_factory, worker_id, "shipped_pipeline", job)[0]


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
