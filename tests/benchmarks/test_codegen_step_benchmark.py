"""The generated-C cost benchmark (`python -m benchmarks.codegen_step`, issue 42 item 5).

Run tiny (a few steps, one repeat, two harness rounds) into a temporary BENCHMARKS.md,
once per solver (OSQP, and DAQP with ``--solver daqp``): the section's tables have their
structure, every time is positive and finite, the timed C run computed what the Python
controller did (the harness prints each step's TRIAC input) and the bare solver's
replay solved the step's QPs as the step did (its iteration counts and its plans, bit
for bit). Speed is never asserted.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import benchmarks.codegen_step as cg
from benchmarks._md import machine_info
from czmpc.codegen.build import find_tools
from czmpc.codegen.daqp_source import daqp_sources
from czmpc.codegen.errors import BuildError, CodegenError
from czmpc.qp_daqp import DAQP_ITER_LIMIT

#: Steps per closed loop of the tiny run (the staircase's first setpoint change is at
#: 600 s = step 300, so the loops hold 45 kW against plant noise: the QP is solved and
#: warm-started every step).
TINY_STEPS = 40
OTHER_SECTIONS = "# Benchmarks\n\n## Identification pipeline\n\nkeep me\n\n## Other\n\nkeep me too\n"


@dataclass(frozen=True, kw_only=True)
class Expected:
    """What a tiny run of one solver must report besides the numbers."""

    name: str            # the solver in the tables' headers
    max_iter: int        # its iteration cap
    data_object: str     # the object of its data (second row of the sizes table)
    data_section: int    # the section that data lies in: 2 .data (OSQP), 3 .bss (DAQP's arena)
    objects: str         # its objects (third row)
    cap: str             # the worst-case solve's line (a regular expression)
    goal: str            # the goal's line


EXPECTED = {
    "osqp": Expected(
        name="OSQP", max_iter=4000, data_object="`czmpc_qp_workspace.o`", data_section=2,
        objects="`osqp_*.o`", cap=r"only the cap stops OSQP: 4000 iterations \(status_val 7\)",
        goal="(the C step with DAQP within 2 of DAQP's bare solve): `--solver daqp`, in its "
             "own section."),
    "daqp": Expected(
        name="DAQP", max_iter=DAQP_ITER_LIMIT, data_object="`czmpc_daqp_heap.o`", data_section=3,
        objects="`daqp_*.o`", cap=r"not at its cap\): [1-9]\d* iterations \(exit flag 1\)",
        goal="the C step with DAQP within 2 of DAQP's bare solve, on the same QPs: **"),
}


def _toolchain(solver: str = "osqp") -> None:
    try:
        find_tools()
    except BuildError as exc:   # pragma: no cover - CI has cc and make
        pytest.skip(str(exc))
    if solver == "daqp":
        try:
            daqp_sources()
        except CodegenError as exc:   # pragma: no cover - CI reaches PyPI
            pytest.skip(f"needs the network (daqp's sdist from PyPI) or CZMPC_DAQP_SDIST: {exc}")


def _tables(section: str) -> dict[str, list[list[str]]]:
    """Each Markdown table of ``section`` (header row first, separator dropped), keyed by
    its first header cell plus the ``###`` heading above it."""
    tables: dict[str, list[list[str]]] = {}
    heading = ""
    current: list[list[str]] | None = None
    for line in section.splitlines():
        if line.startswith("### "):
            heading = line[4:]
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if set("".join(cells)) <= set("-:"):
                continue
            if current is None:
                current = []
                tables[f"{heading} / {cells[0]} {cells[1]}"] = current
            current.append(cells)
        else:
            current = None
    return tables


def _numbers(cell: str) -> list[float]:
    return [float(v) for v in re.findall(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", cell)]


@dataclass(frozen=True, kw_only=True)
class TinyRun:
    """One tiny run of the benchmark."""

    solver: str
    code: int               # its exit code
    text: str               # the BENCHMARKS.md it wrote
    directory: Path         # the generated step

    @property
    def section(self) -> str:
        """The run's own section of ``text``."""
        return self.text.split(cg.section_heading(solver=self.solver), 1)[1]

    @property
    def expected(self) -> Expected:
        return EXPECTED[self.solver]


@pytest.fixture(scope="module", params=["osqp", "daqp"])
def tiny_run(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> TinyRun:
    """One tiny run with the solver of the parameter."""
    solver = request.param
    _toolchain(solver)
    tmp = tmp_path_factory.mktemp(f"codegen_bench_{solver}")
    md = tmp / "BENCHMARKS.md"
    md.write_text(OTHER_SECTIONS, encoding="utf-8")
    code = cg.main(["--repeats", "1", "--steps", str(TINY_STEPS), "--rounds", "2",
                    "--solver", solver, "--out", str(tmp / "step"), "--benchmarks-md", str(md)])
    return TinyRun(solver=solver, code=code, text=md.read_text(encoding="utf-8"),
                   directory=tmp / "step")


def test_the_tiny_run_records_its_own_section_and_keeps_the_others(tiny_run: TinyRun) -> None:
    assert tiny_run.code == 0
    text = tiny_run.text
    headings = {cg.SECTION_HEADING, cg.SECTION_HEADING_FLOAT32, cg.SECTION_HEADING_DAQP}
    own = cg.section_heading(solver=tiny_run.solver)
    assert [text.count(f"{h}\n") for h in sorted(headings)] == [int(h == own) for h in sorted(headings)]
    assert "## Identification pipeline\n\nkeep me\n" in text and "## Other\n\nkeep me too\n" in text
    section = tiny_run.section
    assert (f"python -m benchmarks.codegen_step --repeats 1 --steps 40 --rounds 2 --solver "
            f"{tiny_run.solver}") in section
    assert "-ffp-contract=off" in section and "N = 39" in section


def test_the_timing_tables_have_one_row_per_run_of_positive_finite_times(tiny_run: TinyRun) -> None:
    tables = _tables(tiny_run.section)
    timing = [t for key, t in tables.items() if "Python step" in " ".join(t[0])]
    assert len(timing) == 2   # without, then with preview and voltage
    for table in timing:
        header, *rows = table
        assert len(header) == 7 and len(rows) == 1 and rows[0][0] == "1"
        assert header[4] == f"bare {tiny_run.expected.name} solve: median / p99.9 [us]"
        times = [_numbers(cell) for cell in rows[0][1:5]]   # median / p99.9 of four paths
        for median, p999 in times:
            assert math.isfinite(median) and math.isfinite(p999)
            assert 0.0 < median <= p999
        ratio, python_over_c = float(rows[0][5]), float(rows[0][6])
        assert ratio == pytest.approx(times[1][0] / times[3][0], rel=0.01)
        assert python_over_c == pytest.approx(times[0][0] / times[1][0], rel=0.02)


def test_the_timed_c_run_computed_what_python_did_and_the_bare_replay_what_c_did(
        tiny_run: TinyRun) -> None:
    expected = tiny_run.expected
    agreement = [t for t in _tables(tiny_run.section).values()
                 if "bare replay: same iterations" in t[0]]
    assert len(agreement) == 2
    for header, row in agreement:
        cell = dict(zip(header, row, strict=True))
        mean_it, max_it = _numbers(cell[f"{expected.name} iterations mean / max"])
        assert 1.0 <= mean_it <= max_it < expected.max_iter
        # The bare solver's replay took the step's iterations and found its plans, bit for bit.
        assert cell["bare replay: same iterations"] == "100.0%"
        assert cell["bare replay: same plan"] == "100.0%"
        # Within issue 42's tolerance; a flipped OSQP termination test would be counted.
        differences = int(_numbers(cell["other iteration count than Python: steps (first at k)"])[0])
        assert differences == 0
        assert float(cell["max abs dTRIAC before it [%]"]) <= cg.TRIAC_ATOL_PCT
        assert float(cell["max abs dTRIAC, all steps [%]"]) <= cg.TRIAC_ATOL_PCT
        # The QP vectors differ from Python's by BLAS summation order at most.
        assert float(cell["max rel. diff of q, l, u"]) <= 1e-12
        assert cell["ctypes = harness"] == f"{TINY_STEPS} of {TINY_STEPS}"


def test_the_summary_and_the_sizes_are_measured(tiny_run: TinyRun) -> None:
    expected, section = tiny_run.expected, tiny_run.section
    assert re.search(expected.cap, section) is not None
    assert expected.goal in section
    assert "fuzz set (`tests/codegen/fuzz.py`): not measured here" in section
    state = re.search(r"one `czmpc_state`: (\d+) bytes", section)
    assert state is not None and int(state.group(1)) > 1000
    (header, *rows), = [t for t in _tables(section).values() if t[0][0] == "part"]
    assert header == ["part", "objects", ".text", ".rodata", ".data", ".bss", "total"]
    assert [r[1] for r in rows[:3]] == ["`czmpc_step.o`", expected.data_object, expected.objects]
    sizes = np.array([[int(v) for v in r[2:]] for r in rows])
    assert sizes[0, 0] > 0 and sizes[0, 1] > 0        # the step: code and its matrices
    assert sizes[1, expected.data_section] > 0         # the solver's data
    assert sizes[2, 0] > 0                             # the solver's code
    assert (sizes[:3, :4].sum(axis=1) == sizes[:3, 4]).all()
    assert (sizes[:3].sum(axis=0) == sizes[3]).all()
    # The same numbers as binutils gives for the step's object, section by section.
    (step,) = cg.object_sizes(tiny_run.directory)[:1]
    assert [step.text, step.rodata, step.data, step.bss] == list(sizes[0, :4])


def test_the_harness_refuses_an_input_file_of_another_format(
        tiny_run: TinyRun, tmp_path: Path) -> None:
    bad = tmp_path / "inputs.txt"
    bad.write_text("power,setpoint\n45.0,46.0\n", encoding="ascii")
    with pytest.raises(BuildError, match="exited 2.*expected 'czmpc-timing-inputs/1'"):
        cg.run_harness(tiny_run.directory, bad, n_variables=39, n_constraints=77, float32=False)


def test_float32_goes_to_its_own_section_with_the_deviation_stated(tmp_path: Path) -> None:
    _toolchain()
    md = tmp_path / "BENCHMARKS.md"
    assert cg.main(["--repeats", "1", "--steps", "20", "--rounds", "1", "--float32",
                    "--benchmarks-md", str(md)]) == 0
    text = md.read_text(encoding="utf-8")
    assert cg.SECTION_HEADING_FLOAT32 in text and f"{cg.SECTION_HEADING}\n" not in text
    assert "`cc" in text and "-DCZMPC_FLOAT32" in text and ", float." in text
    dev = re.search(r"float32: the C step's TRIAC input is at most (\S+) % from", text)
    assert dev is not None and 0.0 <= float(dev.group(1)) < 0.1


def test_daqp_in_float32_is_refused_before_anything_is_recorded(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    md = tmp_path / "BENCHMARKS.md"
    md.write_text(OTHER_SECTIONS, encoding="utf-8")
    assert cg.main(["--float32", "--solver", "daqp", "--out", str(tmp_path / "step"),
                    "--benchmarks-md", str(md)]) == 2
    assert "daqp' is generated in double precision only" in capsys.readouterr().err
    assert md.read_text(encoding="utf-8") == OTHER_SECTIONS


# --- the pieces, without a compiler --------------------------------------------------------


def _timing(median_us: float) -> cg.Timing:
    return cg.Timing(n=10, median_us=median_us, p999_us=2 * median_us, max_us=3 * median_us)


def _run(*, c_us: float = 22.0, bare_us: float = 20.0, worst: float = 0.0) -> cg.CodegenRun:
    return cg.CodegenRun(
        n_steps=10, python=_timing(60.0), c_step=_timing(c_us), c_ctypes=_timing(30.0),
        bare=_timing(bare_us), mean_iterations=6.0, max_iterations=15, bare_same_iterations=1.0,
        bare_same_plan=1.0, n_iteration_differences=0, first_difference_k=None, worst_triac_pct=worst,
        worst_triac_all_pct=worst, n_bit_equal=10, qp_max_rel_diff=0.0, ctypes_equal=10,
        cap=cg.CapSolve(k=0, n_iterations=4000, status_val=7, median_ms=20.0, max_ms=25.0))


def _bench(runs: tuple[cg.CodegenRun, ...], solver: str = "osqp") -> cg.CodegenBenchmark:
    size = cg.ObjectSize(part="p", files=("a.o",), text=1, rodata=2, data=3, bss=4)
    return cg.CodegenBenchmark(
        machine=replace(machine_info(), n_cpus=2, load_average=0.1), model_label="m",
        command="python -m benchmarks.codegen_step", revision="abc", compiler="cc",
        compile_command="cc -O2", float32=False, horizon_steps=39, n_variables=39,
        n_constraints=77, max_iter=4000, rounds=3, runs=runs, context_runs=runs,
        sizes=(size, size, size), state_bytes=5000, solver=solver,  # type: ignore[arg-type]
        solver_version="0.11.0" if solver == "daqp" else "")


def test_the_goal_is_judged_on_the_median_ratio_of_each_half() -> None:
    met = cg.format_report(_bench((_run(c_us=22.0), _run(c_us=23.0), _run(c_us=30.0))))
    assert "within 1.15 of OSQP's bare generated solver, on the same QPs: **met**" in met
    assert "**1.150 x**" in met
    missed = _bench((_run(c_us=24.0),))
    assert not missed.goal_met
    assert "**missed**" in cg.format_report(missed)


def test_the_daqp_goal_is_2x_its_bare_solve() -> None:
    met = _bench((_run(c_us=7.0, bare_us=5.0), _run(c_us=9.9, bare_us=5.0)), "daqp")
    assert met.goal == cg.C_OVER_BARE_GOAL_DAQP == 2.0 and met.goal_met
    text = cg.format_report(met)
    assert "within 2 of DAQP's bare solve, on the same QPs: **met**" in text
    assert "DAQP 0.11.0 with 39 variables and 77 rows" in text and "eps 1e-5" not in text
    missed = _bench((_run(c_us=10.1, bare_us=5.0),), "daqp")
    assert not missed.goal_met and "**missed**" in cg.format_report(missed)
    # A cold DAQP solve takes microseconds: its time keeps three significant digits.
    cold = cg.CapSolve(k=3, n_iterations=4, status_val=101, median_ms=0.01234, max_ms=0.0456)
    text = cg.format_report(_bench((replace(_run(), cap=cold),), "daqp"))
    assert ("not at its cap): 4 iterations (exit flag 1) in 0.0123 ms (median over the runs; "
            "slowest run 0.0123 ms, single worst 0.0456 ms)") in text
    assert cg.section_heading(solver="daqp") == cg.SECTION_HEADING_DAQP


def test_agreement_counts_only_the_steps_before_the_first_iteration_difference() -> None:
    n = 6
    loop = cg._PythonLoop(
        power_kw=np.full(n, 45.0), setpoint_kw=np.full(n, 45.0), voltage=np.full(n, np.nan),
        previews=tuple(np.empty(0) for _ in range(n)),
        triac_pct=np.array([45.0, 45.1, 45.2, 45.3, 45.4, 45.5]),
        iterations=np.array([5, 5, 5, 10, 5, 5]), sent=np.zeros((n, 3)), step_s=np.full(n, 1e-4))
    harness = cg._HarnessRun(
        triac_pct=loop.triac_pct + np.array([0.0, 1e-13, 0.0, 2e-3, 1e-4, 0.0]),
        iterations=np.array([5, 5, 5, 15, 5, 5]), status_val=np.ones(n, dtype=int),
        step_s=np.full(2 * n, 2e-5), bare_k=np.arange(n), bare_iterations=np.array([5, 5, 5, 15, 5, 5]),
        bare_plan=np.array([1, 1, 1, 1, -1, 1]), bare_s=np.full(n, 1e-5), cap=None,
        sent=np.zeros((n, 3)))
    run = cg.compare_run(loop, harness, harness.triac_pct.copy(), np.full(n, 3e-5))
    assert run.first_difference_k == 3 and run.n_iteration_differences == 1
    assert run.worst_triac_pct == pytest.approx(1e-13) and run.worst_triac_all_pct == pytest.approx(2e-3)
    assert run.n_bit_equal == 3 and run.ctypes_equal == n
    assert run.bare_same_iterations == 1.0 and run.bare_same_plan == 1.0   # k = 4 had no plan
    assert run.c_step.n == 2 * n and run.c_over_bare == pytest.approx(2.0)
    assert run.agrees(float32=False)
    early = replace(harness, triac_pct=loop.triac_pct + 1e-5)   # 1e-5 % before k = 3
    assert not cg.compare_run(loop, early, early.triac_pct.copy(), np.full(n, 3e-5)).agrees(False)
    # A bare replay that solved a QP otherwise than the step: its ratio is not recorded.
    other_iterations = replace(harness, bare_iterations=np.array([5, 5, 5, 15, 5, 6]))
    run = cg.compare_run(loop, other_iterations, harness.triac_pct.copy(), np.full(n, 3e-5))
    assert run.bare_same_iterations == pytest.approx(5 / 6) and not run.agrees(False)
    other_plan = replace(harness, bare_plan=np.array([1, 1, 0, 1, -1, 1]))
    run = cg.compare_run(loop, other_plan, harness.triac_pct.copy(), np.full(n, 3e-5))
    assert run.bare_same_plan == pytest.approx(4 / 5) and not run.agrees(False)


def test_a_run_that_computed_otherwise_is_not_recorded(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    md = tmp_path / "BENCHMARKS.md"
    md.write_text(OTHER_SECTIONS, encoding="utf-8")
    bad = _bench((_run(worst=1e-3),))
    monkeypatch.setattr(cg, "run_benchmark", lambda *a, **k: bad)
    assert cg.main(["--benchmarks-md", str(md), "--out", str(tmp_path / "step")]) == 1
    assert md.read_text(encoding="utf-8") == OTHER_SECTIONS
    assert "did not compute what the Python controller did" in capsys.readouterr().err


def test_help_says_what_is_measured(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cg.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "What does one step of the controller cost once it is C" in out
    assert "--float32" in out and "--repeats N" in out and "99.9th percentile" in out
    assert "--solver {osqp,daqp}" in out and "DAQP within 2x DAQP's bare solve" in out


def test_a_fuzz_set_that_stops_is_reported_not_raised(monkeypatch: pytest.MonkeyPatch) -> None:
    def stops(*args: object, **kwargs: object) -> None:
        raise AssertionError("mode 'on' refused")

    fake = {"tests.codegen.fuzz": SimpleNamespace(fuzz=stops),
            "tests.codegen.replay": SimpleNamespace(StepBuilder=lambda root: root)}
    monkeypatch.setattr(cg.importlib, "import_module", fake.__getitem__)
    worst = cg.fuzz_worst_iterations(400)
    assert worst.max_iterations is None and worst.n_cases == 400 and worst.n_steps == 0
    assert worst.error is not None and worst.error.startswith("AssertionError at ")
    assert worst.error.endswith(": mode 'on' refused")
    text = cg.format_report(replace(_bench((_run(),)), fuzz=worst))
    assert "400 cases asked): not measured, the fuzz set stopped (AssertionError at" in text
    done = cg.FuzzWorst(n_cases=400, n_steps=1_000_000, seed=1, max_iterations=1915)
    assert "1,000,000 steps; each case's cap is 25, 200 or 4000): **1915**" in cg.format_report(
        replace(_bench((_run(),)), fuzz=done))
