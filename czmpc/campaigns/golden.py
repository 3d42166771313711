"""Golden controller metrics: write them, compare a fresh run against them.

The regression net of the controllers: for every (scenario, plant, controller) of the
golden set — the shipped scenarios shortened by `GOLDEN_SHORT_FACTOR`, both plants,
the controllers in `GOLDEN_CONTROLLERS`, seed `czmpc.campaigns.bench.BENCH_SEED` — a few metrics
(`GOLDEN_METRICS`, never trajectories) are stored in ``tests/golden/<scenario>.json``
with a tolerance each. A run whose metric leaves ``value +- tol`` is a regression.

Tolerances are derived, not guessed, from what may vary legitimately:

* the solver tolerance: the case is run again with much tighter solver settings
  (`TIGHT_OSQP`, `TIGHT_IPOPT_TOL`), and ``SOLVER_SAFETY`` times the change of each metric
  is allowed;
* platform floating point (libm, BLAS summation order): ``FLOAT_RTOL`` of the value,
  at least ``FLOAT_ATOL``.

The tolerance is the larger of the two. Counts (violations, solver failures) must match
exactly. ``czmpc bench --update-golden`` rewrites the files (`write_golden_set`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from czmpc.campaigns.bench import (
    BENCH_SEED,
    CONTROLLERS,
    PLANTS,
    BenchModels,
    BenchRun,
    run_case,
    run_row,
)
from czmpc.errors import CzmpcError
from czmpc.settings import OSQPOptions
from sim.scenario import Scenario, list_scenarios, load_scenario
from sysid.atomic import atomic_write_text

GOLDEN_FORMAT = "czmpc-golden/1"
#: The repository's golden directory.
GOLDEN_DIR = Path(__file__).resolve().parents[2] / "tests" / "golden"
#: Time factor of the golden scenarios (short runs keep the test suite fast).
GOLDEN_SHORT_FACTOR = 0.1
#: Controllers in the golden set (all of `czmpc.campaigns.bench.CONTROLLERS`; the NMPC's short runs
#: take a few seconds in all).
GOLDEN_CONTROLLERS: tuple[str, ...] = tuple(CONTROLLERS)
#: Metrics stored (keys of `czmpc.campaigns.bench.run_row`); the counts must match exactly.
GOLDEN_METRICS: tuple[str, ...] = (
    "iae_kw_s", "ise_kw2_s", "max_overshoot_kw", "max_abs_steady_state_error_kw",
    "input_total_variation_pct", "n_limit_violations", "n_rate_violations",
    "n_solver_failures",
)
_COUNT_METRICS = frozenset({"n_limit_violations", "n_rate_violations", "n_solver_failures"})
#: Solver settings of the reference re-run: far tighter than the defaults (OSQP 1e-5,
#: IPOPT 1e-8), so the metric change measures what the default tolerance allows.
TIGHT_OSQP = OSQPOptions(eps_abs=1e-9, eps_rel=1e-9, max_iter=100_000)
TIGHT_IPOPT_TOL = 1e-11
#: Allowed multiple of the metric change caused by the solver tolerance.
SOLVER_SAFETY = 10.0
#: Platform floating-point allowance, relative to the value. Bit-level differences
#: (1e-16) grow through a few hundred steps of a stable loop to far below 1e-9.
FLOAT_RTOL = 1e-6
#: Platform floating-point allowance, absolute, in the metric's unit.
FLOAT_ATOL = 1e-9


class GoldenError(CzmpcError, ValueError):
    """A golden file that cannot be read (format, missing keys)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Mismatch:
    """One metric of one run outside its golden tolerance.

    Parameters
    ----------
    case :
        ``"<scenario>/<plant>/<controller>"``.
    metric :
        The metric name.
    expected, tolerance, actual :
        Golden value, allowed deviation and the new value (NaN if missing).
    """

    case: str
    metric: str
    expected: float
    tolerance: float
    actual: float

    def __str__(self) -> str:
        return (f"{self.case}: {self.metric} = {self.actual:.10g}, expected "
                f"{self.expected:.10g} +- {self.tolerance:.3g}")


def golden_scenarios(names: Sequence[str] | None = None) -> tuple[Scenario, ...]:
    """The golden set's scenarios: the shipped ones shortened by `GOLDEN_SHORT_FACTOR`."""
    return tuple(load_scenario(n).shortened(GOLDEN_SHORT_FACTOR)
                 for n in (list_scenarios() if names is None else names))


def metric_values(run: BenchRun) -> dict[str, float]:
    """`GOLDEN_METRICS` of ``run``."""
    row = run_row(run)
    return {name: float(row[name]) for name in GOLDEN_METRICS}


def tolerances(nominal: Mapping[str, float], tight: Mapping[str, float]) -> dict[str, float]:
    """Tolerance per metric from a nominal and a tight-solver run (module notes)."""
    out: dict[str, float] = {}
    for name in GOLDEN_METRICS:
        value = nominal[name]
        if name in _COUNT_METRICS:
            out[name] = 0.0
            continue
        solver = SOLVER_SAFETY * abs(value - tight[name]) if math.isfinite(value) else 0.0
        out[name] = max(solver, FLOAT_RTOL * abs(value) if math.isfinite(value) else 0.0,
                        FLOAT_ATOL)
    return out


def compare(case: str, golden: Mapping[str, Mapping[str, float | None]],
            actual: Mapping[str, float]) -> tuple[Mismatch, ...]:
    """Metrics of ``actual`` outside ``golden`` (``{metric: {"value", "tol"}}``).

    NaN matches NaN (stored as null: e.g. no overshoot in a run without a setpoint
    change); a missing metric is a mismatch.
    """
    out: list[Mismatch] = []
    for name, entry in golden.items():
        value = math.nan if entry.get("value") is None else float(entry["value"])  # type: ignore[arg-type]
        tol = float(entry.get("tol") or 0.0)
        got = float(actual.get(name, math.nan))
        if math.isnan(value) and math.isnan(got) and name in actual:
            continue
        if not abs(got - value) <= tol:  # False for NaN
            out.append(Mismatch(case=case, metric=name, expected=value, tolerance=tol, actual=got))
    return tuple(out)


def _json_number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def golden_document(scenario: Scenario, entries: Mapping[str, Mapping[str, tuple[float, float]]],
                    *, seed: int = BENCH_SEED) -> dict[str, Any]:
    """The JSON document of one scenario's golden file."""
    return {
        "format": GOLDEN_FORMAT,
        "scenario": scenario.name,
        "short_factor": GOLDEN_SHORT_FACTOR,
        "seed": seed,
        "tolerance_rule": (
            f"max({SOLVER_SAFETY:g} x |metric(default solver) - metric(tight solver)|, "
            f"{FLOAT_RTOL:g} x |metric|, {FLOAT_ATOL:g}); counts exact"
        ),
        "runs": {
            case: {m: {"value": _json_number(v), "tol": t} for m, (v, t) in metrics.items()}
            for case, metrics in entries.items()
        },
    }


def load_golden(path: str | Path) -> dict[str, Any]:
    """Read one golden file and check its format.

    Raises
    ------
    GoldenError
        Not a ``czmpc-golden/1`` document with ``runs``.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise GoldenError(f"{path}: expected a readable JSON golden file; got {exc}") from exc
    if not isinstance(doc, dict) or doc.get("format") != GOLDEN_FORMAT or not isinstance(
            doc.get("runs"), dict):
        raise GoldenError(f"{path}: expected format {GOLDEN_FORMAT!r} with 'runs'; got "
                          f"{doc.get('format') if isinstance(doc, dict) else type(doc).__name__!r}")
    return doc


def _case_key(plant: str, controller: str) -> str:
    return f"{plant}/{controller}"


def write_golden_set(
    out_dir: str | Path = GOLDEN_DIR, *, scenario_names: Sequence[str] | None = None,
    controllers: Sequence[str] = GOLDEN_CONTROLLERS, plants: Sequence[str] = tuple(PLANTS),
    models: BenchModels | None = None, progress: Callable[[str], None] | None = None,
) -> tuple[Path, ...]:
    """Run the golden set (nominal and tight-solver) and write one file per scenario.

    Parameters
    ----------
    out_dir :
        Where the ``<scenario>.json`` files go.
    scenario_names :
        Shipped scenario names; None: all.
    controllers, plants :
        The golden set's controllers and plants.
    models :
        None: `BenchModels.shipped`.
    progress :
        Called with one line per case.
    """
    models = BenchModels.shipped() if models is None else models
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for scenario in golden_scenarios(scenario_names):
        entries: dict[str, dict[str, tuple[float, float]]] = {}
        for plant in plants:
            for ctrl in controllers:
                if progress is not None:
                    progress(f"golden: {scenario.name} / {plant} / {ctrl}")
                nominal = metric_values(run_case(scenario, plant, ctrl, models))
                tight = metric_values(run_case(scenario, plant, ctrl, models,
                                               settings_updates={"osqp": TIGHT_OSQP},
                                               ipopt_tol=TIGHT_IPOPT_TOL))
                tol = tolerances(nominal, tight)
                entries[_case_key(plant, ctrl)] = {m: (nominal[m], tol[m]) for m in GOLDEN_METRICS}
        path = out / f"{scenario.name.removesuffix('-short')}.json"
        atomic_write_text(path, json.dumps(golden_document(scenario, entries), indent=2) + "\n")
        paths.append(path)
    return tuple(paths)


def check_golden_file(
    path: str | Path, *, models: BenchModels | None = None,
    cases: Sequence[str] | None = None, settings_updates: Mapping[str, Any] | None = None,
) -> tuple[Mismatch, ...]:
    """Re-run the cases of one golden file and return every metric outside tolerance.

    Parameters
    ----------
    path :
        A golden file.
    models :
        None: `BenchModels.shipped`.
    cases :
        ``"<plant>/<controller>"`` keys to check; None: all in the file.
    settings_updates :
        Changes to the MPC settings (to show a worse tuning is caught).
    """
    doc = load_golden(path)
    models = BenchModels.shipped() if models is None else models
    name = str(doc["scenario"]).removesuffix("-short")
    scenario = load_scenario(name).shortened(float(doc["short_factor"]))
    out: list[Mismatch] = []
    for key, golden in doc["runs"].items():
        if cases is not None and key not in cases:
            continue
        plant, ctrl = key.split("/")
        run = run_case(scenario, plant, ctrl, models, seed=int(doc["seed"]),
                       settings_updates=settings_updates)
        out.extend(compare(f"{scenario.name}/{key}", golden, metric_values(run)))
    return tuple(out)


__all__ = [
    "FLOAT_ATOL",
    "FLOAT_RTOL",
    "GOLDEN_CONTROLLERS",
    "GOLDEN_DIR",
    "GOLDEN_FORMAT",
    "GOLDEN_METRICS",
    "GOLDEN_SHORT_FACTOR",
    "SOLVER_SAFETY",
    "TIGHT_IPOPT_TOL",
    "TIGHT_OSQP",
    "GoldenError",
    "Mismatch",
    "check_golden_file",
    "compare",
    "golden_document",
    "golden_scenarios",
    "load_golden",
    "metric_values",
    "tolerances",
    "write_golden_set",
]
