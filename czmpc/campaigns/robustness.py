"""Robustness campaign: the offset-free MPC against plants that differ from its model.

The controller is always built from the one given model. The plants are

* `ModelPlant` s of that model perturbed by `sim.perturbed.perturb_model`: a grid of
  gain factors (all gains x g), slow-time-constant factors (tau x m, with the
  instantaneous response and the static gain held) and extra delays (+n samples);
* the virtual CZ heater (`sim.heater.VirtualHeater`), the grey-box stand-in for the
  real process the model was identified from (structural mismatch).

Every plant starts at rest at the scenario's initial setpoint: at its own steady-state
input for that power (the scenario's ``initial_triac_pct`` is not used, so a plant
with another gain does not start with an error). The controller starts from the same
input. Every run uses the same seed. By default the plants are noise-free, so every
number measures model mismatch alone (with noise, the model plant's slowly drifting
noise ``C/A e``, which the controller rightly follows in the measured power, dominates
the IAE of the true power).

A setpoint the plant cannot hold with the controller's allowed input range (a plant
with 30 % less gain cannot reach the top of the staircase) is *unreachable*; the best
any controller can do there is the closest power the plant can hold, ``P_ss(s_max)`` or
``P_ss(s_min)``. All errors below are taken against this *reachable setpoint* (the
setpoint clipped to ``[P_ss(s_min), P_ss(s_max)]`` of that plant), so an unreachable step
counts as tracked when the power settles at the plant's limit, and the number of
unreachable changes is reported.

Per variant (`VariantResult`), over the setpoint changes of the scenario (the initial
segment, which starts at rest, is left out):

* **offset-free**: every change ends with ``|steady-state error| < threshold``, the
  steady-state error being the mean of the *measured* power minus the reachable
  setpoint over the last quarter of the segment (`sim.metrics.STEADY_STATE_FRACTION`);
  the measured power is what the controller regulates;
* **IAE** of the *true* power against the reachable setpoint [kW s], and its ratio to
  the nominal plant's (gain 1, tau 1, no extra delay);
* **overshoot** of the true power beyond the reachable setpoint: the largest over the
  changes [kW], and in % of that change's (reachable) size;
* **input violations**: samples outside the controller's allowed input range plus
  moves beyond its rate limit (if any). These must be 0 for every plant.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal

import numpy as np
from scipy.optimize import brentq

from czmpc.controller import OffsetFreeMPC
from czmpc.errors import CzmpcError
from czmpc.settings import MPCSettings
from sim.errors import SimError
from sim.heater import HeaterParams, VirtualHeater
from sim.heater import steady_state as heater_steady_state
from sim.loop import ClosedLoopResult, run_closed_loop
from sim.metrics import (
    count_limit_violations,
    count_rate_violations,
    integral_absolute_error_kw_s,
    overshoot_kw,
    steady_state_error_kw,
)
from sim.model_plant import ModelPlant, steady_state_triac_pct
from sim.perturbed import perturb_model
from sim.protocols import Plant
from sim.scenario import Scenario
from sysid.model import HammersteinModel

if TYPE_CHECKING:
    from matplotlib.figure import Figure

GridName = Literal["quick", "full"]
PlantKind = Literal["model", "heater"]
#: ``progress(i, n, variant)`` is called before run ``i`` (1-based) of ``n``.
ProgressCallback = Callable[[int, int, "PlantVariant"], None]

#: Default threshold on |steady-state error| for "offset-free" [kW]: 1 % of the 5 kW
#: setpoint steps of the staircase scenario, about 4 noise standard deviations.
DEFAULT_SSE_THRESHOLD_KW = 0.05


class RobustnessError(CzmpcError, ValueError):
    """A campaign that cannot be run as asked (bad grid, threshold or scenario)."""


@dataclass(frozen=True, kw_only=True)
class RobustnessGrid:
    """Perturbation factors; the campaign runs their full Cartesian product.

    Parameters
    ----------
    gain_factors :
        Gain factors ``g`` [-], each > 0; must include 1.
    time_constant_factors :
        Slow-time-constant factors ``m`` [-], each > 0; must include 1.
    extra_delays_steps :
        Extra input delays [samples], each >= 0; must include 0.
    """

    gain_factors: tuple[float, ...]
    time_constant_factors: tuple[float, ...]
    extra_delays_steps: tuple[int, ...]

    def __post_init__(self) -> None:
        for name, nominal in (("gain_factors", 1.0), ("time_constant_factors", 1.0),
                              ("extra_delays_steps", 0)):
            values = tuple(sorted(set(getattr(self, name))))
            if nominal not in values:
                raise RobustnessError(
                    f"RobustnessGrid.{name}: expected the nominal value {nominal} among "
                    f"the values (IAE ratios are taken to it); got {list(values)}"
                )
            object.__setattr__(self, name, values)

    @property
    def n_variants(self) -> int:
        """Number of perturbed model plants."""
        return len(self.gain_factors) * len(self.time_constant_factors) * len(
            self.extra_delays_steps)


#: The grids of ``czmpc robustness --grid``: gain -30 % .. +30 %, tau x0.5 .. x2, +1 sample.
GRIDS: dict[str, RobustnessGrid] = {
    "quick": RobustnessGrid(
        gain_factors=(0.7, 0.85, 1.0, 1.15, 1.3),
        time_constant_factors=(0.5, 1.0, 2.0),
        extra_delays_steps=(0, 1),
    ),
    "full": RobustnessGrid(
        gain_factors=(0.7, 0.75, 0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2, 1.25, 1.3),
        time_constant_factors=(0.5, 0.59, 0.71, 0.84, 1.0, 1.19, 1.41, 1.68, 2.0),  # 2^(k/4)
        extra_delays_steps=(0, 1),
    ),
}


@dataclass(frozen=True, kw_only=True)
class PlantVariant:
    """One plant of the campaign.

    Parameters
    ----------
    kind :
        ``"model"`` (a perturbed `ModelPlant`) or ``"heater"`` (the virtual heater).
    gain_factor, time_constant_factor, extra_delay_steps :
        The perturbation of a ``"model"`` plant; None for the heater.
    """

    kind: PlantKind
    gain_factor: float | None = None
    time_constant_factor: float | None = None
    extra_delay_steps: int | None = None

    @property
    def is_nominal(self) -> bool:
        """True for the unperturbed model plant."""
        return (self.kind == "model" and self.gain_factor == 1.0
                and self.time_constant_factor == 1.0 and self.extra_delay_steps == 0)

    @property
    def label(self) -> str:
        """Short human-readable name, e.g. ``"gain x0.70, tau x2.00, delay +1"``."""
        if self.kind == "heater":
            return "virtual heater"
        return (f"gain x{self.gain_factor:.2f}, tau x{self.time_constant_factor:.2f}, "
                f"delay +{self.extra_delay_steps}")


@dataclass(frozen=True, kw_only=True)
class VariantResult:
    """What the controller achieved on one plant variant (definitions: module docstring).

    Parameters
    ----------
    variant :
        The plant.
    offset_free :
        Every change ends with ``|steady-state error| < threshold``.
    steady_state_errors_kw :
        Steady-state error of every change (measured power) [kW].
    max_abs_steady_state_error_kw :
        Largest ``|steady-state error|`` over the changes [kW].
    n_unreachable_changes :
        Changes whose setpoint lies outside the plant's steady-state power range over
        the controller's allowed input range.
    iae_kw_s :
        IAE of the true power over the change segments [kW s].
    iae_ratio :
        ``iae_kw_s`` over the nominal plant's [-].
    max_overshoot_kw, max_overshoot_pct :
        Largest overshoot over the changes [kW], and in % of its change's size.
    n_input_violations :
        Input samples outside the allowed range plus moves beyond the rate limit.
    n_solver_fallbacks :
        Controller steps that fell back to a shifted plan or the target.
    run_time_s :
        Wall-clock time of the closed-loop run [s].
    """

    variant: PlantVariant
    offset_free: bool
    steady_state_errors_kw: tuple[float, ...]
    max_abs_steady_state_error_kw: float
    n_unreachable_changes: int
    iae_kw_s: float
    iae_ratio: float
    max_overshoot_kw: float
    max_overshoot_pct: float
    n_input_violations: int
    n_solver_fallbacks: int
    run_time_s: float


@dataclass(frozen=True, kw_only=True)
class RobustnessReport:
    """The whole campaign.

    Parameters
    ----------
    model_source :
        Where the controller's model came from (a file name or a description).
    scenario :
        The scenario every plant ran.
    grid_name :
        ``"quick"``, ``"full"`` or ``"custom"``.
    grid :
        The perturbation grid.
    seed :
        Seed of every run.
    noise :
        Whether the plants had noise (see `run_robustness`).
    settings :
        The controller settings (before the per-plant initial input).
    sse_threshold_kw :
        Threshold of the offset-free test [kW].
    allowed_triac_range_pct :
        The controller's allowed input range [%].
    results :
        One per plant: the model variants in grid order (delay, tau, gain), then the
        heater (if run).
    total_time_s :
        Wall-clock time of the campaign [s].
    """

    model_source: str
    scenario: Scenario
    grid_name: str
    grid: RobustnessGrid
    seed: int
    noise: bool
    settings: MPCSettings
    sse_threshold_kw: float
    allowed_triac_range_pct: tuple[float, float]
    results: tuple[VariantResult, ...] = field(repr=False)
    total_time_s: float

    @property
    def nominal(self) -> VariantResult:
        """The result on the unperturbed model plant."""
        return next(r for r in self.results if r.variant.is_nominal)

    def result_for(self, *, gain_factor: float, time_constant_factor: float,
                   extra_delay_steps: int) -> VariantResult:
        """The result of one model variant (KeyError if it was not run)."""
        for r in self.results:
            v = r.variant
            if (v.kind == "model" and v.gain_factor == gain_factor
                    and v.time_constant_factor == time_constant_factor
                    and v.extra_delay_steps == extra_delay_steps):
                return r
        raise KeyError((gain_factor, time_constant_factor, extra_delay_steps))


# --- running ------------------------------------------------------------------------------
def _heater_triac_for_power_pct(power_kw: float, params: HeaterParams) -> float:
    """TRIAC input whose steady heater power is ``power_kw`` (monotone in s; brentq)."""
    def excess(s: float) -> float:
        return heater_steady_state(s, params)[0] - power_kw

    lo, hi = params.firing_threshold_pct, 100.0
    if not excess(lo) < 0.0 < excess(hi):
        raise RobustnessError(
            f"robustness: expected an initial setpoint the virtual heater reaches in steady "
            f"state with 0..100 % input; got {power_kw:g} kW"
        )
    return float(brentq(excess, lo, hi, xtol=1e-10))


def _build_plant(
    model: HammersteinModel, variant: PlantVariant, scenario: Scenario, noise: bool
) -> tuple[Plant, float, Callable[[float], float]]:
    """The plant, its initial input [%], and its steady-state power [kW] at an input [%]."""
    if variant.kind == "heater":
        quiet = {} if noise else {"sensor_noise_std_kw": 0.0, "grid_wander_std": 0.0}
        base = HeaterParams(ts_s=scenario.ts_s, **quiet)
        s0 = _heater_triac_for_power_pct(scenario.initial_setpoint_kw, base)
        params = replace(base, initial_triac_pct=s0)
        return VirtualHeater(params), s0, lambda s: heater_steady_state(s, params)[0]
    plant_model = perturb_model(
        model, gain_factor=float(variant.gain_factor or 1.0),
        time_constant_factor=float(variant.time_constant_factor or 1.0),
        extra_delay_steps=int(variant.extra_delay_steps or 0),
    )
    s0 = steady_state_triac_pct(plant_model, scenario.initial_setpoint_kw,
                                triac_limits_pct=scenario.triac_limits_pct)
    plant = ModelPlant(plant_model, noise=noise and scenario.plant_noise, initial_triac_pct=s0)
    return plant, s0, lambda s: max(0.0, float(plant_model.steady_state_power_kw(s)))


def _variants(grid: RobustnessGrid, include_heater: bool) -> list[PlantVariant]:
    out = [
        PlantVariant(kind="model", gain_factor=g, time_constant_factor=m, extra_delay_steps=n)
        for n in grid.extra_delays_steps
        for m in grid.time_constant_factors
        for g in grid.gain_factors
    ]
    if include_heater:
        out.append(PlantVariant(kind="heater"))
    return out


@dataclass(frozen=True, kw_only=True)
class _Run:
    variant: PlantVariant
    sse_kw: tuple[float, ...]
    reachable: tuple[bool, ...]
    iae_kw_s: float
    overshoot_kw: float
    overshoot_pct: float
    n_violations: int
    n_fallbacks: int
    run_time_s: float


def _run_one(model: HammersteinModel, variant: PlantVariant, scenario: Scenario,
             settings: MPCSettings, seed: int, noise: bool) -> _Run:
    try:
        plant, s0, power_at = _build_plant(model, variant, scenario, noise)
    except SimError as exc:
        raise RobustnessError(f"robustness: cannot build the plant '{variant.label}': {exc}") from None
    try:
        controller = OffsetFreeMPC(model, settings.with_updates(initial_triac_pct=s0))
    except CzmpcError as exc:
        raise RobustnessError(
            f"robustness: cannot start the controller for the plant '{variant.label}' at "
            f"its initial input {s0:.2f} %: {exc}"
        ) from None
    t0 = time.perf_counter()
    result = run_closed_loop(plant, controller, scenario, rng=seed)
    run_time_s = time.perf_counter() - t0
    m = reachable_measures(result, scenario, power_at, controller.allowed_triac_range_pct,
                           settings.max_move_pct_per_step)
    return _Run(
        variant=variant, sse_kw=m.steady_state_errors_kw, reachable=m.reachable,
        iae_kw_s=m.iae_kw_s, overshoot_kw=m.max_overshoot_kw, overshoot_pct=m.max_overshoot_pct,
        n_violations=m.n_input_violations, n_fallbacks=controller.n_fallbacks,
        run_time_s=run_time_s,
    )


@dataclass(frozen=True, kw_only=True)
class ReachableMeasures:
    """One run measured against its reachable setpoint (definitions: module docstring).

    Parameters
    ----------
    steady_state_errors_kw :
        Steady-state error of the measured power after every change [kW].
    reachable :
        Per change: its setpoint lies strictly inside the plant's power range.
    iae_kw_s :
        IAE of the true power over the change segments [kW s].
    max_overshoot_kw, max_overshoot_pct :
        Largest overshoot over the changes [kW], and in % of that change.
    n_input_violations :
        Samples outside the allowed range plus moves beyond the rate limit.
    """

    steady_state_errors_kw: tuple[float, ...]
    reachable: tuple[bool, ...]
    iae_kw_s: float
    max_overshoot_kw: float
    max_overshoot_pct: float
    n_input_violations: int

    def offset_free(self, threshold_kw: float) -> bool:
        """Every change ends with ``|steady-state error| < threshold_kw`` (NaN fails)."""
        return all(abs(e) < threshold_kw for e in self.steady_state_errors_kw)

    @property
    def max_abs_steady_state_error_kw(self) -> float:
        """Largest ``|steady-state error|`` [kW] (NaN if any is NaN or none exists)."""
        errors = [abs(e) for e in self.steady_state_errors_kw]
        if not errors or any(math.isnan(e) for e in errors):
            return math.nan
        return max(errors)


def reachable_measures(
    result: ClosedLoopResult, scenario: Scenario, power_at: Callable[[float], float],
    allowed_triac_range_pct: tuple[float, float], max_move_pct_per_step: float | None,
) -> ReachableMeasures:
    """Measure a run against the setpoint clipped to what its plant can hold.

    Parameters
    ----------
    result :
        The run.
    scenario :
        Its scenario (the setpoint-change segments).
    power_at :
        The plant's steady-state power [kW] at an input [%].
    allowed_triac_range_pct :
        The controller's allowed input range [%]: its ends give the plant's power range.
    max_move_pct_per_step :
        Rate limit [%/sample] whose excess moves count as violations, or None.

    The segments measured are the setpoint changes; a scenario without any (a
    disturbance scenario such as the voltage sag) is measured over its one segment,
    the whole run (its steady-state error is then that of the run's last quarter).
    """
    lo, hi = allowed_triac_range_pct
    p_lo, p_hi = sorted((power_at(lo), power_at(hi)))
    ts_s = scenario.ts_s
    # errors against the closest power the plant can hold (the setpoint if reachable)
    target = np.clip(result.setpoint_kw, p_lo, p_hi)
    true_error = result.power_true_kw - target
    measured_error = result.power_measured_kw - target
    sse, reachable, iae, worst_kw, worst_pct = [], [], 0.0, 0.0, 0.0
    segments = [seg for seg in scenario.segments() if seg.kind != "initial"]
    if not segments:  # no setpoint change (e.g. a disturbance scenario): the whole run
        segments = list(scenario.segments())
    for seg in segments:
        part = slice(seg.start_k, seg.stop_k)
        reachable.append(bool(p_lo < seg.to_kw < p_hi))
        sse.append(steady_state_error_kw(measured_error[part]))
        iae += integral_absolute_error_kw_s(true_error[part], ts_s)
        from_kw, to_kw = (min(max(v, p_lo), p_hi) for v in (seg.from_kw, seg.to_kw))
        over = overshoot_kw(result.power_true_kw[part], from_kw=from_kw, to_kw=to_kw)
        if over > worst_kw:
            worst_kw = over
            worst_pct = 100.0 * over / abs(to_kw - from_kw) if to_kw != from_kw else math.nan
    n_violations = count_limit_violations(result.triac_pct, (lo, hi))
    if max_move_pct_per_step is not None:
        n_violations += count_rate_violations(result.triac_pct, max_move_pct_per_step)
    return ReachableMeasures(
        steady_state_errors_kw=tuple(sse), reachable=tuple(reachable), iae_kw_s=iae,
        max_overshoot_kw=worst_kw, max_overshoot_pct=worst_pct, n_input_violations=n_violations)


def run_robustness(
    model: HammersteinModel,
    scenario: Scenario,
    *,
    grid: RobustnessGrid | GridName = "quick",
    settings: MPCSettings | None = None,
    seed: int = 1,
    sse_threshold_kw: float = DEFAULT_SSE_THRESHOLD_KW,
    include_heater: bool = True,
    noise: bool = False,
    model_source: str = "<memory>",
    progress: ProgressCallback | None = None,
) -> RobustnessReport:
    """Run the offset-free MPC built from ``model`` against every plant of the campaign.

    Parameters
    ----------
    model :
        The model the controller is built from (and the perturbed plants from).
    scenario :
        Setpoints, disturbances and faults of every run; needs at least one setpoint
        change. Its ``triac_limits_pct`` become the controller's hard limits and its
        rate limit (if any) the controller's.
    grid :
        A `RobustnessGrid` or the name of one of `GRIDS`.
    settings :
        Controller settings; default `MPCSettings.default_for` ``(model)``.
    seed :
        Seed of every run (same noise for every plant), >= 0.
    sse_threshold_kw :
        Offset-free threshold on ``|steady-state error|`` [kW], > 0.
    include_heater :
        Also run the virtual heater.
    noise :
        False (default): noise-free plants (model plants without innovations, the heater
        without sensor noise and grid wander), so every number measures model mismatch
        alone. True: the model plants follow the scenario's ``plant_noise`` and the
        heater has its default noise.
    model_source :
        Where ``model`` came from, for the report.
    progress :
        Called as ``progress(i, n, variant)`` before each run.

    Returns
    -------
    RobustnessReport

    Raises
    ------
    RobustnessError
        Unknown grid name, a scenario without setpoint changes, a bad threshold or
        seed, or a plant the controller cannot start at.
    SamplingTimeError
        The scenario's sampling time differs from the model's.
    """
    grid_name: str
    if isinstance(grid, str):
        if grid not in GRIDS:
            raise RobustnessError(
                f"run_robustness.grid: expected one of {sorted(GRIDS)}; got {grid!r}")
        grid_name, grid = grid, GRIDS[grid]
    else:
        grid_name = next((k for k, v in GRIDS.items() if v == grid), "custom")
    if not scenario.setpoints:
        raise RobustnessError(
            f"run_robustness: expected a scenario with setpoint changes; '{scenario.name}' "
            "has none (offset and overshoot are measured after changes)"
        )
    if isinstance(sse_threshold_kw, bool) or not (
        isinstance(sse_threshold_kw, (int, float)) and math.isfinite(sse_threshold_kw)
        and sse_threshold_kw > 0
    ):
        raise RobustnessError(
            f"run_robustness.sse_threshold_kw: expected a number > 0 [kW]; got {sse_threshold_kw!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise RobustnessError(f"run_robustness.seed: expected an integer >= 0; got {seed!r}")
    model.check_ts(scenario.ts_s, what=f"scenario '{scenario.name}'")
    base = MPCSettings.default_for(model) if settings is None else settings
    lo, hi = scenario.triac_limits_pct
    updates: dict[str, object] = {"triac_min_pct": lo, "triac_max_pct": hi}
    if scenario.max_move_pct_per_step is not None:
        updates["max_move_pct_per_step"] = scenario.max_move_pct_per_step
    base = base.with_updates(**updates)
    allowed = OffsetFreeMPC(model, base).allowed_triac_range_pct

    t_start = time.perf_counter()
    variants = _variants(grid, include_heater)
    runs: list[_Run] = []
    for i, variant in enumerate(variants, start=1):
        if progress is not None:
            progress(i, len(variants), variant)
        runs.append(_run_one(model, variant, scenario, base, seed, noise))
    nominal_iae = next(r.iae_kw_s for r in runs if r.variant.is_nominal)

    results = []
    for run in runs:
        errors = [abs(e) for e in run.sse_kw]
        # NaN (a segment whose samples are all missing) cannot show offset-free tracking
        worst = math.nan if any(math.isnan(e) for e in errors) else max(errors)
        results.append(VariantResult(
            variant=run.variant,
            offset_free=all(e < sse_threshold_kw for e in errors),
            steady_state_errors_kw=run.sse_kw,
            max_abs_steady_state_error_kw=worst,
            n_unreachable_changes=sum(not ok for ok in run.reachable),
            iae_kw_s=run.iae_kw_s,
            iae_ratio=run.iae_kw_s / nominal_iae if nominal_iae > 0 else math.nan,
            max_overshoot_kw=run.overshoot_kw,
            max_overshoot_pct=run.overshoot_pct,
            n_input_violations=run.n_violations,
            n_solver_fallbacks=run.n_fallbacks,
            run_time_s=run.run_time_s,
        ))
    return RobustnessReport(
        model_source=model_source, scenario=scenario, grid_name=grid_name, grid=grid,
        seed=seed, noise=noise, settings=base, sse_threshold_kw=float(sse_threshold_kw),
        allowed_triac_range_pct=allowed, results=tuple(results),
        total_time_s=time.perf_counter() - t_start,
    )


# --- outputs ------------------------------------------------------------------------------
#: Columns of robustness.csv, units in the names.
CSV_COLUMNS = (
    "plant", "gain_factor", "time_constant_factor", "extra_delay_steps", "offset_free",
    "max_abs_steady_state_error_kw", "n_unreachable_changes", "iae_kw_s", "iae_ratio",
    "max_overshoot_kw", "max_overshoot_pct", "n_input_violations", "n_solver_fallbacks",
    "run_time_s",
)


def _num(value: float | int | None) -> str:
    if value is None:
        return ""
    if isinstance(value, int):
        return str(value)
    return "nan" if not math.isfinite(value) else repr(float(value))


def format_csv(report: RobustnessReport) -> str:
    """robustness.csv: one row per plant, columns `CSV_COLUMNS`, full float precision."""
    lines = [",".join(CSV_COLUMNS)]
    for r in report.results:
        v = r.variant
        lines.append(",".join([
            v.kind, _num(v.gain_factor), _num(v.time_constant_factor),
            _num(v.extra_delay_steps), "true" if r.offset_free else "false",
            _num(r.max_abs_steady_state_error_kw), str(r.n_unreachable_changes),
            _num(r.iae_kw_s), _num(r.iae_ratio), _num(r.max_overshoot_kw),
            _num(r.max_overshoot_pct), str(r.n_input_violations), str(r.n_solver_fallbacks),
            _num(r.run_time_s),
        ]))
    return "\n".join(lines) + "\n"


def _offset_cell(r: VariantResult) -> str:
    verdict = "yes" if r.offset_free else "**NO**"
    if r.n_unreachable_changes:
        verdict += f" ({r.n_unreachable_changes} unreachable)"
    return verdict


def format_table(results: Sequence[VariantResult]) -> str:
    """The Markdown table of the report (one row per plant)."""
    lines = [
        "| plant | gain | tau | delay [samples] | offset-free | max abs SSE [kW] | IAE [kW s] "
        "| IAE ratio | max overshoot [kW] | max overshoot [%] | input violations "
        "| fallbacks |",
        "|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        v = r.variant
        if v.kind == "heater":
            head = "virtual heater | - | - | -"
        else:
            head = (f"model | x{v.gain_factor:.2f} | x{v.time_constant_factor:.2f} | "
                    f"+{v.extra_delay_steps}")
        lines.append(
            f"| {head} | {_offset_cell(r)} | {r.max_abs_steady_state_error_kw:.4f} | "
            f"{r.iae_kw_s:.1f} | {r.iae_ratio:.2f} | {r.max_overshoot_kw:.3f} | "
            f"{r.max_overshoot_pct:.1f} | {r.n_input_violations} | {r.n_solver_fallbacks} |"
        )
    return "\n".join(lines) + "\n"


def summary_lines(report: RobustnessReport) -> list[str]:
    """A few lines with the campaign's verdicts (for stdout and the report)."""
    results = report.results
    model_runs = [r for r in results if r.variant.kind == "model"]
    failed = [r for r in results if not r.offset_free]
    violations = sum(r.n_input_violations for r in results)
    worst = max(model_runs, key=lambda r: r.iae_ratio)
    lines = [
        f"{len(results)} plants, {report.total_time_s:.1f} s; nominal IAE "
        f"{report.nominal.iae_kw_s:.1f} kW s",
        f"offset-free (|SSE| < {report.sse_threshold_kw:g} kW after every change): "
        f"{len(results) - len(failed)} of {len(results)} plants"
        + (f"; fails on: {'; '.join(r.variant.label for r in failed)}" if failed else ""),
        f"worst IAE ratio: {worst.iae_ratio:.2f} ({worst.variant.label})",
        f"input violations: {violations} (must be 0)",
    ]
    heater = [r for r in results if r.variant.kind == "heater"]
    if heater:
        h = heater[0]
        lines.append(f"virtual heater: offset-free {'yes' if h.offset_free else 'NO'}, IAE "
                     f"ratio {h.iae_ratio:.2f}, max overshoot {h.max_overshoot_kw:.3f} kW")
    return lines


def format_markdown(report: RobustnessReport, *, command: str | None = None,
                     figure_name: str | None = None) -> str:
    """robustness.md: what was run, the definitions, the table and the verdicts."""
    sc = report.scenario
    s = report.settings
    g = report.grid
    lo, hi = report.allowed_triac_range_pct
    noise = ("noisy (the scenario's setting; heater with sensor noise and grid wander)"
             if report.noise else "noise-free")
    parts = [
        "# Robustness campaign of the offset-free MPC\n",
        *([f"Command: `{command}`\n"] if command else []),
        f"Controller model: {report.model_source}. Scenario: '{sc.name}' ({sc.description}; "
        f"{sc.duration_s:g} s, {len(sc.setpoints)} setpoint changes). Seed {report.seed} "
        "for every run.\n",
        f"Controller: horizon {s.horizon_steps} samples, output weight {s.output_weight:g}, "
        f"move weight {s.move_weight:g}, input-target weight {s.input_target_weight:g}, "
        f"{s.disturbance_model} disturbance model (noise ratio {s.disturbance_noise:g}), "
        f"allowed input {lo:g} .. {hi:g} %, rate limit "
        f"{'none' if s.max_move_pct_per_step is None else f'{s.max_move_pct_per_step:g} %/sample'}.\n",
        f"Grid '{report.grid_name}': gain x{', x'.join(f'{v:g}' for v in g.gain_factors)}; "
        f"slow time constant x{', x'.join(f'{v:g}' for v in g.time_constant_factors)}; "
        f"extra delay +{', +'.join(str(v) for v in g.extra_delays_steps)} samples "
        "(`sim.perturbed.perturb_model`: the gain scales f; the time constant moves the "
        "slow pole with the instantaneous response b1 = 1 and the static gain B(1)/A(1) "
        "held; the delay prepends zeros to B). Plus the virtual CZ heater.\n",
        f"Definitions: every plant starts at rest at the initial setpoint; plants are {noise}. "
        "Errors are taken against the *reachable setpoint*: the setpoint clipped to the "
        "powers that plant can hold within the allowed input (a change outside is counted "
        f"as unreachable). **Offset-free**: |steady-state error| < {report.sse_threshold_kw:g} kW "
        "after every setpoint change (measured power, mean over the last quarter of the "
        "segment). **IAE**: true power over the change segments; ratio to the nominal plant "
        "(gain x1, tau x1, delay +0). **Overshoot**: largest over the changes, true power, "
        "in kW and in % of that change. **Input violations**: samples outside the allowed "
        "input range plus moves beyond the rate limit; must be 0. **Fallbacks**: controller "
        "steps on a fallback plan (failed QP).\n",
        "## Results\n",
        format_table(report.results),
        "## Summary\n",
        "\n".join(f"- {line}" for line in summary_lines(report)) + "\n",
    ]
    if figure_name:
        parts.append(f"![IAE ratio over gain and time-constant factors]({figure_name})\n")
    return "\n".join(parts)


def draw_heatmap(report: RobustnessReport) -> Figure:
    """Heat map of the IAE ratio: gain factor x time-constant factor, one panel per delay.

    Cells where offset-free tracking fails carry a red cross; every cell is annotated
    with its ratio. Returns the `matplotlib.figure.Figure` (Agg canvas, not saved).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import LogNorm
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter

    g = report.grid
    delays = g.extra_delays_steps
    gains, taus = g.gain_factors, g.time_constant_factors
    ratios = np.full((len(delays), len(taus), len(gains)), np.nan)
    fails = np.zeros(ratios.shape, dtype=bool)
    unreachable = np.zeros(ratios.shape, dtype=int)
    for d, n in enumerate(delays):
        for t, m in enumerate(taus):
            for k, gain in enumerate(gains):
                r = report.result_for(gain_factor=gain, time_constant_factor=m,
                                      extra_delay_steps=n)
                ratios[d, t, k] = r.iae_ratio
                fails[d, t, k] = not r.offset_free
                unreachable[d, t, k] = r.n_unreachable_changes
    finite = ratios[np.isfinite(ratios) & (ratios > 0)]
    vmin = min(1.0, float(finite.min())) if finite.size else 0.5
    vmax = max(1.0 + 1e-9, float(finite.max())) if finite.size else 2.0
    norm = LogNorm(vmin=vmin, vmax=vmax)
    panel_w_in = max(4.6, 0.62 * len(gains) + 1.6)
    fontsize = "small" if len(gains) <= 7 else 7
    fig = Figure(figsize=(panel_w_in * len(delays) + 1.2, max(4.4, 0.42 * len(taus) + 1.8)),
                 dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(delays), squeeze=False)[0]
    image = None
    for d, (ax, n) in enumerate(zip(axes, delays, strict=True)):
        image = ax.imshow(ratios[d], origin="lower", cmap="viridis", norm=norm, aspect="auto")
        ax.set_xticks(range(len(gains)), [f"{100 * (v - 1):+.0f}" for v in gains])
        ax.set_yticks(range(len(taus)), [f"x{v:g}" for v in taus])
        ax.set_xlabel("plant gain relative to the model [%]")
        ax.set_ylabel("plant slow time constant / model's [-]")
        ax.set_title(f"extra input delay +{n} sample{'s' if n != 1 else ''} "
                     f"(+{n * report.scenario.ts_s:g} s)")
        for t in range(len(taus)):
            for k in range(len(gains)):
                value = ratios[d, t, k]
                if fails[d, t, k]:
                    ax.plot(k, t, marker="x", color="red", markersize=18, markeredgewidth=2.5)
                note = "*" if unreachable[d, t, k] else ""
                ax.text(k, t, f"{value:.2f}{note}", ha="center", va="center", fontsize=fontsize,
                        color="white" if np.isfinite(value) and norm(value) < 0.6 else "black")
    if image is not None:
        bar = fig.colorbar(image, ax=list(axes), shrink=0.9)
        bar.set_label("IAE / IAE of the nominal plant [-] (log scale)")
        plain = FuncFormatter(lambda v, _pos: f"{v:g}")
        bar.ax.yaxis.set_major_formatter(plain)
        bar.ax.yaxis.set_minor_formatter(plain)
    fig.suptitle(f"Offset-free MPC on perturbed plants, scenario '{report.scenario.name}' "
                 "\n(red x: offset-free tracking fails; *: some setpoint changes are out of "
                 "that plant's reach, errors taken to its limit)", fontsize="medium")
    return fig


__all__ = [
    "DEFAULT_SSE_THRESHOLD_KW",
    "GRIDS",
    "PlantVariant",
    "ReachableMeasures",
    "RobustnessError",
    "RobustnessGrid",
    "RobustnessReport",
    "VariantResult",
    "draw_heatmap",
    "format_csv",
    "format_markdown",
    "format_table",
    "reachable_measures",
    "run_robustness",
    "summary_lines",
]
