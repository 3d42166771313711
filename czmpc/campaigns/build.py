"""The one place that builds a run's plant and its controller.

Plants (`build_plant`): the model (`sim.model_plant.ModelPlant`, started at the
scenario's initial input), the virtual heater (`sim.heater.VirtualHeater`, grey-box
physics), a plant of another kind (`sim.thermal_plant.ThermalPlant`, a furnace zone
whose output is a temperature), the model perturbed (`sim.perturbed.perturb_model`) or sampled
(`czmpc.campaigns.sampling.sample_plant`); the last three start in steady state for the
initial setpoint, so a plant with another gain does not start with an error.

Controllers (`build_controller`, kinds `CONTROLLERS`). Fairness: every controller gets
the Hammerstein MPC's allowed input range (the identified range widened by the validity
margin, inside the scenario's TRIAC limits), the scenario's rate limit and the plant's
start input (`controller_settings`).

``c_step`` is the MPC step as C (a directory written by ``czmpc codegen``, built on demand
with the system's C compiler: `build_c_step`). Its model and settings are compiled in,
so a scenario whose limits would change them is refused (`check_compiled_settings`)
rather than run with other limits than the scenario's; only the start input is the
plant's. Its tight-solver reference (``tight=True``, a regression suite's re-run) is the
Python MPC of the same model and settings at `TIGHT_OSQP`: the compiled solver's
tolerances cannot change, and the C replays the Python MPC at the default ones to the
solver's rounding (issue 42), so a golden ``c_step`` case gets the tolerance an ``mpc``
case of the same model and settings gets.
"""

from __future__ import annotations

import fcntl
import math
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from scipy.optimize import brentq

from czmpc.errors import CzmpcError
from czmpc.inversion import allowed_triac_range
from czmpc.settings import MPCSettings, OSQPOptions
from sim.errors import PlantError
from sim.heater import HeaterParams, VirtualHeater
from sim.heater import steady_state as heater_steady_state
from sim.model_plant import ModelPlant, steady_state_triac_pct
from sim.protocols import Controller, Plant
from sim.scenario import Scenario
from sim.thermal_plant import ThermalParams, ThermalPlant, steady_state_degc
from sim.thermal_plant import steady_state_triac_pct as thermal_steady_state_triac_pct
from sysid.model import HammersteinModel

#: Controller kinds and what they are.
CONTROLLERS: dict[str, str] = {
    "mpc": "offset-free MPC, OSQP, inverted f (Hammerstein)",
    "nmpc": "nonlinear MPC, CasADi + IPOPT, f inside the dynamics (Hammerstein)",
    "linear_mpc": "offset-free MPC on the linear ARMAX(1,2,1)",
    "pi_gs": "PI, anti-windup, gain scheduled on f'(ds)",
    "pi": "PI, anti-windup, fixed gain",
    "pi_table": "PI scheduled by a czmpc.pid table (SIMC, Ms <= 1.4 per row), velocity form",
    "open_loop": "open-loop inversion of the steady state (no feedback)",
    "c_step": "the offset-free MPC's step as C from czmpc codegen (a directory), compiled",
}
#: Campaign spellings of the kinds (``preset = "pi-scheduled"``) -> kind.
PRESET_ALIASES: dict[str, str] = {"pi-scheduled": "pi_gs", "linear-mpc": "linear_mpc",
                                  "pi-table": "pi_table", "open-loop": "open_loop"}
#: Ms bound of the ``pi_table`` controller's rows [-].
PI_TABLE_MS = 1.4
#: Solver settings of the tight reference re-run of a regression suite: far tighter than
#: the defaults (OSQP 1e-5, IPOPT 1e-8), so a metric's change measures what the default
#: tolerance allows.
TIGHT_OSQP = OSQPOptions(eps_abs=1e-9, eps_rel=1e-9, max_iter=100_000)
TIGHT_IPOPT_TOL = 1e-11
#: Lock file a ``c_step`` build holds in its directory, so that runs on parallel workers
#: do not run ``make`` in one directory at once.
C_STEP_BUILD_LOCK = ".czmpc-build.lock"


class BuildError(CzmpcError, ValueError):
    """An unknown plant or controller kind."""


class MutationNotApplicable(Exception):  # noqa: N818 - a signal, not an error
    """The mutation does not change this controller (e.g. no rate limit to switch off)."""


def _double_move_weight(s: MPCSettings) -> MPCSettings | None:
    return s.with_updates(move_weight=2.0 * s.move_weight)


def _shorter_horizon(s: MPCSettings) -> MPCSettings | None:
    shorter = max(1, round(0.8 * s.horizon_steps))
    return None if shorter == s.horizon_steps else s.with_updates(horizon_steps=shorter)


def _no_rate_limit(s: MPCSettings) -> MPCSettings | None:
    return None if s.max_move_pct_per_step is None else s.with_updates(max_move_pct_per_step=None)


def _other_disturbance_model(s: MPCSettings) -> MPCSettings | None:
    return s.with_updates(disturbance_model="input" if s.disturbance_model == "output" else "output")


#: Mutations of an ``mpc`` controller's final settings (after the scenario's limits are
#: merged in): name -> change, None where it does not apply.
MUTATIONS: dict[str, Callable[[MPCSettings], MPCSettings | None]] = {
    "move_weight x2": _double_move_weight,
    "horizon -20%": _shorter_horizon,
    "rate limit off": _no_rate_limit,
    "disturbance model": _other_disturbance_model,
}
#: Controller kinds a mutation changes.
MUTATED_KINDS: frozenset[str] = frozenset({"mpc"})


def heater_steady_state_triac_pct(power_kw: float, params: HeaterParams | None = None) -> float:
    """TRIAC input [%] whose steady power on the virtual heater is ``power_kw`` [kW].

    `scipy.optimize.brentq` on `sim.heater.steady_state` at nominal grid voltage between
    the firing threshold and 100 %, where the power rises monotonically (one root).

    Parameters
    ----------
    power_kw :
        Desired steady power [kW].
    params :
        Heater parameters; default `HeaterParams()`.

    Raises
    ------
    PlantError
        ``power_kw`` is not reachable with 0..100 % input.
    """
    params = HeaterParams() if params is None else params
    lo, hi = params.firing_threshold_pct, 100.0
    p_hi = heater_steady_state(hi, params)[0]
    if not (math.isfinite(power_kw) and 0.0 < power_kw <= p_hi):
        raise PlantError(f"heater_steady_state_triac_pct: expected a steady power in (0, {p_hi:.4g}] kW "
                         f"(the virtual heater's range at 0..100 % input); got {power_kw!r}")
    if power_kw == p_hi:
        return hi
    return float(brentq(lambda s: heater_steady_state(s, params)[0] - power_kw, lo, hi,
                        xtol=1e-9))


def controller_settings(
    model: HammersteinModel, scenario: Scenario, *, initial_triac_pct: float,
    settings: MPCSettings | None = None,
) -> MPCSettings:
    """Settings for a run: ``settings`` with the scenario's limits and the plant's start.

    The TRIAC limits become the intersection of the settings' and the scenario's, the
    rate limit the tighter of the two (None if neither has one), and
    ``initial_triac_pct`` the plant's initial input clipped to the controller's allowed
    range (a plant may start where the model is not valid, e.g. a low meltdown power).

    Parameters
    ----------
    model :
        The controller's model.
    scenario :
        Supplies ``triac_limits_pct`` and ``max_move_pct_per_step``.
    initial_triac_pct :
        The plant's initial TRIAC input [%].
    settings :
        Base settings; None: `MPCSettings.default_for` ``(model)``.

    Raises
    ------
    SettingsError, DesignError
        The combined limits are empty or leave no allowed range.
    """
    base = MPCSettings.default_for(model) if settings is None else settings
    lo = max(base.triac_min_pct, scenario.triac_limits_pct[0])
    hi = min(base.triac_max_pct, scenario.triac_limits_pct[1])
    rates = [r for r in (base.max_move_pct_per_step, scenario.max_move_pct_per_step)
             if r is not None]
    s_lo, s_hi = allowed_triac_range(model, triac_min_pct=lo, triac_max_pct=hi,
                                     validity_margin_pct=base.validity_margin_pct)
    return base.with_updates(triac_min_pct=lo, triac_max_pct=hi,
                             max_move_pct_per_step=min(rates) if rates else None,
                             initial_triac_pct=min(s_hi, max(s_lo, float(initial_triac_pct))))


def build_plant(kind: str, model: HammersteinModel, scenario: Scenario, *, noise: bool
                ) -> tuple[Plant, float, Callable[[float], float]]:
    """The plant, the TRIAC input [%] it starts at, and its steady power [kW] at an input [%].

    Parameters
    ----------
    kind :
        ``"model"`` (started as `ModelPlant.for_scenario` starts it), ``"heater"``,
        ``"thermal"`` (the furnace zone; setpoints are temperatures [degC]), or
        ``"perturbed"`` / ``"sampled"``: a model plant of the perturbed or sampled
        ``model``, started at its own steady state for the initial setpoint.
    model :
        The plant's model (model plants).
    scenario :
        Supplies the sampling time and the initial setpoint or input.
    noise :
        Plant noise on (the model's ``C/A e``, the heater's sensor noise and grid wander,
        the furnace's sensor noise; its sensor's quantisation stays on).

    Raises
    ------
    BuildError
        An unknown kind.
    """
    if kind == "heater":
        params = HeaterParams(ts_s=scenario.ts_s)
        if not noise:
            params = replace(params, sensor_noise_std_kw=0.0, grid_wander_std=0.0)
        s0 = heater_steady_state_triac_pct(scenario.initial_setpoint_kw, params)
        return (VirtualHeater(replace(params, initial_triac_pct=s0)), s0,
                lambda s: float(heater_steady_state(s, params)[0]))
    if kind == "thermal":
        zone = ThermalParams(ts_s=scenario.ts_s)
        if not noise:
            zone = replace(zone, sensor_noise_std_degc=0.0)
        s0 = thermal_steady_state_triac_pct(scenario.initial_setpoint_kw, zone)
        return (ThermalPlant(replace(zone, initial_triac_pct=s0)), s0,
                lambda s: steady_state_degc(s, zone))
    if kind in ("model", "perturbed", "sampled"):
        if kind == "model":
            s0 = ModelPlant.for_scenario(model, scenario).initial_triac_pct
        else:
            s0 = steady_state_triac_pct(model, scenario.initial_setpoint_kw,
                                        triac_limits_pct=scenario.triac_limits_pct)
        return (ModelPlant(model, noise=noise, initial_triac_pct=s0), s0,
                lambda s: max(0.0, float(model.steady_state_power_kw(s))))
    raise BuildError(f"build_plant: expected a plant among model, heater, thermal, perturbed, "
                     f"sampled; got {kind!r}")


def build_controller(
    kind: str, model: HammersteinModel, scenario: Scenario, *, initial_triac_pct: float,
    linear_model: HammersteinModel | None = None, settings_doc: Mapping[str, object] | None = None,
    settings: MPCSettings | None = None, tight: bool = False, mutation: str | None = None,
    c_step_directory: str | None = None,
) -> Controller:
    """Controller ``kind`` (a key of `CONTROLLERS`) set up for ``scenario``.

    Parameters
    ----------
    kind :
        The controller.
    model :
        The Hammerstein model (MPC, NMPC, PI tuning, open loop).
    scenario :
        Supplies the TRIAC and rate limits.
    initial_triac_pct :
        The plant's start input [%] (clipped to the allowed range).
    linear_model :
        The linear ARMAX model of ``linear_mpc``.
    settings_doc :
        A parsed settings file (`czmpc.settings_file`) applied to each model's own
        defaults; None: ``settings``.
    settings :
        The tuning when there is no ``settings_doc``, completed by `controller_settings`
        (limits, rate limit, start input); None: `MPCSettings.default_for`.
    tight :
        Solve at `TIGHT_OSQP` / `TIGHT_IPOPT_TOL` (the reference re-run of a suite).
    mutation :
        A key of `MUTATIONS` applied to an ``mpc``'s final settings, or None.
    c_step_directory :
        The directory of a ``c_step`` (written by ``czmpc codegen``): its own model and
        settings are run; ``model`` must be its model, ``settings_doc`` and ``settings``
        are not used. With ``tight``, the Python MPC of that model and those settings at
        `TIGHT_OSQP` (module notes).

    Raises
    ------
    BuildError
        An unknown kind, ``linear_mpc`` without a linear model, ``c_step`` without a
        directory.
    MutationNotApplicable
        The mutation does not change this controller.
    SettingsError
        A ``c_step`` whose scenario changes its compiled settings, or whose directory
        holds another model than ``model``.
    czmpc.codegen.BuildError
        A ``c_step`` directory that cannot be built (no C compiler or make).
    """
    from czmpc.controller import OffsetFreeMPC
    from czmpc.settings_file import settings_from_dict

    def settings_of(m: HammersteinModel) -> MPCSettings:
        base = (settings if settings_doc is None else settings_from_dict(settings_doc, m))
        final = controller_settings(m, scenario, initial_triac_pct=initial_triac_pct, settings=base)
        if mutation is not None:
            mutated = MUTATIONS[mutation](final) if kind in MUTATED_KINDS else None
            if mutated is None:
                raise MutationNotApplicable(mutation)
            final = mutated
        return final.with_updates(osqp=TIGHT_OSQP) if tight else final

    if kind not in CONTROLLERS:
        raise BuildError(f"build_controller: expected a controller among {', '.join(CONTROLLERS)}; "
                         f"got {kind!r}")
    if kind == "c_step":
        if c_step_directory is None:
            raise BuildError("build_controller: c_step needs the directory 'czmpc codegen' wrote")
        if mutation is not None:
            raise MutationNotApplicable(mutation)
        return _c_step(Path(c_step_directory), model, scenario, initial_triac_pct, tight=tight)
    if kind == "linear_mpc":
        if linear_model is None:
            raise BuildError("build_controller: linear_mpc needs a linear model")
        return OffsetFreeMPC(linear_model, settings_of(linear_model))
    settings = settings_of(model)
    if kind == "mpc":
        return OffsetFreeMPC(model, settings)
    if kind == "nmpc":
        from czmpc.peers.nmpc import NonlinearMPC
        if tight:
            return NonlinearMPC(model, settings, ipopt_tol=TIGHT_IPOPT_TOL)
        return NonlinearMPC(model, settings)
    return _classic(kind, model, settings)


def check_compiled_settings(directory: Path, compiled: MPCSettings, used: MPCSettings, *,
                            what: str) -> None:
    """Refuse settings completed for a run that differ from a C step's compiled ones.

    Only ``initial_triac_pct`` may differ (the C step starts at any input in its allowed
    range).

    Parameters
    ----------
    directory :
        The C step's directory (for the message).
    compiled :
        Its settings (``settings.toml`` there).
    used :
        ``compiled`` completed for the run (`controller_settings`).
    what :
        What completed them, e.g. ``"scenario 'staircase'"``.

    Raises
    ------
    SettingsError
        Another limit, rate limit or anything else, naming the settings that changed and
        the command that generates a C step with them.
    """
    from czmpc.errors import SettingsError

    if replace(used, initial_triac_pct=compiled.initial_triac_pct) == compiled:
        return
    differing = [f"{name} {getattr(compiled, name)!r} -> {getattr(used, name)!r}"
                 for name in ("triac_min_pct", "triac_max_pct", "max_move_pct_per_step")
                 if getattr(compiled, name) != getattr(used, name)]
    raise SettingsError(
        f"{directory}: {what} changes settings compiled into the C step "
        f"({'; '.join(differing) or 'see czmpc settings --show'}); write them into a settings "
        f"file and generate again with 'czmpc codegen MODEL.json --settings FILE --out "
        f"{directory}'")


def build_c_step(directory: Path, *, initial_triac_pct: float | None = None) -> Controller:
    """``directory``'s compiled step (`czmpc.codegen.load_controller`), built on demand.

    The build holds `C_STEP_BUILD_LOCK` in the directory, so that parallel workers of a
    campaign build it once and load it after.

    Raises
    ------
    czmpc.codegen.BuildError
        No C compiler or make, or a failed build.
    SettingsError
        ``initial_triac_pct`` outside the allowed range.
    """
    from czmpc.codegen import load_controller

    with open(directory / C_STEP_BUILD_LOCK, "a", encoding="utf-8") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            return load_controller(directory, initial_triac_pct=initial_triac_pct)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _c_step(directory: Path, model: HammersteinModel, scenario: Scenario,
            initial_triac_pct: float, *, tight: bool) -> Controller:
    """A ``c_step`` set up for ``scenario`` (or its tight reference: module notes)."""
    from czmpc.codegen.generate import MODEL_FILE, read_sources
    from czmpc.controller import OffsetFreeMPC
    from czmpc.errors import SettingsError
    from sysid.modelfile import model_to_dict

    c_model, compiled = read_sources(directory)
    if model_to_dict(c_model) != model_to_dict(model):
        raise SettingsError(f"{directory}: the C step was generated from another model than the "
                            f"one given; run it with {directory / MODEL_FILE}")
    used = controller_settings(model, scenario, initial_triac_pct=initial_triac_pct,
                               settings=compiled)
    check_compiled_settings(directory, compiled, used, what=f"scenario '{scenario.name}'")
    if tight:
        return OffsetFreeMPC(model, used.with_updates(osqp=TIGHT_OSQP))
    return build_c_step(directory, initial_triac_pct=used.initial_triac_pct)


def _classic(kind: str, model: HammersteinModel, settings: MPCSettings) -> Controller:
    """The PIs and the open loop, on the Hammerstein MPC's allowed range and rate limit."""
    from czmpc.controller import OffsetFreeMPC

    lo, hi = OffsetFreeMPC(model, settings).allowed_triac_range_pct
    s0, rate = settings.initial_triac_pct, settings.max_move_pct_per_step
    common: dict[str, Any] = {"initial_triac_pct": s0, "triac_limits_pct": (lo, hi),
                              "max_move_pct_per_step": rate}
    if kind in ("pi", "pi_gs"):
        from czmpc.peers.pi import PIController
        return PIController.tuned_for(model, gain_scheduled=kind == "pi_gs",
                                      validity_margin_pct=settings.validity_margin_pct, **common)
    if kind == "pi_table":
        from czmpc.pid.controller import ScheduledPID
        from czmpc.pid.design import DesignSpec
        from czmpc.pid.schedule import tune_schedule
        schedule = tune_schedule(model, DesignSpec(ms=PI_TABLE_MS), triac_range_pct=(lo, hi))
        return ScheduledPID(schedule=schedule.table_schedule(), ts_s=model.ts_s, **common)
    from czmpc.peers.open_loop import OpenLoopInversion
    return OpenLoopInversion(model, validity_margin_pct=settings.validity_margin_pct, **common)


__all__ = ["CONTROLLERS", "C_STEP_BUILD_LOCK", "MUTATED_KINDS", "MUTATIONS", "PI_TABLE_MS", "PRESET_ALIASES",
           "TIGHT_IPOPT_TOL", "TIGHT_OSQP", "BuildError", "MutationNotApplicable", "build_c_step",
           "build_controller", "build_plant", "check_compiled_settings", "controller_settings",
           "heater_steady_state_triac_pct"]
