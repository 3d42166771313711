"""The C step equals the Python controller under every fault class, and is built clean.

Fault classes of docs/guides/controller_failures.rst (`tests.codegen.replay.fault_replay`):
missing samples (and a run long enough to shed), spikes, a stuck sensor, readings below
the limit or absurd, implausible setpoints, previews cut by a NaN, voltage readings
missing, implausible and sagging, an overridden input, mode changes and TRIAC limit
changes, under settings that switch every guard on, and solver trouble (an iteration cap
that OSQP hits: fallbacks to the shifted plan and the target, then shedding). Also: the
sanitizers, no allocator reachable, and the example program's contract.
"""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from czmpc.codegen import CController, build, generate_step
from czmpc.codegen.build import EXAMPLE
from czmpc.controller import OffsetFreeMPC
from czmpc.settings import MPCSettings, OSQPOptions, ReliabilitySettings
from sysid.model import HammersteinModel
from tests.codegen.replay import (
    STRICT_WARNINGS,
    TRIAC_ATOL_PCT,
    StepBuilder,
    example_lines,
    fault_replay,
)

#: Symbols of an allocator (none may be reachable from the step).
ALLOCATORS = {"malloc", "calloc", "realloc", "free", "aligned_alloc", "posix_memalign",
              "memalign", "valloc", "reallocarray", "sbrk", "mmap", "brk"}
#: What the step's objects may need from outside: libm, and what a compiler emits itself.
ALLOWED_EXTERNAL = {"sqrt", "sqrtf", "fabs", "fabsf", "memset", "memcpy", "memmove",
                    "_GLOBAL_OFFSET_TABLE_"}


def guarded_settings(model: HammersteinModel) -> MPCSettings:
    """Every guard on: spike gate, rate check, power limits, setpoint ramp and filter, a
    safe input, a short soft-sensor run, soft power limits."""
    base = MPCSettings.default_for(model)
    p_nom = model.operating_point.power_kw
    return base.with_updates(
        soft_power_max_kw=p_nom + 12.0, soft_power_min_kw=p_nom - 15.0,
        reliability=ReliabilitySettings(
            spike_gate_k_sigma=8.0, max_change_kw_per_sample=4.0, power_max_kw=150.0,
            setpoint_ramp_kw_per_s=0.5, setpoint_filter_time_s=4.0, shed_triac_pct=40.0,
            max_predicted_samples=20, stuck_samples=6))


def troubled_settings(model: HammersteinModel) -> MPCSettings:
    """Solver trouble: an iteration cap OSQP hits on larger moves; input disturbance."""
    base = MPCSettings.default_for(model)
    return base.with_updates(disturbance_model="input", osqp=OSQPOptions(max_iter=20),
                             reliability=ReliabilitySettings(max_bad_solves=3,
                                                             max_predicted_samples=30))


SETTINGS = {"guarded": guarded_settings, "solver_trouble": troubled_settings}


@pytest.fixture(scope="module")
def fault_steps(step_builder: StepBuilder, paper_armax_model: HammersteinModel
                ) -> dict[str, tuple[Path, MPCSettings]]:
    out = {}
    for name, make in SETTINGS.items():
        settings = make(paper_armax_model)
        out[name] = (step_builder.build(paper_armax_model, settings, name=f"faults_{name}"), settings)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SETTINGS))
def test_c_step_equals_python_under_every_fault_class(
        fault_steps: dict[str, tuple[Path, MPCSettings]], paper_armax_model: HammersteinModel,
        name: str) -> None:
    directory, settings = fault_steps[name]
    py = OffsetFreeMPC(paper_armax_model, settings)
    c = CController(directory / "libczmpc.so")
    cmp, _ = fault_replay(py, c, n_steps=600, rng=np.random.default_rng(42))
    print(f"faults ({name}): {cmp.summary()}")
    assert not cmp.mismatches, cmp.mismatches[:5]
    assert cmp.worst_triac_pct <= TRIAC_ATOL_PCT
    # the replay reached the classes it is for
    assert {"good", "predicted", "held", "shed"} <= set(cmp.statuses)
    assert py.n_rejected_measurements == c.n_rejected_measurements > 100
    assert py.n_shed_steps == c.n_shed_steps > 0
    assert py.n_fallbacks == c.n_fallbacks
    if name == "solver_trouble":
        assert c.n_fallbacks > 10


def _symbols(objects: list[Path], *options: str) -> set[str]:
    out = subprocess.run(["nm", *options, *map(str, objects)], capture_output=True, text=True,
                         check=True).stdout
    return {line.split()[-1] for line in out.splitlines() if line.strip() and not line.endswith(":")}


def test_no_allocator_and_only_libm_is_reachable_from_the_step(
        fault_steps: dict[str, tuple[Path, MPCSettings]], has_nm: bool) -> None:
    if not has_nm:   # pragma: no cover - binutils is on CI
        pytest.skip("nm (binutils) not found")
    directory, _ = fault_steps["guarded"]
    objects = [directory / "czmpc_step.o", directory / "czmpc_qp_workspace.o",
               *sorted(directory.glob("osqp_*.o"))]
    external = _symbols(objects, "-u") - _symbols(objects, "--defined-only")
    assert not external & ALLOCATORS
    assert external <= ALLOWED_EXTERNAL, external - ALLOWED_EXTERNAL
    assert "sqrt" in external   # the check sees the objects' real references


@pytest.mark.slow
def test_sanitized_example_replays_the_faults_clean_and_equal(
        tmp_path: Path, fault_steps: dict[str, tuple[Path, MPCSettings]],
        paper_armax_model: HammersteinModel) -> None:
    """The example built with -fsanitize=address,undefined runs 400 fault samples without
    a report and prints what the plain build's step returns, bit for bit."""
    reference, settings = fault_steps["guarded"]
    directory = tmp_path / "asan"
    generate_step(paper_armax_model, settings, directory)
    flags = "-O1 -g -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=all"
    build(directory, (EXAMPLE,), cflags=flags, ldflags="-fsanitize=address,undefined",
          warnings=STRICT_WARNINGS)
    # the inputs: a closed-loop fault replay (no mode events: the example's stdin has none)
    _, samples = fault_replay(OffsetFreeMPC(paper_armax_model, settings),
                              CController(reference / "libczmpc.so"), n_steps=400,
                              rng=np.random.default_rng(7), modes=False)
    done = subprocess.run([str(directory / EXAMPLE)], input=example_lines(samples),
                          capture_output=True, text=True, check=False, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "runtime error" not in done.stderr and "Sanitizer" not in done.stderr, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert len(lines) == len(samples)
    c = CController(reference / "libczmpc.so")
    statuses = set()
    for k, (s, line) in enumerate(zip(samples, lines, strict=True)):
        extra: dict[str, object] = {"grid_voltage_factor": s.grid_voltage_factor,
                                    "applied_triac_pct": s.applied_triac_pct}
        if s.preview_kw:
            extra["setpoint_preview_kw"] = list(s.preview_kw)
        u = c.step(s.power_kw, s.setpoint_kw, **extra)   # type: ignore[arg-type]
        r = c.last
        assert r is not None
        assert line == (f"{_g17(u)},{r.mode},{r.status},{r.fallback},{r.n_iterations},"
                        f"{r.solver_status}"), k
        statuses.add(r.status)
    assert {"good", "predicted", "shed"} <= statuses


def _g17(value: float) -> str:
    """C's ``%.17g`` of a finite double."""
    return f"{value:.17g}"


def test_example_reads_power_and_setpoint_lines_and_prints_the_triac_input_first(
        fault_steps: dict[str, tuple[Path, MPCSettings]], paper_armax_model: HammersteinModel) -> None:
    directory, settings = fault_steps["guarded"]
    done = subprocess.run([str(directory / EXAMPLE)], input="45.0,46.0\nnan,46.0\n45.3,nan\n",
                          capture_output=True, text=True, check=True, timeout=30)
    py = OffsetFreeMPC(paper_armax_model, settings)
    expected = [py.step(45.0, 46.0), py.step(math.nan, 46.0), py.step(45.3, math.nan)]
    got = [float(line.split(",")[0]) for line in done.stdout.splitlines()]
    assert got == pytest.approx(expected, abs=TRIAC_ATOL_PCT, rel=0.0)
    assert done.stdout.splitlines()[1].split(",")[2] == "predicted"
