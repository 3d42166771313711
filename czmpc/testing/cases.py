"""One regression case: build its plant and controller, run the closed loop, measure it.

A case (`czmpc.testing.suite.CaseSpec`) is run as the benchmark runs its cases
(`czmpc.campaigns.bench.build_plant` and `build_controller`, seed passed to
`sim.loop.run_closed_loop`), with two additions: the controller's settings come from the
user's settings file, and a task may run it at tight solver tolerances (the reference
re-run of `record`) or with a mutated controller (`audit`).

Mutations (`MUTATIONS`) change the final settings of an ``mpc`` case (after the
scenario's limits are merged in by `czmpc.campaigns.simulation.controller_settings`):
``move_weight x2``, ``horizon -20%``, ``rate limit off`` and ``disturbance model``
(output <-> input). Other kinds are not mutated.
"""

from __future__ import annotations

import functools
import math
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from czmpc.settings import MPCSettings
from czmpc.testing.suite import METRICS, CaseSpec, ControllerEntry

#: Signals of the compact trajectory, with their units in the names.
TRAJECTORY_SIGNALS: tuple[str, ...] = ("time_s", "setpoint_kw", "power_true_kw", "triac_pct")
#: Signals compared against the golden band (the first time one leaves it is reported).
BAND_SIGNALS: tuple[str, ...] = ("power_true_kw", "triac_pct")


def _double_move_weight(s: MPCSettings) -> MPCSettings | None:
    return s.with_updates(move_weight=2.0 * s.move_weight)


def _shorter_horizon(s: MPCSettings) -> MPCSettings | None:
    shorter = max(1, round(0.8 * s.horizon_steps))
    return None if shorter == s.horizon_steps else s.with_updates(horizon_steps=shorter)


def _no_rate_limit(s: MPCSettings) -> MPCSettings | None:
    return None if s.max_move_pct_per_step is None else s.with_updates(max_move_pct_per_step=None)


def _other_disturbance_model(s: MPCSettings) -> MPCSettings | None:
    return s.with_updates(disturbance_model="input" if s.disturbance_model == "output" else "output")


#: Mutations of the recorded controller: name -> change of its final settings (None where
#: the change does not apply, e.g. no rate limit to switch off).
MUTATIONS: dict[str, Callable[[MPCSettings], MPCSettings | None]] = {
    "move_weight x2": _double_move_weight,
    "horizon -20%": _shorter_horizon,
    "rate limit off": _no_rate_limit,
    "disturbance model": _other_disturbance_model,
}
#: Controller kinds a mutation changes.
MUTATED_KINDS: frozenset[str] = frozenset({"mpc"})


class MutationNotApplicable(Exception):  # noqa: N818 - a signal, not an error
    """The mutation does not change this case (e.g. no rate limit to switch off)."""


@dataclass(frozen=True, kw_only=True)
class CaseTask:
    """One execution of a case (picklable).

    Parameters
    ----------
    case :
        The case.
    tight :
        Run at the tight solver tolerances of the reference re-run
        (`czmpc.campaigns.golden.TIGHT_OSQP`, `TIGHT_IPOPT_TOL`).
    mutation :
        A key of `MUTATIONS`, or None.
    """

    case: CaseSpec
    tight: bool = False
    mutation: str | None = None


@dataclass(frozen=True, kw_only=True)
class CaseResult:
    """What one case task produced.

    Parameters
    ----------
    case_id :
        The case.
    metrics :
        Every metric of `czmpc.testing.suite.METRICS` (NaN where undefined); empty on error.
    trajectory :
        `TRAJECTORY_SIGNALS` as float64 arrays; empty on error.
    error :
        ``""``, or the exception's type, message and place when the run raised.
    applicable :
        False when the task's mutation does not change this case (nothing was run).
    """

    case_id: str
    metrics: Mapping[str, float] = field(default_factory=dict)
    trajectory: Mapping[str, np.ndarray] = field(default_factory=dict, repr=False)
    error: str = ""
    applicable: bool = True


@functools.lru_cache(maxsize=8)
def _model(path: str) -> Any:
    from sysid.modelfile import load_model
    return load_model(path)


def base_settings(entry: ControllerEntry, model: Any) -> MPCSettings:
    """The controller's settings before the scenario's limits: its file, or the defaults."""
    if entry.settings_path is None:
        return MPCSettings.default_for(model)
    from czmpc.settings_file import load_settings
    return load_settings(Path(entry.settings_path), model)


def _plant(case: CaseSpec, model: Any, scenario: Any) -> tuple[Any, float]:
    from czmpc.campaigns.bench import build_plant

    if case.plant.kind != "perturbed":
        return build_plant(case.plant.kind, model, scenario)
    from sim.model_plant import ModelPlant, steady_state_triac_pct
    from sim.perturbed import perturb_model

    plant_model = perturb_model(model, gain_factor=case.plant.gain_factor,
                                time_constant_factor=case.plant.time_constant_factor,
                                extra_delay_steps=case.plant.extra_delay_steps)
    s0 = steady_state_triac_pct(plant_model, scenario.initial_setpoint_kw,
                                triac_limits_pct=scenario.triac_limits_pct)
    return ModelPlant(plant_model, noise=scenario.plant_noise, initial_triac_pct=s0), s0


def _controller(task: CaseTask, model: Any, scenario: Any, s0: float) -> Any:
    from czmpc.campaigns.bench import BenchModels, build_controller
    from czmpc.campaigns.golden import TIGHT_IPOPT_TOL, TIGHT_OSQP
    from czmpc.campaigns.simulation import controller_settings
    from czmpc.controller import OffsetFreeMPC

    entry = task.case.controller
    tight: dict[str, Any] = {"osqp": TIGHT_OSQP} if task.tight else {}
    if entry.kind in ("mpc", "nmpc"):
        base = base_settings(entry, model)
        final = controller_settings(model, scenario, initial_triac_pct=s0, settings=base)
        if task.mutation is not None:
            mutated = MUTATIONS[task.mutation](final)
            if mutated is None:
                raise MutationNotApplicable(task.mutation)
            final = mutated
        final = final.with_updates(**tight)
        if entry.kind == "mpc":
            return OffsetFreeMPC(model, final)
        from czmpc.peers.nmpc import NonlinearMPC
        if task.tight:
            return NonlinearMPC(model, final, ipopt_tol=TIGHT_IPOPT_TOL)
        return NonlinearMPC(model, final)
    models = BenchModels(hammerstein=model, linear=_model(entry.linear_model_path))
    doc = None
    if entry.settings_path is not None:  # applied to each model's own defaults (linear_mpc)
        from czmpc.settings_file import load_settings_doc
        doc = load_settings_doc(entry.settings_path)
    return build_controller(entry.kind, models, scenario, initial_triac_pct=s0,
                            settings_updates=tight, settings_doc=doc)


@functools.lru_cache(maxsize=32)
def _scenario(name: str, time_scale: float) -> Any:
    from sim.scenario import load_scenario
    scenario = load_scenario(name)
    return scenario if time_scale == 1.0 else scenario.shortened(time_scale)


def run_task(task: CaseTask) -> CaseResult:
    """Run one case task; a run that raises is returned with ``error`` set, not raised."""
    from czmpc.campaigns.bench import BenchRun, run_row
    from sim.loop import run_closed_loop
    from sim.metrics import compute_metrics

    case = task.case
    if task.mutation is not None and case.controller.kind not in MUTATED_KINDS:
        return CaseResult(case_id=case.case_id, applicable=False)
    try:
        model = _model(case.controller.model_path)
        scenario = _scenario(case.scenario, case.time_scale)
        plant, s0 = _plant(case, model, scenario)
        controller = _controller(task, model, scenario, s0)
        result = run_closed_loop(plant, controller, scenario, rng=case.seed)
        run = BenchRun(scenario=scenario.name, plant=case.plant.label,
                       controller=case.controller.name, metrics=compute_metrics(result),
                       result=result, wall_time_s=0.0)
    except MutationNotApplicable:
        return CaseResult(case_id=case.case_id, applicable=False)
    except Exception as exc:  # noqa: BLE001 - a crashed case is a result of the check
        last = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f" at {Path(last[0].filename).name}:{last[0].lineno}" if last else ""
        return CaseResult(case_id=case.case_id, error=f"{type(exc).__name__}: {exc}{where}")
    row = run_row(run, seed=case.seed)
    metrics = {m: math.nan if row[m] is None else float(row[m]) for m in METRICS}
    trajectory = {k: np.asarray(getattr(result, k), dtype=np.float64) for k in TRAJECTORY_SIGNALS}
    return CaseResult(case_id=case.case_id, metrics=metrics, trajectory=trajectory)


__all__ = [
    "BAND_SIGNALS",
    "MUTATED_KINDS",
    "MUTATIONS",
    "TRAJECTORY_SIGNALS",
    "CaseResult",
    "CaseTask",
    "base_settings",
    "run_task",
]
