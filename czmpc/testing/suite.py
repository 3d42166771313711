"""Regression suites: the user's controllers x plants x scenarios x seeds, as cases.

A suite (TOML) says which closed loops define "good" for a controller: its models and
settings files, the scenarios (shipped names or the user's own scenario files, such as a
recipe's setpoint schedule), the plants, the seeds, and the metrics to hold. It expands
into cases (`CaseSpec`), each a pure function of its spec (`czmpc.testing.cases.run_case`).

Suite (TOML)::

    name = "puller-7"                  # default: the file's stem
    description = "MPC tuned for puller 7, recipes A and B"
    scenarios = ["staircase", "recipes/recipe_a.toml"]   # shipped names or .toml paths
    seeds = [7]                        # plant-noise seeds; one case per seed (default [7])
    time_scale = 1.0                   # optional Scenario.shortened factor in (0, 1]
    metrics = ["iae_kw_s", "max_overshoot_kw", "n_rate_violations"]   # default: DEFAULT_METRICS

    [tolerances]                       # optional, per metric: replaces the derived tolerance
    iae_kw_s = 0.5                     # absolute, in the metric's unit
    max_overshoot_kw = "2%"            # or a percentage of the recorded value

    [[controllers]]
    name = "tuned"                     # default: the kind
    kind = "mpc"                       # mpc, nmpc, linear_mpc, pi_gs, pi, pi_table, open_loop
    model = "puller7_model.json"       # path (relative to the suite) or shipped name
    settings = "puller7_settings.toml" # optional MPC settings file (default settings without)
    # linear_model = "armax.json"      # linear_mpc only (default: the shipped ARMAX)

    [[plants]]
    kind = "model"                     # the controller's own model as the plant
    [[plants]]
    kind = "heater"                    # the virtual heater (grey-box physics, mismatch)
    [[plants]]
    kind = "perturbed"                 # the model perturbed: the product of the three lists
    gain_factors = [0.9, 1.1]
    time_constant_factors = [1.0]
    extra_delays_steps = [0]

Relative paths are taken from the suite file's folder. Cases are named
``<controller>/<plant>/<scenario>/s<seed>`` and run in the nesting controllers x plants
x scenarios x seeds.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from czmpc.campaigns.campaign import CampaignError, PlantSpec, perturbed_plants
from czmpc.config_text import choices, shown
from czmpc.errors import CzmpcError

#: Controller kinds (the names of `czmpc.campaigns.bench.CONTROLLERS` and ``pi_table``, the
#: PI schedule tuned by `czmpc.pid`).
CONTROLLER_KINDS: tuple[str, ...] = ("mpc", "nmpc", "linear_mpc", "pi_gs", "pi", "pi_table",
                                     "open_loop")
PLANT_KINDS: tuple[str, ...] = ("model", "heater", "perturbed")
#: Metrics a suite may hold (units in the names); counts must match exactly.
METRICS: tuple[str, ...] = (
    "iae_kw_s", "ise_kw2_s", "max_overshoot_kw", "max_overshoot_pct", "max_settling_time_s",
    "max_abs_steady_state_error_kw", "input_total_variation_pct", "n_not_settled",
    "n_limit_violations", "n_rate_violations", "n_solver_failures",
)
#: Metrics compared exactly (whole counts).
COUNT_METRICS: frozenset[str] = frozenset(
    {"n_not_settled", "n_limit_violations", "n_rate_violations", "n_solver_failures"})
#: Metrics held when the suite names none (the project's golden set holds these).
DEFAULT_METRICS: tuple[str, ...] = (
    "iae_kw_s", "ise_kw2_s", "max_overshoot_kw", "max_abs_steady_state_error_kw",
    "input_total_variation_pct", "n_limit_violations", "n_rate_violations", "n_solver_failures",
)
#: Seed of every case when the suite names none (the benchmark's seed).
DEFAULT_SEEDS: tuple[int, ...] = (7,)
_TOP_KEYS = ("name", "description", "scenarios", "seeds", "time_scale", "metrics", "tolerances",
             "controllers", "plants")


class RegressError(CzmpcError, ValueError):
    """A suite or golden directory that cannot be used as written (the message says why)."""


@dataclass(frozen=True, kw_only=True)
class Tolerance:
    """A tolerance the user set for one metric.

    Parameters
    ----------
    value :
        Absolute (metric unit) or, with ``relative``, a fraction of the recorded value.
    relative :
        Whether ``value`` is a fraction of the recorded value (``"2%"`` gives 0.02).
    """

    value: float
    relative: bool

    def of(self, recorded: float) -> float:
        """The allowed deviation around ``recorded``."""
        return self.value * abs(recorded) if self.relative else self.value

    def describe(self) -> str:
        """``"2%"`` or ``"0.5"``, as written in the suite."""
        return f"{self.value * 100:g}%" if self.relative else f"{self.value:g}"


@dataclass(frozen=True, kw_only=True)
class ControllerEntry:
    """One controller of a suite.

    Parameters
    ----------
    name :
        Its name in case ids.
    kind :
        One of `CONTROLLER_KINDS`.
    model_path :
        The Hammerstein model file it is built from (and the model plant's model).
    settings_path :
        The MPC settings file, or None for `czmpc.settings.MPCSettings.default_for`.
    linear_model_path :
        The linear model of ``linear_mpc`` (the shipped ARMAX by default).
    """

    name: str
    kind: str
    model_path: str
    settings_path: str | None
    linear_model_path: str


@dataclass(frozen=True, kw_only=True)
class CaseSpec:
    """Everything one case depends on (picklable; the run is a pure function of it).

    Parameters
    ----------
    case_id :
        ``<controller>/<plant>/<scenario>/s<seed>``.
    controller :
        The suite's controller entry.
    plant :
        The plant (`czmpc.campaigns.campaign.PlantSpec`).
    scenario :
        Shipped scenario name or absolute path of a scenario file.
    time_scale :
        ``Scenario.shortened`` factor; 1 runs the scenario as written.
    seed :
        Seed of the plant noise.
    """

    case_id: str
    controller: ControllerEntry
    plant: PlantSpec
    scenario: str
    time_scale: float
    seed: int


@dataclass(frozen=True, kw_only=True)
class SuiteSpec:
    """A parsed suite (see the module docstring for the TOML keys).

    Parameters
    ----------
    name, description :
        Names of the suite.
    source :
        The suite file, or ``"<memory>"``.
    controllers, plants, scenarios, seeds :
        The axes; scenarios are shipped names or absolute paths.
    time_scale :
        ``Scenario.shortened`` factor in (0, 1].
    metrics :
        The metrics held, in order.
    tolerances :
        The user's tolerances by metric.
    """

    name: str
    description: str
    source: str
    controllers: tuple[ControllerEntry, ...]
    plants: tuple[PlantSpec, ...]
    scenarios: tuple[str, ...]
    seeds: tuple[int, ...]
    time_scale: float
    metrics: tuple[str, ...]
    tolerances: Mapping[str, Tolerance]

    def expand(self) -> tuple[CaseSpec, ...]:
        """All cases: controllers x plants x scenarios x seeds, in that nesting."""
        return tuple(
            CaseSpec(case_id=f"{c.name}/{p.label}/{Path(s).stem}/s{seed}", controller=c, plant=p,
                     scenario=s, time_scale=self.time_scale, seed=seed)
            for c in self.controllers for p in self.plants for s in self.scenarios
            for seed in self.seeds)

    def input_files(self) -> tuple[str, ...]:
        """Every file (not shipped name) the cases read: models, settings, scenarios."""
        paths: list[str] = []
        for c in self.controllers:
            paths.append(c.model_path)
            if c.kind == "linear_mpc":
                paths.append(c.linear_model_path)
            if c.settings_path is not None:
                paths.append(c.settings_path)
        paths += [s for s in self.scenarios if s.endswith(".toml")]
        return tuple(dict.fromkeys(paths))


# --- parsing ---------------------------------------------------------------------------------
def _check_keys(table: Mapping[str, Any], allowed: Sequence[str], where: str) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise RegressError(f"{where}: unknown key(s) {unknown}; expected some of {sorted(allowed)}")


def _file(value: object, key: str, base: Path, where: str, *, shipped_ok: bool) -> str:
    """Absolute path of a file named in the suite (or of a shipped data file)."""
    from czmpc.shipped import shipped_path

    if not isinstance(value, str) or not value:
        raise RegressError(f"{where}: expected '{key}' a file name; got {shown(value)}")
    candidate = Path(value) if Path(value).is_absolute() else base / value
    if candidate.is_file():
        return str(candidate.resolve())
    if shipped_ok:
        try:
            return str(shipped_path(value))
        except FileNotFoundError:
            pass
    raise RegressError(f"{where}: '{key} = {shown(value)}': no such file ({candidate})"
                       + (" and no shipped file of that name" if shipped_ok else ""))


def _controllers(doc: object, base: Path, where: str) -> tuple[ControllerEntry, ...]:
    from czmpc.shipped import ARMAX_MODEL_JSON, HAMMERSTEIN_MODEL_JSON

    if not isinstance(doc, list) or not doc or not all(isinstance(t, dict) for t in doc):
        raise RegressError(f"{where}: expected at least one [[controllers]] table")
    out: list[ControllerEntry] = []
    for i, table in enumerate(doc, start=1):
        here = f"{where} [[controllers]] #{i}"
        _check_keys(table, ["name", "kind", "model", "settings", "linear_model"], here)
        kind = table.get("kind", "mpc")
        if kind not in CONTROLLER_KINDS:
            raise RegressError(f"{here}: expected kind one of {choices(CONTROLLER_KINDS)}; got {shown(kind)}")
        name = table.get("name", kind)
        if not isinstance(name, str) or not name or "/" in name:
            raise RegressError(f"{here}: expected a non-empty name without '/'; got {shown(name)}")
        if "linear_model" in table and kind != "linear_mpc":
            raise RegressError(f"{here}: 'linear_model' is for kind 'linear_mpc' only; "
                               f"got kind {shown(kind)}")
        settings = table.get("settings")
        out.append(ControllerEntry(
            name=name, kind=kind,
            model_path=_file(table.get("model", HAMMERSTEIN_MODEL_JSON), "model", base, here,
                             shipped_ok=True),
            settings_path=(None if settings is None
                           else _file(settings, "settings", base, here, shipped_ok=False)),
            linear_model_path=_file(table.get("linear_model", ARMAX_MODEL_JSON), "linear_model",
                                    base, here, shipped_ok=True)))
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise RegressError(f"{where}: controller names must differ; got {names}")
    return tuple(out)


def _plants(doc: object, where: str) -> tuple[PlantSpec, ...]:
    if not isinstance(doc, list) or not doc or not all(isinstance(t, dict) for t in doc):
        raise RegressError(f"{where}: expected at least one [[plants]] table")
    out: list[PlantSpec] = []
    for i, table in enumerate(doc, start=1):
        here = f"{where} [[plants]] #{i}"
        kind = table.get("kind")
        if kind not in PLANT_KINDS:
            raise RegressError(f"{here}: expected kind one of {choices(PLANT_KINDS)}; got {shown(kind)}")
        if kind != "perturbed":
            _check_keys(table, ["kind"], here)
            out.append(PlantSpec(kind=kind))
            continue
        try:
            out += perturbed_plants(table, here)
        except CampaignError as exc:
            raise RegressError(str(exc)) from None
    labels = [p.label for p in out]
    if len(set(labels)) != len(labels):
        raise RegressError(f"{where}: plants must differ; got {labels}")
    return tuple(out)


def _scenarios(doc: object, base: Path, where: str) -> tuple[str, ...]:
    from sim.errors import SimError
    from sim.scenario import list_scenarios, load_scenario

    if not isinstance(doc, list) or not doc or not all(isinstance(s, str) for s in doc):
        raise RegressError(f"{where}: expected 'scenarios' a non-empty list of shipped names or "
                           f".toml files; got {shown(doc)}")
    out = []
    for name in doc:
        if name.endswith(".toml"):
            resolved = _file(name, "scenarios", base, where, shipped_ok=False)
        elif name in list_scenarios():
            resolved = name
        else:
            raise RegressError(f"{where}: scenario {shown(name)} is not shipped (shipped: "
                               f"{', '.join(list_scenarios())}) and not a .toml file")
        try:
            load_scenario(resolved)
        except (SimError, OSError) as exc:
            raise RegressError(f"{where}: scenario {shown(name)}: {exc}") from None
        out.append(resolved)
    stems = [Path(s).stem for s in out]
    if len(set(stems)) != len(stems):
        raise RegressError(f"{where}: scenario names (file stems) must differ; got {stems}")
    return tuple(out)


def _tolerances(doc: object, metrics: Sequence[str], where: str) -> dict[str, Tolerance]:
    if not isinstance(doc, dict):
        raise RegressError(f"{where}: expected [tolerances] a table of metric = number or 'N%'; "
                           f"got {shown(doc)}")
    out: dict[str, Tolerance] = {}
    for metric, value in doc.items():
        if metric not in metrics:
            raise RegressError(f"{where}: [tolerances] {shown(metric)} is not a held metric; held: "
                               f"{list(metrics)}")
        if isinstance(value, str) and value.strip().endswith("%"):
            try:
                number = float(value.strip()[:-1])
            except ValueError:
                number = -1.0
            tol = Tolerance(value=number / 100.0, relative=True)
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            tol = Tolerance(value=float(value), relative=False)
        else:
            tol = Tolerance(value=-1.0, relative=False)
        if not tol.value >= 0.0 or tol.value == float("inf"):
            raise RegressError(f"{where}: [tolerances] {metric}: expected a number >= 0 (metric "
                               f"unit) or a percentage such as '2%'; got {shown(value)}")
        out[metric] = tol
    return out


def suite_from_dict(doc: Mapping[str, Any], *, source: str = "<memory>",
                    base_dir: Path | None = None, default_name: str | None = None) -> SuiteSpec:
    """Parse and check a suite given as a mapping (see the module docstring).

    Parameters
    ----------
    doc :
        The parsed TOML.
    source :
        Name of the suite in messages.
    base_dir :
        Folder relative paths are taken from (default: the current directory).
    default_name :
        Name of a suite without ``name`` (default: the stem of ``source``).

    Raises
    ------
    RegressError
        A missing, unknown or invalid key, or a file that does not exist (the message
        names the key and the bad value).
    """
    where = f"suite {source}"
    _check_keys(doc, _TOP_KEYS, where)
    base = base_dir if base_dir is not None else Path.cwd()
    name = doc.get("name", default_name if default_name is not None else Path(source).stem)
    description = doc.get("description", "")
    for key, value in (("name", name), ("description", description)):
        if not isinstance(value, str) or (key == "name" and not value):
            raise RegressError(f"{where}: expected '{key}' a string; got {shown(value)}")
    seeds = doc.get("seeds", list(DEFAULT_SEEDS))
    if (not isinstance(seeds, list) or not seeds or len(set(seeds)) != len(seeds)
            or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)):
        raise RegressError(f"{where}: expected 'seeds' a list of different integers >= 0; got {shown(seeds)}")
    time_scale = doc.get("time_scale", 1.0)
    if (isinstance(time_scale, bool) or not isinstance(time_scale, (int, float))
            or not 0.0 < time_scale <= 1.0):
        raise RegressError(f"{where}: expected 'time_scale' in (0, 1]; got {shown(time_scale)}")
    metrics = doc.get("metrics", list(DEFAULT_METRICS))
    if (not isinstance(metrics, list) or not metrics
            or not all(isinstance(m, str) and m in METRICS for m in metrics)
            or len(set(metrics)) != len(metrics)):
        raise RegressError(f"{where}: expected 'metrics' a list of different names among "
                           f"{choices(METRICS)}; got {shown(metrics)}")
    return SuiteSpec(
        name=name, description=description, source=source,
        controllers=_controllers(doc.get("controllers"), base, where),
        plants=_plants(doc.get("plants"), where),
        scenarios=_scenarios(doc.get("scenarios"), base, where),
        seeds=tuple(seeds), time_scale=float(time_scale), metrics=tuple(metrics),
        tolerances=_tolerances(doc.get("tolerances", {}), metrics, where))


def parse_suite_text(text: str, *, source: str, base_dir: Path,
                     default_name: str | None = None) -> SuiteSpec:
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


def load_suite(path: str | Path) -> SuiteSpec:
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


__all__ = [
    "CONTROLLER_KINDS",
    "COUNT_METRICS",
    "DEFAULT_METRICS",
    "DEFAULT_SEEDS",
    "METRICS",
    "PLANT_KINDS",
    "CaseSpec",
    "ControllerEntry",
    "RegressError",
    "SuiteSpec",
    "Tolerance",
    "load_suite",
    "parse_suite_text",
    "suite_from_dict",
]
