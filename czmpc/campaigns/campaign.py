"""Campaigns: a TOML spec of controllers x plants x scenarios x seeds, expanded to runs.

The one spec parser: a regression suite (`czmpc.campaigns.regression`) is a campaign
spec plus the metrics it holds and their tolerances. A *run* (`RunSpec`) is a pure
function of its spec: `execute_run` builds the plant and the controller inside the
calling process (`czmpc.campaigns.build`, so OSQP/CasADi objects never cross a process
boundary), runs the closed loop and returns one row (`ROW_COLUMNS`). A keyed seed comes
from `numpy.random.SeedSequence` keyed by the run's identity (`run_seed`), never by its
position or by the worker that ran it, so every executor gives the same rows.

Spec (TOML)::

    name = "smoke"                   # default: the file's stem
    description = "..."              # optional
    model = "cz_heater_model.json"   # shipped name or path (relative to the spec file)
    linear_model = "cz_heater_armax_model.json"   # model of "linear_mpc"
    seeds = 2                        # seeds keyed by the run, indices 0..seeds-1; or a list of
                                     # seeds used as they are, e.g. [7]
    base_seed = 2026                 # entropy of the keyed seeds
    noise = true                     # plant noise on (and as each scenario says)
    time_scale = 0.1                 # optional: Scenario.shortened(time_scale)
    scenarios = ["staircase", "recipes/recipe_a.toml"]   # shipped names or .toml paths
    metrics = ["iae_kw_s"]           # a regression suite's held metrics (`METRIC_COLUMNS`)
    [tolerances]                     # a suite's tolerances: absolute, or "2%" of the value
    iae_kw_s = 0.5

    [[controllers]]
    name = "mpc"                     # default: the kind
    kind = "mpc"                     # mpc, nmpc, linear_mpc, pi_gs, pi, pi_table, open_loop,
                                     # c_step (or preset = "pi-scheduled", "linear-mpc", ...)
    # settings = "file.toml"         # MPC settings file (`czmpc.settings_file`)
    # model = "puller7.json"         # this controller's model (and its plants'), default: model
    # linear_model = "armax.json"    # linear_mpc only
    [[controllers]]
    kind = "c_step"                  # the MPC step as C, built on demand with the system's
    directory = "step/"              # C compiler; written by 'czmpc codegen' (relative to the
                                     # spec); its model.json and settings.toml are the
                                     # controller's model (and its plants') and settings

    [[plants]]
    kind = "model"                   # "model", "heater", "thermal", "perturbed" or "sampled"
    [[plants]]
    kind = "perturbed"               # the Cartesian product of the three lists
    gain_factors = [0.8, 1.0, 1.2]
    time_constant_factors = [1.0]
    extra_delays_steps = [0, 1]
    [[plants]]
    kind = "sampled"                 # n plants drawn from the model's parameter
    n = 200                          # covariance (`czmpc.campaigns.sampling`)
    # first = 0                      # numbers first .. first+n-1 (extend a study later)

The plants of a controller are built from that controller's model. Besides
`czmpc.campaigns.measure.metric_row` every row has the robustness measures of
`czmpc.campaigns.measure.reachable_row`. Row columns whose values depend on the machine
(`TIMING_COLUMNS`) differ between executions; every other column is identical bit for
bit whatever the executor (`DETERMINISTIC_COLUMNS`).
"""

from __future__ import annotations

import functools
import math
import os
import time
import tomllib
import traceback
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from czmpc.campaigns.build import CONTROLLERS, PRESET_ALIASES
from czmpc.campaigns.measure import METRIC_COLUMNS, REACHABLE_COLUMNS, TIMING_COLUMNS
from czmpc.config_text import choices, shown
from czmpc.errors import CzmpcError
from sysid.atomic import file_sha256

PlantKindName = Literal["model", "heater", "thermal", "perturbed", "sampled"]
PLANT_KINDS: tuple[str, ...] = ("model", "heater", "thermal", "perturbed", "sampled")
#: Controller kinds and their campaign spellings.
PRESETS: tuple[str, ...] = (*CONTROLLERS, *PRESET_ALIASES)
#: Columns that identify a run.
KEY_COLUMNS: tuple[str, ...] = (
    "run_id", "controller", "kind", "plant", "gain_factor", "time_constant_factor",
    "extra_delay_steps", "scenario", "seed_index", "seed", "sample_index")
#: Columns of what a run gave, a pure function of the run.
RESULT_COLUMNS: tuple[str, ...] = (
    "status", "error", *METRIC_COLUMNS, "n_rejected_draws", "plant_parameter_source",
    "plant_static_gain_kw_per_pct", *REACHABLE_COLUMNS)
ROW_COLUMNS: tuple[str, ...] = KEY_COLUMNS + RESULT_COLUMNS + TIMING_COLUMNS
DETERMINISTIC_COLUMNS: tuple[str, ...] = KEY_COLUMNS + RESULT_COLUMNS
_TOP_KEYS = ("name", "description", "model", "linear_model", "seeds", "base_seed", "noise",
             "time_scale", "scenarios", "controllers", "plants", "metrics", "tolerances")


class CampaignError(CzmpcError, ValueError):
    """A campaign spec that cannot be run as written."""


@dataclass(frozen=True, kw_only=True)
class ControllerSpec:
    """One controller: a kind, named in the rows by ``name``, with its files.

    Parameters
    ----------
    name :
        Its name in the rows.
    kind :
        A key of `czmpc.campaigns.build.CONTROLLERS`.
    model_path, linear_model_path :
        Its Hammerstein model (also the model of its plants) and the linear model of
        ``linear_mpc``.
    settings_path, settings_sha256 :
        A settings file applied to each model's defaults and its SHA-256 when the spec
        was read (a resumed campaign whose settings changed is another spec); "" for the
        defaults.

    A ``c_step``'s model and settings are the ``model.json`` and ``settings.toml`` of its
    directory (`directory`).
    """

    name: str
    kind: str
    model_path: str
    linear_model_path: str
    settings_path: str = ""
    settings_sha256: str = ""

    @property
    def directory(self) -> str:
        """The directory 'czmpc codegen' wrote of a ``c_step`` (that of its model); "" else."""
        return str(Path(self.model_path).parent) if self.kind == "c_step" else ""

    def c_step_files(self) -> dict[str, str]:
        """Role -> path of a ``c_step``'s generated C the runs compile (empty for other kinds):
        ``c_step`` (the step) and ``c_constants`` (the model's and settings' numbers)."""
        if self.kind != "c_step":
            return {}
        return {"c_step": str(Path(self.directory) / "czmpc_step.c"),
                "c_constants": str(Path(self.directory) / "czmpc_model.h")}


@dataclass(frozen=True, kw_only=True)
class PlantSpec:
    """One plant: the model itself, the virtual heater, the model perturbed or sampled.

    Parameters
    ----------
    kind :
        ``"model"``, ``"heater"``, ``"thermal"``, ``"perturbed"`` or ``"sampled"``.
    gain_factor, time_constant_factor, extra_delay_steps :
        Perturbation of a ``"perturbed"`` plant (`sim.perturbed.perturb_model`);
        1, 1, 0 otherwise.
    sample_index :
        Number k of a ``"sampled"`` plant (`czmpc.campaigns.sampling.sample_plant`);
        -1 otherwise.
    """

    kind: PlantKindName
    gain_factor: float = 1.0
    time_constant_factor: float = 1.0
    extra_delay_steps: int = 0
    sample_index: int = -1

    @property
    def label(self) -> str:
        """Name of the plant in the rows, e.g. ``"perturbed g0.8 m1 d+1"``, ``"sampled 17"``."""
        if self.kind == "sampled":
            return f"sampled {self.sample_index}"
        if self.kind != "perturbed":
            return self.kind
        return (f"perturbed g{self.gain_factor:g} m{self.time_constant_factor:g} "
                f"d+{self.extra_delay_steps}")


@dataclass(frozen=True, kw_only=True)
class Tolerance:
    """A tolerance a suite sets for one metric.

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
class RunSpec:
    """Everything one run depends on (picklable; the run is a pure function of it).

    ``seed`` is the run's seed, or None for one keyed by ``base_seed`` (`run_seed`);
    ``tight`` and ``mutation`` are a regression suite's reference re-run and audit
    (`czmpc.campaigns.build.build_controller`).
    """

    run_id: str
    controller: ControllerSpec
    plant: PlantSpec
    scenario: str
    seed_index: int
    seed: int | None
    base_seed: int
    noise: bool
    time_scale: float
    tight: bool = False
    mutation: str | None = None

    @property
    def case_id(self) -> str:
        """The run as a regression case: ``<controller>/<plant>/<scenario>/s<seed>``."""
        return f"{self.controller.name}/{self.plant.label}/{Path(self.scenario).stem}/s{run_seed(self)}"


@dataclass(frozen=True, kw_only=True)
class CampaignSpec:
    """A parsed campaign spec (see the module docstring for the TOML keys).

    Parameters
    ----------
    name, description :
        Names of the campaign.
    source :
        The spec file, or ``"<memory>"``.
    model_path, linear_model_path :
        The spec's models (``model``, ``linear_model``): those of every controller that
        names none.
    controllers, plants, scenarios :
        The axes; scenarios are shipped names or resolved paths.
    seeds :
        Seeds keyed by the run (their number) or the seeds themselves (a tuple).
    base_seed :
        Entropy of keyed seeds, >= 0.
    noise :
        Plant noise on or off.
    time_scale :
        ``Scenario.shortened`` factor in (0, 1]; 1 runs the scenarios as written.
    metrics, tolerances :
        A regression suite's held metrics (empty: not given) and tolerances.
    warnings :
        What the user must know about how the spec runs (e.g. sampled plants falling
        back to standard errors); the CLI prints them.
    """

    name: str
    description: str = ""
    source: str
    model_path: str
    linear_model_path: str
    controllers: tuple[ControllerSpec, ...]
    plants: tuple[PlantSpec, ...]
    scenarios: tuple[str, ...]
    seeds: int | tuple[int, ...]
    base_seed: int
    noise: bool
    time_scale: float
    metrics: tuple[str, ...] = ()
    tolerances: Mapping[str, Tolerance] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    def expand(self) -> tuple[RunSpec, ...]:
        """All runs: controllers x plants x scenarios x seeds, in that nesting."""
        seeds: Sequence[int | None] = ([None] * self.seeds if isinstance(self.seeds, int)
                                       else self.seeds)
        return tuple(
            RunSpec(run_id=f"{c.name}|{p.label}|{Path(s).stem}|{k}", controller=c, plant=p,
                    scenario=s, seed_index=k, seed=seed, base_seed=self.base_seed,
                    noise=self.noise, time_scale=self.time_scale)
            for c in self.controllers for p in self.plants for s in self.scenarios
            for k, seed in enumerate(seeds))

    def input_files(self) -> tuple[str, ...]:
        """Every file the runs read (not shipped scenario names): models, settings, scenarios."""
        paths: list[str] = []
        for c in self.controllers:
            paths.append(c.model_path)
            if c.kind == "linear_mpc":
                paths.append(c.linear_model_path)
            if c.settings_path:
                paths.append(c.settings_path)
            paths += c.c_step_files().values()
        paths += [s for s in self.scenarios if s.endswith(".toml")]
        return tuple(dict.fromkeys(paths))


# --- spec parsing ---------------------------------------------------------------------------
def _check_keys(table: Mapping[str, Any], allowed: Sequence[str], where: str) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise CampaignError(f"{where}: unknown key(s) {unknown}; expected some of {sorted(allowed)}")


def _file(value: object, key: str, base: Path, where: str, *, shipped_ok: bool) -> str:
    """Absolute path of a file named in the spec (or of a shipped data file)."""
    from czmpc.shipped import shipped_path

    if not isinstance(value, str) or not value:
        raise CampaignError(f"{where}: expected '{key}' a file name; got {shown(value)}")
    candidate = Path(value) if Path(value).is_absolute() else base / value
    if candidate.is_file():
        return str(candidate.resolve())
    if shipped_ok:
        try:
            return str(shipped_path(value))
        except FileNotFoundError:
            pass
    raise CampaignError(f"{where}: '{key} = {shown(value)}': no such file ({candidate})"
                        + (" and no shipped file of that name" if shipped_ok else ""))


def _number_list(table: Mapping[str, Any], key: str, where: str) -> list[float]:
    values = table.get(key, [0] if key == "extra_delays_steps" else [1.0])
    if (not isinstance(values, list) or not values
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)):
        raise CampaignError(f"{where}: expected '{key}' a non-empty list of numbers; got {shown(values)}")
    return [float(v) for v in values]


def _plants(doc: Any, where: str) -> tuple[PlantSpec, ...]:
    if not isinstance(doc, list) or not doc or not all(isinstance(t, dict) for t in doc):
        raise CampaignError(f"{where}: expected at least one [[plants]] table")
    out: list[PlantSpec] = []
    for i, table in enumerate(doc, start=1):
        here = f"{where} [[plants]] #{i}"
        kind = table.get("kind")
        if kind not in PLANT_KINDS:
            raise CampaignError(f"{here}: expected kind one of {choices(PLANT_KINDS)}; got {shown(kind)}")
        if kind == "sampled":
            _check_keys(table, ["kind", "n", "first"], here)
            n, first = table.get("n"), table.get("first", 0)
            for key, value, low in (("n", n, 1), ("first", first, 0)):
                if isinstance(value, bool) or not isinstance(value, int) or value < low:
                    raise CampaignError(f"{here}: expected '{key}' an integer >= {low}; got {shown(value)}")
            out += [PlantSpec(kind="sampled", sample_index=k) for k in range(first, first + n)]
        elif kind == "perturbed":
            _check_keys(table, ["kind", "gain_factors", "time_constant_factors",
                                "extra_delays_steps"], here)
            gains, taus, delays = (_number_list(table, key, here) for key in (
                "gain_factors", "time_constant_factors", "extra_delays_steps"))
            if not all(v > 0 for v in gains + taus) or not all(d >= 0 and d == int(d) for d in delays):
                raise CampaignError(f"{here}: expected factors > 0 and whole delays >= 0; got gains "
                                    f"{gains}, time constants {taus}, delays {delays}")
            out += [PlantSpec(kind="perturbed", gain_factor=g, time_constant_factor=m,
                              extra_delay_steps=int(d)) for d in delays for m in taus for g in gains]
        else:
            _check_keys(table, ["kind"], here)
            out.append(PlantSpec(kind=kind))
    labels = [p.label for p in out]
    if len(set(labels)) != len(labels):
        raise CampaignError(f"{where}: plants must differ; got {labels}")
    return tuple(out)


def _controllers(doc: Any, base: Path, where: str, model: str, linear: str
                 ) -> tuple[ControllerSpec, ...]:
    from czmpc.errors import SettingsError
    from czmpc.settings_file import load_settings
    from sysid.errors import SysidError

    if not isinstance(doc, list) or not doc or not all(isinstance(t, dict) for t in doc):
        raise CampaignError(f"{where}: expected at least one [[controllers]] table")
    out: list[ControllerSpec] = []
    for i, table in enumerate(doc, start=1):
        here = f"{where} [[controllers]] #{i}"
        _check_keys(table, ["name", "kind", "preset", "model", "settings", "linear_model",
                            "directory"], here)
        written = table.get("kind", table.get("preset", "mpc"))
        kind = PRESET_ALIASES.get(written, written) if isinstance(written, str) else written
        if kind not in CONTROLLERS:
            raise CampaignError(f"{here}: expected kind one of {choices(PRESETS)}; got {shown(written)}")
        name = table.get("name", written)
        if not isinstance(name, str) or not name or "/" in name or "|" in name:
            raise CampaignError(f"{here}: expected a non-empty name without '/' or '|'; got {shown(name)}")
        if "linear_model" in table and kind != "linear_mpc":
            raise CampaignError(f"{here}: 'linear_model' is for kind 'linear_mpc' only; "
                                f"got kind {shown(kind)}")
        if "directory" in table and kind != "c_step":
            raise CampaignError(f"{here}: 'directory' is for kind 'c_step' only; "
                                f"got kind {shown(kind)}")
        if kind == "c_step":
            out.append(_c_step_controller(table, name, base, here, linear))
            continue
        model_path = (_file(table["model"], "model", base, here, shipped_ok=True)
                      if "model" in table else model)
        linear_path = (_file(table["linear_model"], "linear_model", base, here, shipped_ok=True)
                       if "linear_model" in table else linear)
        settings, digest = "", ""
        if "settings" in table:
            text = table["settings"]
            if not isinstance(text, str) or not text:
                raise CampaignError(f"{here}: expected 'settings' a file name; got {shown(text)}")
            settings = str((Path(text) if Path(text).is_absolute() else base / text).resolve())
            try:
                load_settings(settings, load_model_cached(model_path))
            except (SettingsError, SysidError, OSError) as exc:
                raise CampaignError(f"{here}: settings: {exc}") from None
            digest = file_sha256(settings)
        out.append(ControllerSpec(name=name, kind=kind, model_path=model_path,
                                  linear_model_path=linear_path, settings_path=settings,
                                  settings_sha256=digest))
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise CampaignError(f"{where}: controller names must differ; got {names}")
    return tuple(out)


def _c_step_controller(table: Mapping[str, Any], name: str, base: Path, here: str,
                       linear: str) -> ControllerSpec:
    """A ``kind = "c_step"`` table: its directory, whose model and settings it runs."""
    from czmpc.codegen.errors import CodegenError
    from czmpc.codegen.generate import MODEL_FILE, SETTINGS_FILE, read_sources
    from czmpc.errors import SettingsError
    from sysid.errors import SysidError

    given = [key for key in ("model", "settings") if key in table]
    if given:
        raise CampaignError(f"{here}: a c_step runs the model and settings it was generated "
                            f"from ({MODEL_FILE} and {SETTINGS_FILE} in its directory); drop "
                            f"{' and '.join(repr(k) for k in given)}")
    text = table.get("directory")
    if not isinstance(text, str) or not text:
        raise CampaignError(f"{here}: expected 'directory' the directory 'czmpc codegen' wrote "
                            f"(relative to the spec); got {shown(text)}")
    folder = (Path(text) if Path(text).is_absolute() else base / text).resolve()
    if not folder.is_dir():
        raise CampaignError(f"{here}: directory = {shown(text)}: no such directory ({folder}); "
                            f"write one with 'czmpc codegen MODEL.json --out {folder}'")
    try:
        read_sources(folder)
    except (CodegenError, SettingsError, SysidError, OSError) as exc:
        raise CampaignError(f"{here}: directory: {exc}") from None
    settings = str(folder / SETTINGS_FILE)
    return ControllerSpec(name=name, kind="c_step", model_path=str(folder / MODEL_FILE),
                          linear_model_path=linear, settings_path=settings,
                          settings_sha256=file_sha256(settings))


def build_c_steps(spec: CampaignSpec) -> None:
    """Build every ``c_step`` directory of ``spec`` once, before its runs (a missing compiler
    is then one clear error, not one per run; the runs build on demand all the same).

    Raises
    ------
    czmpc.codegen.BuildError
        No C compiler or make, or a failed build.
    """
    from czmpc.campaigns.build import build_c_step

    for directory in dict.fromkeys(c.directory for c in spec.controllers if c.kind == "c_step"):
        build_c_step(Path(directory))


def _scenarios(doc: object, base: Path, where: str) -> tuple[str, ...]:
    from sim.errors import SimError
    from sim.scenario import list_scenarios, load_scenario

    if not isinstance(doc, list) or not doc or not all(isinstance(s, str) for s in doc):
        raise CampaignError(f"{where}: expected 'scenarios' a non-empty list of shipped names or "
                            f".toml files; got {shown(doc)}")
    out = []
    for name in doc:
        if name.endswith(".toml"):
            resolved = _file(name, "scenarios", base, where, shipped_ok=False)
        elif name in list_scenarios():
            resolved = name
        else:
            raise CampaignError(f"{where}: scenario {shown(name)} is not shipped (shipped: "
                                f"{', '.join(list_scenarios())}) and not a .toml file")
        try:
            load_scenario(resolved)
        except (SimError, OSError) as exc:
            raise CampaignError(f"{where}: scenario {shown(name)}: {exc}") from None
        out.append(resolved)
    stems = [Path(s).stem for s in out]
    if len(set(stems)) != len(stems):
        raise CampaignError(f"{where}: scenario names (file stems) must differ; got {stems}")
    return tuple(out)


def _seeds(value: object, where: str) -> int | tuple[int, ...]:
    def whole(v: object, low: int) -> bool:
        return isinstance(v, int) and not isinstance(v, bool) and v >= low

    if isinstance(value, int) and whole(value, 1):
        return value
    if (isinstance(value, list) and value and len(set(value)) == len(value)
            and all(whole(v, 0) for v in value)):
        return tuple(value)
    raise CampaignError(f"{where}: expected 'seeds' an integer >= 1 (seeds keyed by the run) or "
                        f"a list of different integers >= 0; got {shown(value)}")


def _metrics(doc: Mapping[str, Any], where: str) -> tuple[tuple[str, ...], dict[str, Tolerance]]:
    metrics = doc.get("metrics", [])
    if (not isinstance(metrics, list) or ("metrics" in doc and not metrics)
            or not all(isinstance(m, str) and m in METRIC_COLUMNS for m in metrics)
            or len(set(metrics)) != len(metrics)):
        raise CampaignError(f"{where}: expected 'metrics' a list of different names among "
                            f"{choices(METRIC_COLUMNS)}; got {shown(metrics)}")
    table = doc.get("tolerances", {})
    if not isinstance(table, dict):
        raise CampaignError(f"{where}: expected [tolerances] a table of metric = number or 'N%'; "
                            f"got {shown(table)}")
    tolerances: dict[str, Tolerance] = {}
    for metric, value in table.items():
        if metric not in metrics:
            raise CampaignError(f"{where}: [tolerances] {shown(metric)} is not a held metric; "
                                f"held: {list(metrics)}")
        relative = isinstance(value, str) and value.strip().endswith("%")
        try:
            number = float(value.strip()[:-1]) / 100.0 if relative else (
                -1.0 if isinstance(value, (bool, str)) else float(value))
        except (TypeError, ValueError):
            number = -1.0
        if not 0.0 <= number < math.inf:
            raise CampaignError(f"{where}: [tolerances] {metric}: expected a number >= 0 (metric "
                                f"unit) or a percentage such as '2%'; got {shown(value)}")
        tolerances[metric] = Tolerance(value=number, relative=relative)
    return tuple(metrics), tolerances


def spec_from_dict(doc: Mapping[str, Any], *, source: str = "<memory>",
                   base_dir: Path | None = None, what: str = "campaign spec",
                   default_name: str | None = None) -> CampaignSpec:
    """Parse and check a campaign spec given as a mapping (see the module docstring).

    Parameters
    ----------
    doc :
        The parsed TOML.
    source :
        Name of the spec in messages.
    base_dir :
        Folder relative paths are taken from (default: the current directory).
    what :
        What the spec is called in messages (``"suite"`` for a regression suite).
    default_name :
        Name of a spec without ``name`` (default: the stem of ``source``).

    Raises
    ------
    CampaignError
        A missing, unknown or invalid key, or a file that does not exist (the message
        names the key and the bad value).
    """
    from czmpc.shipped import ARMAX_MODEL_JSON, HAMMERSTEIN_MODEL_JSON

    where = f"{what} {source}"
    _check_keys(doc, _TOP_KEYS, where)
    base = base_dir if base_dir is not None else Path.cwd()
    name = doc.get("name", default_name if default_name is not None else Path(source).stem)
    description = doc.get("description", "")
    for key, value in (("name", name), ("description", description)):
        if not isinstance(value, str) or (key == "name" and not value):
            raise CampaignError(f"{where}: expected '{key}' a string; got {shown(value)}")
    model = _file(doc.get("model", HAMMERSTEIN_MODEL_JSON), "model", base, where, shipped_ok=True)
    linear = _file(doc.get("linear_model", ARMAX_MODEL_JSON), "linear_model", base, where,
                   shipped_ok=True)
    base_seed = doc.get("base_seed", 0)
    if isinstance(base_seed, bool) or not isinstance(base_seed, int) or base_seed < 0:
        raise CampaignError(f"{where}: expected 'base_seed' an integer >= 0; got {shown(base_seed)}")
    time_scale = doc.get("time_scale", 1.0)
    if (isinstance(time_scale, bool) or not isinstance(time_scale, (int, float))
            or not 0.0 < time_scale <= 1.0):
        raise CampaignError(f"{where}: expected 'time_scale' in (0, 1]; got {shown(time_scale)}")
    noise = doc.get("noise", True)
    if not isinstance(noise, bool):
        raise CampaignError(f"{where}: expected 'noise' true or false; got {shown(noise)}")
    metrics, tolerances = _metrics(doc, where)
    controllers = _controllers(doc.get("controllers"), base, where, model, linear)
    plants = _plants(doc.get("plants"), where)
    warnings: list[str] = []
    if any(p.kind == "sampled" for p in plants):
        from czmpc.campaigns.sampling import SamplingError, parameter_distribution
        for path in dict.fromkeys(c.model_path for c in controllers):
            try:
                dist = parameter_distribution(load_model_cached(path))
            except (SamplingError, OSError, ValueError) as exc:
                raise CampaignError(f"{where}: sampled plants of model {path}: {exc}") from None
            if dist.warning:
                warnings.append(f"sampled plants of {Path(path).name}: {dist.warning}")
    return CampaignSpec(
        name=name, description=description, source=source, model_path=model,
        linear_model_path=linear, controllers=controllers,
        plants=plants, scenarios=_scenarios(doc.get("scenarios"), base, where),
        seeds=_seeds(doc.get("seeds", 1), where), base_seed=base_seed, noise=noise,
        time_scale=float(time_scale), metrics=metrics, tolerances=tolerances,
        warnings=tuple(warnings))


def load_spec(path: str | os.PathLike[str], *, samples: int | None = None,
              time_scale: float | None = None,
              controllers: Sequence[str] | None = None) -> CampaignSpec:
    """Read a campaign spec TOML file (relative paths in it are taken from its folder).

    Parameters
    ----------
    path :
        The spec file.
    samples :
        Override ``n`` of every ``kind = "sampled"`` plant table (a smaller or larger
        Monte Carlo from the same spec).
    time_scale :
        Override ``time_scale``.
    controllers :
        Keep only the controllers of these names (in the spec's order).

    Raises
    ------
    CampaignError
        Unreadable file, bad TOML, an invalid spec, or an override naming no controller
        of the spec / a spec without sampled plants.
    """
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CampaignError(f"campaign spec {p}: cannot read it: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise CampaignError(f"campaign spec {p}: not valid TOML: {exc}") from None
    if samples is not None:
        tables = [t for t in doc.get("plants", []) if isinstance(t, dict) and t.get("kind") == "sampled"]
        if not tables:
            raise CampaignError(f"campaign spec {p}: --samples {samples} given, but the spec has "
                                "no [[plants]] kind = \"sampled\"")
        for t in tables:
            t["n"] = samples
    if time_scale is not None:
        doc["time_scale"] = time_scale
    if controllers is not None:
        tables = doc.get("controllers", [])
        names = [t.get("name", t.get("kind", t.get("preset", "mpc"))) for t in tables
                 if isinstance(t, dict)]
        missing = [c for c in controllers if c not in names]
        if missing:
            raise CampaignError(f"campaign spec {p}: no controller named {missing}; the spec "
                                f"has {names}")
        doc["controllers"] = [t for t, n in zip(tables, names, strict=True) if n in controllers]
    return spec_from_dict(doc, source=str(p), base_dir=p.resolve().parent)


# --- one run --------------------------------------------------------------------------------
def run_seed(run: RunSpec) -> int:
    """The run's seed: its own, or `SeedSequence` of ``base_seed`` keyed by its identity.

    The key is the CRC-32 of the plant, scenario and seed index, so a run gets the same
    seed whatever its position in the campaign or the worker. Controllers compared on
    the same plant, scenario and seed index share a seed (the same noise), since the
    controller name is left out of the key.
    """
    if run.seed is not None:
        return run.seed
    key = f"{run.plant.label}|{Path(run.scenario).stem}|{run.seed_index}"
    seq = np.random.SeedSequence(run.base_seed, spawn_key=(zlib.crc32(key.encode("utf-8")),))
    return int(seq.generate_state(1, dtype=np.uint32)[0])


def load_model_cached(path: str) -> Any:
    """`sysid.modelfile.load_model`, cached by the file's content (a changed file is re-read)."""
    return _model(path, file_sha256(path))


@functools.lru_cache(maxsize=8)
def _model(path: str, sha256: str) -> Any:
    from sysid.modelfile import load_model
    return load_model(path)


@functools.lru_cache(maxsize=32)
def _scenario(name: str, time_scale: float, sha256: str) -> Any:
    from sim.scenario import load_scenario
    scenario = load_scenario(name)
    return scenario if time_scale == 1.0 else scenario.shortened(time_scale)


def run_scenario(run: RunSpec) -> Any:
    """The run's scenario (shortened by its time scale)."""
    return _scenario(run.scenario, run.time_scale,
                     file_sha256(run.scenario) if run.scenario.endswith(".toml") else "")


@functools.lru_cache(maxsize=8)
def _settings_doc(path: str, sha256: str) -> dict[str, Any] | None:
    """The parsed settings file of a controller (None: the defaults)."""
    if not path:
        return None
    from czmpc.settings_file import load_settings_doc
    return load_settings_doc(path)


@functools.lru_cache(maxsize=4)
def _sampled(path: str, sha256: str, base_seed: int, sample_index: int) -> Any:
    from czmpc.campaigns.sampling import sample_plant
    return sample_plant(_model(path, sha256), base_seed, sample_index)


def _plant_model(run: RunSpec, model: Any) -> tuple[Any, int, str]:
    """A model plant's model, the draws rejected to get it, and where its parameters came
    from ("" for plants not sampled)."""
    from sim.perturbed import perturb_model

    if run.plant.kind == "sampled":
        path = run.controller.model_path
        drawn = _sampled(path, file_sha256(path), run.base_seed, run.plant.sample_index)
        return drawn.model, drawn.n_rejected, drawn.source
    if run.plant.kind == "perturbed":
        return perturb_model(model, gain_factor=run.plant.gain_factor,
                             time_constant_factor=run.plant.time_constant_factor,
                             extra_delay_steps=run.plant.extra_delay_steps), 0, ""
    return model, 0, ""


@dataclass(frozen=True, eq=False, kw_only=True)
class SimulatedRun:
    """A finished closed loop and what measuring it against its plant needs.

    Parameters
    ----------
    result :
        The `sim.loop.ClosedLoopResult`.
    power_at :
        The plant's steady-state power [kW] at an input [%].
    allowed_triac_range_pct, max_move_pct_per_step :
        The Hammerstein MPC's allowed input range [%] and rate limit [%/sample], which
        every controller gets.
    n_rejected_draws, plant_parameter_source, plant_static_gain_kw_per_pct :
        Of a sampled plant (0, "" otherwise; the gain NaN for the heater).
    """

    result: Any
    power_at: Any
    allowed_triac_range_pct: tuple[float, float]
    max_move_pct_per_step: float | None
    n_rejected_draws: int
    plant_parameter_source: str
    plant_static_gain_kw_per_pct: float


def simulate_run(run: RunSpec) -> SimulatedRun:
    """Build the run's plant and controller (`czmpc.campaigns.build`) and run the loop.

    Raises
    ------
    czmpc.campaigns.build.MutationNotApplicable
        The run's mutation does not change its controller.
    """
    from czmpc.campaigns.build import build_controller, build_plant, controller_settings
    from czmpc.campaigns.sampling import static_gain_kw_per_pct
    from czmpc.inversion import allowed_triac_range
    from czmpc.settings import MPCSettings
    from czmpc.settings_file import settings_from_dict
    from sim.loop import run_closed_loop

    c = run.controller
    model = load_model_cached(c.model_path)
    scenario = run_scenario(run)
    plant_model, n_rejected, source = _plant_model(run, model)
    plant, s0, power_at = build_plant(run.plant.kind, plant_model, scenario,
                                      noise=run.noise and scenario.plant_noise)
    doc = _settings_doc(c.settings_path, c.settings_sha256)
    controller = build_controller(
        c.kind, model, scenario, initial_triac_pct=s0, settings_doc=doc, tight=run.tight,
        linear_model=load_model_cached(c.linear_model_path) if c.kind == "linear_mpc" else None,
        mutation=run.mutation, c_step_directory=c.directory or None)
    result = run_closed_loop(plant, controller, scenario, rng=run_seed(run))
    base = MPCSettings.default_for(model) if doc is None else settings_from_dict(doc, model)
    used = controller_settings(model, scenario, initial_triac_pct=s0, settings=base)
    allowed = allowed_triac_range(model, triac_min_pct=used.triac_min_pct,
                                  triac_max_pct=used.triac_max_pct,
                                  validity_margin_pct=used.validity_margin_pct)
    gain = (math.nan if run.plant.kind in ("heater", "thermal") else float(
        static_gain_kw_per_pct(plant_model, np.array(model.operating_point.triac_pct))))
    return SimulatedRun(result=result, power_at=power_at,
                        allowed_triac_range_pct=(float(allowed[0]), float(allowed[1])),
                        max_move_pct_per_step=used.max_move_pct_per_step,
                        n_rejected_draws=n_rejected, plant_parameter_source=source,
                        plant_static_gain_kw_per_pct=gain)


def error_text(exc: BaseException) -> str:
    """An exception's type, message and the place it was raised (a crashed run's ``error``)."""
    last = traceback.extract_tb(exc.__traceback__)[-1:]
    where = f" at {Path(last[0].filename).name}:{last[0].lineno}" if last else ""
    return f"{type(exc).__name__}: {exc}{where}"


def execute_run(run: RunSpec) -> dict[str, Any]:
    """Run one campaign run and return its row (`ROW_COLUMNS`).

    A run that raises is recorded, not propagated: ``status = "error"`` and ``error``
    holds the exception's type, message and place; the numbers are NaN, the counts -1.
    """
    from czmpc.campaigns.measure import COUNT_COLUMNS, metric_row, reachable_row

    row: dict[str, Any] = {
        "run_id": run.run_id, "controller": run.controller.name, "kind": run.controller.kind,
        "plant": run.plant.label, "gain_factor": run.plant.gain_factor,
        "time_constant_factor": run.plant.time_constant_factor,
        "extra_delay_steps": run.plant.extra_delay_steps, "scenario": Path(run.scenario).stem,
        "seed_index": run.seed_index, "seed": run_seed(run), "sample_index": run.plant.sample_index,
    }
    t0 = time.perf_counter()
    try:
        sim = simulate_run(run)
        row.update(status="ok", error="", **metric_row(sim.result),
                   n_rejected_draws=sim.n_rejected_draws,
                   plant_parameter_source=sim.plant_parameter_source,
                   plant_static_gain_kw_per_pct=sim.plant_static_gain_kw_per_pct,
                   **reachable_row(sim.result, run_scenario(run), sim.power_at,
                                   sim.allowed_triac_range_pct, sim.max_move_pct_per_step))
    except Exception as exc:  # noqa: BLE001 - a crashed run is a result of the campaign
        row.update({k: -1 if k in COUNT_COLUMNS or k == "n_rejected_draws" else math.nan
                    for k in (*METRIC_COLUMNS, *REACHABLE_COLUMNS, *TIMING_COLUMNS,
                              "n_rejected_draws", "plant_static_gain_kw_per_pct")})
        row.update(status="error", error=error_text(exc), plant_parameter_source="",
                   offset_free=False)
    row["wall_time_s"] = time.perf_counter() - t0
    return row


__all__ = ["DETERMINISTIC_COLUMNS", "KEY_COLUMNS", "PLANT_KINDS", "PRESETS", "RESULT_COLUMNS", "ROW_COLUMNS",
           "CampaignError", "CampaignSpec", "ControllerSpec", "PlantSpec", "RunSpec", "SimulatedRun",
           "Tolerance", "build_c_steps", "error_text", "execute_run", "load_model_cached", "load_spec",
           "run_scenario", "run_seed", "simulate_run", "spec_from_dict"]
