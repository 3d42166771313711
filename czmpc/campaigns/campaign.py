"""Campaigns: a TOML spec of controllers x plants x scenarios x seeds, expanded to runs.

A *run* (`RunSpec`) is a pure function of its spec: `execute_run` builds the plant and
the controller inside the calling process (so OSQP/CasADi objects never cross a process
boundary), runs the closed loop and returns one row of metrics (`ROW_COLUMNS`). Its seed
comes from `numpy.random.SeedSequence` keyed by the run's identity (`run_seed`), never by
its position or by the worker that ran it, so every executor gives the same rows.

Spec (TOML)::

    name = "smoke"
    model = "cz_heater_model.json"   # shipped name or path (relative to the spec file)
    seeds = 2                        # seed indices 0..seeds-1 per (controller, plant, scenario)
    base_seed = 2026                 # entropy of every run's SeedSequence
    noise = true                     # plant noise on
    time_scale = 0.1                 # optional: Scenario.shortened(time_scale)
    scenarios = ["staircase", "voltage_sag"]   # shipped names or TOML paths

    # seed = 7                       # optional: this one seed for every run (as `czmpc
                                     # bench` and `czmpc robustness` run), not keyed
    # linear_model = "cz_heater_armax_model.json"   # model of the "linear-mpc" preset

    [[controllers]]
    name = "mpc"
    preset = "mpc"                   # "mpc", "pi", "pi-scheduled", "pi-table", "linear-mpc",
                                     # "nmpc", "open-loop" (as `czmpc bench` builds them)
    # settings = "file.toml"         # optional MPC settings file (`czmpc.settings_file`,
                                     # as `czmpc bench --settings`); preset default "mpc"

    [[plants]]
    kind = "model"                   # "model", "heater" or "perturbed"
    [[plants]]
    kind = "perturbed"               # the Cartesian product of the three lists
    gain_factors = [0.8, 1.0, 1.2]
    time_constant_factors = [1.0]
    extra_delays_steps = [0, 1]
    [[plants]]
    kind = "sampled"                 # n plants drawn from the model's parameter
    n = 200                          # covariance (`czmpc.campaigns.sampling`)
    # first = 0                      # numbers first .. first+n-1 (extend a study later)

Presets: ``mpc`` is `OffsetFreeMPC` on the campaign's model; ``pi`` / ``pi-scheduled``
the `PIController` tuned on it; ``pi-table`` the PI schedule `czmpc.pid` tunes on it
(``czmpc tune-pid --ms 1.4``: bench's ``pi_table``); ``linear-mpc`` the `OffsetFreeMPC` on the linear ARMAX
model ``linear_model`` (no static nonlinearity: the linear MPC of `czmpc bench`),
``nmpc`` the CasADi/IPOPT NMPC and ``open-loop`` the steady-state inversion. Every
preset is built as `czmpc.campaigns.bench.build_controller` builds it: every controller
gets the Hammerstein MPC's allowed input range (the identified range widened by the
validity margin, inside the scenario's limits), the scenario's rate limit and the
plant's start input, so a comparison is fair.

Besides the metrics of `sim.metrics.compute_metrics` (errors against the setpoint over
the whole run), every row has the robustness campaign's measures
(`czmpc.campaigns.robustness`): errors against the *reachable setpoint* (the setpoint
clipped to the powers that plant holds inside the controllers' allowed input range)
over the setpoint-change segments, ``offset_free`` (every change ends with |mean
measured error over the last quarter of its segment| < `OFFSET_FREE_THRESHOLD_KW`),
the number of unreachable changes and the samples outside the allowed range or rate
limit.

Row columns whose values depend on the machine (``wall_time_s`` and the controller step
times, `TIMING_COLUMNS`) differ between executions; every other column is identical bit
for bit whatever the executor (`DETERMINISTIC_COLUMNS`).
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
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from czmpc.config_text import choices, shown
from czmpc.errors import CzmpcError

PresetName = Literal["mpc", "pi", "pi-scheduled", "pi-table", "linear-mpc", "nmpc", "open-loop"]
PRESETS: tuple[str, ...] = ("mpc", "pi", "pi-scheduled", "pi-table", "linear-mpc", "nmpc",
                            "open-loop")
#: Preset -> the name `czmpc.campaigns.bench.build_controller` builds it by.
_BENCH_NAMES = {"mpc": "mpc", "pi": "pi", "pi-scheduled": "pi_gs", "pi-table": "pi_table",
                "linear-mpc": "linear_mpc",
                "nmpc": "nmpc", "open-loop": "open_loop"}
PlantKindName = Literal["model", "heater", "perturbed", "sampled"]
PLANT_KINDS: tuple[str, ...] = ("model", "heater", "perturbed", "sampled")
#: Offset-free threshold on |steady-state error| [kW]: the robustness campaign's.
OFFSET_FREE_THRESHOLD_KW = 0.05

#: Columns of machine-dependent timings (excluded from the bit-for-bit comparison).
TIMING_COLUMNS: tuple[str, ...] = (
    "wall_time_s", "step_time_median_ms", "step_time_p95_ms", "step_time_max_ms")
#: Columns that identify a run.
KEY_COLUMNS: tuple[str, ...] = (
    "run_id", "controller", "preset", "plant", "gain_factor", "time_constant_factor",
    "extra_delay_steps", "scenario", "seed_index", "seed", "sample_index")
#: Columns of metrics that are a pure function of the run.
METRIC_COLUMNS: tuple[str, ...] = (
    "status", "error", "n_steps", "iae_kw_s", "ise_kw2_s", "max_overshoot_kw",
    "max_abs_steady_state_error_kw", "input_total_variation_pct", "n_limit_violations",
    "n_rate_violations", "n_fallbacks", "n_rejected_draws", "plant_parameter_source",
    "plant_static_gain_kw_per_pct", "offset_free", "max_abs_steady_state_error_reachable_kw",
    "n_unreachable_changes", "iae_changes_reachable_kw_s", "max_overshoot_reachable_kw",
    "max_overshoot_reachable_pct", "n_allowed_range_violations")
ROW_COLUMNS: tuple[str, ...] = KEY_COLUMNS + METRIC_COLUMNS + TIMING_COLUMNS
DETERMINISTIC_COLUMNS: tuple[str, ...] = KEY_COLUMNS + METRIC_COLUMNS


class CampaignError(CzmpcError, ValueError):
    """A campaign spec that cannot be run as written."""


@dataclass(frozen=True, kw_only=True)
class ControllerSpec:
    """One controller of a campaign: a preset, named in the rows by ``name``.

    Parameters
    ----------
    name :
        Its name in the rows.
    preset :
        One of `PRESETS`.
    settings_path :
        A settings file (`czmpc.settings_file`) applied to each model's defaults, as
        ``czmpc bench --settings`` does; "" for the defaults.
    settings_sha256 :
        SHA-256 of that file when the spec was read (so a resumed campaign whose settings
        file changed is refused as another spec); "" without one.
    """

    name: str
    preset: PresetName
    settings_path: str = ""
    settings_sha256: str = ""


@dataclass(frozen=True, kw_only=True)
class PlantSpec:
    """One plant: the model itself, the virtual heater, the model perturbed or sampled.

    Parameters
    ----------
    kind :
        ``"model"``, ``"heater"``, ``"perturbed"`` or ``"sampled"``.
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
class RunSpec:
    """Everything one run depends on (picklable; the run is a pure function of it)."""

    run_id: str
    controller: ControllerSpec
    plant: PlantSpec
    scenario: str
    seed_index: int
    base_seed: int
    model_path: str
    noise: bool
    time_scale: float
    fixed_seed: int | None = None
    linear_model_path: str = ""


@dataclass(frozen=True, kw_only=True)
class CampaignSpec:
    """A parsed campaign spec (see the module docstring for the TOML keys).

    Parameters
    ----------
    name :
        Campaign name.
    source :
        The spec file, or ``"<memory>"``.
    model_path :
        Resolved path of the model every controller (and the model plants) use.
    controllers, plants, scenarios :
        The axes of the campaign; scenarios are shipped names or resolved paths.
    seeds :
        Seeds per (controller, plant, scenario), >= 1.
    base_seed :
        Entropy of every run's `numpy.random.SeedSequence`, >= 0.
    noise :
        Plant noise on or off.
    time_scale :
        ``Scenario.shortened`` factor in (0, 1]; 1 runs the scenarios as written.
    fixed_seed :
        One seed for every run (the ``seed`` key), or None: seeds keyed by the run.
    linear_model_path :
        Resolved path of the ``linear-mpc`` preset's linear model.
    warnings :
        What the user must know about how the spec runs (e.g. sampled plants falling
        back to standard errors); the CLI prints them.
    """

    name: str
    source: str
    model_path: str
    controllers: tuple[ControllerSpec, ...]
    plants: tuple[PlantSpec, ...]
    scenarios: tuple[str, ...]
    seeds: int
    base_seed: int
    noise: bool
    time_scale: float
    fixed_seed: int | None = None
    linear_model_path: str = ""
    warnings: tuple[str, ...] = ()

    def expand(self) -> tuple[RunSpec, ...]:
        """All runs: controllers x plants x scenarios x seed indices, in that nesting."""
        runs = []
        for c in self.controllers:
            for p in self.plants:
                for s in self.scenarios:
                    for k in range(self.seeds):
                        runs.append(RunSpec(
                            run_id=f"{c.name}|{p.label}|{Path(s).stem}|{k}", controller=c,
                            plant=p, scenario=s, seed_index=k, base_seed=self.base_seed,
                            model_path=self.model_path, noise=self.noise,
                            time_scale=self.time_scale, fixed_seed=self.fixed_seed,
                            linear_model_path=self.linear_model_path))
        return tuple(runs)


# --- spec parsing ---------------------------------------------------------------------------
def _check_keys(table: Mapping[str, Any], allowed: Sequence[str], where: str) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise CampaignError(f"{where}: unknown key(s) {unknown}; expected some of {sorted(allowed)}")


def _number_list(table: Mapping[str, Any], key: str, default: list[float], where: str) -> list[float]:
    values = table.get(key, default)
    if (not isinstance(values, list) or not values
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)):
        raise CampaignError(f"{where}: expected '{key}' a non-empty list of numbers; got {shown(values)}")
    return [float(v) for v in values]


def _plants(doc: Any, where: str) -> list[PlantSpec]:
    if not isinstance(doc, list) or not doc:
        raise CampaignError(f"{where}: expected at least one [[plants]] table")
    out: list[PlantSpec] = []
    for i, table in enumerate(doc):
        here = f"{where} [[plants]] #{i + 1}"
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
            continue
        if kind != "perturbed":
            _check_keys(table, ["kind"], here)
            out.append(PlantSpec(kind=kind))
            continue
        out += perturbed_plants(table, here)
    return out


def perturbed_plants(table: Mapping[str, Any], where: str) -> list[PlantSpec]:
    """The grid of a ``kind = "perturbed"`` plant table: one plant per combination.

    Raises
    ------
    CampaignError
        An unknown key, a factor <= 0 or a delay that is not a whole number >= 0.
    """
    _check_keys(table, ["kind", "gain_factors", "time_constant_factors", "extra_delays_steps"],
                where)
    gains = _number_list(table, "gain_factors", [1.0], where)
    taus = _number_list(table, "time_constant_factors", [1.0], where)
    delays = _number_list(table, "extra_delays_steps", [0], where)
    if not all(v > 0 for v in gains + taus) or not all(d >= 0 and d == int(d) for d in delays):
        raise CampaignError(f"{where}: expected factors > 0 and whole delays >= 0; got gains "
                            f"{gains}, time constants {taus}, delays {delays}")
    return [PlantSpec(kind="perturbed", gain_factor=g, time_constant_factor=m,
                      extra_delay_steps=int(d))
            for d in delays for m in taus for g in gains]


def _settings(table: Mapping[str, Any], base: Path, model_path: Path,
              here: str) -> tuple[str, str]:
    """A controller's settings file: resolved path and SHA-256, checked against the model."""
    import hashlib

    from czmpc.errors import SettingsError
    from czmpc.settings_file import load_settings

    text = table.get("settings")
    if text is None:
        return "", ""
    if not isinstance(text, str) or not text:
        raise CampaignError(f"{here}: expected 'settings' a file name; got {shown(text)}")
    path = Path(text) if Path(text).is_absolute() else base / text
    try:
        load_settings(path, _model(str(model_path)))
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
    except (SettingsError, OSError) as exc:
        raise CampaignError(f"{here}: settings: {exc}") from None
    return str(path), digest


def _controllers(doc: Any, where: str, base: Path | None = None,
                 model_path: Path | None = None) -> list[ControllerSpec]:
    if not isinstance(doc, list) or not doc:
        raise CampaignError(f"{where}: expected at least one [[controllers]] table")
    out = []
    for i, table in enumerate(doc):
        here = f"{where} [[controllers]] #{i + 1}"
        _check_keys(table, ["name", "preset", "settings"], here)
        preset = table.get("preset", "mpc" if "settings" in table else None)
        if preset not in PRESETS:
            raise CampaignError(f"{here}: expected preset one of {choices(PRESETS)}; got {shown(preset)}")
        name = table.get("name", preset)
        if not isinstance(name, str) or not name or "|" in name:
            raise CampaignError(f"{here}: expected a non-empty name without '|'; got {shown(name)}")
        settings_path, settings_sha256 = ("", "") if model_path is None else _settings(
            table, base or Path.cwd(), model_path, here)
        out.append(ControllerSpec(name=name, preset=preset, settings_path=settings_path,
                                  settings_sha256=settings_sha256))
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise CampaignError(f"{where}: controller names must differ; got {names}")
    return out


def _resolve(name: str, base: Path, suffix: str) -> str:
    """A shipped name stays a name; anything with the suffix is a path relative to ``base``."""
    if name.endswith(suffix):
        path = Path(name) if Path(name).is_absolute() else base / name
        return str(path)
    return name


def spec_from_dict(doc: Mapping[str, Any], *, source: str = "<memory>",
                   base_dir: Path | None = None) -> CampaignSpec:
    """Parse and check a campaign spec given as a mapping (see the module docstring).

    Raises
    ------
    CampaignError
        A missing, unknown or invalid key (the message names it and the bad value).
    """
    from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

    where = f"campaign spec {source}"
    _check_keys(doc, ["name", "model", "seeds", "base_seed", "noise", "time_scale", "scenarios",
                      "controllers", "plants", "seed", "linear_model"], where)
    base = base_dir if base_dir is not None else Path.cwd()
    model = doc.get("model", HAMMERSTEIN_MODEL_JSON)
    if not isinstance(model, str):
        raise CampaignError(f"{where}: expected 'model' a file name; got {shown(model)}")
    candidate = Path(model) if Path(model).is_absolute() else base / model
    try:
        model_path = candidate if candidate.is_file() else shipped_path(model)
    except FileNotFoundError:
        raise CampaignError(f"{where}: model {shown(model)} is neither a file next to the spec nor "
                            f"a shipped model") from None
    from czmpc.shipped import ARMAX_MODEL_JSON
    linear = doc.get("linear_model", ARMAX_MODEL_JSON)
    if not isinstance(linear, str):
        raise CampaignError(f"{where}: expected 'linear_model' a file name; got {shown(linear)}")
    candidate = Path(linear) if Path(linear).is_absolute() else base / linear
    try:
        linear_path = candidate if candidate.is_file() else shipped_path(linear)
    except FileNotFoundError:
        raise CampaignError(f"{where}: linear_model {shown(linear)} is neither a file next to the "
                            f"spec nor a shipped model") from None
    fixed_seed = doc.get("seed")
    if fixed_seed is not None and (isinstance(fixed_seed, bool) or not isinstance(fixed_seed, int)
                                   or fixed_seed < 0):
        raise CampaignError(f"{where}: expected 'seed' an integer >= 0; got {shown(fixed_seed)}")
    seeds, base_seed = doc.get("seeds", 1), doc.get("base_seed", 0)
    for key, value, low in (("seeds", seeds, 1), ("base_seed", base_seed, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise CampaignError(f"{where}: expected '{key}' an integer >= {low}; got {shown(value)}")
    time_scale = doc.get("time_scale", 1.0)
    if (isinstance(time_scale, bool) or not isinstance(time_scale, (int, float))
            or not 0.0 < time_scale <= 1.0):
        raise CampaignError(f"{where}: expected 'time_scale' in (0, 1]; got {shown(time_scale)}")
    noise = doc.get("noise", True)
    if not isinstance(noise, bool):
        raise CampaignError(f"{where}: expected 'noise' true or false; got {shown(noise)}")
    scenarios = doc.get("scenarios")
    if (not isinstance(scenarios, list) or not scenarios
            or not all(isinstance(s, str) for s in scenarios)):
        raise CampaignError(f"{where}: expected 'scenarios' a non-empty list of names; "
                            f"got {shown(scenarios)}")
    resolved = tuple(_resolve(s, base, ".toml") for s in scenarios)
    from sim.errors import SimError
    from sim.scenario import load_scenario
    for s in resolved:
        try:
            load_scenario(s)
        except (SimError, OSError) as exc:
            raise CampaignError(f"{where}: scenario {shown(s)}: {exc}") from None
    name = doc.get("name", Path(source).stem)
    if not isinstance(name, str) or not name:
        raise CampaignError(f"{where}: expected 'name' a non-empty string; got {shown(name)}")
    plants = tuple(_plants(doc.get("plants"), where))
    warnings: list[str] = []
    if any(p.kind == "sampled" for p in plants):
        from czmpc.campaigns.sampling import SamplingError, parameter_distribution
        try:
            dist = parameter_distribution(_model(str(model_path)))
        except (SamplingError, OSError, ValueError) as exc:
            raise CampaignError(f"{where}: sampled plants of model {model}: {exc}") from None
        if dist.warning:
            warnings.append(f"sampled plants of {Path(model_path).name}: {dist.warning}")
    return CampaignSpec(
        name=name, source=source, model_path=str(model_path),
        controllers=tuple(_controllers(doc.get("controllers"), where, base, model_path)),
        plants=plants, scenarios=resolved, seeds=seeds,
        base_seed=base_seed, noise=noise, time_scale=float(time_scale),
        fixed_seed=fixed_seed, linear_model_path=str(linear_path), warnings=tuple(warnings))


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
        names = [t.get("name", t.get("preset")) for t in tables if isinstance(t, dict)]
        missing = [c for c in controllers if c not in names]
        if missing:
            raise CampaignError(f"campaign spec {p}: no controller named {missing}; the spec "
                                f"has {names}")
        doc["controllers"] = [t for t in tables if t.get("name", t.get("preset")) in controllers]
    return spec_from_dict(doc, source=str(p), base_dir=p.parent)


# --- one run --------------------------------------------------------------------------------
def run_seed(run: RunSpec) -> int:
    """The run's seed: `SeedSequence` of ``base_seed`` spawned by a digest of its identity.

    The key is the CRC-32 of the run id (controller, plant, scenario, seed index), so a
    run gets the same seed whatever its position in the campaign or the worker.
    Controllers compared on the same plant, scenario and seed index share a seed (the
    same noise), since the controller name is left out of the key. A spec with a fixed
    ``seed`` gives every run that seed.
    """
    if run.fixed_seed is not None:
        return run.fixed_seed
    key = f"{run.plant.label}|{Path(run.scenario).stem}|{run.seed_index}"
    seq = np.random.SeedSequence(run.base_seed, spawn_key=(zlib.crc32(key.encode("utf-8")),))
    return int(seq.generate_state(1, dtype=np.uint32)[0])


@functools.lru_cache(maxsize=8)
def _model(path: str) -> Any:
    from sysid.modelfile import load_model
    return load_model(path)


@functools.lru_cache(maxsize=32)
def _scenario(name: str, time_scale: float) -> Any:
    from sim.scenario import load_scenario
    scenario = load_scenario(name)
    return scenario if time_scale == 1.0 else scenario.shortened(time_scale)


@functools.lru_cache(maxsize=4)
def _sampled(path: str, base_seed: int, sample_index: int) -> Any:
    from czmpc.campaigns.sampling import sample_plant
    return sample_plant(_model(path), base_seed, sample_index)


def _plant_model(run: RunSpec, model: Any) -> tuple[Any, int, str]:
    """A model plant's model, the draws rejected to get it, and where its parameters came
    from ("" for plants not sampled)."""
    from sim.perturbed import perturb_model

    if run.plant.kind == "sampled":
        drawn = _sampled(run.model_path, run.base_seed, run.plant.sample_index)
        return drawn.model, drawn.n_rejected, drawn.source
    if run.plant.kind == "perturbed":
        return perturb_model(model, gain_factor=run.plant.gain_factor,
                             time_constant_factor=run.plant.time_constant_factor,
                             extra_delay_steps=run.plant.extra_delay_steps), 0, ""
    return model, 0, ""


def _plant(run: RunSpec, model: Any, scenario: Any) -> tuple[Any, float]:
    """The plant of a run and the input [%] it starts in steady state at."""

    from czmpc.campaigns.simulation import heater_steady_state_triac_pct
    from sim.heater import HeaterParams, VirtualHeater
    from sim.model_plant import ModelPlant, steady_state_triac_pct

    if run.plant.kind == "heater":
        params = HeaterParams(ts_s=scenario.ts_s)
        if not run.noise:
            params = replace(params, sensor_noise_std_kw=0.0, grid_wander_std=0.0)
        s0 = heater_steady_state_triac_pct(scenario.initial_setpoint_kw, params)
        return VirtualHeater(replace(params, initial_triac_pct=s0)), s0
    if run.plant.kind == "model":  # as `czmpc simulate` builds it
        built = ModelPlant.for_scenario(model, scenario)
        if built.noise != (run.noise and scenario.plant_noise):
            built = ModelPlant(model, noise=run.noise and scenario.plant_noise,
                               initial_triac_pct=built.initial_triac_pct)
        return built, built.initial_triac_pct
    plant_model = _plant_model(run, model)[0]
    s0 = steady_state_triac_pct(plant_model, scenario.initial_setpoint_kw,
                                triac_limits_pct=scenario.triac_limits_pct)
    return ModelPlant(plant_model, noise=run.noise and scenario.plant_noise, initial_triac_pct=s0), s0


def _controller(run: RunSpec, model: Any, scenario: Any, s0: float) -> Any:
    """The run's controller, built as `czmpc.campaigns.bench.build_controller` builds it
    (every controller gets the Hammerstein MPC's allowed input range, the scenario's rate
    limit and the plant's start input)."""
    from czmpc.campaigns.bench import BenchModels, build_controller

    linear = _model(run.linear_model_path) if run.linear_model_path else model
    models = BenchModels(hammerstein=model, linear=linear)
    return build_controller(_BENCH_NAMES[run.controller.preset], models, scenario,
                            initial_triac_pct=s0,
                            settings_doc=_settings_doc(run.controller.settings_path))


@functools.lru_cache(maxsize=8)
def _settings_doc(path: str) -> dict[str, Any] | None:
    """The parsed settings file of a controller (None: the defaults)."""
    if not path:
        return None
    from czmpc.settings_file import load_settings_doc
    return load_settings_doc(path)


def simulate_run(run: RunSpec) -> Any:
    """Run the closed loop of one run; returns its `sim.loop.ClosedLoopResult`."""
    from sim.loop import run_closed_loop

    model = _model(run.model_path)
    scenario = _scenario(run.scenario, run.time_scale)
    plant, s0 = _plant(run, model, scenario)
    controller = _controller(run, model, scenario, s0)
    return run_closed_loop(plant, controller, scenario, rng=run_seed(run))


@functools.lru_cache(maxsize=32)
def _allowed_range(model_path: str, scenario_name: str, time_scale: float, settings_path: str
                   ) -> tuple[tuple[float, float], float | None]:
    """The Hammerstein MPC's allowed input range [%] and rate limit [%/sample] of a scenario
    (every controller gets them, `czmpc.campaigns.bench.build_controller`)."""
    from czmpc.campaigns.simulation import controller_settings
    from czmpc.inversion import allowed_triac_range
    from czmpc.settings_file import settings_from_dict

    model = _model(model_path)
    scenario = _scenario(scenario_name, time_scale)
    doc = _settings_doc(settings_path)
    base = None if doc is None else settings_from_dict(doc, model, source=settings_path)
    settings = controller_settings(model, scenario, initial_triac_pct=model.operating_point.triac_pct,
                                   settings=base)
    allowed = allowed_triac_range(model, triac_min_pct=settings.triac_min_pct,
                                  triac_max_pct=settings.triac_max_pct,
                                  validity_margin_pct=settings.validity_margin_pct)
    return (float(allowed[0]), float(allowed[1])), settings.max_move_pct_per_step


def _reachable_row(run: RunSpec, result: Any) -> dict[str, Any]:
    """The robustness measures and the sampled-plant columns of a finished run."""
    from czmpc.campaigns.robustness import reachable_measures
    from czmpc.campaigns.sampling import static_gain_kw_per_pct
    from sim.heater import HeaterParams
    from sim.heater import steady_state as heater_steady_state

    model = _model(run.model_path)
    scenario = _scenario(run.scenario, run.time_scale)
    allowed, max_move = _allowed_range(run.model_path, run.scenario, run.time_scale,
                                       run.controller.settings_path)
    if run.plant.kind == "heater":
        params = HeaterParams(ts_s=scenario.ts_s)
        if not run.noise:
            params = replace(params, sensor_noise_std_kw=0.0, grid_wander_std=0.0)

        def power_at(s: float) -> float:
            return float(heater_steady_state(s, params)[0])
        n_rejected, source, gain = 0, "", math.nan
    else:
        plant_model, n_rejected, source = _plant_model(run, model)

        def power_at(s: float) -> float:
            return max(0.0, float(plant_model.steady_state_power_kw(s)))
        gain = float(static_gain_kw_per_pct(plant_model, np.array(model.operating_point.triac_pct)))
    m = reachable_measures(result, scenario, power_at, allowed, max_move)
    return {
        "n_rejected_draws": n_rejected, "plant_parameter_source": source,
        "plant_static_gain_kw_per_pct": gain,
        "offset_free": m.offset_free(OFFSET_FREE_THRESHOLD_KW),
        "max_abs_steady_state_error_reachable_kw": m.max_abs_steady_state_error_kw,
        "n_unreachable_changes": sum(not ok for ok in m.reachable),
        "iae_changes_reachable_kw_s": m.iae_kw_s, "max_overshoot_reachable_kw": m.max_overshoot_kw,
        "max_overshoot_reachable_pct": m.max_overshoot_pct,
        "n_allowed_range_violations": m.n_input_violations,
    }


def _nan_if_none(value: float | None) -> float:
    return math.nan if value is None else float(value)


def execute_run(run: RunSpec) -> dict[str, Any]:
    """Run one campaign run and return its row (`ROW_COLUMNS`).

    A run that raises is recorded, not propagated: ``status = "error"`` and ``error``
    holds the exception's type and message; the metric columns are NaN / -1.
    """
    from sim.metrics import compute_metrics

    row: dict[str, Any] = {
        "run_id": run.run_id, "controller": run.controller.name, "preset": run.controller.preset,
        "plant": run.plant.label, "gain_factor": run.plant.gain_factor,
        "time_constant_factor": run.plant.time_constant_factor,
        "extra_delay_steps": run.plant.extra_delay_steps, "scenario": Path(run.scenario).stem,
        "seed_index": run.seed_index, "seed": run_seed(run), "sample_index": run.plant.sample_index,
    }
    t0 = time.perf_counter()
    try:
        result = simulate_run(run)
        m = compute_metrics(result)
        extra = _reachable_row(run, result)
    except Exception as exc:  # noqa: BLE001 - a crashed run is a result of the campaign
        last = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f" at {Path(last[0].filename).name}:{last[0].lineno}" if last else ""
        row.update(status="error", error=f"{type(exc).__name__}: {exc}{where}", n_steps=-1,
                   **dict.fromkeys(("iae_kw_s", "ise_kw2_s", "max_overshoot_kw",
                                    "max_abs_steady_state_error_kw", "input_total_variation_pct"),
                                   math.nan),
                   **dict.fromkeys(("n_limit_violations", "n_rate_violations", "n_fallbacks"), -1),
                   **dict.fromkeys(TIMING_COLUMNS, math.nan),
                   **dict.fromkeys(("plant_static_gain_kw_per_pct",
                                    "max_abs_steady_state_error_reachable_kw",
                                    "iae_changes_reachable_kw_s", "max_overshoot_reachable_kw",
                                    "max_overshoot_reachable_pct"), math.nan),
                   **dict.fromkeys(("n_rejected_draws", "n_unreachable_changes",
                                    "n_allowed_range_violations"), -1),
                   plant_parameter_source="", offset_free=False)
        row["wall_time_s"] = time.perf_counter() - t0
        return row
    row.update(
        status="ok", error="", n_steps=int(result.n_steps), iae_kw_s=m.iae_kw_s,
        ise_kw2_s=m.ise_kw2_s,
        max_overshoot_kw=max((c.overshoot_kw for c in m.changes), default=0.0),
        max_abs_steady_state_error_kw=_nan_if_none(m.max_abs_steady_state_error_kw),
        input_total_variation_pct=m.input_total_variation_pct,
        n_limit_violations=int(m.n_limit_violations), n_rate_violations=int(m.n_rate_violations),
        n_fallbacks=-1 if m.n_solver_failures is None else int(m.n_solver_failures),
        wall_time_s=time.perf_counter() - t0, step_time_median_ms=m.step_time_median_ms,
        step_time_p95_ms=m.step_time_p95_ms, step_time_max_ms=m.step_time_max_ms, **extra,
    )
    return row


__all__ = [
    "DETERMINISTIC_COLUMNS",
    "KEY_COLUMNS",
    "METRIC_COLUMNS",
    "OFFSET_FREE_THRESHOLD_KW",
    "PLANT_KINDS",
    "PRESETS",
    "ROW_COLUMNS",
    "TIMING_COLUMNS",
    "CampaignError",
    "CampaignSpec",
    "ControllerSpec",
    "PlantSpec",
    "RunSpec",
    "execute_run",
    "load_spec",
    "run_seed",
    "simulate_run",
    "spec_from_dict",
]
