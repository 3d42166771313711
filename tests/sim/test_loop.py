"""The closed-loop runner: sample order, faults to the controller, seeds, records, CSV."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from czmpc.peers.pi import PIController
from sim.disturbances import MeasurementSpike, MissingSamples, PowerShift, RandomSpikes
from sim.errors import SimError
from sim.loop import CSV_COLUMNS, ClosedLoopResult, run_closed_loop
from sim.metrics import compute_metrics
from sim.model_plant import ModelPlant
from sim.protocols import Controller
from sim.scenario import Scenario, SetpointStep, load_scenario
from sysid.errors import SamplingTimeError
from sysid.model import HammersteinModel


class ConstantController:
    """Returns a fixed input and records what it was given."""

    def __init__(self, triac_pct: float = 45.0, ts_s: float = 2.0) -> None:
        self.triac_pct = triac_pct
        self.ts_s = ts_s
        self.seen: list[tuple[float, float]] = []
        self.n_resets = 0

    def step(self, power_kw: float, setpoint_kw: float) -> float:
        self.seen.append((power_kw, setpoint_kw))
        return self.triac_pct

    def reset(self) -> None:
        self.seen = []
        self.n_resets += 1


@dataclass(frozen=True)
class FakeDiagnostics:
    disturbance_estimate: float
    fallback: str


class DiagnosingController(ConstantController):
    """A constant controller exposing MPC-like diagnostics."""

    def __init__(self) -> None:
        super().__init__()
        self._last: FakeDiagnostics | None = None

    def step(self, power_kw: float, setpoint_kw: float) -> float:
        k = len(self.seen)
        self._last = FakeDiagnostics(disturbance_estimate=0.5 * k,
                                     fallback="target" if k % 10 == 3 else "none")
        return super().step(power_kw, setpoint_kw)

    @property
    def last_step(self) -> FakeDiagnostics | None:
        return self._last


def _scenario(**changes: object) -> Scenario:
    base: dict[str, object] = dict(name="t", duration_s=200.0, initial_setpoint_kw=45.0)
    base.update(changes)
    return Scenario(**base)  # type: ignore[arg-type]


def test_constant_controller_satisfies_the_protocol() -> None:
    assert isinstance(ConstantController(), Controller)
    assert isinstance(PIController(gain_pct_per_kw=0.3, integral_time_s=20.0, ts_s=2.0,
                                   initial_triac_pct=45.0), Controller)


def test_loop_order_measurement_then_input_then_plant(paper_oe_model: HammersteinModel) -> None:
    scenario = _scenario(setpoints=(SetpointStep(at_s=10, power_kw=50.0),), plant_noise=False)
    controller = ConstantController(triac_pct=50.0)
    result = run_closed_loop(ModelPlant(paper_oe_model, noise=False), controller, scenario, rng=0)
    assert result.n_steps == 100
    # sample 0: the initial steady state; sample 1: the first input acted (one delay)
    assert result.power_measured_kw[0] == 45.0
    f5 = float(paper_oe_model.input_nonlinearity(5.0))
    assert result.power_true_kw[1] == pytest.approx(45.0 + f5, abs=1e-12)
    assert [r for _, r in controller.seen[4:6]] == [45.0, 50.0]   # setpoint step at k = 5
    np.testing.assert_array_equal(result.setpoint_kw, scenario.setpoint_profile_kw())
    np.testing.assert_array_equal(result.time_s, np.arange(100) * 2.0)
    np.testing.assert_array_equal(result.triac_pct, np.full(100, 50.0))
    assert np.all(result.step_time_s >= 0)
    assert result.diagnostics is None


def test_missing_samples_deliver_nan_for_exactly_the_window(paper_armax_model: HammersteinModel) -> None:
    scenario = load_scenario("missing_samples")
    controller = ConstantController()
    result = run_closed_loop(ModelPlant(paper_armax_model), controller, scenario, rng=1)
    delivered = np.array([p for p, _ in controller.seen])
    assert np.flatnonzero(np.isnan(delivered)).tolist() == list(range(330, 360))   # 660..718 s
    np.testing.assert_array_equal(delivered, result.power_measured_kw)
    assert np.all(np.isfinite(result.power_true_kw))


def test_spikes_reach_the_controller_and_faults_do_not_shift_the_noise(
    paper_armax_model: HammersteinModel,
) -> None:
    clean = run_closed_loop(ModelPlant(paper_armax_model), ConstantController(), _scenario(), rng=5)
    faults = (MeasurementSpike(at_s=20, spike_kw=3.0),
              RandomSpikes(probability_per_sample=0.2, spike_kw=1.0))
    faulty = run_closed_loop(ModelPlant(paper_armax_model), ConstantController(),
                             _scenario(faults=faults), rng=5)
    difference = faulty.power_measured_kw - clean.power_measured_kw
    # same noise stream: the difference is exactly the spikes (0, +-1, 3, 3 +- 1 kW)
    np.testing.assert_allclose(difference, np.round(difference), rtol=0, atol=1e-9)  # kW sums
    assert abs(difference[10] - 3.0) <= 1.0 + 1e-9
    assert np.count_nonzero(difference) > 5
    np.testing.assert_array_equal(faulty.power_true_kw, clean.power_true_kw)


def test_disturbances_reach_the_plant(paper_oe_model: HammersteinModel) -> None:
    scenario = _scenario(disturbances=(PowerShift(at_s=100, offset_kw=0.15),), plant_noise=False)
    result = run_closed_loop(ModelPlant(paper_oe_model, noise=False), ConstantController(),
                             scenario, rng=0)
    # the offset of sample k = 50 acts over [t_50, t_51) and shows at t_51
    assert result.power_true_kw[50] == 45.0
    assert result.power_true_kw[51] == pytest.approx(45.15, abs=1e-12)


def test_same_seed_same_result_and_reused_instances_are_reset(
    paper_armax_model: HammersteinModel,
) -> None:
    scenario = load_scenario("staircase").shortened(0.1)
    plant = ModelPlant.for_scenario(paper_armax_model, scenario)
    pi = PIController.tuned_for(paper_armax_model)
    first = run_closed_loop(plant, pi, scenario, rng=42)
    second = run_closed_loop(plant, pi, scenario, rng=42)
    other = run_closed_loop(plant, pi, scenario, rng=43)
    for name in ("power_measured_kw", "power_true_kw", "triac_pct", "setpoint_kw"):
        assert np.array_equal(getattr(first, name), getattr(second, name))
    assert not np.array_equal(first.power_measured_kw, other.power_measured_kw)
    assert first.seed == 42


def test_unseeded_run_records_a_seed_that_repeats_it(paper_armax_model: HammersteinModel) -> None:
    scenario = _scenario()
    first = run_closed_loop(ModelPlant(paper_armax_model), ConstantController(), scenario)
    assert isinstance(first.seed, int)
    again = run_closed_loop(ModelPlant(paper_armax_model), ConstantController(), scenario,
                            rng=first.seed)
    assert np.array_equal(first.power_measured_kw, again.power_measured_kw)


def test_sampling_time_mismatch_is_refused(paper_oe_model: HammersteinModel) -> None:
    with pytest.raises(SamplingTimeError, match=r"controller's ts_s.*'t''s 2 s; got 1 s"):
        run_closed_loop(ModelPlant(paper_oe_model), ConstantController(ts_s=1.0), _scenario())
    with pytest.raises(SamplingTimeError, match=r"plant's ts_s"):
        run_closed_loop(ModelPlant(paper_oe_model), ConstantController(ts_s=1.0),
                        _scenario(ts_s=1.0))


def test_non_finite_controller_output_stops_the_run(paper_oe_model: HammersteinModel) -> None:
    with pytest.raises(SimError, match=r"finite TRIAC input.*nan at sample 0"):
        run_closed_loop(ModelPlant(paper_oe_model), ConstantController(math.nan), _scenario())


def test_diagnostics_are_collected_and_progress_is_reported(paper_oe_model: HammersteinModel) -> None:
    calls: list[tuple[int, int]] = []
    result = run_closed_loop(ModelPlant(paper_oe_model), DiagnosingController(), _scenario(),
                             rng=0, progress=lambda done, total: calls.append((done, total)))
    assert result.diagnostics is not None and len(result.diagnostics) == 100
    estimate = result.disturbance_estimate_kw
    assert estimate is not None
    np.testing.assert_array_equal(estimate, 0.5 * np.arange(100))
    assert compute_metrics(result).n_solver_failures == 10
    assert calls[-1] == (100, 100) and len(calls) == 100


def test_pi_on_model_plant_tracks_the_staircase_without_offset(
    paper_armax_model: HammersteinModel,
) -> None:
    scenario = load_scenario("staircase")
    plant = ModelPlant.for_scenario(paper_armax_model, scenario)
    result = run_closed_loop(plant, PIController.tuned_for(paper_armax_model), scenario, rng=7)
    metrics = compute_metrics(result)
    # ARMAX noise C/A e has std 1.19 sigma_e = 0.016 kW and DC gain 10 (slow): the mean
    # over 225 samples still wanders by about 0.01 kW; 0.05 kW is 3 noise stds
    assert metrics.max_abs_steady_state_error_kw < 0.05
    assert len(metrics.changes) == 4
    assert all(c.settling_time_s is not None and c.settling_time_s < 600 for c in metrics.changes)
    assert metrics.n_limit_violations == 0


def test_to_csv_writes_every_sample_with_units_and_round_trips(
    tmp_path: Path, paper_armax_model: HammersteinModel,
) -> None:
    scenario = _scenario(faults=(MissingSamples(at_s=10, duration_s=4),))
    result = run_closed_loop(ModelPlant(paper_armax_model), DiagnosingController(), scenario, rng=3)
    path = tmp_path / "run.csv"
    result.to_csv(path)
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == (*CSV_COLUMNS, "disturbance_estimate_kw", "fallback")
    assert len(rows) == 1 + result.n_steps
    assert [r[-1] for r in rows[1:5]] == ["none", "none", "none", "target"]  # status as text
    table = np.array([r[:-1] for r in rows[1:]], dtype=float)
    for i, name in enumerate(CSV_COLUMNS):
        np.testing.assert_array_equal(table[:, i], getattr(result, name))   # repr round trip
    assert np.isnan(table[5, 2]) and np.isnan(table[6, 2])
    assert [p.name for p in tmp_path.iterdir()] == ["run.csv"]   # no temporary file left
    plain = run_closed_loop(ModelPlant(paper_armax_model), ConstantController(), scenario, rng=3)
    plain.to_csv(tmp_path / "plain.csv")
    header = (tmp_path / "plain.csv").read_text(encoding="utf-8").splitlines()[0]
    assert header == ",".join(CSV_COLUMNS)


def test_result_is_read_only_and_checks_lengths(paper_oe_model: HammersteinModel) -> None:
    result = run_closed_loop(ModelPlant(paper_oe_model), ConstantController(), _scenario(), rng=0)
    with pytest.raises(ValueError, match=r"read-only"):
        result.triac_pct[0] = 1.0
    with pytest.raises(SimError, match=r"ClosedLoopResult\.triac_pct.*\(100,\)"):
        ClosedLoopResult(scenario=result.scenario, seed=None, time_s=result.time_s,
                         setpoint_kw=result.setpoint_kw,
                         power_measured_kw=result.power_measured_kw,
                         power_true_kw=result.power_true_kw, triac_pct=np.zeros(3),
                         step_time_s=result.step_time_s)
