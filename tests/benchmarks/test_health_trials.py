"""The health benchmark's trials (benchmarks.health): the stale-model alarm, plant kept or drifted."""

from __future__ import annotations

import pytest

from benchmarks.health import closed_loop_trial, false_alarm_trial, heater_trials
from czmpc.health import RUNTIME_HEALTH, HealthSettings
from czmpc.shipped import shipped_path
from sim.drift import DriftEvent, PlantVariation
from sysid.modelfile import load_model

SHIPPED = load_model(shipped_path("cz_heater_model.json"))
#: 30 min of plant time: the issue's bound on the detection delay [s].
DETECTION_BOUND_S = 1800.0


@pytest.mark.slow
def test_24_hours_of_the_unchanged_plant_raise_no_alarm() -> None:
    trial = false_alarm_trial(SHIPPED, duration_s=86_400.0, seed=1)
    assert trial.duration_s == 86_400.0
    assert trial.alarm_at_s is None
    assert trial.max_health_before_drift < 1.0


@pytest.mark.parametrize("event", [DriftEvent(quantity="gain", value=0.75, at_s=1800.0),
                                   DriftEvent(quantity="tau", value=2 * 248.55, at_s=1800.0)],
                         ids=["gain-25pct", "tau-doubled"])
def test_a_drifted_plant_raises_the_alarm_within_30_min(event: DriftEvent) -> None:
    trial = closed_loop_trial(SHIPPED, PlantVariation(drifts=(event,)), duration_s=3800.0, seed=3)
    assert not trial.false_alarm
    assert trial.detection_delay_s is not None
    assert 0.0 < trial.detection_delay_s <= DETECTION_BOUND_S


@pytest.mark.slow
def test_the_baseline_test_accepts_the_mismatch_the_model_started_with() -> None:
    """Virtual heater vs the model identified from it: only the test against the model alarms."""
    against_model, against_baseline = heater_trials(
        SHIPPED, duration_s=7200.0, seed=2, settings=[HealthSettings(), RUNTIME_HEALTH])
    assert against_model.alarm_at_s is not None          # structural mismatch is seen ...
    assert against_baseline.alarm_at_s is None            # ... and is no change
    assert against_baseline.max_health_before_drift < 1.0


def test_the_baseline_test_alarms_on_a_gain_drift() -> None:
    at_s = RUNTIME_HEALTH.baseline_samples * 2.0 + 600.0
    trial = closed_loop_trial(SHIPPED, PlantVariation(drifts=(
        DriftEvent(quantity="gain", value=0.75, at_s=at_s),)), duration_s=at_s + 1800.0,
        seed=1, settings=RUNTIME_HEALTH)
    assert not trial.false_alarm
    assert trial.detection_delay_s is not None and trial.detection_delay_s <= DETECTION_BOUND_S
