"""The generated-C cost benchmark (`python -m benchmarks.codegen_step`, issue 42 item 5).

Run tiny (a few steps, one repeat, one harness round) into a temporary BENCHMARKS.md:
the section's tables have their structure, every time is positive and finite, and the
timed C run computed what the Python controller did (the harness prints each step's
TRIAC input). Speed is never asserted.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import benchmarks.codegen_step as cg
from benchmarks._md import machine_info
from czmpc.codegen.build import find_tools
from czmpc.codegen.errors import BuildError

#: Steps per closed loop of the tiny run (the staircase's first setpoint change is at
#: 600 s = step 300, so the loops hold 45 kW against plant noise: the QP is solved and
#: warm-started every step).
TINY_STEPS = 40
OTHER_SECTIONS = "# Benchmarks\n\n## Identification pipeline\n\nkeep me\n\n## Other\n\nkeep me too\n"


def _toolchain() -> None:
    try:
        find_tools()
    except BuildError as exc:   # pragma: no cover - CI has cc and make
        pytest.skip(str(exc))


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


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, str, Path]:
    """``(exit code, BENCHMARKS.md text, generated directory)`` of one tiny run."""
    _toolchain()
    tmp = tmp_path_factory.mktemp("codegen_bench")
    md = tmp / "BENCHMARKS.md"
    md.write_text(OTHER_SECTIONS, encoding="utf-8")
    code = cg.main(["--repeats", "1", "--steps", str(TINY_STEPS), "--rounds", "2",
                    "--out", str(tmp / "step"), "--benchmarks-md", str(md)])
    return code, md.read_text(encoding="utf-8"), tmp / "step"


def test_the_tiny_run_records_its_own_section_and_keeps_the_others(
        tiny_run: tuple[int, str, Path]) -> None:
    code, text, _ = tiny_run
    assert code == 0
    assert text.count(cg.SECTION_HEADING) == 1
    assert "## Identification pipeline\n\nkeep me\n" in text and "## Other\n\nkeep me too\n" in text
    section = text.split(cg.SECTION_HEADING, 1)[1]
    assert "python -m benchmarks.codegen_step --repeats 1 --steps 40" in section
    assert "-ffp-contract=off" in section and "N = 39" in section


def test_the_timing_tables_have_one_row_per_run_of_positive_finite_times(
        tiny_run: tuple[int, str, Path]) -> None:
    _, text, _ = tiny_run
    tables = _tables(text.split(cg.SECTION_HEADING, 1)[1])
    timing = [t for key, t in tables.items() if "Python step" in " ".join(t[0])]
    assert len(timing) == 2   # without, then with preview and voltage
    for table in timing:
        header, *rows = table
        assert len(header) == 7 and len(rows) == 1 and rows[0][0] == "1"
        times = [_numbers(cell) for cell in rows[0][1:5]]   # median / p99.9 of four paths
        for median, p999 in times:
            assert math.isfinite(median) and math.isfinite(p999)
            assert 0.0 < median <= p999
        ratio, python_over_c = float(rows[0][5]), float(rows[0][6])
        assert ratio == pytest.approx(times[1][0] / times[3][0], rel=0.01)
        assert python_over_c == pytest.approx(times[0][0] / times[1][0], rel=0.02)


def test_the_timed_c_run_computed_what_python_did(tiny_run: tuple[int, str, Path]) -> None:
    _, text, _ = tiny_run
    tables = _tables(text.split(cg.SECTION_HEADING, 1)[1])
    agreement = [t for t in tables.values() if "bare replay: same iterations" in t[0]]
    assert len(agreement) == 2
    for header, row in agreement:
        cell = dict(zip(header, row, strict=True))
        mean_it, max_it = _numbers(cell["OSQP iterations mean / max"])
        assert 1.0 <= mean_it <= max_it < 4000
        assert cell["bare replay: same iterations"] == "100.0%"
        # Within issue 42's tolerance; a flipped OSQP termination test would be counted.
        differences = int(_numbers(cell["other iteration count than Python: steps (first at k)"])[0])
        assert differences == 0
        assert float(cell["max abs dTRIAC before it [%]"]) <= cg.TRIAC_ATOL_PCT
        assert float(cell["max abs dTRIAC, all steps [%]"]) <= cg.TRIAC_ATOL_PCT
        # The QP vectors differ from Python's by BLAS summation order at most.
        assert float(cell["max rel. diff of q, l, u"]) <= 1e-12
        assert cell["ctypes = harness"] == f"{TINY_STEPS} of {TINY_STEPS}"


def test_the_summary_and_the_sizes_are_measured(tiny_run: tuple[int, str, Path]) -> None:
    _, text, directory = tiny_run
    section = text.split(cg.SECTION_HEADING, 1)[1]
    assert "only the cap stops OSQP: 4000 iterations (status_val 7)" in section
    assert "fuzz set (`tests/codegen/fuzz.py`): not measured here" in section
    assert "DAQP" in section and "is not measured" in section
    state = re.search(r"one `czmpc_state`: (\d+) bytes", section)
    assert state is not None and int(state.group(1)) > 1000
    (header, *rows), = [t for t in _tables(section).values() if t[0][0] == "part"]
    assert header == ["part", "objects", ".text", ".rodata", ".data", ".bss", "total"]
    assert [r[1] for r in rows[:2]] == ["`czmpc_step.o`", "`czmpc_qp_workspace.o`"]
    sizes = np.array([[int(v) for v in r[2:]] for r in rows])
    assert sizes[0, 0] > 0 and sizes[0, 1] > 0        # the step: code and its matrices
    assert sizes[1, 2] > 0                             # OSQP's workspace: initialised data
    assert sizes[2, 0] > 0                             # OSQP's code
    assert (sizes[:3, :4].sum(axis=1) == sizes[:3, 4]).all()
    assert (sizes[:3].sum(axis=0) == sizes[3]).all()
    # The same numbers as binutils gives for the step's object, section by section.
    (step,) = cg.object_sizes(directory)[:1]
    assert [step.text, step.rodata, step.data, step.bss] == list(sizes[0, :4])


def test_the_harness_refuses_an_input_file_of_another_format(
        tiny_run: tuple[int, str, Path], tmp_path: Path) -> None:
    _, _, directory = tiny_run
    bad = tmp_path / "inputs.txt"
    bad.write_text("power,setpoint\n45.0,46.0\n", encoding="ascii")
    with pytest.raises(BuildError, match="exited 2.*expected 'czmpc-timing-inputs/1'"):
        cg.run_harness(directory, bad, n_variables=39, n_constraints=77, float32=False)


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


# --- the pieces, without a compiler --------------------------------------------------------


def _timing(median_us: float) -> cg.Timing:
    return cg.Timing(n=10, median_us=median_us, p999_us=2 * median_us, max_us=3 * median_us)


def _run(*, c_us: float = 22.0, bare_us: float = 20.0, worst: float = 0.0) -> cg.CodegenRun:
    return cg.CodegenRun(
        n_steps=10, python=_timing(60.0), c_step=_timing(c_us), c_ctypes=_timing(30.0),
        bare=_timing(bare_us), mean_iterations=6.0, max_iterations=15, bare_same_iterations=1.0,
        n_iteration_differences=0, first_difference_k=None, worst_triac_pct=worst,
        worst_triac_all_pct=worst, n_bit_equal=10, qp_max_rel_diff=0.0, ctypes_equal=10,
        cap=cg.CapSolve(k=0, n_iterations=4000, status_val=7, median_ms=20.0, max_ms=25.0))


def _bench(runs: tuple[cg.CodegenRun, ...]) -> cg.CodegenBenchmark:
    size = cg.ObjectSize(part="p", files=("a.o",), text=1, rodata=2, data=3, bss=4)
    return cg.CodegenBenchmark(
        machine=replace(machine_info(), n_cpus=2, load_average=0.1), model_label="m",
        command="python -m benchmarks.codegen_step", revision="abc", compiler="cc",
        compile_command="cc -O2", float32=False, horizon_steps=39, n_variables=39,
        n_constraints=77, max_iter=4000, rounds=3, runs=runs, context_runs=runs,
        sizes=(size, size, size), state_bytes=5000)


def test_the_goal_is_judged_on_the_median_ratio_of_each_half() -> None:
    met = cg.format_report(_bench((_run(c_us=22.0), _run(c_us=23.0), _run(c_us=30.0))))
    assert "within 1.15 of OSQP's bare generated solver, on the same QPs: **met**" in met
    assert "**1.150 x**" in met
    missed = _bench((_run(c_us=24.0),))
    assert not missed.goal_met
    assert "**missed**" in cg.format_report(missed)


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
        step_s=np.full(2 * n, 2e-5), bare_k=np.arange(n), bare_iterations=np.array([5, 5, 5, 15, 5, 6]),
        bare_s=np.full(n, 1e-5), cap=None, sent=np.zeros((n, 3)))
    run = cg.compare_run(loop, harness, harness.triac_pct.copy(), np.full(n, 3e-5))
    assert run.first_difference_k == 3 and run.n_iteration_differences == 1
    assert run.worst_triac_pct == pytest.approx(1e-13) and run.worst_triac_all_pct == pytest.approx(2e-3)
    assert run.n_bit_equal == 3 and run.ctypes_equal == n
    assert run.bare_same_iterations == pytest.approx(5 / 6)
    assert run.c_step.n == 2 * n and run.c_over_bare == pytest.approx(2.0)
    assert run.agrees(float32=False)
    early = replace(harness, triac_pct=loop.triac_pct + 1e-5)   # 1e-5 % before k = 3
    assert not cg.compare_run(loop, early, early.triac_pct.copy(), np.full(n, 3e-5)).agrees(False)


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
