"""Disturbance and fault signals: windows on the sample grid, combinations, validation."""

from __future__ import annotations

import numpy as np
import pytest

from sim.disturbances import (
    MeasurementSpike,
    MissingSamples,
    PowerShift,
    RandomSpikes,
    VoltageRamp,
    VoltageStep,
    exogenous_at,
    exogenous_profile,
    fault_profile,
    sample_times_s,
    scaled_times,
)
from sim.errors import ScenarioError
from sim.protocols import Exogenous
from tests.tolerances import IDENTITY_RTOL

TS_S = 2.0
T = sample_times_s(1000, TS_S)


def test_voltage_sag_is_active_exactly_for_its_window() -> None:
    sag = VoltageStep(at_s=600, factor=0.97, duration_s=600)
    factor = sag.voltage_factor(T, TS_S)
    active = np.flatnonzero(factor != 1.0)
    assert active[0] == 300 and active[-1] == 599 and active.size == 300
    assert np.all(factor[active] == 0.97)


def test_voltage_step_without_duration_lasts_to_the_end() -> None:
    factor = VoltageStep(at_s=1.0, factor=1.02).voltage_factor(T, TS_S)
    assert factor[0] == 1.0 and np.all(factor[1:] == 1.02)   # t = 2 s is the first >= 1 s


def test_voltage_ramp_is_linear_then_holds() -> None:
    ramp = VoltageRamp(start_s=100, end_s=300, factor=0.95)
    factor = ramp.voltage_factor(T, TS_S)
    expected = np.interp(T, [100, 300], [1.0, 0.95])
    np.testing.assert_allclose(factor, expected, rtol=IDENTITY_RTOL, atol=1e-15)  # same line


def test_profiles_multiply_voltages_and_add_offsets() -> None:
    profile = exogenous_profile(
        [VoltageStep(at_s=10, factor=0.9), VoltageStep(at_s=20, factor=0.5, duration_s=4),
         PowerShift(at_s=10, offset_kw=0.15), PowerShift(at_s=30, offset_kw=-1.0, duration_s=2)],
        n_steps=20, ts_s=TS_S,
    )
    volt = profile.grid_voltage_factor
    assert volt[4] == 1.0 and volt[5] == 0.9 and volt[10] == pytest.approx(0.45, rel=IDENTITY_RTOL)
    assert volt[11] == pytest.approx(0.45, rel=IDENTITY_RTOL) and volt[12] == 0.9
    off = profile.power_offset_kw
    assert off[4] == 0.0 and off[5] == 0.15 and off[15] == pytest.approx(-0.85, rel=IDENTITY_RTOL)
    assert off[16] == 0.15
    assert not volt.flags.writeable and not off.flags.writeable


def test_missing_window_of_60_s_is_30_samples() -> None:
    faults = fault_profile([MissingSamples(at_s=660, duration_s=60)], n_steps=1000, ts_s=TS_S,
                           rng=np.random.default_rng(0))
    missing = np.flatnonzero(faults.missing)
    assert missing.tolist() == list(range(330, 360))


def test_spike_hits_exactly_one_sample_and_spikes_add() -> None:
    faults = fault_profile(
        [MeasurementSpike(at_s=101, spike_kw=3.0), MeasurementSpike(at_s=102, spike_kw=-1.0)],
        n_steps=100, ts_s=TS_S, rng=np.random.default_rng(0),
    )
    assert np.flatnonzero(faults.spike_kw).tolist() == [51]
    assert faults.spike_kw[51] == 2.0


def test_random_spikes_are_seeded_windowed_and_at_the_given_rate() -> None:
    spikes = RandomSpikes(probability_per_sample=0.05, spike_kw=2.0, start_s=200, end_s=1800)
    first = spikes.spike_profile_kw(T, TS_S, np.random.default_rng(1))
    again = spikes.spike_profile_kw(T, TS_S, np.random.default_rng(1))
    other = spikes.spike_profile_kw(T, TS_S, np.random.default_rng(2))
    assert np.array_equal(first, again) and not np.array_equal(first, other)
    hits = np.flatnonzero(first)
    assert hits.min() >= 100 and hits.max() < 900
    assert set(np.abs(first[hits]).tolist()) == {2.0}
    # 800 samples at p = 0.05: 40 expected, standard deviation 6.2; allow 4 of them
    assert abs(hits.size - 40) < 25


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: VoltageStep(at_s=0, factor=0.0), r"VoltageStep.factor.*> 0"),
        (lambda: VoltageStep(at_s=-1, factor=0.97), r"VoltageStep.at_s.*>= 0"),
        (lambda: VoltageStep(at_s=0, factor=0.97, duration_s=0), r"duration_s.*> 0"),
        (lambda: VoltageRamp(start_s=10, end_s=10, factor=0.9), r"VoltageRamp.end_s.*> start_s"),
        (lambda: PowerShift(at_s=0, offset_kw=float("nan")), r"PowerShift.offset_kw"),
        (lambda: PowerShift(at_s=True, offset_kw=1.0), r"PowerShift.at_s.*True"),
        (lambda: MeasurementSpike(at_s=0, spike_kw="3"), r"MeasurementSpike.spike_kw"),
        (lambda: RandomSpikes(probability_per_sample=1.5, spike_kw=1.0),
         r"probability_per_sample.*<= 1"),
        (lambda: RandomSpikes(probability_per_sample=0.1, spike_kw=1.0, start_s=5, end_s=1),
         r"RandomSpikes.end_s"),
        (lambda: MissingSamples(at_s=0, duration_s=-60), r"MissingSamples.duration_s.*> 0"),
    ],
    ids=["zero-voltage", "negative-time", "zero-duration", "inverted-ramp", "nan-offset",
         "bool-time", "string-spike", "probability-above-one", "inverted-window",
         "negative-outage"],
)
def test_invalid_events_are_refused_naming_class_and_field(make, match: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ScenarioError, match=match):
        make()


def test_scaled_times_scales_only_time_fields() -> None:
    scaled = scaled_times(VoltageStep(at_s=600, factor=0.97, duration_s=600), 0.1)
    assert scaled == VoltageStep(at_s=60, factor=0.97, duration_s=60)
    spikes = scaled_times(RandomSpikes(probability_per_sample=0.1, spike_kw=1.0, start_s=100), 0.5)
    assert spikes == RandomSpikes(probability_per_sample=0.1, spike_kw=1.0, start_s=50)


def test_exogenous_at_one_sample_equals_the_profile() -> None:
    events = [VoltageRamp(start_s=0, end_s=40, factor=0.9), PowerShift(at_s=10, offset_kw=0.15)]
    profile = exogenous_profile(events, n_steps=30, ts_s=TS_S)
    for k in (0, 4, 5, 12, 29):
        assert exogenous_at(events, k, TS_S) == Exogenous(
            grid_voltage_factor=float(profile.grid_voltage_factor[k]),
            power_offset_kw=float(profile.power_offset_kw[k]))
