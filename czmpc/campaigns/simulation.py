"""run_simulation and write_outputs: one closed-loop run of the offset-free MPC, wired up.

`czmpc simulate` and `czmpc demo` call it. The plant (``"model"``: the model's own
difference equation, no mismatch; ``"heater"``: the virtual heater's grey-box physics;
``"thermal"``: a furnace zone, a plant of another kind, `sim.thermal_plant`)
is built and started in steady state by `czmpc.campaigns.build.build_plant`, or varied
and drifting (`sim.drift`). The controller's limits and start input are the plant's and
the scenario's (`czmpc.campaigns.build.controller_settings`), so the metrics check it
against the limits it was told.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal, cast, get_args

import numpy as np
from matplotlib.figure import Figure

from czmpc.campaigns.build import build_controller, build_plant, controller_settings
from czmpc.controller import OffsetFreeMPC
from czmpc.inversion import allowed_triac_range
from czmpc.reports.closed_loop_figure import plot_closed_loop
from czmpc.settings import MPCSettings
from sim.drift import PlantVariation, vary_heater, vary_model_plant
from sim.errors import SimError
from sim.heater import HeaterParams, VirtualHeater
from sim.loop import VOLTAGE_SENSOR_NOISE_STD, ClosedLoopResult, ProgressCallback, run_closed_loop
from sim.metrics import ClosedLoopMetrics, compute_metrics
from sim.protocols import Controller, Plant
from sim.scenario import Scenario
from sysid.atomic import atomic_write_text, file_sha256
from sysid.model import HammersteinModel

PlantKind = Literal["model", "heater", "thermal"]
#: A controller to run instead of the MPC: its name and how to build it from the completed
#: settings and the allowed input range [%] (`run_simulation`).
ControllerFactory = tuple[str, Callable[[MPCSettings, tuple[float, float]], Controller]]

#: What each plant kind is, for tables, figures and metrics.json.
PLANT_DESCRIPTIONS: dict[str, str] = {
    "model": "plant built from the identified model (no model mismatch)",
    "heater": "virtual CZ heater (grey-box physics: model mismatch)",
    "thermal": "furnace zone, lags of 20 s and 140 s, 0.1 degC sensor (a plant of another kind)",
}

#: Files `write_outputs` writes into its directory.
TRAJECTORY_FILE = "trajectory.csv"
METRICS_FILE = "metrics.json"
FIGURE_FILE = "figure.png"


@dataclass(frozen=True, kw_only=True)
class SimulationOutcome:
    """One closed-loop run of the offset-free MPC with what it was run with.

    Parameters
    ----------
    plant :
        ``"model"``, ``"heater"`` or ``"thermal"`` (see the module docstring).
    noise :
        Whether the plant's noise was on.
    seed :
        Seed of the run's noise and fault streams.
    initial_triac_pct :
        TRIAC input the plant started in steady state at [%].
    settings :
        The controller settings used (limits from the scenario, initial input set).
    allowed_triac_range_pct :
        ``(s_min, s_max)`` the controller kept its output in [%] (model validity range
        widened by the margin, within the TRIAC limits).
    result :
        The recorded run.
    metrics :
        Its metrics on the plant's true power (without sensor noise, spikes and missing
        samples).
    controller :
        What ran: ``"mpc"`` (`OffsetFreeMPC` with ``settings``) or the name the caller
        gave its own controller (`run_simulation`'s ``controller_factory``).
    metrics_measured :
        Its metrics on the measured power (NaN samples skipped; spikes included): on the
        model plant the ones to judge offsets by. The controller rejects the mostly slow
        noise ``v = C/A e`` (``C(1)/A(1)`` about 50 for the shipped model), so the
        noise-free power wanders by ``-v``'s slow part (a few hundredths of a kW).
    """

    plant: PlantKind
    noise: bool
    seed: int
    initial_triac_pct: float
    settings: MPCSettings
    allowed_triac_range_pct: tuple[float, float]
    result: ClosedLoopResult
    metrics: ClosedLoopMetrics
    metrics_measured: ClosedLoopMetrics
    controller: str = "mpc"

    @property
    def scenario(self) -> Scenario:
        """The scenario that was run."""
        return self.result.scenario

    def to_dict(self, *, model_sha256: str | None = None) -> dict[str, Any]:
        """JSON-ready summary: the run's configuration and its metrics (metrics.json).

        ``model_sha256`` is the SHA-256 of the model file the controller was built from
        (None: not from a file); the czmpc version is recorded beside it.
        """
        from sysid._version import __version__

        settings = asdict(self.settings)
        return {
            "format": "czmpc-simulation-metrics/1",
            "czmpc_version": str(__version__),
            "model_sha256": model_sha256,
            "scenario": self.scenario.name,
            "scenario_source": self.scenario.source,
            "plant": self.plant,
            "plant_description": PLANT_DESCRIPTIONS[self.plant],
            "noise": self.noise,
            "seed": self.seed,
            "n_steps": self.result.n_steps,
            "ts_s": self.result.ts_s,
            "initial_triac_pct": self.initial_triac_pct,
            "controller": self.controller,
            "allowed_triac_range_pct": list(self.allowed_triac_range_pct),
            "controller_settings": settings,
            "metrics": self.metrics.to_dict(),
            "metrics_measured": self.metrics_measured.to_dict(),
        }

    def metrics_table(self) -> str:
        """The metrics as a plain-text table: one row per setpoint change, then the run.

        Units are in the column headers; ``-`` marks a response that did not settle
        within its segment.
        """
        return format_metrics_table(self.metrics, self.metrics_measured, title=(
            f"scenario '{self.scenario.name}', {PLANT_DESCRIPTIONS[self.plant]}, "
            f"seed {self.seed}, noise {'on' if self.noise else 'off'}"
        ))


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None or not math.isfinite(value) else format(value, spec)


def format_metrics_table(metrics: ClosedLoopMetrics, measured: ClosedLoopMetrics | None = None,
                         *, title: str) -> str:
    """Render `ClosedLoopMetrics` as text: per setpoint change, then overall.

    Parameters
    ----------
    metrics :
        The run's metrics on the true power.
    measured :
        The same run's metrics on the measured power, or None; adds its steady-state
        errors as a column.
    title :
        First line of the table.
    """
    lines = [title]
    if metrics.changes:
        header = (f"{'change at [s]':>13}  {'setpoint [kW]':>15}  {'IAE [kW s]':>10}  "
                  f"{'overshoot [kW]':>14}  {'overshoot [%]':>13}  {'settling [s]':>12}  "
                  f"{'steady error true [kW]':>22}")
        if measured is not None:
            header += f"  {'steady error measured [kW]':>26}"
        lines += ["per setpoint change (errors of the true power unless marked 'measured'; "
                  "2 % settling band; steady error: mean over the segment's last quarter):", header]
        for i, c in enumerate(metrics.changes):
            row = (
                f"{c.time_s:>13.0f}  {c.from_kw:>6.1f} -> {c.to_kw:<5.1f}  "
                f"{c.iae_kw_s:>10.2f}  {c.overshoot_kw:>14.3f}  {_fmt(c.overshoot_pct, '.1f'):>13}  "
                f"{_fmt(c.settling_time_s, '.0f'):>12}  {c.steady_state_error_kw:>22.4f}"
            )
            if measured is not None:
                row += f"  {_fmt(measured.changes[i].steady_state_error_kw, '.4f'):>26}"
            lines.append(row)
    failures = "-" if metrics.n_solver_failures is None else str(metrics.n_solver_failures)
    lines += [
        "overall:",
        f"  IAE {metrics.iae_kw_s:.2f} kW s, ISE {metrics.ise_kw2_s:.3f} kW^2 s, "
        f"largest |steady error| {_fmt(metrics.max_abs_steady_state_error_kw, '.4f')} kW"
        + ("" if measured is None else
           f" (measured power: {_fmt(measured.max_abs_steady_state_error_kw, '.4f')} kW)"),
        f"  input total variation {metrics.input_total_variation_pct:.1f} %, largest move "
        f"{metrics.max_move_pct:.2f} %/step, limit violations {metrics.n_limit_violations}, "
        f"rate violations {metrics.n_rate_violations}, solver fallbacks {failures}",
        f"  controller step time: median {metrics.step_time_median_ms:.3f} ms, p95 "
        f"{metrics.step_time_p95_ms:.3f} ms, max {metrics.step_time_max_ms:.3f} ms",
    ]
    return "\n".join(lines)


def _build_plant(model: HammersteinModel, scenario: Scenario, plant: PlantKind,
                 noise: bool, variation: PlantVariation | None = None) -> tuple[Plant, float]:
    """The plant and the TRIAC input [%] it starts in steady state at.

    A plant with a ``variation`` (`sim.drift`) starts in steady state at the *nominal*
    plant's input for the initial setpoint (so a plant with another gain starts off the
    setpoint, as a drifted one would).
    """
    nominal, s0, _ = build_plant(plant, model, scenario, noise=noise)
    if variation is None or variation.is_nominal:
        return nominal, s0
    if plant == "thermal":
        raise SimError("run_simulation: the thermal plant has no variations (sim.drift varies the "
                       f"model plant and the heater); got {variation!r}")
    if plant == "model":
        return vary_model_plant(model, variation, noise=noise, initial_triac_pct=s0), s0
    params = nominal.params if isinstance(nominal, VirtualHeater) else HeaterParams()
    return vary_heater(variation, params), s0


def run_simulation(
    model: HammersteinModel,
    scenario: Scenario,
    *,
    plant: PlantKind,
    seed: int,
    settings: MPCSettings | None = None,
    noise: bool = True,
    progress: ProgressCallback | None = None,
    variation: PlantVariation | None = None,
    controller_factory: ControllerFactory | None = None,
) -> SimulationOutcome:
    """Run the offset-free MPC of ``model`` (or another controller) through ``scenario``.

    Parameters
    ----------
    model :
        The identified model the controller is built from (and, for ``plant="model"``,
        the plant).
    scenario :
        Setpoints, disturbances, faults and duration; its ``ts_s`` must be the model's.
    plant :
        ``"model"`` (`ModelPlant`, no mismatch), ``"heater"`` (`VirtualHeater`) or
        ``"thermal"`` (`sim.thermal_plant.ThermalPlant`, for a model identified from it).
    seed :
        Seed of the plant noise and sensor faults (int >= 0); the same seed gives
        bit-identical runs.
    settings :
        Controller tuning; None: `MPCSettings.default_for` ``(model)``. Limits and the
        initial input are completed by `czmpc.campaigns.build.controller_settings`.
    noise :
        Plant noise on (the model's innovations through ``C/A``, or the heater's sensor
        noise and grid wander) or off.
    progress :
        Called as ``progress(samples_done, n_steps)`` about every 1 % of the run.
    variation :
        A plant that differs from its nominal self and drifts (`sim.drift`); None: the
        nominal plant.
    controller_factory :
        ``(name, build)``: run ``build(settings, allowed_triac_range_pct)`` instead of the
        MPC, with the completed settings (limits, rate limit, start input) and the MPC's
        allowed input range, so it gets what the MPC would; None: the MPC.

    Returns
    -------
    SimulationOutcome
        The run, its metrics and the settings used.

    Raises
    ------
    SamplingTimeError
        The scenario's sampling time differs from the model's.
    SimError
        An unknown plant kind, an initial setpoint no plant input reaches.
    SettingsError, DesignError
        No sound controller from ``model`` and the (completed) settings.
    """
    if plant not in get_args(PlantKind):
        raise SimError(f"run_simulation: expected plant 'model', 'heater' or 'thermal'; got {plant!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimError(f"run_simulation: expected an int seed >= 0; got {seed!r}")
    model.check_ts(scenario.ts_s, what=f"scenario '{scenario.name}'")
    the_plant, s0 = _build_plant(model, scenario, plant, bool(noise), variation)
    used = controller_settings(model, scenario, initial_triac_pct=s0, settings=settings)
    allowed = allowed_triac_range(model, triac_min_pct=used.triac_min_pct,
                                  triac_max_pct=used.triac_max_pct,
                                  validity_margin_pct=used.validity_margin_pct)
    controller: Controller
    if controller_factory is None:
        mpc = cast(OffsetFreeMPC, build_controller("mpc", model, scenario, initial_triac_pct=s0,
                                                   settings=settings))
        name, controller, allowed = "mpc", mpc, mpc.allowed_triac_range_pct
    else:
        name, controller = controller_factory[0], controller_factory[1](used, allowed)
    result = run_closed_loop(the_plant, controller, scenario, rng=int(seed), progress=progress,
                             voltage_noise_std=VOLTAGE_SENSOR_NOISE_STD if noise else 0.0)
    return SimulationOutcome(
        plant=plant, noise=bool(noise), seed=int(seed), initial_triac_pct=s0, settings=used,
        controller=name, allowed_triac_range_pct=allowed, result=result,
        metrics=compute_metrics(result),
        metrics_measured=compute_metrics(result, power_signal="measured"),
    )


def write_outputs(outcome: SimulationOutcome, out_dir: str | os.PathLike[str], *,
                  model_path: str | os.PathLike[str] | None = None) -> tuple[Path, ...]:
    """Write a run's trajectory, metrics and figure into ``out_dir`` (created if needed).

    Files: ``trajectory.csv`` (`ClosedLoopResult.to_csv`: one row per sample, units in
    the column names, the controller's status per step), ``metrics.json``
    (`SimulationOutcome.to_dict`) and ``figure.png``
    (`czmpc.reports.closed_loop_figure.plot_closed_loop`).

    Parameters
    ----------
    outcome :
        The run.
    out_dir :
        Output directory; existing files of the same names are replaced.
    model_path :
        The model file the controller was built from (its SHA-256 goes into
        metrics.json), or None.

    Nothing in ``out_dir`` changes unless every writer succeeded: the files are written
    into a hidden scratch directory there, then renamed into place (a failure anywhere,
    SIGINT/SIGTERM included, leaves no new ``trajectory.csv``).

    Returns
    -------
    tuple of Path
        The files written, in the order above.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = (TRAJECTORY_FILE, METRICS_FILE, FIGURE_FILE)
    scratch = Path(tempfile.mkdtemp(prefix=".czmpc-simulate.", suffix=".tmp", dir=out))
    try:
        outcome.result.to_csv(scratch / TRAJECTORY_FILE)
        digest = None if model_path is None else file_sha256(model_path)
        atomic_write_text(scratch / METRICS_FILE, json.dumps(
            outcome.to_dict(model_sha256=digest), indent=2, allow_nan=False) + "\n")
        plot_outcome(outcome, scratch / FIGURE_FILE)
        for name in names:
            os.replace(scratch / name, out / name)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return tuple(out / name for name in names)


def plot_outcome(outcome: SimulationOutcome, path: str | os.PathLike[str]) -> Figure:
    """`czmpc.reports.closed_loop_figure.plot_closed_loop` of one `SimulationOutcome`.

    The disturbance panel shows ``disturbance_power_kw`` of each step's diagnostics
    (the estimated ``d`` as the steady power change it causes, kW for either
    disturbance model).
    """
    result = outcome.result
    diags = result.diagnostics
    dist = None
    if diags and all(hasattr(d, "disturbance_power_kw") for d in diags):
        dist = np.array([float(d.disturbance_power_kw) for d in diags])  # type: ignore[attr-defined]
    settings = outcome.settings
    return plot_closed_loop(
        result.time_s, result.setpoint_kw, result.power_measured_kw, result.power_true_kw,
        result.triac_pct, dist,
        allowed_triac_range_pct=outcome.allowed_triac_range_pct,
        triac_limits_pct=(settings.triac_min_pct, settings.triac_max_pct),
        soft_power_limits_kw=(settings.soft_power_min_kw, settings.soft_power_max_kw),
        title=(f"Offset-free MPC, scenario '{outcome.scenario.name}': "
               f"{PLANT_DESCRIPTIONS[outcome.plant]}, seed {outcome.seed}"),
        path=path,
    )


__all__ = ["FIGURE_FILE", "METRICS_FILE", "PLANT_DESCRIPTIONS", "TRAJECTORY_FILE", "PlantKind",
           "SimulationOutcome", "format_metrics_table", "plot_outcome", "run_simulation", "write_outputs"]
