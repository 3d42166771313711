"""Cost of the generated C step: against the Python step and the bare solver inside it.

``python -m benchmarks.codegen_step [--repeats N] [--steps N] [--float32] [--fuzz-cases N]``
``python -m benchmarks.codegen_step --solver daqp [--repeats N] [--steps N]``

What does one step of the controller cost once it is C (``czmpc codegen``), compared
with the Python controller it was generated from and with the QP solve inside it,
and how much code and data is it? (Issue 42, item 5: the C step with OSQP within 1.15x
OSQP's bare generated solve, with DAQP within 2x DAQP's bare solve, on the same QPs.)

The controller: the shipped model's (``--model``), default settings
(`MPCSettings.default_for`; N = 39 for the shipped model), with ``--solver daqp``
the same with ``solver = "daqp"`` (`czmpc.qp_daqp`; the C's DAQP from the installed
version's sdist, `czmpc.codegen.daqp_source`), generated and built once per run of this
benchmark with the generated Makefile's flags. Each repeat replays the same closed-loop
steps through every path:

1. **Python**: `OffsetFreeMPC.step` steps the shipped staircase against the model plant
   (noise on, seed = repeat - 1), `time.perf_counter` around each call; the inputs it
   got (measured power, setpoint, and in the second half of the measurement the next
   30 setpoints and a grid voltage reading, as ``benchmarks.mpc_step`` gives them), its
   TRIAC output, iteration count and the ``q, l, u`` it sent to its solver are kept.
2. **C step**: the kept inputs, read from a file by a small C harness
   (``benchmarks/codegen_timing.c``, linked against the directory's ``libczmpc.a`` with
   its Makefile's flags, ``benchmarks/codegen_timing.mk``), each ``czmpc_step`` timed
   with ``clock_gettime(CLOCK_MONOTONIC)``; no Python in the loop. The harness prints
   each step's TRIAC output, so the benchmark checks that the timed C run computed
   what Python did (issue 42: within 1e-6 %, up to the first step whose iteration
   count differs; such steps are counted). For reference, the same C step through
   ctypes (`czmpc.codegen.CController.step`, perf_counter per call).
3. **Bare solver**: in the same harness, the solver alone on the very ``q, l, u`` the C
   step sent, in the same order, cold-started where the step cold-started: exactly the
   solver calls of the step's solve stage. OSQP: ``osqp_update_data_vec`` +
   ``osqp_solve`` on the generated workspace, set up afresh by ``czmpc_init_at``. DAQP:
   ``daqp_update_ldp`` (``f``, ``bupper``, ``blower``; the working set cleared on a cold
   start) + ``daqp_solve`` from the previous working set, on a DAQP workspace the
   harness sets up as ``czmpc_init`` sets up the step's (``setup_daqp`` on the same
   ``H``, rows and settings, in the same static arena), with the step library's DAQP
   objects. The same QPs from the same warm starts, hence the same iterations and the
   same plans, bit for bit (both checked). The ratio C step / bare solver is what the
   controller costs around its QP.

Reported per path: median and 99.9th percentile of the per-step times, one row per
repeat; the ratios; the worst iteration count of these runs against the cap (OSQP's
``max_iter``, DAQP's `DAQP_ITER_LIMIT`) and the time of a worst-case solve: the hardest
QP of the run from a cold start, OSQP with ``eps_abs = eps_rel = 0`` so that only the
cap stops it, DAQP from an empty working set (an active-set method stops at the
optimum); with ``--fuzz-cases N`` the worst iteration count on the fuzz set of
``tests/codegen/fuzz.py`` (seed 1, 2,500 steps per case, with the run's solver; 400
cases are its 1e6-step set; it builds a C step per case: 400 cases took 19 min here with
OSQP), otherwise it says that was not measured; and ``size -A`` of the step's object
(``czmpc_step.o``: code and the model's constant matrices), the solver's data (OSQP's
generated workspace ``czmpc_qp_workspace.o``; DAQP's static arena
``czmpc_daqp_heap.o``) and the solver's objects, with ``sizeof(czmpc_state)``.

Machine note: compare within one run and quote medians; the shared machine's load shows
in the percentiles. The numbers go to stdout and, with the machine, under
`SECTION_HEADING` (`--float32`: `SECTION_HEADING_FLOAT32`; ``--solver daqp``:
`SECTION_HEADING_DAQP`) in BENCHMARKS.md.

Exit codes: 0 done; 1 the timed C run did not compute what Python did, or the bare
replay did not solve the step's QPs as the step did (nothing recorded); 2 bad input
(model file, ``--float32`` with DAQP), no C toolchain or a failed build.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import importlib
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import get_args

import numpy as np

from benchmarks._md import BENCHMARKS_MD, MachineInfo, benchmark_parser, machine_info, run_main
from benchmarks._md import write_benchmarks_section as _write_section
from benchmarks.mpc_step import BENCH_SEED, PREVIEW_STEPS, SAG_FACTOR
from czmpc.cli import _argtypes, _progress
from czmpc.codegen import CController, build, generate_step
from czmpc.codegen.build import SHARED_LIBRARY, find_tools
from czmpc.codegen.daqp_source import daqp_version
from czmpc.codegen.errors import BuildError
from czmpc.controller import OffsetFreeMPC
from czmpc.qp_daqp import DAQP_ITER_LIMIT
from czmpc.settings import MPCSettings, QPSolverName
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
#: Heading of the ``--solver daqp`` run's section.
SECTION_HEADING_DAQP = ("## Generated C step with DAQP: cost against Python and the bare "
                        "solver (issue 42)")
#: Goal of issue 42: the C step's median at most this times the bare generated solver's.
C_OVER_BARE_GOAL = 1.15
#: The same with DAQP: the C step's median at most this times DAQP's bare solve.
C_OVER_BARE_GOAL_DAQP = 2.0
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
class _SolverWords:
    """What the report says of one solver; the rest of it reads the same for both."""

    name: str
    goal: float
    bare_name: str          # the goal's "within x of ..."
    qp: str                 # the QP as solved: {n_variables}, {n_constraints}, {max_iter}, {version}
    bare: str               # the bare solve, in the paragraph of the paths
    flipped: str            # why an iteration count may differ between C and Python
    cap: str                # how the worst-case solve was run
    cap_meaning: str        # what its time says
    status: str             # what its status number is
    status_offset: int      # the harness's status_val minus that number
    fuzz_cap: str           # the iteration caps of the fuzz set's cases
    other_goal: str         # where the other ratio is
    sizes: str              # what the solver's data is, in the sizes paragraph


_WORDS: dict[str, _SolverWords] = {
    "osqp": _SolverWords(
        name="OSQP", goal=C_OVER_BARE_GOAL, bare_name="OSQP's bare generated solver",
        qp="OSQP with {n_variables} variables and {n_constraints} rows, eps 1e-5, warm-started, "
           "adaptive rho, at most {max_iter} iterations; generated with `czmpc codegen` (OSQP's "
           "solver from the controller's own OSQP object)",
        bare="the bare generated solve: `osqp_update_data_vec` + `osqp_solve` on the generated "
             "workspace, set up afresh",
        flipped="an OSQP termination test flipped by an ulp of `q`: the two then warm-start "
                "from different iterates",
        cap="solved from a cold start with eps_abs = eps_rel = 0, so that only the cap stops "
            "OSQP",
        cap_meaning="a step's solve is bounded by that, the rest of the step adds the few us "
                    "between the C step and the bare solve",
        status="status_val", status_offset=0, fuzz_cap="each case's cap is 25, 200 or 4000",
        other_goal="The issue's second ratio (the C step with DAQP within 2 of DAQP's bare "
                   "solve): `--solver daqp`, in its own section.",
        sizes="OSQP's workspace is initialised data"),
    "daqp": _SolverWords(
        name="DAQP", goal=C_OVER_BARE_GOAL_DAQP, bare_name="DAQP's bare solve",
        qp="DAQP {version} with {n_variables} variables and {n_constraints} rows (the first N "
           "its simple bounds), hot-started from the previous working set, primal_tol 1e-6, at "
           "most {max_iter} iterations (active-set changes); generated with `czmpc codegen` "
           "(DAQP's C from its sdist, set up at `czmpc_init` from the controller's own H and "
           "rows)",
        bare="the bare DAQP solve: `daqp_update_ldp` (`f`, `bupper`, `blower`) + `daqp_solve` "
             "from the previous working set, the step library's DAQP objects on a workspace the "
             "harness sets up as `czmpc_init` sets up the step's (`setup_daqp` on the same H, "
             "rows and settings, in the same static arena)",
        flipped="a DAQP pivot decided otherwise by an ulp: the two then start from different "
                "working sets",
        cap="solved from an empty working set (a cold start; DAQP stops at the optimum, not at "
            "its cap)",
        cap_meaning="what a solve costs when the step starts it without a working set (at "
                    "start and after an unusable solve); DAQP's own bound is its cap",
        status="exit flag", status_offset=100, fuzz_cap=f"DAQP's cap is {DAQP_ITER_LIMIT}",
        other_goal="The issue's first ratio (the C step with OSQP within 1.15 of OSQP's bare "
                   "generated solver): the section of the run without `--solver daqp`.",
        sizes="DAQP's workspace lies in a static arena (`.bss`) that `czmpc_init` has DAQP's "
              "set-up fill"),
}


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
    """The hardest QP of a run from a cold start: OSQP until only its iteration cap stops
    it, DAQP from an empty working set.

    Parameters
    ----------
    k :
        Step whose QP it is (the one that took the most iterations in the run).
    n_iterations :
        Iterations the solver ran (OSQP: the cap, unless it stopped otherwise).
    status_val :
        The step's ``solver_status_val`` for it: OSQP's ``status_val`` (7: maximum
        iterations reached), DAQP's exit flag + 100 (101: optimal).
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
        `CController.step` and of the bare solve (solved QPs only).
    mean_iterations, max_iterations :
        Solver iterations of the C step per step.
    bare_same_iterations :
        Fraction of the replayed QPs that took the C step's iteration count.
    bare_same_plan :
        Fraction of the replayed QPs whose solution's first ``N`` entries are bit-equal
        to the plan the C step used (over the QPs whose plan it used).
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
    bare_same_plan: float
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
        first iteration difference; both: ctypes bit-equal to the harness) and the bare
        replay solved the step's QPs as the step did (iterations and plans)."""
        same_c = self.ctypes_equal == self.n_steps
        same_bare = self.bare_same_iterations == 1.0 and self.bare_same_plan == 1.0
        return same_c and same_bare and (float32 or self.worst_triac_pct <= TRIAC_ATOL_PCT)


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
    """Worst solver iteration count on the fuzz set (``tests/codegen/fuzz.py``).

    Parameters
    ----------
    n_cases, n_steps :
        Random controllers and steps run.
    seed :
        The fuzz set's seed.
    max_iterations :
        Largest iteration count of the Python controller over all steps (the C step's
        equal where the two agree; OSQP's cap drawn per case is 25, 200 or 4,000, DAQP's
        is `DAQP_ITER_LIMIT`), or None if the fuzz set stopped.
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
        The QP: ``N``, its variables and rows, the solver's iteration cap.
    rounds :
        Alternating passes of the C step and the bare solve per repeat.
    runs, context_runs :
        One `CodegenRun` per repeat, without and with preview and voltage.
    sizes :
        Object sizes: the step, the solver's data, the solver's objects.
    state_bytes :
        ``sizeof(czmpc_state)``.
    fuzz :
        The fuzz set's worst iteration count, or None (not measured).
    solver :
        `MPCSettings.solver` of the controller.
    solver_version :
        The DAQP version of the C (``solver = "daqp"``), else empty.
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
    solver: QPSolverName = "osqp"
    solver_version: str = ""

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
    def goal(self) -> float:
        """Issue 42's bound on the C step / bare solve ratio for this solver
        (`C_OVER_BARE_GOAL`, `C_OVER_BARE_GOAL_DAQP`)."""
        return _WORDS[self.solver].goal

    @property
    def goal_met(self) -> bool:
        """C step within `goal` of the bare solve, in both halves."""
        halves = [h for h in (self.runs, self.context_runs) if h]
        return all(self.c_over_bare(h) <= self.goal for h in halves)


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
    sent: FloatArray                     # (n, n_var + 2 m): q, l, u as sent to the solver
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
    bare_plan: np.ndarray                # per bare solve: 1 the step's plan, 0 another, -1 none
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
        # round, k, triac_pct, n_iterations, status_val, ns, same_plan
        phase, *fields = line.split(",")
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
        bare_plan=np.array([int(r[6]) if r[6] else -1 for r in bare], dtype=int),
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
    has_plan = harness.bare_plan >= 0
    return CodegenRun(
        n_steps=n, python=Timing.of(loop.step_s), c_step=Timing.of(harness.step_s),
        c_ctypes=Timing.of(ctypes_s), bare=Timing.of(harness.bare_s),
        mean_iterations=float(np.mean(harness.iterations)),
        max_iterations=int(np.max(harness.iterations)),
        bare_same_iterations=float(np.mean(same_bare)) if same_bare.size else 1.0,
        bare_same_plan=float(np.mean(harness.bare_plan[has_plan] == 1)) if has_plan.any() else 1.0,
        n_iteration_differences=int(differ.size), first_difference_k=first,
        worst_triac_pct=float(np.max(dev[:upto])) if upto else 0.0,
        worst_triac_all_pct=float(np.max(dev)),
        n_bit_equal=int(np.sum(harness.triac_pct == loop.triac_pct)),
        qp_max_rel_diff=_rel_diff(harness.sent[solved], loop.sent[solved]),
        ctypes_equal=int(np.sum(ctypes_triac == harness.triac_pct)),
        cap=harness.cap)


# --- sizes, revision -----------------------------------------------------------------------


def _is_daqp_step(directory: Path) -> bool:
    """The step in ``directory`` solves with DAQP (``CZMPC_SOLVER_DAQP`` of its czmpc_model.h)."""
    header = (directory / "czmpc_model.h").read_text(encoding="utf-8")
    return re.search(r"^#define CZMPC_SOLVER_DAQP 1\b", header, flags=re.MULTILINE) is not None


def object_sizes(directory: Path) -> tuple[ObjectSize, ...]:
    """``size -A`` of the step, the solver's data and the solver's objects in ``directory``
    (OSQP's generated workspace and objects; for a step generated with DAQP, which its
    ``czmpc_model.h`` says as the harness reads it, DAQP's arena and objects).

    Raises
    ------
    BuildError
        ``size`` (binutils) is missing or fails.
    """
    step = "the step (code, the model's constant matrices"
    if _is_daqp_step(directory):
        step += "; DAQP's H and rows, and their working copies in .bss)"
        data = ("DAQP's static arena (its workspace, filled by `setup_daqp` at init)",
                ("czmpc_daqp_heap.o",))
        name, prefix = "DAQP", "daqp_"
    else:
        step += ")"
        data = ("OSQP's generated workspace (problem, scaling, KKT factor, iterates)",
                ("czmpc_qp_workspace.o",))
        name, prefix = "OSQP", "osqp_"
    solver = tuple(sorted(p.name for p in directory.glob(f"{prefix}*.o")))
    groups = ((step, ("czmpc_step.o",)), data, (f"{name}'s solver ({len(solver)} objects)", solver))
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


def controller_settings(model: HammersteinModel, solver: QPSolverName) -> MPCSettings:
    """The benchmark's settings: `MPCSettings.default_for` ``model`` with ``solver``."""
    return MPCSettings.default_for(model).with_updates(solver=solver)


def measure(model: HammersteinModel, directory: Path, *, repeats: int, n_steps: int | None,
            context: bool, float32: bool, rounds: int = 1, progress: Progress | None = None,
            solver: QPSolverName = "osqp") -> tuple[CodegenRun, ...]:
    """Replay ``repeats`` closed loops through every path (module notes).

    Parameters
    ----------
    model :
        The controller's model (and the plant's).
    directory :
        A built step of ``OffsetFreeMPC(model, controller_settings(model, solver))`` with
        the harness (`build_harness`).
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
    solver :
        The controller's QP solver (`MPCSettings.solver`).
    """
    scenario = load_scenario("staircase")
    settings = controller_settings(model, solver)
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


def fuzz_worst_iterations(n_cases: int, progress: Progress | None = None,
                          solver: QPSolverName = "osqp") -> FuzzWorst:
    """The worst Python iteration count of ``tests/codegen/fuzz.py``'s set (seed 1), its
    controllers with ``solver``.

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
                               n_steps=FUZZ_STEPS_PER_CASE, seed=FUZZ_SEED, solver=solver)
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
                  rounds: int = 3, fuzz_cases: int = 0, progress: Progress | None = None,
                  solver: QPSolverName = "osqp") -> CodegenBenchmark:
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
    solver :
        The controller's QP solver (`MPCSettings.solver`; "daqp": double only).

    Raises
    ------
    BuildError
        No C toolchain, or a build failed.
    CodegenError
        ``float32`` with ``solver = "daqp"``, or DAQP's sources unavailable.
    """
    machine = machine_info()
    settings = controller_settings(model, solver)
    step = generate_step(model, settings, directory, float32=float32,
                         settings_source=f"MPCSettings.default_for(model), solver = {solver!r}")
    compile_command = build_harness(directory)
    sizes = object_sizes(directory)
    runs = measure(model, directory, repeats=repeats, n_steps=n_steps, context=False,
                   float32=float32, rounds=rounds, progress=progress, solver=solver)
    context_runs = measure(model, directory, repeats=repeats, n_steps=n_steps, context=True,
                           float32=float32, rounds=rounds, progress=progress, solver=solver)
    cc = _first_line([compile_command.split()[0] if compile_command else "cc", "--version"])
    sizeof_state = ctypes.CDLL(str(directory / SHARED_LIBRARY)).czmpc_sizeof_state
    sizeof_state.restype = ctypes.c_ulong
    state_bytes = int(sizeof_state())
    fuzz = fuzz_worst_iterations(fuzz_cases, progress, solver) if fuzz_cases > 0 else None
    is_daqp = solver == "daqp"
    return CodegenBenchmark(
        machine=machine, model_label=model_label, command=command, revision=revision(),
        compiler=cc, compile_command=compile_command, float32=float32,
        horizon_steps=step.horizon_steps, n_variables=step.n_variables,
        n_constraints=step.n_constraints,
        max_iter=DAQP_ITER_LIMIT if is_daqp else settings.osqp.max_iter, rounds=rounds,
        runs=runs, context_runs=context_runs, sizes=sizes, state_bytes=state_bytes, fuzz=fuzz,
        solver=solver, solver_version=daqp_version() if is_daqp else "")


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


def _ms(value: float) -> str:
    """A time [ms]: two decimals, three significant digits below 1 ms (DAQP's solves)."""
    return f"{value:.2f}" if value >= 1.0 else f"{value:.3g}"


def format_report(bench: CodegenBenchmark) -> str:
    """The numbers as Markdown (stdout and BENCHMARKS.md share it)."""
    real = "float" if bench.float32 else "double"
    n = bench.runs[0].n_steps if bench.runs else 0
    words = _WORDS[bench.solver]
    qp = words.qp.format(n_variables=bench.n_variables, n_constraints=bench.n_constraints,
                         max_iter=bench.max_iter, version=bench.solver_version)
    settings = "" if bench.solver == "osqp" else f" with `solver = \"{bench.solver}\"`"
    lines = [
        f"Command: `{bench.command}`",
        "",
        f"Machine: {bench.machine.describe()}",
        "",
        f"Code: {bench.revision}. C: {bench.compiler}; `{bench.compile_command}` (the generated "
        f"Makefile's flags), {real}.",
        "",
        f"Model: {bench.model_label}, default settings (`MPCSettings.default_for`){settings}: "
        f"N = {bench.horizon_steps}, {qp}.",
        "",
        f"The same steps through every path: the shipped staircase ({n} samples) against the "
        "model plant (noise on, seed = run - 1) stepped by the Python controller "
        "(`OffsetFreeMPC.step`, perf_counter per call); its inputs then replayed through the C "
        "step in a C harness (`benchmarks/codegen_timing.c`: `czmpc_step` against the "
        "directory's `libczmpc.a`, `clock_gettime(CLOCK_MONOTONIC)` per call, no Python in "
        f"the loop) and through ctypes (`CController.step`, for reference); and {words.bare}, "
        "fed the very `q`, `l`, `u` the C step sent, in the same order, cold-started where it "
        f"was. The harness alternates {bench.rounds} passes of the C "
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
    words = _WORDS[bench.solver]
    lines = [
        "",
        f"### The step in Python, in C and the bare solver{what}, N = {bench.horizon_steps}",
        "",
        "| run | Python step: median / p99.9 [us] | C step: median / p99.9 [us] | C step via "
        f"ctypes: median / p99.9 [us] | bare {words.name} solve: median / p99.9 [us] | C step "
        "/ bare | Python / C step |",
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
        f"Did the timed C run compute what Python did? Per run: {words.name} iterations of the "
        "C step; the bare replay's iterations equal to the step's, and its solutions bit-equal "
        "to the plans the step used; steps whose iteration count differs between C and Python "
        f"({words.flipped}); the largest TRIAC difference before the first of them{tol} and "
        "over all steps; the largest relative difference of the `q`, `l`, `u` the two sent "
        "before it; the ctypes step's outputs bit-equal to the harness's.",
        "",
        f"| run | {words.name} iterations mean / max | bare replay: same iterations | bare "
        "replay: same plan | other iteration count than Python: steps (first at k) | max abs "
        "dTRIAC before it [%] | max abs dTRIAC, all steps [%] | TRIAC bit-equal | max rel. "
        "diff of q, l, u | ctypes = harness |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, r in enumerate(runs, start=1):
        first = "" if r.first_difference_k is None else f" (k = {r.first_difference_k})"
        lines.append(
            f"| {i} | {r.mean_iterations:.2f} / {r.max_iterations} | "
            f"{r.bare_same_iterations:.1%} | {r.bare_same_plan:.1%} | "
            f"{r.n_iteration_differences}{first} | "
            f"{r.worst_triac_pct:.2e} | {r.worst_triac_all_pct:.2e} | "
            f"{r.n_bit_equal} of {r.n_steps} | {r.qp_max_rel_diff:.1e} | "
            f"{r.ctypes_equal} of {r.n_steps} |")
    return lines


def _summary(bench: CodegenBenchmark) -> list[str]:
    """Ratios, the goal, the worst case and the fuzz set."""
    runs = bench.all_runs
    if not runs:
        return []
    words = _WORDS[bench.solver]
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
        f"- Goal (issue 42): the C step with {words.name} within {bench.goal:g} of "
        f"{words.bare_name}, on the same QPs: {_met(bench.goal_met)}. {words.other_goal}",
    ]
    worst = max(r.max_iterations for r in runs)
    caps = [r.cap for r in runs if r.cap is not None]
    line = (f"- Worst case: at most {worst} {words.name} iterations per step on these runs (cap "
            f"{bench.max_iter}).")
    if caps:
        hardest = max(caps, key=lambda c: c.median_ms)
        line += (f" The hardest QP of each run {words.cap}: {hardest.n_iterations} iterations "
                 f"({words.status} {hardest.status_val - words.status_offset}) in "
                 f"{_ms(_median([c.median_ms for c in caps]))} ms (median over the runs; slowest "
                 f"run {_ms(hardest.median_ms)} ms, single worst "
                 f"{_ms(max(c.max_ms for c in caps))} ms): {words.cap_meaning}.")
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
                     f"{f.n_steps:,} steps; {words.fuzz_cap}): **{f.max_iterations}**.")
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
        f"the model's matrices; {_WORDS[bench.solver].sizes}). The caller also holds one "
        f"`czmpc_state`: {bench.state_bytes} bytes.",
        "",
        "| part | objects | .text | .rodata | .data | .bss | total |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for s in bench.sizes:
        files = (", ".join(f"`{f}`" for f in s.files) if len(s.files) <= 2
                 else f"`{s.files[0].split('_')[0]}_*.o`")
        lines.append(f"| {s.part} | {files} | {s.text} | {s.rodata} | {s.data} | {s.bss} | "
                     f"{s.text + s.rodata + s.data + s.bss} |")
    t = {k: sum(getattr(s, k) for s in bench.sizes) for k in ("text", "rodata", "data", "bss")}
    lines.append(f"| all | | {t['text']} | {t['rodata']} | {t['data']} | {t['bss']} | "
                 f"{sum(t.values())} |")
    return lines


def section_heading(*, float32: bool = False, solver: QPSolverName = "osqp") -> str:
    """This benchmark's heading in BENCHMARKS.md for a run with ``float32`` and ``solver``."""
    if solver == "daqp":
        return SECTION_HEADING_DAQP
    return SECTION_HEADING_FLOAT32 if float32 else SECTION_HEADING


def write_benchmarks_section(path: str | Path, body: str, *, float32: bool = False,
                             solver: QPSolverName = "osqp") -> None:
    """Put ``body`` under this benchmark's heading (`section_heading`) in a BENCHMARKS.md."""
    _write_section(path, body, heading=section_heading(float32=float32, solver=solver))


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
        "--solver", choices=get_args(QPSolverName), default="osqp",
        help="the controller's QP solver (MPCSettings.solver) in Python and in C; daqp: the "
             "bare solver is DAQP's, the goal 2x, its own section of BENCHMARKS.md, double "
             "only (default: osqp)")
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
                              fuzz_cases=args.fuzz_cases, progress=progress,
                              solver=args.solver)
    text = format_report(bench)
    print(text, end="")
    if not bench.agrees:
        print("error: the timed C run did not compute what the Python controller did, or the "
              "bare replay did not solve the step's QPs as the step did (see the agreement "
              "table); nothing recorded", file=sys.stderr)
        return 1
    if not args.no_record:
        write_benchmarks_section(args.benchmarks_md, text, float32=args.float32,
                                 solver=args.solver)
        progress(f"wrote the numbers to {args.benchmarks_md}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print it, record it in BENCHMARKS.md; return the exit code."""
    return run_main(build_parser(), _run, argv)


__all__ = [
    "C_OVER_BARE_GOAL",
    "C_OVER_BARE_GOAL_DAQP",
    "SECTION_HEADING",
    "SECTION_HEADING_DAQP",
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
    "controller_settings",
    "format_report",
    "fuzz_worst_iterations",
    "main",
    "measure",
    "object_sizes",
    "revision",
    "run_benchmark",
    "run_harness",
    "section_heading",
    "write_benchmarks_section",
    "write_inputs",
]


if __name__ == "__main__":
    sys.exit(main())
