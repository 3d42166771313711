"""Scenarios: shipped TOML files, strict validation naming file and key, profiles."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim.disturbances import MissingSamples, PowerShift, VoltageStep
from sim.errors import ScenarioError
from sim.scenario import (
    MAX_N_STEPS,
    Scenario,
    SetpointRamp,
    SetpointStep,
    list_scenarios,
    load_scenario,
)
from tests.tolerances import IDENTITY_RTOL

SHIPPED = {"staircase", "large_step", "meltdown_ramp", "voltage_sag", "level_shift",
           "missing_samples"}

GOOD = """\
name = "t"
duration_s = 600
initial_setpoint_kw = 45.0

[limits]
triac_min_pct = 10.0
triac_max_pct = 70.0

[[setpoint]]
kind = "step"
at_s = 100
power_kw = 50.0
"""


def _write(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_every_shipped_scenario_loads_and_is_listed() -> None:
    assert SHIPPED <= set(list_scenarios())
    for name in list_scenarios():
        scenario = load_scenario(name)
        assert scenario.name == name
        assert scenario.ts_s == 2.0
        assert 3600 <= scenario.duration_s <= 3 * 3600   # 1-3 h of plant time
        assert scenario.description


def test_staircase_is_the_papers_45_to_65_kw_steps() -> None:
    scenario = load_scenario("staircase")
    levels = [scenario.initial_setpoint_kw] + [c.power_kw for c in scenario.setpoints]
    assert levels == [45.0, 50.0, 55.0, 60.0, 65.0]
    profile = scenario.setpoint_profile_kw()
    assert profile.shape == (scenario.n_steps,)
    assert profile[299] == 45.0 and profile[300] == 50.0 and profile[-1] == 65.0


def test_shipped_disturbances_are_what_their_names_say() -> None:
    assert load_scenario("voltage_sag").disturbances == (
        VoltageStep(at_s=1200, factor=0.97, duration_s=600),)
    assert load_scenario("level_shift").disturbances == (PowerShift(at_s=1200, offset_kw=0.15),)
    assert load_scenario("missing_samples").faults == (MissingSamples(at_s=660, duration_s=60),)
    ramp = load_scenario("meltdown_ramp")
    assert ramp.setpoints == (SetpointRamp(start_s=600, end_s=2400, power_kw=60.0),)
    assert ramp.initial_setpoint_kw == 20.0 and ramp.initial_triac_pct is None
    assert max(c.power_kw for c in load_scenario("large_step").setpoints) == 80.0


def test_ramp_profile_is_linear_between_its_ends() -> None:
    scenario = load_scenario("meltdown_ramp")
    t = scenario.time_s()
    expected = np.interp(t, [600, 2400], [20.0, 60.0])
    np.testing.assert_allclose(scenario.setpoint_profile_kw(), expected,
                               rtol=IDENTITY_RTOL, atol=1e-12)  # same straight line


def test_load_from_a_path_and_segments_on_the_sample_grid(tmp_path: Path) -> None:
    scenario = load_scenario(_write(tmp_path, GOOD, "mine.toml"))
    assert scenario.source.endswith("mine.toml")
    assert scenario.triac_limits_pct == (10.0, 70.0)
    assert scenario.plant_noise is True and scenario.max_move_pct_per_step is None
    kinds = [(s.kind, s.start_k, s.stop_k, s.from_kw, s.to_kw) for s in scenario.segments()]
    assert kinds == [("initial", 0, 50, 45.0, 45.0), ("step", 50, 300, 45.0, 50.0)]


def test_shortened_scales_every_time() -> None:
    scenario = load_scenario("missing_samples").shortened(0.1)
    assert scenario.duration_s == 360.0
    assert scenario.setpoints == (SetpointStep(at_s=60.0, power_kw=50.0),)
    assert scenario.faults == (MissingSamples(at_s=66.0, duration_s=6.0),)
    with pytest.raises(ScenarioError, match=r"factor"):
        scenario.shortened(0.0)


@pytest.mark.parametrize(
    ("text", "key", "what"),
    [
        ("duration = 5\n" + GOOD, "duration", r"unknown key \(did you mean 'duration_s'\?\)"),
        ("power_kw = 5\n" + GOOD, "power_kw", r"unknown key"),
        (GOOD.replace("power_kw = 50.0", "power_kw = 50.0\nfactor = 1.0"), r"setpoint\[1\]\.factor",
         r"unknown key"),
        (GOOD.replace("triac_max_pct = 70.0", "triac_max_pct = 70.0\nmax_pct = 3"),
         r"limits\.max_pct", r"unknown key"),
        (GOOD.replace("duration_s = 600", "duration_s = -600"), "duration_s", r"> 0"),
        (GOOD.replace("at_s = 100", "at_s = -100"), r"setpoint\[1\]\.at_s", r">= 0"),
        (GOOD.replace("duration_s = 600", 'duration_s = "600"'), "duration_s",
         r"expected a number; got '600'"),
        (GOOD.replace("power_kw = 50.0", "power_kw = true"), r"setpoint\[1\]\.power_kw",
         r"expected a number; got True"),
        (GOOD.replace('name = "t"', "name = 3"), "name", r"expected a string"),
        (GOOD.replace("triac_max_pct = 70.0", "triac_max_pct = 5.0"), r"limits\.triac_max_pct",
         r"min < max"),
        (GOOD.replace('name = "t"\n', ""), "name", r"missing"),
        (GOOD.replace('kind = "step"', 'kind = "stp"'), r"setpoint\[1\]\.kind",
         r"did you mean 'step'"),
        (GOOD.replace("at_s = 100\n", ""), r"setpoint\[1\]\.at_s", r"missing"),
        (GOOD + "[limits2]\n", "limits2", r"unknown key"),
        (GOOD.replace("triac_max_pct = 70.0", "triac_max_pct = 70.0\nmax_move_pct_per_step = 0"),
         r"limits\.max_move_pct_per_step", r"> 0"),
    ],
    ids=["unknown-top-key-with-hint", "unit-less-key-at-top", "unknown-setpoint-key",
         "unknown-limits-key", "negative-duration", "negative-step-time", "string-for-number",
         "bool-for-number", "number-for-string", "inverted-limits", "missing-name",
         "unknown-kind", "missing-at_s", "unknown-table", "non-positive-rate-limit"],
)
def test_bad_files_name_the_file_and_the_key(tmp_path: Path, text: str, key: str, what: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ScenarioError, match=rf"bad\.toml: key '{key}'.*{what}"):
        load_scenario(path)


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ('[[disturbance]]\nkind = "voltage_ramp"\nstart_s = 300\nend_s = 200\nfactor = 0.9\n',
         r"bad\.toml: disturbance\[1\] \(voltage_ramp\): VoltageRamp\.end_s: expected a time > "
         r"start_s"),
        ('[[fault]]\nkind = "missing_samples"\nat_s = 10\nduration_s = -60\n',
         r"bad\.toml: fault\[1\] \(missing_samples\): MissingSamples\.duration_s.*> 0"),
        ('[[setpoint]]\nkind = "ramp"\nstart_s = 90\nend_s = 200\npower_kw = 60\n',
         r"bad\.toml: key 'setpoint\[2\]\.start_s': expected a time after the previous"),
        ('[[setpoint]]\nkind = "ramp"\nstart_s = 300\nend_s = 200\npower_kw = 60\n',
         r"bad\.toml: key 'setpoint\[2\]\.end_s': expected a time > start_s"),
        ('[[fault]]\nkind = "spike"\nat_s = 900\nspike_kw = 1\n',
         r"bad\.toml: Scenario: MeasurementSpike starts at 900 s"),
    ],
    ids=["inverted-voltage-ramp", "negative-outage", "overlapping-setpoints",
         "inverted-setpoint-ramp", "event-after-the-end"],
)
def test_inconsistent_events_name_the_file_and_the_entry(tmp_path: Path, extra: str, match: str) -> None:
    with pytest.raises(ScenarioError, match=match):
        load_scenario(_write(tmp_path, GOOD + extra))


def test_duration_must_be_whole_samples_and_toml_must_parse(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"bad\.toml: key 'duration_s'.*whole number"):
        load_scenario(_write(tmp_path, GOOD.replace("duration_s = 600", "duration_s = 601")))
    with pytest.raises(ScenarioError, match=r"bad\.toml: not a valid TOML"):
        load_scenario(_write(tmp_path, "name = \n"))
    with pytest.raises(ScenarioError, match=r"cannot read"):
        load_scenario(tmp_path / "absent.toml")


def test_unknown_scenario_name_lists_the_shipped_ones() -> None:
    with pytest.raises(ScenarioError, match=r"staircase.*got 'stairs'.*did you mean 'staircase'"):
        load_scenario("stairs")


def test_in_memory_scenario_is_validated() -> None:
    with pytest.raises(ScenarioError, match=r"Scenario\.triac_limits_pct.*min < max"):
        Scenario(name="t", duration_s=10, initial_setpoint_kw=45, triac_limits_pct=(60, 50))
    with pytest.raises(ScenarioError, match=r"Scenario\.ts_s.*> 0"):
        Scenario(name="t", duration_s=10, ts_s=0, initial_setpoint_kw=45)
    with pytest.raises(ScenarioError, match=r"Scenario\.setpoints\[1\].*end before the run ends"):
        Scenario(name="t", duration_s=10, initial_setpoint_kw=45,
                 setpoints=(SetpointStep(at_s=10, power_kw=50),))


# --- bounds: what the machine can hold (issue 13.5) ------------------------------------
_HUGE_INT = "1" + "0" * 39          # a 40-digit integer


@pytest.mark.parametrize(("duration", "bound"), [
    ("1e8", "MAX_TIME_S"),                  # 1e8 s: beyond every time bound
    (_HUGE_INT, "MAX_TIME_S"),              # a 40-digit integer
    ("2000000\nts_s = 1.0", "MAX_N_STEPS"), # within the time bound, 2e6 samples
])
def test_a_scenario_the_machine_cannot_hold_is_refused_naming_key_and_bound(
        tmp_path: Path, duration: str, bound: str) -> None:
    text = GOOD.replace("duration_s = 600", f"duration_s = {duration}")
    with pytest.raises(ScenarioError, match=rf"key 'duration_s'.*{bound}") as info:
        load_scenario(_write(tmp_path, text))
    assert "bad.toml" in str(info.value)


def test_the_bounds_hold_through_the_api_and_the_largest_run_is_accepted() -> None:
    with pytest.raises(ScenarioError, match=r"Scenario.duration_s.*MAX_TIME_S"):
        Scenario(name="x", duration_s=1e8, initial_setpoint_kw=45.0)
    with pytest.raises(ScenarioError, match=r"Scenario.duration_s.*MAX_N_STEPS"):
        Scenario(name="x", duration_s=MAX_N_STEPS * 2.0 + 2.0, initial_setpoint_kw=45.0)
    with pytest.raises(ScenarioError, match=r"MissingSamples.duration_s.*MAX_TIME_S"):
        Scenario(name="x", duration_s=600.0, initial_setpoint_kw=45.0,
                 faults=(MissingSamples(at_s=10.0, duration_s=1e39),))
    largest = Scenario(name="x", duration_s=MAX_N_STEPS * 2.0, initial_setpoint_kw=45.0)
    assert largest.n_steps == MAX_N_STEPS          # nothing is allocated to check this


def test_event_times_of_40_digits_are_refused_with_the_entry(tmp_path: Path) -> None:
    text = GOOD + f'\n[[fault]]\nkind = "missing_samples"\nat_s = 10\nduration_s = {_HUGE_INT}\n'
    with pytest.raises(ScenarioError, match=r"bad.toml.*duration_s.*MAX_TIME_S"):
        load_scenario(_write(tmp_path, text))



def test_powers_beyond_the_float_safe_bound_are_refused() -> None:
    with pytest.raises(ScenarioError, match=r"initial_setpoint_kw.*MAX_ABS_POWER_KW"):
        Scenario(name="x", duration_s=600.0, initial_setpoint_kw=1e308)
    with pytest.raises(ScenarioError, match=r"setpoints\[1\].power_kw.*MAX_ABS_POWER_KW"):
        Scenario(name="x", duration_s=600.0, initial_setpoint_kw=45.0,
                 setpoints=(SetpointStep(at_s=10.0, power_kw=-1e101),))
    with pytest.raises(ScenarioError, match=r"PowerShift.offset_kw.*MAX_ABS_POWER_KW"):
        Scenario(name="x", duration_s=600.0, initial_setpoint_kw=45.0,
                 disturbances=(PowerShift(at_s=10.0, offset_kw=1e200),))
    ok = Scenario(name="x", duration_s=600.0, initial_setpoint_kw=45.0,
                  setpoints=(SetpointStep(at_s=10.0, power_kw=1e100),))
    assert ok.setpoint_profile_kw()[-1] == 1e100
