"""Regression suites: record a suite's golden results, check a controller, audit the suite.

A suite is a campaign spec (`czmpc.campaigns.campaign`) plus the metrics it holds
(``metrics``, default `DEFAULT_METRICS`) and their tolerances (``[tolerances]``); its
seeds default to `DEFAULT_SEEDS`. Its runs are the campaign engine's
(`czmpc.campaigns.campaign.simulate_run` on the executors of
`czmpc.campaigns.runner.map_runs`), named as cases ``<controller>/<plant>/<scenario>/s<seed>``.

Golden directory, written by `record_suite` (format `GOLDEN_FORMAT`, a contract of
users' recorded suites):

* ``regress.json``: provenance (czmpc version, Python, platform, time); the suite's
  name and where its folder is (relative to the golden directory, so a repository
  checked out elsewhere still finds it); the SHA-256 of every input file (models,
  settings files, scenario files); per case its metrics, each ``{"value", "tol",
  "source"}``, the trajectory band per signal and the trajectory file;
* ``suite/suite.toml``: the suite as recorded (the check runs this copy, so an edited
  suite file cannot silently change what is checked);
* ``inputs/``: copies of the input files as recorded (to say *what* changed in a settings,
  model or scenario file when a check fails);
* ``trajectories/NNNN.npz``: per case, float32 `TRAJECTORY_SIGNALS`.

The tolerance rule (`derived_tolerance`, one rule for every golden number): every case is
run again at tight solver tolerances (`czmpc.campaigns.build.TIGHT_OSQP`,
``TIGHT_IPOPT_TOL``); a metric may move by `SOLVER_SAFETY` times the change that re-run
caused, or by the platform's floating-point share `FLOAT_RTOL` x |value| (at least
`FLOAT_ATOL`: bit-level differences grow through a few hundred steps of a stable loop to
far below 1e-9), whichever is larger; counts must match exactly. A tolerance the suite
sets replaces the derived one. The trajectory band of each signal is derived the same way
from the largest difference over the run, plus the float32 rounding of the stored
trajectory.

A ``c_step`` case (the MPC step as C, `czmpc.campaigns.build`) has no tight solver of its
own: its compiled solver's tolerances are fixed. Its reference re-run is the Python MPC of
the same model and settings at the tight tolerances, so its tolerances are those an
``mpc`` case of that model and settings gets (the C replays the Python MPC to the
solver's rounding). Its generated C (``czmpc_step.c``, ``czmpc_model.h``) is an input file
like its model and settings: regenerated C is named as a likely cause of a failure.

`check_golden` re-runs every case with the input files as they are now; a case fails when
a metric leaves its tolerance or the run raises. For every case it also finds the first
time the new trajectory leaves the golden band. `audit_golden` re-runs the cases with the
controller mutated (`czmpc.campaigns.build.MUTATIONS`) and says which mutations the suite
catches.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import shutil
import sys
import tomllib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from czmpc.campaigns.build import MUTATED_KINDS, MUTATIONS, MutationNotApplicable
from czmpc.campaigns.campaign import (
    CampaignError,
    CampaignSpec,
    RunSpec,
    build_c_steps,
    error_text,
    load_model_cached,
    simulate_run,
    spec_from_dict,
)
from czmpc.campaigns.measure import COUNT_COLUMNS, METRIC_COLUMNS, metric_row
from czmpc.campaigns.runner import map_runs
from czmpc.errors import CzmpcError
from sysid._version import __version__
from sysid.atomic import atomic_write_text, file_sha256

GOLDEN_FORMAT = "czmpc-regress/1"
GOLDEN_FILE = "regress.json"
SUITE_COPY = "suite/suite.toml"
INPUTS_DIR = "inputs"
TRAJECTORY_DIR = "trajectories"
#: Metrics held when the suite names none (the project's golden set holds these).
DEFAULT_METRICS: tuple[str, ...] = (
    "iae_kw_s", "ise_kw2_s", "max_overshoot_kw", "max_abs_steady_state_error_kw",
    "input_total_variation_pct", "n_limit_violations", "n_rate_violations", "n_solver_failures",
)
#: Seeds of a suite that names none.
DEFAULT_SEEDS: tuple[int, ...] = (7,)
#: Signals of the compact trajectory, with their units in the names.
TRAJECTORY_SIGNALS: tuple[str, ...] = ("time_s", "setpoint_kw", "power_true_kw", "triac_pct")
#: Signals compared against the golden band (the first time one leaves it is reported).
BAND_SIGNALS: tuple[str, ...] = ("power_true_kw", "triac_pct")
#: Allowed multiple of the metric change caused by the solver tolerance.
SOLVER_SAFETY = 10.0
#: Platform floating-point allowance, relative to the value.
FLOAT_RTOL = 1e-6
#: Platform floating-point allowance, absolute, in the metric's unit.
FLOAT_ATOL = 1e-9
TOLERANCE_RULE = (f"max({SOLVER_SAFETY:g} x |metric(default solver) - metric(tight solver)|, "
                  f"{FLOAT_RTOL:g} x |metric|, {FLOAT_ATOL:g}); counts exact; a suite's "
                  f"[tolerances] replace the derived ones")
#: ``progress(done, total)`` after each finished case.
TaskProgress = Callable[[int, int], None]


class RegressError(CampaignError):
    """A suite or golden directory that cannot be used as written (the message says why)."""


class RegressRunError(CzmpcError, RuntimeError):
    """A case that could not be run while recording (the golden directory is not written)."""


# --- suites and cases ------------------------------------------------------------------------
def suite_from_dict(doc: Mapping[str, Any], *, source: str = "<memory>",
                    base_dir: Path | None = None, default_name: str | None = None) -> CampaignSpec:
    """Parse a suite: a campaign spec with `DEFAULT_SEEDS` and `DEFAULT_METRICS` by default.

    Raises
    ------
    RegressError
        A missing, unknown or invalid key, or a file that does not exist.
    """
    full = {"seeds": list(DEFAULT_SEEDS), "metrics": list(DEFAULT_METRICS), **doc}
    try:
        return spec_from_dict(full, source=source, base_dir=base_dir, what="suite",
                              default_name=default_name)
    except CampaignError as exc:
        raise RegressError(str(exc)) from None


def parse_suite_text(text: str, *, source: str, base_dir: Path,
                     default_name: str | None = None) -> CampaignSpec:
    """Parse suite TOML text (relative paths from ``base_dir``; see `suite_from_dict`).

    Raises
    ------
    RegressError
        Bad TOML or an invalid suite.
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RegressError(f"suite {source}: not valid TOML: {exc}") from None
    return suite_from_dict(doc, source=source, base_dir=base_dir, default_name=default_name)


def load_suite(path: str | Path) -> CampaignSpec:
    """Read a suite file (relative paths in it are taken from its folder).

    Raises
    ------
    RegressError
        Unreadable file, bad TOML, or an invalid suite.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise RegressError(f"suite {p}: cannot read it: {exc.strerror}") from None
    return parse_suite_text(text, source=str(p), base_dir=p.resolve().parent)


@dataclass(frozen=True, kw_only=True)
class CaseResult:
    """What one case run produced.

    Parameters
    ----------
    case_id :
        The case.
    metrics :
        The metric columns (`czmpc.campaigns.measure.metric_row`); empty on error.
    trajectory :
        `TRAJECTORY_SIGNALS` as float64 arrays; empty on error.
    error :
        ``""``, or the exception's type, message and place when the run raised.
    applicable :
        False when the run's mutation does not change this case (nothing was run).
    """

    case_id: str
    metrics: Mapping[str, float] = field(default_factory=dict)
    trajectory: Mapping[str, np.ndarray] = field(default_factory=dict, repr=False)
    error: str = ""
    applicable: bool = True


def execute_case(run: RunSpec) -> CaseResult:
    """Run one case; a run that raises is returned with ``error`` set, not raised."""
    if run.mutation is not None and run.controller.kind not in MUTATED_KINDS:
        return CaseResult(case_id=run.case_id, applicable=False)
    try:
        result = simulate_run(run).result
    except MutationNotApplicable:
        return CaseResult(case_id=run.case_id, applicable=False)
    except Exception as exc:  # noqa: BLE001 - a crashed case is a result of the check
        return CaseResult(case_id=run.case_id, error=error_text(exc))
    row = metric_row(result)
    metrics = {k: float(row[k]) for k in METRIC_COLUMNS}  # not the machine's step times
    trajectory = {k: np.asarray(getattr(result, k), dtype=np.float64) for k in TRAJECTORY_SIGNALS}
    return CaseResult(case_id=run.case_id, metrics=metrics, trajectory=trajectory)


def run_cases(runs: Sequence[RunSpec], *, executor: str = "serial", workers: int = 2,
              dask_address: str = "local", progress: TaskProgress | None = None
              ) -> list[CaseResult]:
    """`execute_case` of every run on an executor (`czmpc.campaigns.runner.map_runs`), in order.

    Raises
    ------
    RegressError
        Unknown executor, bad worker count, Dask missing.
    """
    results: list[CaseResult | None] = [None] * len(runs)
    try:
        for n_done, (i, result) in enumerate(map_runs(
                execute_case, runs, executor=executor, workers=workers,
                dask_address=dask_address), start=1):
            results[i] = result
            if progress is not None:
                progress(n_done, len(runs))
    except CampaignError as exc:
        raise RegressError(str(exc)) from None
    return [r for r in results if r is not None]


# --- the tolerance rule ----------------------------------------------------------------------
def derived_tolerance(metric: str, nominal: float, tight: float) -> float:
    """Tolerance of one metric from its nominal and tight-solver values (module notes)."""
    if metric in COUNT_COLUMNS:
        return 0.0
    if not math.isfinite(nominal):
        return FLOAT_ATOL
    solver = SOLVER_SAFETY * abs(nominal - tight) if math.isfinite(tight) else 0.0
    return max(solver, FLOAT_RTOL * abs(nominal), FLOAT_ATOL)


def trajectory_band(nominal: np.ndarray, tight: np.ndarray) -> float:
    """Allowed deviation of one signal from its golden trajectory (module notes)."""
    both = np.isfinite(nominal) & np.isfinite(tight)
    solver = (SOLVER_SAFETY * float(np.max(np.abs(nominal[both] - tight[both])))
              if nominal.shape == tight.shape and both.any() else 0.0)
    scale = float(np.max(np.abs(nominal[np.isfinite(nominal)]), initial=0.0))
    rounding = float(np.max(np.abs(nominal - nominal.astype(np.float32)), initial=0.0,
                            where=np.isfinite(nominal)))
    return max(solver, FLOAT_RTOL * scale, FLOAT_ATOL) + rounding


def _input_key(path: str, base: Path) -> str:
    """How an input file is named in ``regress.json``: relative to the suite, or shipped."""
    from czmpc.shipped import shipped_path

    p = Path(path)
    try:
        return p.relative_to(base).as_posix()
    except ValueError:
        pass
    try:
        if shipped_path(p.name) == p:
            return f"shipped:{p.name}"
    except FileNotFoundError:
        pass
    return p.as_posix()


def _case_inputs(case: RunSpec) -> dict[str, str]:
    """Role -> path of the files a case reads."""
    c = case.controller
    out = {"model": c.model_path}
    if c.kind == "linear_mpc":
        out["linear_model"] = c.linear_model_path
    if c.settings_path:
        out["settings"] = c.settings_path
    out |= c.c_step_files()
    if case.scenario.endswith(".toml"):
        out["scenario"] = case.scenario
    return out


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def validate_inputs(suite: CampaignSpec) -> None:
    """Read every controller's model once and build every ``c_step``, before any case runs.

    Raises
    ------
    SysidError
        A model file that cannot be used (bad input, not a failed case).
    czmpc.codegen.BuildError
        A ``c_step`` directory that cannot be built (no C compiler or make).
    """
    for entry in suite.controllers:
        load_model_cached(entry.model_path)
        if entry.kind == "linear_mpc":
            load_model_cached(entry.linear_model_path)
    build_c_steps(suite)


# --- record ----------------------------------------------------------------------------------
def _prepare_out(out: Path, force: bool) -> None:
    if out.exists() and not out.is_dir():
        raise RegressError(f"{out} exists and is not a directory; name a new golden directory")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise RegressError(f"golden directory {out} already exists; pass --force to replace "
                               f"it, or name a new one")
        if not (out / GOLDEN_FILE).is_file():
            raise RegressError(f"{out} is not empty and holds no {GOLDEN_FILE}: --force replaces "
                               f"golden directories only; name a new or empty directory")


def record_suite(
    suite_path: str | Path, out_dir: str | Path, *, force: bool = False,
    executor: str = "serial", workers: int = 2, dask_address: str = "local",
    progress: TaskProgress | None = None,
) -> Path:
    """Run every case of a suite (nominal and tight-solver) and write a golden directory.

    Parameters
    ----------
    suite_path :
        The suite TOML.
    out_dir :
        The golden directory to write (module notes).
    force :
        Replace an existing golden directory.
    executor, workers, dask_address, progress :
        See `run_cases`.

    Returns
    -------
    Path
        The written ``regress.json``.

    Raises
    ------
    RegressError
        Invalid suite, an existing directory without ``force``.
    RegressRunError
        A case raised (the message lists every failed case); nothing is written.
    czmpc.codegen.BuildError
        A ``c_step`` directory cannot be built (no C compiler or make).
    """
    suite_file = Path(suite_path)
    suite = load_suite(suite_file)
    out = Path(out_dir)
    _prepare_out(out, force)
    validate_inputs(suite)
    cases = suite.expand()
    tasks = [replace(c, tight=t) for c in cases for t in (False, True)]
    results = run_cases(tasks, executor=executor, workers=workers, dask_address=dask_address,
                        progress=progress)
    errors = [f"{r.case_id}{' (tight solver)' if i % 2 else ''}: {r.error}"
              for i, r in enumerate(results) if r.error]
    if errors:
        raise RegressRunError("cannot record: case(s) failed to run:\n  " + "\n  ".join(errors))
    base = suite_file.resolve().parent
    tmp = out.with_name(out.name + ".recording")
    if tmp.exists():
        shutil.rmtree(tmp)
    for folder in (TRAJECTORY_DIR, "suite", INPUTS_DIR):
        (tmp / folder).mkdir(parents=True)
    shutil.copyfile(suite_file, tmp / SUITE_COPY)
    inputs: dict[str, dict[str, str]] = {}
    for i, path in enumerate(suite.input_files()):
        key = _input_key(path, base)
        copy = f"{INPUTS_DIR}/{i:02d}-{Path(path).name}"
        shutil.copyfile(path, tmp / copy)
        inputs[key] = {"sha256": file_sha256(path), "copy": copy}
    doc_cases: dict[str, Any] = {}
    for k, case in enumerate(cases):
        nominal, tight = results[2 * k], results[2 * k + 1]
        metrics: dict[str, Any] = {}
        for m in suite.metrics:
            value = nominal.metrics[m]
            user = suite.tolerances.get(m)
            tol = user.of(value) if user is not None else derived_tolerance(m, value, tight.metrics[m])
            metrics[m] = {"value": _finite(value), "tol": tol,
                          "source": f"suite: {user.describe()}" if user is not None else "derived"}
        traj_name = f"{TRAJECTORY_DIR}/{k:04d}.npz"
        arrays: dict[str, Any] = {s: nominal.trajectory[s].astype(np.float32)
                                  for s in TRAJECTORY_SIGNALS}
        np.savez_compressed(tmp / traj_name, **arrays)
        doc_cases[nominal.case_id] = {
            "controller": case.controller.name, "kind": case.controller.kind,
            "plant": case.plant.label, "scenario": Path(case.scenario).stem, "seed": case.seed,
            "inputs": {role: _input_key(p, base) for role, p in _case_inputs(case).items()},
            "metrics": metrics, "trajectory": traj_name,
            "band": {s: trajectory_band(nominal.trajectory[s], tight.trajectory[s])
                     for s in BAND_SIGNALS},
        }
    rel_base = os.path.relpath(base, out.resolve())
    doc = {
        "format": GOLDEN_FORMAT,
        "suite": {"name": suite.name, "description": suite.description, "copy": SUITE_COPY,
                  "folder": Path(rel_base).as_posix(), "folder_absolute": str(base)},
        "provenance": {
            "czmpc_version": __version__, "python": platform.python_version(),
            "platform": platform.platform(), "numpy": np.__version__,
            "recorded_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "command": " ".join(["czmpc", *sys.argv[1:]]) if sys.argv else "",
        },
        "tolerance_rule": TOLERANCE_RULE,
        "metrics": list(suite.metrics),
        "inputs": inputs,
        "cases": doc_cases,
    }
    atomic_write_text(tmp / GOLDEN_FILE, json.dumps(doc, indent=1) + "\n")
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)
    return out / GOLDEN_FILE


# --- load ------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class Golden:
    """A golden directory, read.

    Parameters
    ----------
    path :
        The directory.
    doc :
        ``regress.json``.
    suite :
        The recorded suite, its relative paths taken from the suite's folder.
    suite_dir :
        That folder.
    """

    path: Path
    doc: Mapping[str, Any] = field(repr=False)
    suite: CampaignSpec
    suite_dir: Path

    def trajectory(self, case_id: str) -> dict[str, np.ndarray]:
        """The golden trajectory of a case (float64 copies of the stored float32)."""
        with np.load(self.path / self.doc["cases"][case_id]["trajectory"]) as data:
            return {s: np.asarray(data[s], dtype=np.float64) for s in TRAJECTORY_SIGNALS}


def load_golden_dir(path: str | Path, *, suite_dir: str | Path | None = None) -> Golden:
    """Read a golden directory and the suite it was recorded from.

    Parameters
    ----------
    path :
        The golden directory.
    suite_dir :
        Folder the suite's relative paths are taken from; None: where the suite was when
        it was recorded (relative to the golden directory, else its absolute path).

    Raises
    ------
    RegressError
        Not a golden directory, an unknown format, a suite whose files are gone, or a
        suite copy whose cases differ from the recorded ones.
    """
    root = Path(path)
    file = root / GOLDEN_FILE
    try:
        doc = json.loads(file.read_text(encoding="utf-8"))
    except OSError:
        raise RegressError(f"{root} is not a golden directory (no readable {GOLDEN_FILE}); "
                           f"record one with 'czmpc regress record SUITE.toml --out {root}'") from None
    except json.JSONDecodeError as exc:
        raise RegressError(f"{file}: not valid JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != GOLDEN_FORMAT:
        found = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise RegressError(f"{file}: expected format {GOLDEN_FORMAT!r}; got {found!r}")
    info = doc["suite"]
    if suite_dir is not None:
        base = Path(suite_dir).resolve()
    else:
        relative = (root / info["folder"]).resolve()
        base = relative if relative.is_dir() else Path(info["folder_absolute"])
    try:
        text = (root / info["copy"]).read_text(encoding="utf-8")
    except OSError as exc:
        raise RegressError(f"{root}: cannot read the suite copy {info['copy']}: {exc.strerror}") from None
    suite = parse_suite_text(text, source=f"{root / info['copy']} (files from {base})",
                             base_dir=base, default_name=str(info["name"]))
    recorded = list(doc["cases"])
    now = [c.case_id for c in suite.expand()]
    if recorded != now:
        raise RegressError(f"{root}: the suite copy expands to other cases than were recorded "
                           f"({len(now)} vs {len(recorded)}); record the suite again")
    return Golden(path=root, doc=doc, suite=suite, suite_dir=base)


# --- check -----------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class MetricFailure:
    """One metric of one case outside its tolerance."""

    metric: str
    golden: float
    tolerance: float
    new: float


@dataclass(frozen=True, kw_only=True)
class Divergence:
    """Where a new trajectory first leaves the golden band.

    Parameters
    ----------
    signal :
        ``"power_true_kw"`` or ``"triac_pct"``.
    time_s :
        Scenario time of the first sample outside the band [s].
    golden, new :
        The two values there (signal unit).
    band :
        The allowed deviation (signal unit).
    """

    signal: str
    time_s: float
    golden: float
    new: float
    band: float


@dataclass(frozen=True, kw_only=True)
class InputChange:
    """An input file whose bytes differ from the recorded ones.

    Parameters
    ----------
    name :
        The file as named in ``regress.json``.
    recorded_sha256, current_sha256 :
        The hashes ("missing" when the file is gone).
    details :
        Changed keys with old and new values (settings and model files), e.g.
        ``"move_weight: 0.1 -> 0.2"``.
    """

    name: str
    recorded_sha256: str
    current_sha256: str
    details: tuple[str, ...]


@dataclass(frozen=True, kw_only=True)
class CaseCheck:
    """The check of one case.

    Parameters
    ----------
    case_id :
        The case.
    failures :
        Metrics outside tolerance.
    divergence :
        First exit from the golden band, or None.
    error :
        The exception of a run that raised, or ``""``.
    changed_inputs :
        Names of this case's input files that changed since recording (likely cause).
    new_trajectory :
        The new run's trajectory (for figures).
    """

    case_id: str
    failures: tuple[MetricFailure, ...]
    divergence: Divergence | None
    error: str
    changed_inputs: tuple[str, ...]
    new_trajectory: Mapping[str, np.ndarray] = field(repr=False, default_factory=dict)

    @property
    def passed(self) -> bool:
        """No metric outside tolerance and no error."""
        return not self.failures and not self.error


@dataclass(frozen=True, kw_only=True)
class CheckReport:
    """The check of a golden directory.

    Parameters
    ----------
    golden :
        The golden directory.
    cases :
        Every case's check, in suite order.
    input_changes :
        Input files changed since recording.
    recorded_version, current_version :
        czmpc versions.
    wall_time_s :
        Duration of the check [s].
    """

    golden: Golden
    cases: tuple[CaseCheck, ...]
    input_changes: tuple[InputChange, ...]
    recorded_version: str
    current_version: str
    wall_time_s: float

    @property
    def passed(self) -> bool:
        """Every case held."""
        return all(c.passed for c in self.cases)

    @property
    def failed(self) -> tuple[CaseCheck, ...]:
        """The cases that did not hold."""
        return tuple(c for c in self.cases if not c.passed)


def first_divergence(golden: Mapping[str, np.ndarray], new: Mapping[str, np.ndarray],
                     band: Mapping[str, float]) -> Divergence | None:
    """The earliest sample at which a `BAND_SIGNALS` signal leaves its golden band.

    NaN matches NaN; a run of another length diverges at the end of the shorter one.
    """
    best: Divergence | None = None
    time_s = golden["time_s"]
    for signal in BAND_SIGNALS:
        g, n = golden[signal], new[signal]
        k = min(len(g), len(n))
        diff = np.abs(n[:k] - g[:k])
        both_nan = np.isnan(g[:k]) & np.isnan(n[:k])
        outside = np.flatnonzero(~both_nan & ~(diff <= band[signal]))
        if outside.size:
            i = int(outside[0])
        elif len(g) != len(n):
            i = k - 1 if k else 0
        else:
            continue
        if i >= len(time_s):
            continue
        if best is None or time_s[i] < best.time_s:
            best = Divergence(signal=signal, time_s=float(time_s[i]),
                              golden=float(g[i]) if i < len(g) else math.nan,
                              new=float(n[i]) if i < len(n) else math.nan, band=float(band[signal]))
    return best


def _flatten(doc: object, name: str = "") -> dict[str, Any]:
    """Leaf values by dotted key; list items by index (``setpoint[1].power_kw``)."""
    items: Iterable[tuple[str, object]]
    if isinstance(doc, Mapping):
        items = ((f"{name}.{k}" if name else str(k), v) for k, v in doc.items())
    elif isinstance(doc, list):
        items = ((f"{name}[{i}]", v) for i, v in enumerate(doc))
    else:
        return {name: doc}
    out: dict[str, Any] = {}
    for key, value in items:
        out.update(_flatten(value, key))
    return out


def _describe_change(old: Path, new: Path) -> tuple[str, ...]:
    """Changed values of a TOML or JSON file, ``"key: old -> new"`` (at most 8), in full."""
    def read(p: Path) -> dict[str, Any]:
        text = p.read_text(encoding="utf-8")
        doc = tomllib.loads(text) if p.suffix == ".toml" else json.loads(text)
        return _flatten(doc) if isinstance(doc, dict) else {}

    try:
        a, b = read(old), read(new)
    except (OSError, ValueError):
        return ()
    old_new = {key: (a.get(key, "<absent>"), b.get(key, "<absent>")) for key in sorted(set(a) | set(b))}
    lines = [f"{key}: {was!r} -> {now!r}" for key, (was, now) in old_new.items() if was != now]
    return tuple(lines[:8]) + ((f"... and {len(lines) - 8} more",) if len(lines) > 8 else ())


def input_changes(golden: Golden) -> tuple[InputChange, ...]:
    """Input files whose current bytes differ from the recorded hashes."""
    base = golden.suite_dir
    current = {_input_key(p, base): p for p in golden.suite.input_files()}
    out = []
    for name, entry in golden.doc["inputs"].items():
        path = current.get(name)
        now = file_sha256(path) if path is not None and Path(path).is_file() else "missing"
        if now != entry["sha256"]:
            details = (_describe_change(golden.path / entry["copy"], Path(path))
                       if path is not None and now != "missing" else ())
            out.append(InputChange(name=name, recorded_sha256=entry["sha256"],
                                   current_sha256=now, details=details))
    return tuple(out)


def _outside(golden: Mapping[str, Mapping[str, float | None]], new: Mapping[str, float]
             ) -> Iterable[MetricFailure]:
    """Metrics of ``new`` outside ``golden`` (``{metric: {"value", "tol"}}``).

    NaN matches NaN (stored as null: e.g. no overshoot in a run without a setpoint
    change); a missing metric fails.
    """
    for name, entry in golden.items():
        value = math.nan if entry.get("value") is None else float(entry["value"])  # type: ignore[arg-type]
        tol = float(entry.get("tol") or 0.0)
        got = float(new.get(name, math.nan))
        if not (abs(got - value) <= tol or (math.isnan(value) and math.isnan(got) and name in new)):
            yield MetricFailure(metric=name, golden=value, tolerance=tol, new=got)


def _judge(golden: Golden, case_id: str, result: CaseResult, changed: set[str]) -> CaseCheck:
    entry = golden.doc["cases"][case_id]
    causes = tuple(sorted(n for n in entry["inputs"].values() if n in changed))
    if result.error:
        return CaseCheck(case_id=case_id, failures=(), divergence=None, error=result.error,
                         changed_inputs=causes)
    failures = tuple(_outside(entry["metrics"], result.metrics))
    divergence = first_divergence(golden.trajectory(case_id), result.trajectory, entry["band"])
    return CaseCheck(case_id=case_id, failures=failures, divergence=divergence, error="",
                     changed_inputs=causes,
                     new_trajectory=result.trajectory if failures or divergence else {})


def check_golden(
    golden_dir: str | Path, *, suite_dir: str | Path | None = None, executor: str = "serial",
    workers: int = 2, dask_address: str = "local", progress: TaskProgress | None = None,
    cases: Sequence[str] | None = None, mutation: str | None = None,
) -> CheckReport:
    """Re-run the cases of a golden directory and compare them with the recorded ones.

    Parameters
    ----------
    golden_dir :
        Written by `record_suite`.
    suite_dir :
        See `load_golden_dir`.
    executor, workers, dask_address, progress :
        See `run_cases`.
    cases :
        Case ids to check; None: all.
    mutation :
        Run the controller mutated (a key of `czmpc.campaigns.build.MUTATIONS`); cases the
        mutation does not change are left out.

    Raises
    ------
    RegressError
        Not a golden directory, unknown case ids or mutation.
    czmpc.codegen.BuildError
        A ``c_step`` directory cannot be built (no C compiler or make).
    """
    import time

    t0 = time.perf_counter()
    golden = load_golden_dir(golden_dir, suite_dir=suite_dir)
    if mutation is not None and mutation not in MUTATIONS:
        raise RegressError(f"expected a mutation among {list(MUTATIONS)}; got {mutation!r}")
    chosen = list(golden.suite.expand())
    if cases is not None:
        unknown = sorted(set(cases) - {c.case_id for c in chosen})
        if unknown:
            raise RegressError(f"{golden.path}: no case(s) {unknown} in the golden directory")
        chosen = [c for c in chosen if c.case_id in set(cases)]
    changes = input_changes(golden)
    validate_inputs(golden.suite)
    results = run_cases([replace(c, mutation=mutation) for c in chosen], executor=executor,
                        workers=workers, dask_address=dask_address, progress=progress)
    changed = {c.name for c in changes}
    checks = tuple(_judge(golden, r.case_id, r, changed) for r in results if r.applicable)
    return CheckReport(golden=golden, cases=checks, input_changes=changes,
                       recorded_version=str(golden.doc["provenance"]["czmpc_version"]),
                       current_version=__version__, wall_time_s=time.perf_counter() - t0)


# --- audit -----------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class MutationResult:
    """What the suite said about one mutation.

    Parameters
    ----------
    mutation :
        A key of `czmpc.campaigns.build.MUTATIONS`.
    n_cases :
        Cases the mutation changes.
    caught :
        Cases that failed with it (first failing metric or the error, per case).
    """

    mutation: str
    n_cases: int
    caught: tuple[tuple[str, str], ...]

    @property
    def is_caught(self) -> bool:
        """At least one case failed."""
        return bool(self.caught)


@dataclass(frozen=True, kw_only=True)
class AuditReport:
    """The audit of a golden directory.

    Parameters
    ----------
    golden_dir :
        The directory.
    baseline_failures :
        Cases that fail without any mutation (left out of the counts).
    mutations :
        One result per mutation.
    """

    golden_dir: Path
    baseline_failures: tuple[str, ...]
    mutations: tuple[MutationResult, ...]

    @property
    def catches_any(self) -> bool:
        """The suite catches at least one mutation."""
        return any(m.is_caught for m in self.mutations)


def audit_golden(
    golden_dir: str | Path, *, mutations: Sequence[str] | None = None,
    suite_dir: str | Path | None = None, executor: str = "serial", workers: int = 2,
    dask_address: str = "local", progress: Callable[[str], None] | None = None,
) -> AuditReport:
    """Mutate the recorded controller and report which mutations the suite catches.

    Only cases of the mutated kinds (`czmpc.campaigns.build.MUTATED_KINDS`) are run: first
    unchanged (a case that already fails is left out), then once per mutation.

    Raises
    ------
    RegressError
        Not a golden directory, an unknown mutation, or no case the mutations apply to.
    """
    names = list(MUTATIONS) if mutations is None else list(mutations)
    unknown = [m for m in names if m not in MUTATIONS]
    if unknown:
        raise RegressError(f"expected mutations among {list(MUTATIONS)}; got {unknown}")
    golden = load_golden_dir(golden_dir, suite_dir=suite_dir)
    ids = [c.case_id for c in golden.suite.expand() if c.controller.kind in MUTATED_KINDS]
    if not ids:
        raise RegressError(f"{golden.path}: the suite has no controller of kind "
                           f"{sorted(MUTATED_KINDS)}; there is nothing to mutate")
    common = {"suite_dir": suite_dir, "executor": executor, "workers": workers,
              "dask_address": dask_address, "cases": ids}
    if progress is not None:
        progress(f"audit: {len(ids)} case(s) unchanged")
    baseline = check_golden(golden_dir, **common)  # type: ignore[arg-type]
    bad = {c.case_id for c in baseline.failed}
    out = []
    for name in names:
        if progress is not None:
            progress(f"audit: mutation '{name}' on {len(ids)} case(s)")
        report = check_golden(golden_dir, mutation=name, **common)  # type: ignore[arg-type]
        considered = [c for c in report.cases if c.case_id not in bad]
        caught = tuple((c.case_id, c.error or c.failures[0].metric) for c in considered
                       if not c.passed)
        out.append(MutationResult(mutation=name, n_cases=len(considered), caught=caught))
    return AuditReport(golden_dir=golden.path, baseline_failures=tuple(sorted(bad)),
                       mutations=tuple(out))


__all__ = ["BAND_SIGNALS", "DEFAULT_METRICS", "DEFAULT_SEEDS", "FLOAT_ATOL", "FLOAT_RTOL", "GOLDEN_FILE",
           "GOLDEN_FORMAT", "SOLVER_SAFETY", "TOLERANCE_RULE", "TRAJECTORY_SIGNALS", "AuditReport",
           "CaseCheck", "CaseResult", "CheckReport", "Divergence", "Golden", "InputChange", "MetricFailure",
           "MutationResult", "RegressError", "RegressRunError", "audit_golden", "check_golden",
           "derived_tolerance", "execute_case", "first_divergence", "input_changes", "load_golden_dir",
           "load_suite", "parse_suite_text", "record_suite", "run_cases", "suite_from_dict",
           "trajectory_band", "validate_inputs"]
