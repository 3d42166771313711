"""The C step with ``solver = "daqp"`` equals the Python controller with ``solver = "daqp"``.

DAQP's C comes from the sdist of the installed daqp version (downloaded once with pip and
cached: these tests skip, saying so, when PyPI cannot be reached and no sdist is cached
or given in ``CZMPC_DAQP_SDIST``). Required at every step, as for OSQP: the same mode,
status, fallback, solver status and iteration count; the TRIAC input within
`TRIAC_ATOL_PCT`.

Not bit-equal everywhere, measured: the ``daqp`` wheel's C is compiled by GCC 14.2.1 with
``-O3 -fassociative-math -fno-signed-zeros -fno-trapping-math`` (its setup.py; no fused
multiply-adds: 0 ``vfmadd`` instructions, 586 packed SSE2 multiplies and adds), which lets
the compiler reorder sums. The same sources built here (GCC 12.2) reproduce the wheel's
plans bit for bit on 0 of 1,500 closed-loop QPs (shipped model, N = 39, 77 rows) under
each of ``-O2 -ffp-contract=off``, ``-O3 -ffp-contract=off``, the wheel's flags and
``-O2`` with them: the plans differ by at most 1.8e-14 kW-equivalent, the iteration
counts are equal on 1,500 of 1,500. The generated step builds DAQP with the step's flags
(``-ffp-contract=off``, no reassociation): its results do not depend on the compiler's
vectoriser.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from czmpc.codegen import CController, CodegenError, generate_step
from czmpc.codegen.daqp_source import daqp_sources
from czmpc.controller import OffsetFreeMPC
from czmpc.qp_daqp import DAQP_ITER_LIMIT
from czmpc.settings import MPCSettings
from sysid.model import HammersteinModel
from tests.codegen.replay import TRIAC_ATOL_PCT, Comparison, StepBuilder, fault_replay
from tests.codegen.test_codegen_faults import ALLOCATORS, ALLOWED_EXTERNAL, guarded_settings


#: Settings of the replays: the defaults; every guard on with soft power limits (the
#: slack variable and DAQP's general soft rows) and a rate limit; box bounds only.
def _guarded_with_rate_limit(model: HammersteinModel) -> MPCSettings:
    return guarded_settings(model).with_updates(max_move_pct_per_step=1.5)


def _box_only(model: HammersteinModel) -> MPCSettings:
    """No rate and no soft limits: DAQP's simple bounds only, no general rows (its set-up
    asks for a 0 x n matrix: malloc(0), which the arena must grant; fuzz seed 1, case 20)."""
    return MPCSettings.default_for(model).with_updates(max_move_pct_per_step=None)


SETTINGS: dict[str, Callable[[HammersteinModel], MPCSettings]] = {
    "default": MPCSettings.default_for,
    "guarded": _guarded_with_rate_limit,
    "box_only": _box_only,
}
#: What DAQP's objects need beyond the OSQP step's: libm's fmax (daqp_prox.c).
DAQP_EXTERNAL = {"fmax"}


@pytest.fixture(scope="module")
def daqp_source() -> Path:
    """DAQP's sources (cache, ``CZMPC_DAQP_SDIST`` or a download); skip if PyPI is unreachable."""
    try:
        import daqp  # noqa: F401
    except ImportError:   # pragma: no cover - the dev environment has czmpc[daqp]
        pytest.skip("daqp is not installed (pip install 'czmpc[daqp]')")
    try:
        return daqp_sources()
    except CodegenError as exc:   # pragma: no cover - CI reaches PyPI
        pytest.skip(f"needs the network (daqp's sdist from PyPI) or CZMPC_DAQP_SDIST: {exc}")


@pytest.fixture(scope="module")
def daqp_steps(step_builder: StepBuilder, paper_armax_model: HammersteinModel,
               daqp_source: Path) -> dict[str, tuple[Path, MPCSettings]]:
    out = {}
    for name, make in SETTINGS.items():
        settings = make(paper_armax_model).with_updates(solver="daqp")
        out[name] = (step_builder.build(paper_armax_model, settings, name=f"daqp_{name}"), settings)
    return out


@pytest.mark.parametrize("name", list(SETTINGS))
def test_c_daqp_step_equals_python_daqp_under_every_fault_class(
        daqp_steps: dict[str, tuple[Path, MPCSettings]], paper_armax_model: HammersteinModel,
        name: str) -> None:
    directory, settings = daqp_steps[name]
    py = OffsetFreeMPC(paper_armax_model, settings)
    c = CController(directory / "libczmpc.so")
    cmp, _ = fault_replay(py, c, n_steps=600, rng=np.random.default_rng(42))
    print(f"daqp faults ({name}): {cmp.summary()}, {cmp.n_iterations_py} iterations, "
          f"at most {cmp.max_iterations_py}")
    assert not cmp.mismatches, cmp.mismatches[:5]
    assert cmp.worst_triac_pct <= TRIAC_ATOL_PCT
    assert {"good", "predicted", "held", "shed"} <= set(cmp.statuses)
    assert py.n_rejected_measurements == c.n_rejected_measurements > 100
    assert py.n_fallbacks == c.n_fallbacks
    # DAQP ran, hot-started: a few active-set changes per solve, not OSQP's tens
    assert 0 < cmp.max_iterations_py <= 40
    assert cmp.n_iterations_py > 100


def test_c_daqp_step_equals_python_daqp_on_the_shipped_model(
        step_builder: StepBuilder, shipped_model: HammersteinModel, daqp_source: Path) -> None:
    settings = MPCSettings.default_for(shipped_model).with_updates(solver="daqp")
    directory = step_builder.build(shipped_model, settings, name="daqp_shipped")
    total = Comparison()
    for seed in (1, 2):
        py = OffsetFreeMPC(shipped_model, settings)
        c = CController(directory / "libczmpc.so")
        cmp, _ = fault_replay(py, c, n_steps=400, rng=np.random.default_rng(seed))
        assert not cmp.mismatches, cmp.mismatches[:5]
        total.merge(cmp)
    print(f"daqp shipped: {total.summary()}")
    assert total.n_steps == 800
    assert total.worst_triac_pct <= TRIAC_ATOL_PCT


def _symbols(objects: list[Path], *options: str) -> set[str]:
    out = subprocess.run(["nm", *options, *map(str, objects)], capture_output=True, text=True,
                         check=True).stdout
    return {line.split()[-1] for line in out.splitlines() if line.strip() and not line.endswith(":")}


def test_no_allocator_is_reachable_from_the_daqp_step(
        daqp_steps: dict[str, tuple[Path, MPCSettings]], has_nm: bool) -> None:
    """DAQP's objects are compiled with czmpc_daqp_heap.h forced in: their malloc, calloc
    and free are the static arena's, which czmpc_init seals after DAQP's set-up."""
    if not has_nm:   # pragma: no cover - binutils is on CI
        pytest.skip("nm (binutils) not found")
    directory, _ = daqp_steps["guarded"]
    objects = [directory / "czmpc_step.o", directory / "czmpc_daqp_heap.o",
               *sorted(directory.glob("daqp_*.o"))]
    assert len(objects) > 8
    external = _symbols(objects, "-u") - _symbols(objects, "--defined-only")
    assert not external & ALLOCATORS
    assert external <= ALLOWED_EXTERNAL | DAQP_EXTERNAL, external - ALLOWED_EXTERNAL - DAQP_EXTERNAL
    # the check sees the objects' real references: DAQP's set-up asks the arena
    daqp_refs = _symbols(sorted(directory.glob("daqp_*.o")), "-u")
    assert {"czmpc_daqp_malloc", "czmpc_daqp_free"} <= daqp_refs


def test_daqp_arena_holds_the_setup_and_nothing_after_init(
        daqp_steps: dict[str, tuple[Path, MPCSettings]]) -> None:
    """The arena is large enough for DAQP's set-up, and no step asks it for more."""
    import ctypes

    directory, _ = daqp_steps["default"]
    c = CController(directory / "libczmpc.so")
    lib = c._lib   # its private copy of the library: the state c set up
    lib.czmpc_daqp_arena_used.restype = ctypes.c_size_t
    lib.czmpc_daqp_arena_refused.restype = ctypes.c_ulong
    text = (directory / "czmpc_daqp.h").read_text(encoding="utf-8")
    size = int(text.split("#define CZMPC_DAQP_ARENA_BYTES ")[1].split("u")[0])
    used = lib.czmpc_daqp_arena_used()
    for k in range(200):
        c.step(power_kw=float(45.0 + np.sin(k / 7)), setpoint_kw=46.0)
    assert 0 < used <= size
    assert lib.czmpc_daqp_arena_used() == used
    assert lib.czmpc_daqp_arena_refused() == 0
    print(f"daqp arena: {used} of {size} bytes used")


def test_daqp_float32_is_refused(paper_armax_model: HammersteinModel, tmp_path: Path) -> None:
    settings = MPCSettings.default_for(paper_armax_model).with_updates(solver="daqp")
    with pytest.raises(CodegenError, match="double precision only"):
        generate_step(paper_armax_model, settings, tmp_path / "f32", float32=True)


def test_daqp_sources_from_a_given_sdist(tmp_path: Path, daqp_source: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """Offline: a sdist given in CZMPC_DAQP_SDIST is used; a file that is not one is refused."""
    import tarfile

    from czmpc.codegen.daqp_source import SDIST_ENV, daqp_version

    version = daqp_version()
    sdist = tmp_path / f"daqp-{version}.tar.gz"
    with tarfile.open(sdist, "w:gz") as tar:
        tar.add(daqp_source / "csrc", arcname=f"daqp-{version}/csrc")
        tar.add(daqp_source / "LICENSE", arcname=f"daqp-{version}/LICENSE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv(SDIST_ENV, str(sdist))
    got = daqp_sources()
    assert (got / "csrc" / "src" / "daqp.c").read_bytes() == \
        (daqp_source / "csrc" / "src" / "daqp.c").read_bytes()
    bad = tmp_path / "bad.tar.gz"
    with tarfile.open(bad, "w:gz") as tar:
        tar.add(daqp_source / "LICENSE", arcname=f"daqp-{version}/LICENSE")
    monkeypatch.setenv(SDIST_ENV, str(bad))
    with pytest.raises(CodegenError, match="must be the sdist of daqp"):
        daqp_sources()


@pytest.mark.slow
def test_c_daqp_step_equals_python_daqp_on_the_golden_suite(
        step_builder: StepBuilder, daqp_source: Path) -> None:
    """Every MPC case of the golden regression suite, both controllers with solver "daqp"."""
    from czmpc.campaigns.build import build_plant
    from czmpc.campaigns.campaign import load_model_cached, run_scenario, run_seed
    from sim.loop import run_closed_loop
    from tests.codegen.replay import TeeController
    from tests.codegen.test_codegen_golden import _mpc_runs, _python_controller

    libs: dict[str, Path] = {}
    total = Comparison()
    for run in _mpc_runs():
        base = _python_controller(run)
        settings = base.settings.with_updates(solver="daqp")
        kind = run.controller.kind
        if kind not in libs:
            libs[kind] = step_builder.build(base.model, settings.with_updates(initial_triac_pct=None),
                                            name=f"daqp_golden_{kind}")
        model = load_model_cached(run.controller.model_path)
        scenario = run_scenario(run)
        plant, _, _ = build_plant(run.plant.kind, model, scenario,
                                  noise=run.noise and scenario.plant_noise)
        py = OffsetFreeMPC(base.model, settings)
        c = CController(libs[kind] / "libczmpc.so", initial_triac_pct=settings.initial_triac_pct)
        cmp = Comparison()
        run_closed_loop(plant, TeeController(py, c, cmp), scenario, rng=run_seed(run))
        assert not cmp.mismatches, f"{run.case_id}: {cmp.mismatches[:5]}"
        total.merge(cmp)
    print(f"daqp golden: {total.summary()}, {total.n_iterations_py} iterations, at most "
          f"{total.max_iterations_py}")
    assert total.n_steps == 7440
    assert total.worst_triac_pct <= TRIAC_ATOL_PCT


@pytest.mark.slow
def test_fuzzed_c_daqp_steps_equal_python_daqp(step_builder: StepBuilder, daqp_source: Path) -> None:
    """The fuzz set's first 4 controllers (`tests.codegen.fuzz`, seed 20261129) with solver
    "daqp". Measured: 10,000 steps, 0 mismatches, 1,901 bit-equal, TRIAC within 8.7e-12 %,
    at most 47 DAQP iterations (8 cases: 20,000 steps, within 2.5e-11 %)."""
    from tests.codegen.fuzz import fuzz

    result = fuzz(step_builder, n_cases=4, n_steps=2500, seed=20261129, solver="daqp")
    print(f"daqp fuzz: {result.summary()}")
    assert result.total.n_steps == 10_000
    assert result.n_bad == 0, result.bad
    assert result.total.worst_triac_pct <= TRIAC_ATOL_PCT
    assert 10 <= result.max_iterations <= DAQP_ITER_LIMIT
    assert set(result.total.statuses) == {"good", "predicted", "clamped", "held", "shed"}


def test_daqp_sdist_is_downloaded_and_checked_against_pypi(
        tmp_path: Path, daqp_source: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A fresh cache: the sdist from PyPI's address, its sha256 PyPI's; a file whose hash
    differs is refused (network)."""
    import hashlib

    from czmpc.codegen import daqp_source as source

    monkeypatch.delenv(source.SDIST_ENV, raising=False)
    version = source.daqp_version()
    found = source._pypi_sdist(version)
    if found is None:   # pragma: no cover - CI reaches PyPI's JSON API
        pytest.skip("needs the network (PyPI's JSON metadata)")
    try:
        sdist = source.download_sdist(version, tmp_path)
    except CodegenError as exc:   # pragma: no cover - CI reaches PyPI
        pytest.skip(f"needs the network (PyPI): {exc}")
    assert hashlib.sha256(sdist.read_bytes()).hexdigest() == found[1]
    (tmp_path / "tampered").mkdir()
    monkeypatch.setattr(source, "_pypi_sdist", lambda _v: (found[0], "0" * 64))
    with pytest.raises(CodegenError, match="must have PyPI's sha256 0{64}; got"):
        source.download_sdist(version, tmp_path / "tampered")
    monkeypatch.undo()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv(source.SDIST_ENV, str(sdist))
    got = daqp_sources()
    assert (got / "LICENSE").read_bytes() == (daqp_source / "LICENSE").read_bytes()
