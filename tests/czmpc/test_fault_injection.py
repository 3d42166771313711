"""Fault injection: each fault through the closed loop (model plant and virtual heater).

Every run: the shipped model's controller with a 2 %/step rate limit, the spike gate on
(8 sigma, 0.5 kW floor) and a 150 kW rating, a 5 kW setpoint step at 100 s, and one
fault. Each test checks what is reported (status, counters), what the input does, that
tracking resumes within a stated time after the fault clears, and that the returned
input never leaves its limits or the rate limit (moves measured from the input that
was really applied).

Faults the loop in `sim` has no class for (a stuck sensor, a stuck TRIAC, manual
operation, a run-time limit change) are made by the small `Rig` plant wrapper and the
`Operator` controller wrapper below, which pass the applied input back through
``step(..., applied_triac_pct=...)`` as a plant interface would.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable

import numpy as np
import pytest

from czmpc.controller import OffsetFreeMPC, StepDiagnostics
from czmpc.modes import Mode, Status
from czmpc.settings import MPCSettings, OSQPOptions, ReliabilitySettings
from czmpc.validation import Verdict
from sim.disturbances import Fault, MeasurementSpike, MissingSamples, RandomSpikes
from sim.heater import VirtualHeater
from sim.loop import ClosedLoopResult, run_closed_loop
from sim.model_plant import ModelPlant
from sim.protocols import NOMINAL, Exogenous, Plant
from sim.scenario import Scenario, SetpointStep
from sysid.model import HammersteinModel
from sysid.modelfile import load_model

MODEL_PATH = "data/cz_heater_model.json"
S0_PCT = 45.0
TS_S = 2.0
RATE_PCT = 2.0
#: The controller clips to [s_prev - delta, s_prev + delta] in floating point.
RATE_ATOL_PCT = 1e-9
#: Tracking counts as resumed when the true power stays this close to the setpoint
#: [kW]: about 15 noise-model sigmas; the noisy model plant wanders about 0.1 kW
#: under closed-loop control in the clean run (measured), the heater less.
TRACK_TOL_KW = 0.3
#: Time after the fault clears within which tracking must have resumed [s].
RESUME_S = 60.0

Actuator = Callable[[int, float], float]


class Rig:
    """A plant wrapper with an actuator fault and a stuck-sensor window (sample indices)."""

    def __init__(self, plant: Plant, *, actuator: Actuator | None = None,
                 stuck_sensor: tuple[int, int] | None = None, quantum_kw: float = 0.0) -> None:
        self.plant = plant
        self.quantum_kw = quantum_kw
        self.actuator = actuator
        self.stuck_sensor = stuck_sensor
        self.ts_s = plant.ts_s
        self.k = 0
        self.applied = math.nan
        self.frozen = math.nan
        self.applied_log: list[float] = []

    def reset(self, rng: np.random.Generator | int | None = None) -> float:
        self.k = 0
        self.applied = math.nan
        self.applied_log = []
        self.frozen = self._quantize(self.plant.reset(rng))
        return self.frozen

    def _quantize(self, power_kw: float) -> float:
        q = self.quantum_kw
        return round(power_kw / q) * q if q > 0.0 else power_kw

    @property
    def true_power_kw(self) -> float:
        return float(self.plant.true_power_kw)

    def step(self, triac_pct: float, exogenous: Exogenous = NOMINAL) -> float:
        applied = triac_pct if self.actuator is None else self.actuator(self.k, triac_pct)
        self.applied = applied
        self.applied_log.append(applied)
        y = self._quantize(self.plant.step(applied, exogenous))
        self.k += 1
        if self.stuck_sensor is not None:
            k0, k1 = self.stuck_sensor
            if self.k == k0:
                self.frozen = y
            if k0 <= self.k < k1:
                y = self.frozen
        return y


class Operator:
    """Passes the applied input to the controller; mode and limit changes by sample."""

    def __init__(self, mpc: OffsetFreeMPC, rig: Rig, *, modes: dict[int, Mode] | None = None,
                 limits: dict[int, tuple[float, float]] | None = None) -> None:
        self.mpc = mpc
        self.rig = rig
        self.modes = modes or {}
        self.limits = limits or {}
        self.ts_s = mpc.ts_s
        self.k = 0

    def reset(self) -> None:
        self.mpc.reset()
        self.k = 0

    @property
    def last_step(self) -> StepDiagnostics | None:
        return self.mpc.last_step

    def step(self, power_kw: float, setpoint_kw: float) -> float:
        if self.k in self.modes:
            self.mpc.request_mode(self.modes[self.k])
        if self.k in self.limits:
            self.mpc.set_triac_limits(*self.limits[self.k])
        applied = self.rig.applied
        s = self.mpc.step(power_kw, setpoint_kw,
                          applied_triac_pct=applied if math.isfinite(applied) else None)
        self.k += 1
        return s


@pytest.fixture(scope="module")
def model() -> HammersteinModel:
    return load_model(MODEL_PATH)


def _settings(model: HammersteinModel, **reliability: object) -> MPCSettings:
    rel: dict[str, object] = {"spike_gate_k_sigma": 8.0, "spike_gate_floor_kw": 0.5,
                              "power_max_kw": 150.0}
    rel.update(reliability)
    return MPCSettings.default_for(model).with_updates(
        initial_triac_pct=S0_PCT, max_move_pct_per_step=RATE_PCT,
        reliability=ReliabilitySettings(**rel))  # type: ignore[arg-type]


def _plant(kind: str, model: HammersteinModel) -> Plant:
    if kind == "model":
        return ModelPlant(model, noise=True, initial_triac_pct=S0_PCT)
    return VirtualHeater()


def _run(kind: str, model: HammersteinModel, faults: tuple[Fault, ...] = (), *,
         settings: MPCSettings | None = None, duration_s: float = 1000.0,
         step_at_s: float = 100.0, step_kw: float = 5.0, actuator: Actuator | None = None,
         stuck_sensor: tuple[int, int] | None = None, modes: dict[int, Mode] | None = None,
         limits: dict[int, tuple[float, float]] | None = None,
         ) -> tuple[ClosedLoopResult, OffsetFreeMPC, Rig]:
    plant = _plant(kind, model)
    plant.reset(np.random.default_rng(0))
    p0 = round(float(plant.true_power_kw), 3)
    scenario = Scenario(
        name="fault", duration_s=duration_s, initial_setpoint_kw=p0, initial_triac_pct=S0_PCT,
        setpoints=(SetpointStep(at_s=step_at_s, power_kw=p0 + step_kw),), faults=faults,
    )
    rig = Rig(plant, actuator=actuator, stuck_sensor=stuck_sensor)
    mpc = OffsetFreeMPC(model, settings or _settings(model))
    result = run_closed_loop(rig, Operator(mpc, rig, modes=modes, limits=limits), scenario,
                             rng=1)
    return result, mpc, rig


def _diags(result: ClosedLoopResult) -> list[StepDiagnostics]:
    assert result.diagnostics is not None
    return [d for d in result.diagnostics if isinstance(d, StepDiagnostics)]


def _statuses(result: ClosedLoopResult, k0: int, k1: int) -> Counter[Status]:
    return Counter(d.status for d in _diags(result)[k0:k1])


def _assert_input_safe(result: ClosedLoopResult, mpc: OffsetFreeMPC, rig: Rig) -> None:
    """Finite, inside the limits, and within the rate limit of the applied input (ON)."""
    s = result.triac_pct
    lo, hi = mpc.allowed_triac_range_pct
    assert np.all(np.isfinite(s))
    assert np.all((s >= lo) & (s <= hi))
    applied = np.concatenate([[S0_PCT], rig.applied_log[:-1]])
    on = np.array([d.mode is Mode.ON for d in _diags(result)])
    assert np.all(np.abs(s - applied)[on] <= RATE_PCT + RATE_ATOL_PCT)


def _assert_resumed(result: ClosedLoopResult, clear_k: int, *, within_s: float = RESUME_S,
                    tol_kw: float = TRACK_TOL_KW) -> None:
    """From ``within_s`` after sample ``clear_k`` on, the true power tracks the setpoint."""
    start = clear_k + int(within_s / TS_S)
    error = result.power_true_kw[start:] - result.setpoint_kw[start:]
    assert np.max(np.abs(error)) < tol_kw


PLANTS = ["model", "heater"]


@pytest.mark.parametrize("kind", PLANTS)
def test_clean_run_is_all_good_and_tracks(kind: str, model: HammersteinModel) -> None:
    result, mpc, rig = _run(kind, model, duration_s=600.0)
    assert _statuses(result, 80, 300) == Counter({Status.GOOD: 220})
    assert mpc.n_rejected_measurements == 0 and mpc.n_fallbacks == 0
    _assert_input_safe(result, mpc, rig)
    _assert_resumed(result, 50)


@pytest.mark.parametrize("kind", PLANTS)
def test_short_outage_runs_on_the_soft_sensor_and_resumes(
        kind: str, model: HammersteinModel) -> None:
    result, mpc, rig = _run(kind, model, (MissingSamples(at_s=400.0, duration_s=40.0),))
    assert _statuses(result, 200, 220) == Counter({Status.PREDICTED: 20})
    assert all(d.verdict is Verdict.MISSING for d in _diags(result)[200:220])
    assert _diags(result)[219].samples_without_measurement == 20
    assert _statuses(result, 220, 500) == Counter({Status.GOOD: 280})
    assert mpc.n_rejected_measurements == 20 and mpc.n_shed_steps == 0
    # the soft sensor keeps the loop on its setpoint through the outage
    error = result.power_true_kw[200:220] - result.setpoint_kw[200:220]
    assert np.max(np.abs(error)) < TRACK_TOL_KW
    _assert_input_safe(result, mpc, rig)
    _assert_resumed(result, 220)


@pytest.mark.parametrize("kind", PLANTS)
def test_long_outage_sheds_to_the_trusted_steady_input_then_resumes_bumplessly(
        kind: str, model: HammersteinModel) -> None:
    result, mpc, rig = _run(kind, model, (MissingSamples(at_s=400.0, duration_s=300.0),))
    n_soft = mpc.settings.reliability.max_predicted_samples
    assert _statuses(result, 200, 200 + n_soft) == Counter({Status.PREDICTED: n_soft})
    assert _statuses(result, 200 + n_soft, 350) == Counter({Status.SHED: 150 - n_soft})
    s = result.triac_pct
    diags = _diags(result)
    # shed: the steady input of the last trusted estimate (the target), held constant
    target = diags[200 + n_soft].target_triac_pct
    assert abs(s[200 + n_soft] - s[200 + n_soft - 1]) <= RATE_PCT + RATE_ATOL_PCT
    assert np.all(s[200 + n_soft:350] == pytest.approx(target, abs=1e-9))
    assert diags[350].status is Status.GOOD
    assert mpc.n_shed_steps == 150 - n_soft
    _assert_input_safe(result, mpc, rig)  # includes the first move after the outage
    _assert_resumed(result, 350)


@pytest.mark.parametrize("kind", PLANTS)
def test_shed_moves_to_the_configured_safe_input_at_the_rate_limit(
        kind: str, model: HammersteinModel) -> None:
    settings = _settings(model, max_predicted_samples=10, shed_triac_pct=40.0)
    result, mpc, rig = _run(kind, model, (MissingSamples(at_s=400.0, duration_s=200.0),),
                            settings=settings, duration_s=800.0)
    s = result.triac_pct
    assert _diags(result)[211].status is Status.SHED
    assert np.all(s[215:300] == 40.0)  # reached within 5 samples at 2 %/step
    _assert_input_safe(result, mpc, rig)
    _assert_resumed(result, 300)


@pytest.mark.parametrize("kind", PLANTS)
def test_stuck_sensor_is_detected_and_rejected_until_it_moves_again(
        kind: str, model: HammersteinModel) -> None:
    # frozen from sample 200 to 300; a setpoint step at 420 s moves the input
    result, mpc, rig = _run(kind, model, step_at_s=420.0, stuck_sensor=(200, 300))
    diags = _diags(result)
    n_stuck = mpc.settings.reliability.stuck_samples
    stuck_k = [d.k for d in diags if d.verdict is Verdict.STUCK]
    # detected once the input moves (step at sample 210), then every frozen sample
    assert stuck_k[0] <= 210 + n_stuck and stuck_k == list(range(stuck_k[0], 300))
    assert all(not diags[k].measurement_used for k in stuck_k)
    assert Status.SHED in _statuses(result, 200, 300)  # soft sensor exhausted
    assert _statuses(result, 300, 500) == Counter({Status.GOOD: 200})
    _assert_input_safe(result, mpc, rig)
    _assert_resumed(result, 300)


@pytest.mark.parametrize("noise", [False, True], ids=["noise-free", "noisy"])
def test_quiet_signal_at_constant_input_never_trips_the_stuck_check(
        noise: bool, model: HammersteinModel) -> None:
    # a 1 W sensor quantum: noise-free, the steady measurement repeats exactly; with the
    # model's 13 W noise, values repeat often (at a constant setpoint the input barely moves)
    plant = Rig(ModelPlant(model, noise=noise, initial_triac_pct=S0_PCT), quantum_kw=0.001)
    p0 = plant.reset(np.random.default_rng(0))
    scenario = Scenario(name="quiet", duration_s=1200.0, initial_setpoint_kw=p0,
                        initial_triac_pct=S0_PCT, plant_noise=noise)
    mpc = OffsetFreeMPC(model, _settings(model))
    result = run_closed_loop(plant, mpc, scenario, rng=0)
    measured = result.power_measured_kw[50:]
    if noise:
        # repeats do occur: P(diff == 0) ~ 1 W / (sqrt(2 pi) * 19 W) ~ 2 %, about 11 expected
        # in 550 samples; 3 or more has probability > 0.99 under Poisson(11)
        assert np.count_nonzero(np.diff(measured) == 0.0) >= 3
    else:
        assert np.unique(measured).size == 1  # it is really quiet
    assert mpc.n_rejected_measurements == 0
    assert all(d.status is Status.GOOD for d in _diags(result))


@pytest.mark.parametrize("kind", PLANTS)
def test_spikes_are_rejected_and_barely_move_the_power(
        kind: str, model: HammersteinModel) -> None:
    spikes = RandomSpikes(probability_per_sample=0.05, spike_kw=3.0, start_s=300.0, end_s=700.0)
    result, mpc, rig = _run(kind, model, (spikes,))
    hit = np.nonzero(result.power_measured_kw != result.power_measured_kw)[0]  # none: no NaN
    assert hit.size == 0
    diags = _diags(result)
    spiked = [d.k for d in diags if d.verdict is Verdict.SPIKE]
    assert len(spiked) >= 5  # the fault did hit (seeded)
    assert all(diags[k].status is Status.PREDICTED for k in spiked)
    assert not any(d.level_change_accepted for d in diags)  # isolated spikes never re-open
    error = result.power_true_kw[150:] - result.setpoint_kw[150:]
    assert np.max(np.abs(error)) < TRACK_TOL_KW  # 3 kW spikes, not even 0.3 kW at the plant
    _assert_input_safe(result, mpc, rig)


@pytest.mark.parametrize("kind", PLANTS)
def test_negative_and_over_rating_readings_are_rejected(
        kind: str, model: HammersteinModel) -> None:
    faults = (MeasurementSpike(at_s=400.0, spike_kw=-100.0),
              MeasurementSpike(at_s=404.0, spike_kw=200.0))
    result, mpc, rig = _run(kind, model, faults)
    diags = _diags(result)
    assert diags[200].verdict is Verdict.BELOW_LIMIT
    assert diags[202].verdict is Verdict.ABOVE_LIMIT
    assert diags[200].status is Status.PREDICTED and diags[202].status is Status.PREDICTED
    assert mpc.n_rejected_measurements == 2
    _assert_input_safe(result, mpc, rig)
    _assert_resumed(result, 203, within_s=0.0)


@pytest.mark.parametrize("kind", PLANTS)
def test_level_change_is_accepted_after_a_few_samples(
        kind: str, model: HammersteinModel) -> None:
    # a 2 kW sensor offset from 400 s on looks like spikes at first
    faults = tuple(MeasurementSpike(at_s=400.0 + 2.0 * i, spike_kw=2.0) for i in range(300))
    result, mpc, rig = _run(kind, model, faults, duration_s=1000.0)
    diags = _diags(result)
    n = mpc.settings.reliability.reopen_after_samples
    assert [d.verdict for d in diags[200:200 + n]] == [Verdict.SPIKE] * n
    assert diags[200 + n].level_change_accepted and diags[200 + n].measurement_used
    assert all(d.measurement_used for d in diags[200 + n:])
    # offset-free on the measurement: the (biased) measured power reaches the setpoint
    measured_error = result.power_measured_kw[400:] - result.setpoint_kw[400:]
    assert abs(float(np.mean(measured_error))) < 0.02
    # the bias moves the disturbance estimate by its size, and the diagnostic flags it
    shift = diags[-1].disturbance_power_kw - diags[199].disturbance_power_kw
    # reason: 600 s after the change the slow mode (tau about 250 s) has not quite
    # settled: 1.81-1.88 kW measured on the two plants
    assert shift == pytest.approx(2.0, abs=0.25)
    assert any(d.mismatch is not None and d.mismatch.biased for d in diags[200 + n:230])
    _assert_input_safe(result, mpc, rig)


@pytest.mark.parametrize("kind", PLANTS)
def test_solver_at_one_iteration_falls_back_then_sheds_to_the_target(
        kind: str, model: HammersteinModel) -> None:
    settings = _settings(model).with_updates(osqp=OSQPOptions(max_iter=1))
    result, mpc, rig = _run(kind, model, settings=settings, duration_s=600.0)
    diags = _diags(result)
    n_bad = mpc.settings.reliability.max_bad_solves
    assert [d.status for d in diags[:n_bad - 1]] == [Status.HELD] * (n_bad - 1)
    assert all(d.status is Status.SHED and d.fallback == "target" for d in diags[n_bad - 1:])
    assert mpc.n_fallbacks == result.n_steps
    assert diags[-1].solver_status == "maximum iterations reached"
    _assert_input_safe(result, mpc, rig)
    # holding the offset-free target still tracks, slowly (open loop through the model)
    _assert_resumed(result, 200)


def test_solver_time_budget_exceeded_falls_back_and_recovers(model: HammersteinModel) -> None:
    tiny = _settings(model).with_updates(osqp=OSQPOptions(time_limit_s=1e-9))
    mpc = OffsetFreeMPC(model, tiny)
    s = mpc.step(45.0, 46.0)
    last = mpc.last_step
    assert last is not None and last.fallback != "none" and "time limit" in last.solver_status
    lo, hi = mpc.allowed_triac_range_pct
    assert lo <= s <= hi and abs(s - S0_PCT) <= RATE_PCT + RATE_ATOL_PCT


@pytest.mark.parametrize("kind", PLANTS)
def test_manual_override_then_auto_is_bumpless(kind: str, model: HammersteinModel) -> None:
    # PREDICT (manual) from sample 150 to 300 at 42 %; the operator applies it
    def manual(k: int, commanded: float) -> float:
        return 42.0 if 150 <= k < 300 else commanded

    result, mpc, rig = _run(kind, model, actuator=manual, duration_s=900.0,
                            modes={150: Mode.PREDICT, 300: Mode.ON})
    diags = _diags(result)
    assert all(d.mode is Mode.PREDICT and d.status is Status.HELD for d in diags[150:300])
    # in PREDICT the controller hands back the operator's input, and advises its own
    assert np.all(result.triac_pct[152:300] == 42.0)
    assert abs(diags[299].advised_triac_pct - 42.0) <= RATE_PCT + RATE_ATOL_PCT
    assert diags[300].mode is Mode.ON and diags[300].transition is not None
    assert abs(result.triac_pct[300] - 42.0) <= RATE_PCT + RATE_ATOL_PCT  # bumpless
    log = mpc.drain_transitions()
    assert [(t.from_mode, t.to_mode) for t in log] == [(Mode.ON, Mode.PREDICT),
                                                        (Mode.PREDICT, Mode.ON)]
    assert mpc.drain_transitions() == ()
    _assert_input_safe(result, mpc, rig)
    _assert_resumed(result, 300)


@pytest.mark.parametrize("kind", PLANTS)
def test_stuck_triac_is_reported_without_windup(kind: str, model: HammersteinModel) -> None:
    def stuck(k: int, commanded: float) -> float:
        return 47.0 if 200 <= k < 300 else commanded

    result, mpc, rig = _run(kind, model, step_at_s=420.0, actuator=stuck)
    diags = _diags(result)
    assert all(d.status is Status.CLAMPED for d in diags[201:301])
    assert all(d.applied_triac_pct == 47.0 for d in diags[201:301])
    # no windup: the disturbance estimate stays where it was (the estimator knew the input)
    d_before = diags[199].disturbance_power_kw
    d_during = np.array([d.disturbance_power_kw for d in diags[201:301]])
    assert np.max(np.abs(d_during - d_before)) < TRACK_TOL_KW
    _assert_input_safe(result, mpc, rig)
    _assert_resumed(result, 300, within_s=20.0)


@pytest.mark.parametrize("kind", PLANTS)
def test_tightened_limit_ramps_in_and_is_held(kind: str, model: HammersteinModel) -> None:
    # at sample 300 (input about 49 %) the maximum drops to 46 %
    result, mpc, rig = _run(kind, model, duration_s=900.0, limits={300: (0.0, 46.0)})
    diags = _diags(result)
    s = result.triac_pct
    ramp = mpc.settings.reliability.limit_ramp_pct_per_s * TS_S
    limit_hi = np.array([d.triac_limits_pct[1] for d in diags])
    assert limit_hi[299] > 60.0 and limit_hi[-1] == pytest.approx(46.0, abs=1e-12)
    assert np.all(-np.diff(limit_hi[300:]) <= ramp + 1e-12)  # moves in at the ramp rate
    assert np.all(s <= limit_hi + 1e-12)
    settled = int(np.argmax(limit_hi == 46.0))
    assert np.all(s[settled:] <= 46.0 + 1e-12)
    assert all(d.status is Status.CLAMPED for d in diags[settled + 5:])
    assert not diags[-1].setpoint_reachable
    _assert_input_safe(result, mpc, rig)


#: Issue 13 class 1: the true power must end this close to the setpoint after a frozen
#: sensor is detected [kW] (before the roll-back it ended about 2.2 kW above).
FROZEN_END_TOL_KW = 0.3


@pytest.mark.parametrize("kind", PLANTS)
def test_frozen_sensor_during_a_setpoint_change_is_undone_and_ends_at_the_setpoint(
        kind: str, model: HammersteinModel) -> None:
    # The sensor freezes 4 samples before a +5 kW setpoint step and never recovers: the
    # frozen readings accepted before detection must be undone (roll-back to the last
    # live sample) and the shed must hold the steady input of that trusted estimate.
    result, mpc, rig = _run(kind, model, step_at_s=420.0, stuck_sensor=(206, 10**9),
                            duration_s=1600.0)
    diags = _diags(result)
    k_detect = next(d.k for d in diags if d.verdict is Verdict.STUCK)
    assert diags[k_detect].rolled_back_samples == k_detect - 206 - 1   # frozen, accepted ones
    assert all(d.rolled_back_samples == 0 for d in diags if d.k != k_detect)
    assert diags[-1].status is Status.SHED
    error = result.power_true_kw[-50:] - result.setpoint_kw[-50:]
    assert np.max(np.abs(error)) < FROZEN_END_TOL_KW
    _assert_input_safe(result, mpc, rig)
