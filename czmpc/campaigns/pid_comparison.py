"""A tuned PID table in closed loop beside the MPC and a fixed-gain PI, on one scenario.

`compare_pid_table` runs three controllers through the same scenario, plant and seed
with what `czmpc.campaigns.simulation.run_simulation` gives the MPC (limits, rate limit,
start input, allowed range):

* ``pi_table``: `czmpc.pid.controller.ScheduledPID` running the table;
* ``mpc``: the offset-free MPC of the model;
* ``pi_fixed``: the same law with the table's row at the model's operating point
  everywhere (a PI tuned at the operating point, not scheduled).

Per controller it reports the run's IAE, the worst step (largest IAE of one setpoint
change and largest overshoot in percent of its step), the input travel and the ratio of
each to the MPC's. A scenario's ``setpoint_preview_s`` and ``measured_voltage`` reach every
controller: the MPC plans with both, the PIs use the voltage through the model's
characterizer (`table_pi_factory`) and have no use for the preview.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from czmpc.campaigns.simulation import (
    ControllerFactory,
    PlantKind,
    SimulationOutcome,
    run_simulation,
)
from czmpc.errors import CzmpcError
from czmpc.inversion import build_input_map
from czmpc.pid.controller import ScheduledPID, TableSchedule
from czmpc.settings import MPCSettings
from czmpc.voltage import VoltageCharacterizer, absolute_drive_kw
from sim.scenario import Scenario
from sysid.model import HammersteinModel

#: Names of the compared controllers, in report order.
COMPARED = ("pi_table", "mpc", "pi_fixed")


def table_pi_factory(name: str, schedule: TableSchedule, model: HammersteinModel
                     ) -> ControllerFactory:
    """A `run_simulation` controller factory running ``schedule`` with the run's limits.

    The PI gets ``model``'s voltage characterizer (`czmpc.voltage.VoltageCharacterizer`), so
    in a scenario with ``measured_voltage`` it divides the drive by ``v^2`` as the MPC does.
    """
    def build(settings: MPCSettings, allowed: tuple[float, float]) -> ScheduledPID:
        if settings.initial_triac_pct is None:  # run_simulation always completes it
            raise CzmpcError(f"{name}: expected settings with initial_triac_pct; got None")
        input_map = build_input_map(model, triac_min_pct=settings.triac_min_pct,
                                    triac_max_pct=settings.triac_max_pct,
                                    validity_margin_pct=settings.validity_margin_pct)
        characterizer = VoltageCharacterizer(input_map=input_map, w0_kw=absolute_drive_kw(
            model.operating_point.power_kw, model.linear_static_gain))
        return ScheduledPID(schedule=schedule, ts_s=model.ts_s,
                            initial_triac_pct=settings.initial_triac_pct,
                            triac_limits_pct=allowed,
                            max_move_pct_per_step=settings.max_move_pct_per_step,
                            voltage_characterizer=characterizer)
    return name, build


def fixed_at_operating_point(schedule: TableSchedule, model: HammersteinModel) -> TableSchedule:
    """The one-row schedule of the row in force at the model's operating point."""
    row = schedule.tuning_at(model.operating_point.triac_pct)
    return TableSchedule(breakpoints_pct=(model.operating_point.triac_pct,), tunings=(row,))


@dataclass(frozen=True, kw_only=True)
class ControllerSummary:
    """One controller's run, summarised.

    Parameters
    ----------
    name :
        One of `COMPARED`.
    outcome :
        The run.
    iae_kw_s :
        IAE of the whole run [kW s] (true power).
    worst_step_iae_kw_s :
        Largest IAE of one setpoint change [kW s].
    worst_overshoot_pct :
        Largest overshoot of one setpoint step, in % of that step [%].
    iae_ratio_to_mpc :
        ``iae_kw_s`` over the MPC's [-].
    input_travel_pct :
        Sum of the input's moves ``sum |s_k - s_{k-1}|`` [%].
    overshoot_ratio_to_mpc, travel_ratio_to_mpc :
        ``worst_overshoot_pct`` and ``input_travel_pct`` over the MPC's [-] (NaN where
        the MPC's is 0 or there is no step).
    """

    name: str
    outcome: SimulationOutcome
    iae_kw_s: float
    worst_step_iae_kw_s: float
    worst_overshoot_pct: float
    iae_ratio_to_mpc: float
    input_travel_pct: float
    overshoot_ratio_to_mpc: float
    travel_ratio_to_mpc: float


def _ratio(value: float, reference: float) -> float:
    return value / reference if reference > 0 and math.isfinite(value) else math.nan


def compare_pid_table(
    model: HammersteinModel, schedule: TableSchedule, scenario: Scenario, *, plant: PlantKind,
    seed: int, noise: bool, settings: MPCSettings | None = None,
) -> tuple[ControllerSummary, ...]:
    """Run `COMPARED` through ``scenario`` on ``plant`` (module notes).

    Parameters
    ----------
    model :
        The model of the MPC and of the model plant; its sampling time is the table's.
    schedule :
        The table (`czmpc.pid.table.read_pid_table`).
    scenario, plant, seed, noise, settings :
        As `czmpc.campaigns.simulation.run_simulation`.
    """
    factories = {"pi_table": table_pi_factory("pi_table", schedule, model),
                 "mpc": None,
                 "pi_fixed": table_pi_factory("pi_fixed", fixed_at_operating_point(
                     schedule, model), model)}
    outcomes = {name: run_simulation(model, scenario, plant=plant, seed=seed, settings=settings,
                                     noise=noise, controller_factory=factory)
                for name, factory in factories.items()}
    def worst_overshoot(name: str) -> float:
        steps = [c for c in outcomes[name].metrics.changes if c.kind == "step"]
        return max((c.overshoot_pct for c in steps), default=math.nan)

    mpc = outcomes["mpc"].metrics
    out = []
    for name in COMPARED:
        metrics = outcomes[name].metrics
        overshoot = worst_overshoot(name)
        out.append(ControllerSummary(
            name=name, outcome=outcomes[name], iae_kw_s=metrics.iae_kw_s,
            worst_step_iae_kw_s=max((c.iae_kw_s for c in metrics.changes), default=math.nan),
            worst_overshoot_pct=overshoot,
            iae_ratio_to_mpc=metrics.iae_kw_s / mpc.iae_kw_s,
            input_travel_pct=metrics.input_total_variation_pct,
            overshoot_ratio_to_mpc=_ratio(overshoot, worst_overshoot("mpc")),
            travel_ratio_to_mpc=_ratio(metrics.input_total_variation_pct,
                                       mpc.input_total_variation_pct)))
    return tuple(out)


def comparison_table(summaries: tuple[ControllerSummary, ...], *, title: str) -> str:
    """Plain-text table of `compare_pid_table`'s summaries, units in the header."""
    lines = [title, f"{'controller':>10}  {'IAE [kW s]':>11}  {'IAE / MPC [-]':>13}  "
             f"{'worst step IAE [kW s]':>21}  {'worst overshoot [% of step]':>27}  "
             f"{'/ MPC [-]':>9}  {'input travel [%]':>16}  {'/ MPC [-]':>9}"]
    for s in summaries:
        lines.append(f"{s.name:>10}  {s.iae_kw_s:>11.2f}  {s.iae_ratio_to_mpc:>13.3f}  "
                     f"{s.worst_step_iae_kw_s:>21.2f}  {s.worst_overshoot_pct:>27.2f}  "
                     f"{s.overshoot_ratio_to_mpc:>9.2f}  {s.input_travel_pct:>16.1f}  "
                     f"{s.travel_ratio_to_mpc:>9.2f}")
    return "\n".join(lines)


def comparison_csv(summaries: tuple[ControllerSummary, ...]) -> str:
    """CSV text of the summaries (units in the column names)."""
    lines = ["controller,iae_kw_s,iae_ratio_to_mpc,worst_step_iae_kw_s,worst_overshoot_pct,"
             "overshoot_ratio_to_mpc,input_travel_pct,travel_ratio_to_mpc"]
    lines += [f"{s.name},{s.iae_kw_s!r},{s.iae_ratio_to_mpc!r},{s.worst_step_iae_kw_s!r},"
              f"{s.worst_overshoot_pct!r},{s.overshoot_ratio_to_mpc!r},{s.input_travel_pct!r},"
              f"{s.travel_ratio_to_mpc!r}" for s in summaries]
    return "\n".join(lines) + "\n"


__all__ = ["COMPARED", "ControllerSummary", "compare_pid_table", "comparison_csv",
           "comparison_table", "fixed_at_operating_point", "table_pi_factory"]
