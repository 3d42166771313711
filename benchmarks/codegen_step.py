"""Cost of the generated C step: against the Python step and the bare generated OSQP solve.

``python -m benchmarks.codegen_step [--repeats N] [--steps N] [--float32] [--fuzz-cases N]``

What does one step of the controller cost once it is C (``czmpc codegen``), compared
with the Python controller it was generated from and with the OSQP solve inside it,
and how much code and data is it? (Issue 42, item 5.)

The controller: the shipped model's (``--model``), default settings
(`MPCSettings.default_for`; N = 39 for the shipped model), generated and built once per
run of this benchmark with the generated Makefile's flags. Each repeat replays the same
closed-loop steps through every path:

1. **Python**: `OffsetFreeMPC.step` steps the shipped staircase against the model plant
   (noise on, seed = repeat - 1), `time.perf_counter` around each call; the inputs it
   got (measured power, setpoint, and in the second half of the measurement the next
   30 setpoints and a grid voltage reading, as ``benchmarks.mpc_step`` gives them), its
   TRIAC output, iteration count and the ``q, l, u`` it sent to OSQP are kept.
2. **C step**: the kept inputs, read from a file by a small C harness
   (``benchmarks/codegen_timing.c``, linked against the directory's ``libczmpc.a`` with
   its Makefile's flags, ``benchmarks/codegen_timing.mk``), each ``czmpc_step`` timed
   with ``clock_gettime(CLOCK_MONOTONIC)``; no Python in the loop. The harness prints
   each step's TRIAC output, so the benchmark checks that the timed C run computed
   what Python did (issue 42: within 1e-6 %, up to the first step whose OSQP iteration
   count differs; such steps are counted). For reference, the same C step through
   ctypes (`czmpc.codegen.CController.step`, perf_counter per call).
3. **Bare solver**: in the same harness, the generated OSQP solver alone
   (``osqp_update_data_vec`` + ``osqp_solve`` on the generated workspace, set up afresh
   by ``czmpc_init_at``) on the very ``q, l, u`` the C step sent, in the same order,
   cold-started where the step cold-started: the same QPs from the same warm starts,
   hence the same iterations (checked). The ratio C step / bare solver is what the
   controller costs around its QP.

Reported per path: median and 99.9th percentile of the per-step times, one row per
repeat; the ratios; the worst OSQP iteration count of these runs against the cap
(``max_iter``) and the time of a solve that runs to that cap (the hardest QP of the run
from a cold start with ``eps_abs = eps_rel = 0``); with ``--fuzz-cases N`` the worst
iteration count on the fuzz set of ``tests/codegen/fuzz.py`` (seed 1, 2,500 steps per
case; 400 cases are its 1e6-step set; it builds a C step per case: 400 cases took 19 min here),
otherwise it says that was not measured; and ``size -A`` of the step's object
(``czmpc_step.o``: code and the model's constant matrices), OSQP's generated workspace
(``czmpc_qp_workspace.o``) and OSQP's objects, with ``sizeof(czmpc_state)``.

Machine note: compare within one run and quote medians; the shared machine's load shows
in the percentiles. The numbers go to stdout and, with the machine, under
`SECTION_HEADING` (`--float32`: `SECTION_HEADING_FLOAT32`) in BENCHMARKS.md.

Exit codes: 0 done; 1 the timed C run did not compute what Python did (nothing
recorded); 2 bad input (model file), no C toolchain or a failed build.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import importlib
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks._md import BENCHMARKS_MD, MachineInfo, benchmark_parser, machine_info, run_main
from benchmarks._md import write_benchmarks_section as _write_section
from benchmarks.mpc_step import BENCH_SEED, PREVIEW_STEPS, SAG_FACTOR
from czmpc.cli import _argtypes, _progress
from czmpc.codegen import CController, build, generate_step
from czmpc.codegen.build import SHARED_LIBRARY, find_tools
from czmpc.codegen.errors import BuildError
from czmpc.controller import OffsetFreeMPC
from czmpc.settings import MPCSettings
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.model_plant import ModelPlant
from sim.protocols import NOMINAL, Exogenous
from sim.scenario import Scenario, load_scenario
from sysid._typing import FloatArray
from sysid.model import HammersteinModel
from sysid.modelfile import load_model

#: Heading of this benchmark's section in BENCHMARKS.md (double precision).
SECTION_HEADING = "## Generated C step: cost against Python and the bare solver (issue 42)"
#: Heading of the ``--float32`` run's section.
SECTION_HEADING_FLOAT32 = ("## Generated C step in float32: cost against Python and the bare "
                           "solver (issue 42)")
#: Goal of issue 42: the C step's median at most this times the bare generated solver's.
C_OVER_BARE_GOAL = 1.15
#: TRIAC agreement of the C step with Python's required in double precision [%] (issue 42).
TRIAC_ATOL_PCT = 1e-6
#: The fuzz set of tests/codegen/fuzz.py measured with --fuzz-cases (its documented one).
FUZZ_SEED = 1
FUZZ_STEPS_PER_CASE = 2500
#: The harness and its make fragment, kept beside this file.
HARNESS_C = Path(__file__).with_name("codegen_timing.c")
HARNESS_MK = Path(__file__).with_name("codegen_timing.mk")
HARNESS = "codegen_timing"
#: First line of the harness's input file.
INPUTS_MAGIC = "czmpc-timing-inputs/1"

Progress = Callable[[str], None]


@dataclass(frozen=True, slots=True, kw_only=True)
class Timing:
    """Per-step wall times of one path over one run [us].

    Parameters
    ----------
    n :
        Calls timed.
    median_us, p999_us, max_us :
        Median, 99.9th percentile and maximum [us].
    """

    n: int
    median_us: float
    p999_us: float
    max_us: float

    @classmethod
    def of(cls, seconds: FloatArray) -> Timing:
        """The statistics of ``seconds`` (one entry per call) [s]."""
        us = np.asarray(seconds, dtype=float) * 1e6
        return cls(n=int(us.size), median_us=float(np.median(us)),
                   p999_us=float(np.percentile(us, 99.9)), max_us=float(us.max()))


@dataclass(frozen=True, slots=True, kw_only=True)
class CapSolve:
    """The hardest QP of a run solved until only the iteration cap stops OSQP.

    Parameters
    ----------
    k :
        Step whose QP it is (the one that took the most iterations in the run).
    n_iterations :
        Iterations OSQP ran (the cap, unless it stopped otherwise).
    status_val :
        OSQP's ``status_val`` (7: maximum iterations reached).
    median_ms, max_ms :
        Of the repeated solves [ms].
    """

    k: int
    n_iterations: int
    status_val: int
    median_ms: float
    max_ms: float


@dataclass(frozen=True, slots=True, kw_only=True)
class CodegenRun:
    """One repeat: the same steps through every path, and whether they computed the same.

    Parameters
    ----------
    n_steps :
        Steps replayed.
    python, c_step, c_ctypes, bare :
        Per-step times of `OffsetFreeMPC.step`, of ``czmpc_step`` in the C harness, of
        `CController.step` and of the bare generated solve (solved QPs only).
    mean_iterations, max_iterations :
        OSQP iterations of the C step per step.
    bare_same_iterations :
        Fraction of the replayed QPs that took the C step's iteration count.
    n_iteration_differences :
        Steps whose iteration count differs between C and Python.
    first_difference_k :
        The first such step, or None.
    worst_triac_pct :
        ``max |u_C - u_Python|`` over the steps before ``first_difference_k`` [%].
    worst_triac_all_pct :
        The same over all steps [%].
    n_bit_equal :
        Steps whose TRIAC outputs are bit-equal.
    qp_max_rel_diff :
        Largest ``|a - b| / max(1, |a|, |b|)`` between the ``q, l, u`` the C step and
        the Python step sent, over the solved steps before ``first_difference_k``.
    ctypes_equal :
        Steps whose ctypes TRIAC output is bit-equal to the harness's.
    cap :
        The worst-case solve, or None (no QP solved).
    """

    n_steps: int
    python: Timing
    c_step: Timing
    c_ctypes: Timing
    bare: Timing
    mean_iterations: float
    max_iterations: int
    bare_same_iterations: float
    n_iteration_differences: int
    first_difference_k: int | None
    worst_triac_pct: float
    worst_triac_all_pct: float
    n_bit_equal: int
    qp_max_rel_diff: float
    ctypes_equal: int
    cap: CapSolve | None

    @property
    def c_over_bare(self) -> float:
        """C step median over the bare solve's median."""
        return self.c_step.median_us / self.bare.median_us

    @property
    def python_over_c(self) -> float:
        """Python step median over the C step's median."""
        return self.python.median_us / self.c_step.median_us

    def agrees(self, float32: bool) -> bool:
        """The timed C run computed what Python did (double: `TRIAC_ATOL_PCT` up to the
        first iteration difference; both: ctypes bit-equal to the harness)."""
        same_c = self.ctypes_equal == self.n_steps
        return same_c and (float32 or self.worst_triac_pct <= TRIAC_ATOL_PCT)


@dataclass(frozen=True, slots=True, kw_only=True)
class ObjectSize:
    """``size -A`` of a group of object files [bytes].

    Parameters
    ----------
    part :
        What the group is.
    files :
        Its object files.
    text, rodata, data, bss :
        Summed sizes of the ``.text*``, ``.rodata*``, ``.data*`` and ``.bss*`` sections.
    """

    part: str
    files: tuple[str, ...]
    text: int
    rodata: int
    data: int
    bss: int


@dataclass(frozen=True, slots=True, kw_only=True)
class FuzzWorst:
    """Worst OSQP iteration count on the fuzz set (``tests/codegen/fuzz.py``).

    Parameters
    ----------
    n_cases, n_steps :
        Random controllers and steps run.
    seed :
        The fuzz set's seed.
    max_iterations :
        Largest iteration count of the Python controller over all steps (the C step's
        equal where the two agree; the cap drawn per case is 25, 200 or 4,000), or None
        if the fuzz set stopped.
    error :
        Why the fuzz set stopped (its exception), or None.
    """

    n_cases: int
    n_steps: int
    seed: int
    max_iterations: int | None
    error: str | None = None


@dataclass(frozen=True, kw_only=True)
class CodegenBenchmark:
    """Everything `run_benchmark` measured.

    Parameters
    ----------
    machine :
        The machine.
    model_label :
        Which model.
    command :
        The command line.
    revision :
        ``git`` revision of the code measured (and whether the tree had changes).
    compiler :
        The C compiler's first ``--version`` line.
    compile_command :
        Compiler and flags of the generated Makefile.
    float32 :
        The C step computes in ``float``.
    horizon_steps, n_variables, n_constraints, max_iter :
        The QP: ``N``, OSQP's variables and rows, the iteration cap.
    rounds :
        Alternating passes of the C step and the bare solve per repeat.
    runs, context_runs :
        One `CodegenRun` per repeat, without and with preview and voltage.
    sizes :
        Object sizes: the step, OSQP's workspace, OSQP's objects.
    state_bytes :
        ``sizeof(czmpc_state)``.
    fuzz :
        The fuzz set's worst iteration count, or None (not measured).
    """

    machine: MachineInfo
    model_label: str
    command: str
    revision: str
    compiler: str
    compile_command: str
    float32: bool
    horizon_steps: int
    n_variables: int
    n_constraints: int
    max_iter: int
    rounds: int
    runs: tuple[CodegenRun, ...]
    context_runs: tuple[CodegenRun, ...]
    sizes: tuple[ObjectSize, ...]
    state_bytes: int
    fuzz: FuzzWorst | None = None

    @property
    def all_runs(self) -> tuple[CodegenRun, ...]:
        """Both halves' runs."""
        return self.runs + self.context_runs

    @property
    def agrees(self) -> bool:
        """Every timed C run computed what Python did (`CodegenRun.agrees`)."""
        return all(r.agrees(self.float32) for r in self.all_runs)

    def c_over_bare(self, runs: tuple[CodegenRun, ...]) -> float:
        """Median over ``runs`` of each run's C step / bare solve ratio."""
        return float(np.median([r.c_over_bare for r in runs]))

    @property
    def goal_met(self) -> bool:
        """C step within `C_OVER_BARE_GOAL` of the bare solve, in both halves."""
        halves = [h for h in (self.runs, self.context_runs) if h]
        return all(self.c_over_bare(h) <= C_OVER_BARE_GOAL for h in halves)


# --- the closed loop in Python ------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class _PythonLoop:
    """One closed loop of the Python controller: per step, in order."""

    power_kw: FloatArray
    setpoint_kw: FloatArray
    voltage: FloatArray                  # NaN: no reading given
    previews: tuple[FloatArray, ...]     # empty: none given
    triac_pct: FloatArray
    iterations: np.ndarray
    sent: FloatArray                     # (n, n_var + 2 m): q, l, u as sent to OSQP
    step_s: FloatArray


def _python_loop(model: HammersteinModel, settings: MPCSettings, scenario: Scenario, *,
                 initial_triac_pct: float, n_steps: int, seed: int, context: bool) -> _PythonLoop:
    """Step `OffsetFreeMPC` through the staircase against the model plant, each step timed.

    ``context``: each step gets the next `PREVIEW_STEPS` setpoints and a voltage reading
    of 1 +- 1e-4, then of `SAG_FACTOR` for the second half, which the plant gets too (as
    ``benchmarks.mpc_step`` gives them).
    """
    setpoints = np.array(scenario.setpoint_profile_kw()[:n_steps], dtype=float)
    n = setpoints.size
    mpc = OffsetFreeMPC(model, settings, initial_triac_pct=initial_triac_pct)
    qp = mpc.qp
    sent = np.empty((n, qp.n_variables + 2 * qp.n_constraints))
    power_in, triac, step_s = np.empty(n), np.empty(n), np.empty(n)
    iterations = np.empty(n, dtype=int)
    plant = ModelPlant.for_scenario(model, scenario)
    power = plant.reset(np.random.default_rng(seed))
    volts = (np.where(np.arange(n) < n // 2, 1.0, SAG_FACTOR)
             + 1e-4 * np.random.default_rng(seed + 1000).standard_normal(n))
    previews: list[FloatArray] = []
    for k in range(n):
        power_in[k] = power
        setpoint = float(setpoints[k])
        if context:
            preview = setpoints[k + 1 : k + 1 + PREVIEW_STEPS]
            volt = float(volts[k])
            previews.append(preview)
            t0 = time.perf_counter()
            u = mpc.step(power, setpoint, setpoint_preview_kw=preview, grid_voltage_factor=volt)
            step_s[k] = time.perf_counter() - t0
        else:
            previews.append(np.empty(0))
            t0 = time.perf_counter()
            u = mpc.step(power, setpoint)
            step_s[k] = time.perf_counter() - t0
        sent[k] = qp._data  # q, l, u as this step sent them (one array in MPCQP)
        triac[k] = u
        iterations[k] = mpc.last_step.n_iterations  # type: ignore[union-attr]
        power = plant.step(u, Exogenous(grid_voltage_factor=float(volts[k])) if context
                           else NOMINAL)
    return _PythonLoop(power_kw=power_in, setpoint_kw=setpoints,
                       voltage=volts if context else np.full(n, np.nan),
                       previews=tuple(previews), triac_pct=triac, iterations=iterations,
                       sent=sent, step_s=step_s)


# --- the C harness -------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class _HarnessRun:
    """What the harness printed, parsed."""

    triac_pct: FloatArray
    iterations: np.ndarray
    status_val: np.ndarray
    step_s: FloatArray
    bare_k: np.ndarray
    bare_iterations: np.ndarray
    bare_s: FloatArray
    cap: CapSolve | None
    sent: FloatArray                     # (n, n_var + 2 m) as the C step sent them


def _fmt(value: float) -> str:
    """A float the harness's strtod reads back bit for bit (``nan``, ``inf`` included)."""
    return repr(float(value))


def write_inputs(path: Path, loop: _PythonLoop, *, initial_triac_pct: float) -> None:
    """The harness's input file of ``loop`` (format: benchmarks/codegen_timing.c)."""
    lines = [INPUTS_MAGIC, f"{loop.power_kw.size} {_fmt(initial_triac_pct)}"]
    for k in range(loop.power_kw.size):
        preview = loop.previews[k]
        lines.append(" ".join([_fmt(loop.power_kw[k]), _fmt(loop.setpoint_kw[k]),
                               _fmt(loop.voltage[k]), str(preview.size),
                               *(_fmt(v) for v in preview)]))
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def build_harness(directory: Path) -> str:
    """Build ``directory/codegen_timing`` with the directory's Makefile; return its compile line.

    Raises
    ------
    BuildError
        No compiler or make, or the build failed (with the compiler's messages).
    """
    build(directory, ("all", SHARED_LIBRARY))
    make, _ = find_tools()
    args = [make, "-s", "-C", str(directory), "-f", "Makefile", "-f", str(HARNESS_MK),
            f"HARNESS={HARNESS_C}", "WARNINGS=-Wall -Wextra -Werror -pedantic"]
    done = subprocess.run([*args, HARNESS], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise BuildError(f"{directory}: the timing harness did not build:\n{done.stderr.strip()}")
    flags = subprocess.run([*args, "--no-print-directory", "codegen_timing_flags"],
                           capture_output=True, text=True, check=False)
    return " ".join(flags.stdout.split())


def run_harness(directory: Path, inputs: Path, *, n_variables: int, n_constraints: int,
                float32: bool, rounds: int = 1) -> _HarnessRun:
    """Run the built harness on ``inputs`` (``rounds`` alternating step and bare passes);
    parse its lines and the QP vectors it wrote. Times of all rounds are pooled; outputs,
    iterations and statuses are round 1's (later rounds repeat them bit for bit, or the
    harness fails).

    Raises
    ------
    BuildError
        The harness failed (its message).
    """
    qp_file = inputs.with_suffix(".qp")
    done = subprocess.run([str(directory / HARNESS), str(inputs), str(qp_file), str(rounds)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise BuildError(f"{directory / HARNESS} exited {done.returncode}: {done.stderr.strip()}")
    lines = done.stdout.splitlines()   # a comment line, the CSV header, the rows
    rows: dict[str, list[list[str]]] = {"step": [], "bare": [], "cap": []}
    for line in lines[2:]:
        phase, *fields = line.split(",")   # round, k, triac_pct, n_iterations, status_val, ns
        rows[phase].append(fields)
    first = [r for r in rows["step"] if r[0] == "0"]
    bare = rows["bare"]
    cap = None
    if rows["cap"]:
        ns = np.array([int(r[5]) for r in rows["cap"]], dtype=float)
        cap = CapSolve(k=int(rows["cap"][0][1]), n_iterations=int(rows["cap"][0][3]),
                       status_val=int(rows["cap"][0][4]), median_ms=float(np.median(ns)) * 1e-6,
                       max_ms=float(ns.max()) * 1e-6)
    dtype = np.float32 if float32 else np.float64
    width = n_variables + 2 * n_constraints
    sent = np.fromfile(qp_file, dtype=dtype).astype(float).reshape(len(first), width)
    return _HarnessRun(
        triac_pct=np.array([float(r[2]) for r in first]),
        iterations=np.array([int(r[3]) for r in first]),
        status_val=np.array([int(r[4]) for r in first]),
        step_s=np.array([int(r[5]) for r in rows["step"]], dtype=float) * 1e-9,
        bare_k=np.array([int(r[1]) for r in bare], dtype=int),
        bare_iterations=np.array([int(r[3]) for r in bare], dtype=int),
        bare_s=np.array([int(r[5]) for r in bare], dtype=float) * 1e-9,
        cap=cap, sent=sent)


def _ctypes_loop(library: Path, loop: _PythonLoop, *, initial_triac_pct: float,
                 context: bool) -> tuple[FloatArray, FloatArray]:
    """``(triac_pct, step_s)`` of `CController.step` on ``loop``'s inputs."""
    c = CController(library, initial_triac_pct=initial_triac_pct)
    n = loop.power_kw.size
    triac, step_s = np.empty(n), np.empty(n)
    for k in range(n):
        power, setpoint = float(loop.power_kw[k]), float(loop.setpoint_kw[k])
        if context:
            preview, volt = loop.previews[k], float(loop.voltage[k])
            t0 = time.perf_counter()
            u = c.step(power, setpoint, setpoint_preview_kw=preview, grid_voltage_factor=volt)
            step_s[k] = time.perf_counter() - t0
        else:
            t0 = time.perf_counter()
            u = c.step(power, setpoint)
            step_s[k] = time.perf_counter() - t0
        triac[k] = u
    return triac, step_s


def _rel_diff(a: FloatArray, b: FloatArray) -> float:
    """Largest ``|a - b| / max(1, |a|, |b|)`` (0 where equal, infinities included)."""
    if a.size == 0:
        return 0.0
    with np.errstate(invalid="ignore"):
        diff = np.where(a == b, 0.0, np.abs(a - b) / np.maximum(1.0, np.maximum(np.abs(a),
                                                                                np.abs(b))))
    return float(np.nanmax(np.where(np.isnan(diff), np.inf, diff)))


def compare_run(loop: _PythonLoop, harness: _HarnessRun, ctypes_triac: FloatArray,
                ctypes_s: FloatArray) -> CodegenRun:
    """The statistics and agreement of one repeat (`CodegenRun`)."""
    n = loop.triac_pct.size
    differ = np.flatnonzero(harness.iterations != loop.iterations)
    first = int(differ[0]) if differ.size else None
    upto = n if first is None else first
    dev = np.abs(harness.triac_pct - loop.triac_pct)
    solved = np.flatnonzero(harness.status_val[:upto] > 0)
    same_bare = harness.bare_iterations == harness.iterations[harness.bare_k]
    return CodegenRun(
        n_steps=n, python=Timing.of(loop.step_s), c_step=Timing.of(harness.step_s),
        c_ctypes=Timing.of(ctypes_s), bare=Timing.of(harness.bare_s),
        mean_iterations=float(np.mean(harness.iterations)),
        max_iterations=int(np.max(harness.iterations)),
        bare_same_iterations=float(np.mean(same_bare)) if same_bare.size else 1.0,
        n_iteration_differences=int(differ.size), first_difference_k=first,
        worst_triac_pct=float(np.max(dev[:upto])) if upto else 0.0,
        worst_triac_all_pct=float(np.max(dev)),
        n_bit_equal=int(np.sum(harness.triac_pct == loop.triac_pct)),
        qp_max_rel_diff=_rel_diff(harness.sent[solved], loop.sent[solved]),
        ctypes_equal=int(np.sum(ctypes_triac == harness.triac_pct)),
        cap=harness.cap)


# --- sizes, revision -----------------------------------------------------------------------


def object_sizes(directory: Path) -> tuple[ObjectSize, ...]:
    """``size -A`` of the step, OSQP's workspace and OSQP's objects in ``directory``.

    Raises
    ------
    BuildError
        ``size`` (binutils) is missing or fails.
    """
    osqp = tuple(sorted(p.name for p in directory.glob("osqp_*.o")))
    groups = (("the step (code, the model's constant matrices)", ("czmpc_step.o",)),
              ("OSQP's generated workspace (problem, scaling, KKT factor, iterates)",
               ("czmpc_qp_workspace.o",)),
              (f"OSQP's solver ({len(osqp)} objects)", osqp))
    out = []
    for part, files in groups:
        sums = {"text": 0, "rodata": 0, "data": 0, "bss": 0}
        for name in files:
            try:
                done = subprocess.run(["size", "-A", str(directory / name)], capture_output=True,
                                      text=True, check=True)
            except (OSError, subprocess.CalledProcessError) as exc:
                raise BuildError(f"size -A {directory / name}: {exc}") from exc
            for line in done.stdout.splitlines():
                fields = line.split()
                if len(fields) == 3 and fields[1].isdigit():
                    kind = fields[0].lstrip(".").split(".")[0]
                    if kind in sums:
                        sums[kind] += int(fields[1])
        out.append(ObjectSize(part=part, files=files, **sums))
    return tuple(out)


def _first_line(args: Sequence[str]) -> str:
    with contextlib.suppress(OSError, subprocess.CalledProcessError):
        done = subprocess.run(list(args), capture_output=True, text=True, check=True,
                              cwd=Path(__file__).parent)
        return done.stdout.strip().splitlines()[0] if done.stdout.strip() else ""
    return "unknown"


def revision() -> str:
    """``git`` revision of this tree, and a note if czmpc/ has uncommitted changes."""
    rev = _first_line(["git", "rev-parse", "--short", "HEAD"])
    dirty = _first_line(["git", "status", "--porcelain", "--", "../czmpc"])
    return f"{rev} (with uncommitted changes in czmpc/)" if dirty and dirty != "unknown" else rev


# --- the benchmark -------------------------------------------------------------------------


def measure(model: HammersteinModel, directory: Path, *, repeats: int, n_steps: int | None,
            context: bool, float32: bool, rounds: int = 1, progress: Progress | None = None,
            ) -> tuple[CodegenRun, ...]:
    """Replay ``repeats`` closed loops through every path (module notes).

    Parameters
    ----------
    model :
        The controller's model (and the plant's).
    directory :
        A built step of ``OffsetFreeMPC(model)`` with the harness (`build_harness`).
    repeats :
        Closed loops (seeds ``BENCH_SEED ..``).
    n_steps :
        Steps of the staircase replayed (None: all).
    context :
        Preview and voltage given (module notes).
    float32 :
        The directory's step computes in ``float``.
    rounds :
        Alternating step and bare passes of the harness per repeat (times pooled).
    progress :
        Called with a line per repeat.
    """
    scenario = load_scenario("staircase")
    settings = MPCSettings.default_for(model)
    n = len(scenario.setpoint_profile_kw()) if n_steps is None else n_steps
    qp = OffsetFreeMPC(model, settings).qp
    initial = (scenario.initial_triac_pct if scenario.initial_triac_pct is not None
               else model.operating_point.triac_pct)   # given to both controllers
    runs = []
    for i in range(repeats):
        loop = _python_loop(model, settings, scenario, initial_triac_pct=initial, n_steps=n,
                            seed=BENCH_SEED + i, context=context)
        inputs = directory / f"inputs_{'context' if context else 'plain'}_{i}.txt"
        write_inputs(inputs, loop, initial_triac_pct=initial)
        harness = run_harness(directory, inputs, n_variables=qp.n_variables,
                              n_constraints=qp.n_constraints, float32=float32, rounds=rounds)
        triac, step_s = _ctypes_loop(directory / SHARED_LIBRARY, loop,
                                     initial_triac_pct=initial, context=context)
        runs.append(compare_run(loop, harness, triac, step_s))
        if progress is not None:
            r = runs[-1]
            progress(f"{'preview and voltage' if context else 'plain'}, run {i + 1}/{repeats}: "
                     f"Python {r.python.median_us:.1f} us, C {r.c_step.median_us:.1f} us, bare "
                     f"{r.bare.median_us:.1f} us ({r.c_over_bare:.2f} x)")
    return tuple(runs)


def fuzz_worst_iterations(n_cases: int, progress: Progress | None = None) -> FuzzWorst:
    """The worst Python iteration count of ``tests/codegen/fuzz.py``'s set (seed 1).

    Needs the repository's tests (run from its root) and builds one C step per case. The
    fuzz set is the tests' code: if it stops (an exception, an assertion of its replay),
    the result says so instead of losing the timings measured before it.
    """
    # The repository's tests, not a package of this project: imported by name, so that
    # type checking `benchmarks` stays out of them.
    fuzz = importlib.import_module("tests.codegen.fuzz")
    replay = importlib.import_module("tests.codegen.replay")
    try:
        with tempfile.TemporaryDirectory(prefix="czmpc_bench_fuzz_") as tmp:
            result = fuzz.fuzz(replay.StepBuilder(Path(tmp)), n_cases=n_cases,
                               n_steps=FUZZ_STEPS_PER_CASE, seed=FUZZ_SEED)
    except Exception as exc:  # the tests' code: any failure is reported, not raised
        where = exc.__traceback__
        while where is not None and where.tb_next is not None:
            where = where.tb_next
        place = (f" at {Path(where.tb_frame.f_code.co_filename).name}:{where.tb_lineno}"
                 if where is not None else "")
        worst = FuzzWorst(n_cases=n_cases, n_steps=0, seed=FUZZ_SEED, max_iterations=None,
                          error=f"{type(exc).__name__}{place}: {exc}".rstrip(": "))
    else:
        worst = FuzzWorst(n_cases=result.n_cases, n_steps=result.total.n_steps, seed=FUZZ_SEED,
                          max_iterations=int(result.max_iterations))
    if progress is not None:
        progress(f"fuzz set: {worst.n_steps} steps, worst iteration count {worst.max_iterations}"
                 + (f" (stopped: {worst.error})" if worst.error else ""))
    return worst


def run_benchmark(model: HammersteinModel, directory: Path, *, model_label: str, command: str,
                  repeats: int = 5, n_steps: int | None = None, float32: bool = False,
                  rounds: int = 3, fuzz_cases: int = 0,
                  progress: Progress | None = None) -> CodegenBenchmark:
    """Generate and build the step into ``directory``, then measure (module notes).

    Parameters
    ----------
    model :
        The controller's model (default settings).
    directory :
        Where the step is generated (created).
    model_label :
        How to name the model in the report.
    command :
        The command line, recorded with the numbers.
    repeats :
        Closed loops per half (>= 1).
    n_steps :
        Steps of the staircase per loop (None: all 3,900).
    float32 :
        Generate the step in single precision.
    rounds :
        Alternating passes of the C step and the bare solve per repeat.
    fuzz_cases :
        Cases of the fuzz set for its worst iteration count (0: not measured).
    progress :
        Called with a short message per stage.

    Raises
    ------
    BuildError
        No C toolchain, or a build failed.
    """
    machine = machine_info()
    step = generate_step(model, None, directory, float32=float32)
    compile_command = build_harness(directory)
    sizes = object_sizes(directory)
    runs = measure(model, directory, repeats=repeats, n_steps=n_steps, context=False,
                   float32=float32, rounds=rounds, progress=progress)
    context_runs = measure(model, directory, repeats=repeats, n_steps=n_steps, context=True,
                           float32=float32, rounds=rounds, progress=progress)
    cc = _first_line([compile_command.split()[0] if compile_command else "cc", "--version"])
    sizeof_state = ctypes.CDLL(str(directory / SHARED_LIBRARY)).czmpc_sizeof_state
    sizeof_state.restype = ctypes.c_ulong
    state_bytes = int(sizeof_state())
    settings = MPCSettings.default_for(model)
    fuzz = fuzz_worst_iterations(fuzz_cases, progress) if fuzz_cases > 0 else None
    return CodegenBenchmark(
        machine=machine, model_label=model_label, command=command, revision=revision(),
        compiler=cc, compile_command=compile_command, float32=float32,
        horizon_steps=step.horizon_steps, n_variables=step.n_variables,
        n_constraints=step.n_constraints, max_iter=settings.osqp.max_iter, rounds=rounds, runs=runs,
        context_runs=context_runs, sizes=sizes, state_bytes=state_bytes, fuzz=fuzz)


# --- the report ----------------------------------------------------------------------------


def _met(ok: bool) -> str:
    return "**met**" if ok else "**missed**"


def _load_note(machine: MachineInfo) -> list[str]:
    """A note when other work shared the machine (it shows in the percentiles)."""
    load = machine.load_average
    if load is None or load < 0.5 * machine.n_cpus:
        return []
    return ["", f"Note: other jobs shared the machine (load average {load:.2f} on "
                f"{machine.n_cpus} cores). A step that loses its core for a time slice takes "
                "milliseconds: that shows in p99.9, which varies from run to run, more than in "
                "the medians."]


def _median(values: Sequence[float]) -> float:
    return float(np.median(list(values)))


def format_report(bench: CodegenBenchmark) -> str:
    """The numbers as Markdown (stdout and BENCHMARKS.md share it)."""
    real = "float" if bench.float32 else "double"
    n = bench.runs[0].n_steps if bench.runs else 0
    lines = [
        f"Command: `{bench.command}`",
        "",
        f"Machine: {bench.machine.describe()}",
        "",
        f"Code: {bench.revision}. C: {bench.compiler}; `{bench.compile_command}` (the generated "
        f"Makefile's flags), {real}.",
        "",
        f"Model: {bench.model_label}, default settings (`MPCSettings.default_for`): N = "
        f"{bench.horizon_steps}, OSQP with {bench.n_variables} variables and "
        f"{bench.n_constraints} rows, eps 1e-5, warm-started, adaptive rho, at most "
        f"{bench.max_iter} iterations; generated with `czmpc codegen` (OSQP's solver from the "
        "controller's own OSQP object).",
        "",
        f"The same steps through every path: the shipped staircase ({n} samples) against the "
        "model plant (noise on, seed = run - 1) stepped by the Python controller "
        "(`OffsetFreeMPC.step`, perf_counter per call); its inputs then replayed through the C "
        "step in a C harness (`benchmarks/codegen_timing.c`: `czmpc_step` against the "
        "directory's `libczmpc.a`, `clock_gettime(CLOCK_MONOTONIC)` per call, no Python in "
        "the loop) and through ctypes (`CController.step`, for reference); and the bare "
        "generated solve: `osqp_update_data_vec` + `osqp_solve` on the generated workspace, "
        "set up afresh, fed the very `q`, `l`, `u` the C step sent, in the same order, "
        f"cold-started where it was. The harness alternates {bench.rounds} passes of the C "
        "step with as many of the bare solve, so that a change of the machine's load falls on "
        "both. Medians and 99.9th percentiles over the steps (the C paths: over all passes) "
        "[us], one row per run.",
        *_load_note(bench.machine),
    ]
    lines += _half(bench, bench.runs, "")
    lines += _half(bench, bench.context_runs,
                   f" with a {PREVIEW_STEPS * 2} s setpoint preview and a measured voltage")
    lines += _summary(bench)
    lines += _sizes(bench)
    return "\n".join(lines) + "\n"


def _half(bench: CodegenBenchmark, runs: tuple[CodegenRun, ...], what: str) -> list[str]:
    """The timing and agreement tables of one half of the measurement."""
    if not runs:
        return []
    lines = [
        "",
        f"### The step in Python, in C and the bare solver{what}, N = {bench.horizon_steps}",
        "",
        "| run | Python step: median / p99.9 [us] | C step: median / p99.9 [us] | C step via "
        "ctypes: median / p99.9 [us] | bare OSQP solve: median / p99.9 [us] | C step / bare "
        "| Python / C step |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, r in enumerate(runs, start=1):
        lines.append(
            f"| {i} | {r.python.median_us:.2f} / {r.python.p999_us:.1f} | "
            f"{r.c_step.median_us:.2f} / {r.c_step.p999_us:.1f} | "
            f"{r.c_ctypes.median_us:.2f} / {r.c_ctypes.p999_us:.1f} | "
            f"{r.bare.median_us:.2f} / {r.bare.p999_us:.1f} | {r.c_over_bare:.3f} | "
            f"{r.python_over_c:.2f} |")
    tol = "" if bench.float32 else f" (issue 42: at most {TRIAC_ATOL_PCT:g} %)"
    lines += [
        "",
        "Did the timed C run compute what Python did? Per run: OSQP iterations of the C step; "
        "the bare replay's iterations equal to the step's; steps whose iteration count "
        "differs between C and Python (an OSQP termination test flipped by an ulp of `q`: "
        f"the two then warm-start from different iterates); the largest TRIAC difference "
        f"before the first of them{tol} and over all steps; the largest relative difference "
        "of the `q`, `l`, `u` the two sent before it; the ctypes step's outputs bit-equal to "
        "the harness's.",
        "",
        "| run | OSQP iterations mean / max | bare replay: same iterations | other iteration "
        "count than Python: steps (first at k) | max abs dTRIAC before it [%] | max abs dTRIAC, "
        "all steps [%] | TRIAC bit-equal | max rel. diff of q, l, u | ctypes = harness |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, r in enumerate(runs, start=1):
        first = "" if r.first_difference_k is None else f" (k = {r.first_difference_k})"
        lines.append(
            f"| {i} | {r.mean_iterations:.2f} / {r.max_iterations} | "
            f"{r.bare_same_iterations:.1%} | {r.n_iteration_differences}{first} | "
            f"{r.worst_triac_pct:.2e} | {r.worst_triac_all_pct:.2e} | "
            f"{r.n_bit_equal} of {r.n_steps} | {r.qp_max_rel_diff:.1e} | "
            f"{r.ctypes_equal} of {r.n_steps} |")
    return lines


def _summary(bench: CodegenBenchmark) -> list[str]:
    """Ratios, the goal, the worst case and the fuzz set."""
    runs = bench.all_runs
    if not runs:
        return []
    lines = ["", "### Summary", ""]
    for label, half in (("without preview", bench.runs),
                        ("with preview and voltage", bench.context_runs)):
        if not half:
            continue
        lines.append(
            f"- {label.capitalize()} (medians over the runs): the C step "
            f"{_median([r.c_step.median_us for r in half]):.2f} us (p99.9 "
            f"{_median([r.c_step.p999_us for r in half]):.1f} us), the bare solve "
            f"{_median([r.bare.median_us for r in half]):.2f} us (p99.9 "
            f"{_median([r.bare.p999_us for r in half]):.1f} us): **{bench.c_over_bare(half):.3f} "
            f"x**; the Python step {_median([r.python.median_us for r in half]):.1f} us: "
            f"**{_median([r.python_over_c for r in half]):.1f} x the C step**; through ctypes "
            f"{_median([r.c_ctypes.median_us for r in half]):.1f} us.")
    lines += [
        f"- Goal (issue 42): the C step with OSQP within {C_OVER_BARE_GOAL:g} of OSQP's bare "
        f"generated solver, on the same QPs: {_met(bench.goal_met)}. The issue's second ratio "
        "(the C step with DAQP within 2 of DAQP's bare solve) is not measured: the generated "
        "C has OSQP only.",
    ]
    worst = max(r.max_iterations for r in runs)
    caps = [r.cap for r in runs if r.cap is not None]
    line = (f"- Worst case: at most {worst} OSQP iterations per step on these runs (cap "
            f"{bench.max_iter}).")
    if caps:
        hardest = max(caps, key=lambda c: c.median_ms)
        line += (f" The hardest QP of each run solved from a cold start with eps_abs = eps_rel = "
                 f"0, so that only the cap stops OSQP: {hardest.n_iterations} iterations "
                 f"(status_val {hardest.status_val}) in {_median([c.median_ms for c in caps]):.2f} "
                 f"ms (median over the runs; slowest run {hardest.median_ms:.2f} ms, single "
                 f"worst {max(c.max_ms for c in caps):.2f} ms): a step's solve is bounded by "
                 "that, the rest of the step adds the few us between the C step and the bare "
                 "solve.")
    lines.append(line)
    if bench.fuzz is None:
        lines.append("- Worst iteration count on the fuzz set (`tests/codegen/fuzz.py`): not "
                     "measured here (`--fuzz-cases 400` runs its 1e6-step set).")
    elif bench.fuzz.max_iterations is None:
        lines.append(f"- Worst iteration count on the fuzz set (`tests/codegen/fuzz.py`, seed "
                     f"{bench.fuzz.seed}, {bench.fuzz.n_cases} cases asked): not measured, the "
                     f"fuzz set stopped ({bench.fuzz.error}).")
    else:
        f = bench.fuzz
        lines.append(f"- Worst iteration count on the fuzz set (`tests/codegen/fuzz.py`, seed "
                     f"{f.seed}, {f.n_cases} random controllers x {FUZZ_STEPS_PER_CASE} steps = "
                     f"{f.n_steps:,} steps; each case's cap is 25, 200 or 4000): **{f.max_iterations}**.")
    if bench.float32:
        worst_dev = max(r.worst_triac_all_pct for r in runs)
        lines.append(f"- float32: the C step's TRIAC input is at most {worst_dev:.2e} % from the "
                     "Python (double) controller's on these runs.")
    return lines


def _sizes(bench: CodegenBenchmark) -> list[str]:
    """The code and data size table."""
    lines = [
        "",
        "### Code and data size",
        "",
        "`size -A` of the objects the step links (bytes; `.rodata` holds constant data such as "
        "the model's matrices; OSQP's workspace is initialised data). The caller also holds "
        f"one `czmpc_state`: {bench.state_bytes} bytes.",
        "",
        "| part | objects | .text | .rodata | .data | .bss | total |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for s in bench.sizes:
        files = ", ".join(f"`{f}`" for f in s.files) if len(s.files) <= 2 else "`osqp_*.o`"
        lines.append(f"| {s.part} | {files} | {s.text} | {s.rodata} | {s.data} | {s.bss} | "
                     f"{s.text + s.rodata + s.data + s.bss} |")
    t = {k: sum(getattr(s, k) for s in bench.sizes) for k in ("text", "rodata", "data", "bss")}
    lines.append(f"| all | | {t['text']} | {t['rodata']} | {t['data']} | {t['bss']} | "
                 f"{sum(t.values())} |")
    return lines


def write_benchmarks_section(path: str | Path, body: str, *, float32: bool = False) -> None:
    """Put ``body`` under this benchmark's heading (``float32``: its own) in a BENCHMARKS.md."""
    _write_section(path, body, heading=SECTION_HEADING_FLOAT32 if float32 else SECTION_HEADING)


def build_parser() -> argparse.ArgumentParser:
    """The options of ``python -m benchmarks.codegen_step``."""
    parser = benchmark_parser("codegen_step", __doc__)
    parser.add_argument(
        "--model", metavar="MODEL.json", type=Path, default=None,
        help="identified model file for the controller and the model plant (default: the "
             "shipped data/cz_heater_model.json)")
    parser.add_argument(
        "--repeats", metavar="N", type=_argtypes.positive_int, default=5,
        help="closed loops per half (without, then with preview and voltage) (default: 5)")
    parser.add_argument(
        "--steps", metavar="N", type=_argtypes.positive_int, default=None,
        help="steps of the staircase per loop (default: all 3,900)")
    parser.add_argument(
        "--rounds", metavar="N", type=_argtypes.positive_int, default=3,
        help="alternating passes of the C step and the bare solve over each loop's steps in "
             "the harness, times pooled (default: 3)")
    parser.add_argument(
        "--float32", action="store_true",
        help="generate the step in single precision (its own section of BENCHMARKS.md)")
    parser.add_argument(
        "--fuzz-cases", metavar="N", type=int, default=0,
        help="also run N cases of tests/codegen/fuzz.py's set (seed 1, 2,500 steps each; "
             "400: its 1e6 steps, 19 min here) for its worst iteration count (default: 0, "
             "not measured)")
    parser.add_argument(
        "--out", metavar="DIR", type=Path, default=None,
        help="generate the step and keep the harness's files here (default: a temporary "
             "directory)")
    parser.add_argument(
        "--benchmarks-md", metavar="FILE", type=Path, default=BENCHMARKS_MD,
        help="Markdown file to put the section in (default: BENCHMARKS.md of this repository)")
    parser.add_argument(
        "--no-record", action="store_true",
        help="only print the numbers; do not write them into BENCHMARKS.md")
    return parser


def _run(args: argparse.Namespace) -> int:
    path = args.model if args.model is not None else shipped_path(HAMMERSTEIN_MODEL_JSON)
    model = load_model(path)
    label = str(path)
    with contextlib.suppress(ValueError):  # the shipped file relative to here if below
        label = str(path.resolve().relative_to(Path.cwd()))
    progress = _progress.Progress()
    with contextlib.ExitStack() as stack:
        directory = (args.out if args.out is not None else
                     Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="czmpc_cg_"))))
        bench = run_benchmark(model, directory, model_label=f"`{label}`",
                              command=args.command_line, repeats=args.repeats,
                              n_steps=args.steps, float32=args.float32, rounds=args.rounds,
                              fuzz_cases=args.fuzz_cases, progress=progress)
    text = format_report(bench)
    print(text, end="")
    if not bench.agrees:
        print("error: the timed C run did not compute what the Python controller did (see the "
              "agreement table); nothing recorded", file=sys.stderr)
        return 1
    if not args.no_record:
        write_benchmarks_section(args.benchmarks_md, text, float32=args.float32)
        progress(f"wrote the numbers to {args.benchmarks_md}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print it, record it in BENCHMARKS.md; return the exit code."""
    return run_main(build_parser(), _run, argv)


__all__ = [
    "C_OVER_BARE_GOAL",
    "SECTION_HEADING",
    "SECTION_HEADING_FLOAT32",
    "TRIAC_ATOL_PCT",
    "CapSolve",
    "CodegenBenchmark",
    "CodegenRun",
    "FuzzWorst",
    "ObjectSize",
    "Timing",
    "build_harness",
    "build_parser",
    "compare_run",
    "format_report",
    "fuzz_worst_iterations",
    "main",
    "measure",
    "object_sizes",
    "revision",
    "run_benchmark",
    "run_harness",
    "write_benchmarks_section",
    "write_inputs",
]


if __name__ == "__main__":
    sys.exit(main())
