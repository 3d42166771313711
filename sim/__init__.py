"""sim: plants and closed loops (the virtual CZ heater, model plants, scenarios, runner).

Public names load on first use (see `sysid._lazy`)::

    run = sim.run_closed_loop(sim.VirtualHeater(), mpc, sim.load_scenario("staircase"), rng=7)
    print(sim.compute_metrics(run).to_dict())
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sysid._lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(["PlantError", "ScenarioError", "SimError"], "sim.errors"),
    **dict.fromkeys(["Controller", "Exogenous", "NOMINAL", "Plant"], "sim.protocols"),
    **dict.fromkeys(["HeaterParams", "VirtualHeater"], "sim.heater"),
    "ModelPlant": "sim.model_plant",
    **dict.fromkeys(["ExperimentSpec", "identification_experiment"], "sim.experiment"),
    **dict.fromkeys(
        ["MeasurementSpike", "MissingSamples", "PowerShift", "RandomSpikes", "VoltageRamp",
         "VoltageStep"], "sim.disturbances"),
    **dict.fromkeys(
        ["Scenario", "SetpointRamp", "SetpointStep", "list_scenarios", "load_scenario"],
        "sim.scenario"),
    **dict.fromkeys(["ClosedLoopResult", "run_closed_loop"], "sim.loop"),
    **dict.fromkeys(
        ["ClosedLoopMetrics", "compute_metrics", "integral_absolute_error_kw_s",
         "integral_squared_error_kw2_s", "overshoot_kw", "settling_time_s",
         "steady_state_error_kw", "total_variation_pct"], "sim.metrics"),
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
__all__ = sorted(_EXPORTS)

if TYPE_CHECKING:
    from sim.disturbances import (
        MeasurementSpike,
        MissingSamples,
        PowerShift,
        RandomSpikes,
        VoltageRamp,
        VoltageStep,
    )
    from sim.errors import PlantError, ScenarioError, SimError
    from sim.experiment import ExperimentSpec, identification_experiment
    from sim.heater import HeaterParams, VirtualHeater
    from sim.loop import ClosedLoopResult, run_closed_loop
    from sim.metrics import (
        ClosedLoopMetrics,
        compute_metrics,
        integral_absolute_error_kw_s,
        integral_squared_error_kw2_s,
        overshoot_kw,
        settling_time_s,
        steady_state_error_kw,
        total_variation_pct,
    )
    from sim.model_plant import ModelPlant
    from sim.protocols import NOMINAL, Controller, Exogenous, Plant
    from sim.scenario import Scenario, SetpointRamp, SetpointStep, list_scenarios, load_scenario
