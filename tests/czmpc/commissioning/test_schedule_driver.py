"""The open-loop test without a plant: schedule file, driver, test limits, config."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from commissioning_rig import write_schedule

from czmpc.commissioning.test_run import (
    CONSTANT_SCHEDULE_RAMP_PCT,
    LEAD_IN_HOLD_SAMPLES,
    InputSchedule,
    ScheduleDriver,
    ScheduleError,
    load_input_schedule,
)
from czmpc.modes import Mode
from czmpc.runtime import alignment
from czmpc.runtime.config import ExperimentLimits, RunConfigError, run_config_from_dict


def test_schedule_reads_and_holds(tmp_path: Path) -> None:
    sched = load_input_schedule(write_schedule(tmp_path / "t.csv", [0, 4, 10], [45, 50, 42]))
    assert sched.max_step_pct == 8.0
    assert sched.duration_s == 10.0
    assert [sched.triac_at(t) for t in (0.0, 3.9, 4.0, 9.0, 10.0, 99.0)] == [45, 45, 50, 50, 42, 42]
    assert sched.sha256 is not None and len(sched.sha256) == 64


@pytest.mark.parametrize(("text", "match"), [
    ("time_s,triac_pct\n0,45\n2,abc\n", "line 3"),
    ("time_s,power_kw\n0,45\n2,46\n", "line 2"),
    ("time_s,triac_pct\n0,45\n0,46\n", "increase"),
    ("time_s,triac_pct\n2,45\n4,46\n", "start at 0"),
    ("time_s,triac_pct\n0,45\n2,146\n", "0..100"),
])
def test_bad_schedules_are_named(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "t.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ScheduleError, match=match):
        load_input_schedule(path)


def _schedule(times: list[float], values: list[float]) -> InputSchedule:
    return InputSchedule(time_s=np.asarray(times, float), triac_pct=np.asarray(values, float))


def test_driver_starts_bumplessly_and_ramps_at_the_largest_designed_step() -> None:
    drv = ScheduleDriver(_schedule([0, 4, 8], [45, 50, 45]), ts_s=2.0, hold_samples=0)
    # the plant sits at 30 %: ramp 30 -> 35 -> 40 -> 45 at 5 %/sample (the sample that
    # arrives is the schedule's time 0), then the schedule at 2, 4, 6, 8 s
    u = [drv.step(math.nan, math.nan, applied_triac_pct=30.0)]
    phases = [drv.status_words()[0]]
    for _ in range(6):
        assert drv.finished() is None
        u.append(drv.step(math.nan, math.nan))
        phases.append(drv.status_words()[0])
    assert u == [35.0, 40.0, 45.0, 45.0, 50.0, 50.0, 45.0]
    assert phases[:3] == ["LEAD_IN"] * 3 and phases[3:] == ["TEST"] * 4
    assert drv.lead_in_samples == 3
    assert drv.finished() == "end of schedule"


def test_the_driver_holds_the_applied_input_until_the_loop_has_aligned() -> None:
    drv = ScheduleDriver(_schedule([0, 4], [45, 50]), ts_s=2.0)
    u = [drv.step(math.nan, math.nan, applied_triac_pct=30.0)]
    u += [drv.step(math.nan, math.nan) for _ in range(LEAD_IN_HOLD_SAMPLES + 2)]
    # held at 30 % while the loop estimates its read phase (8 good samples, then a delay),
    # then the ramp at 5 %/sample
    assert LEAD_IN_HOLD_SAMPLES > alignment.WINDOW
    assert u[:LEAD_IN_HOLD_SAMPLES] == [30.0] * LEAD_IN_HOLD_SAMPLES
    assert u[LEAD_IN_HOLD_SAMPLES:] == [35.0, 40.0, 45.0]
    assert drv.lead_in_samples == LEAD_IN_HOLD_SAMPLES + 3
    assert drv.status_words()[0] == "LEAD_IN"
    with pytest.raises(ScheduleError, match="hold_samples"):
        ScheduleDriver(_schedule([0, 4], [45, 50]), ts_s=2.0, hold_samples=-1)


def test_skipped_periods_keep_the_schedule_on_plant_time() -> None:
    drv = ScheduleDriver(_schedule([0, 10, 20], [45, 55, 45]), ts_s=2.0, hold_samples=0)
    drv.step(math.nan, math.nan, applied_triac_pct=45.0)   # at 45: schedule sample 0
    drv.skipped(4)                                           # plant time 8 s
    assert drv.step(math.nan, math.nan) == 55.0              # sample 5 = 10 s
    assert drv.finished() is None
    drv.skipped(4)
    assert drv.step(math.nan, math.nan) == 45.0              # sample 10 = 20 s
    assert drv.finished() == "end of schedule"


def test_constant_schedule_ramps_at_the_stated_rate() -> None:
    drv = ScheduleDriver(_schedule([0, 10], [50, 50]), ts_s=2.0, hold_samples=0)
    assert drv.rate_limit_pct_per_step == CONSTANT_SCHEDULE_RAMP_PCT
    assert drv.step(math.nan, math.nan, applied_triac_pct=47.5) == 47.5 + CONSTANT_SCHEDULE_RAMP_PCT


def test_operator_taking_the_heater_aborts_the_test() -> None:
    drv = ScheduleDriver(_schedule([0, 10], [50, 55]), ts_s=2.0)
    assert drv.abort_reason() is None
    drv.request_mode(Mode.ON)
    assert drv.abort_reason() is None
    drv.request_mode(Mode.OFF)
    assert drv.mode is Mode.OFF
    assert "OFF" in (drv.abort_reason() or "")


def test_limits_band_and_bad_quality_stretch() -> None:
    lim = ExperimentLimits(power_band_kw=(40.0, 50.0), max_bad_quality_s=6.0)
    assert lim.violation(45.0, "good", 0.0) is None
    assert lim.violation(40.0, "good", 0.0) is None
    assert "above" in (lim.violation(50.01, "good", 0.0) or "")
    assert "below" in (lim.violation(39.9, "good", 0.0) or "")
    assert lim.violation(math.nan, "bad", 6.0) is None
    assert "max_bad_quality_s" in (lim.violation(math.nan, "bad", 8.0) or "")


def _doc(**tables: dict[str, object]) -> dict[str, object]:
    doc: dict[str, object] = {
        "plant": {"endpoint": "opc.tcp://127.0.0.1:4840/x/", "ts_s": 2.0},
        "nodes": {"power_kw": "a", "triac_pct": "b"},
        "run": {"log": "run.csv"},
    }
    doc.update(tables)
    return doc


def test_a_test_config_needs_no_controller(tmp_path: Path) -> None:
    cfg = run_config_from_dict(_doc(safety={"safe_triac_pct": 30.0},
                                    test={"power_band_kw": [20, 60]}), base_dir=tmp_path)
    assert cfg.model_path is None
    assert cfg.test_limits == ExperimentLimits(power_band_kw=(20.0, 60.0), max_bad_quality_s=10.0)


@pytest.mark.parametrize(("tables", "key"), [
    ({"test": {"power_band_kw": [20, 60]}}, "safety.safe_triac_pct"),
    ({"safety": {"safe_triac_pct": 30.0}, "test": {"power_band_kw": [60, 20]}}, "test.power_band_kw"),
    ({"safety": {"safe_triac_pct": 30.0}, "test": {}}, "test.power_band_kw"),
    ({"safety": {"safe_triac_pct": 30.0},
      "test": {"power_band_kw": [2, 6], "max_bad_quality_s": -1}}, "test.max_bad_quality_s"),
    ({"safety": {"safe_triac_pct": 30.0},
      "test": {"power_band_kw": [2, 6], "band": 1}}, "test.band"),
    ({"controller": {}}, "controller.model"),
])
def test_bad_test_sections_are_named(tmp_path: Path, tables: dict[str, dict[str, object]],
                                     key: str) -> None:
    with pytest.raises(RunConfigError, match=key.replace(".", r"\.")):
        run_config_from_dict(_doc(**tables), base_dir=tmp_path)


def test_the_shipped_commissioning_config_reads() -> None:
    from czmpc.runtime.config import load_run_config

    repo = Path(__file__).resolve().parents[3]
    cfg = load_run_config(repo / "examples" / "plant_link" / "commission.toml")
    assert cfg.model_path is None
    assert cfg.test_limits == ExperimentLimits(power_band_kw=(25.0, 70.0), max_bad_quality_s=10.0)
    assert cfg.safe_triac_pct == 33.0 and cfg.setpoint_kw == 45.0


def test_a_test_loop_states_its_plan_and_refuses_a_config_without_a_test_section(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    from czmpc.commissioning.test_run import make_test_loop

    schedule = InputSchedule(time_s=np.array([0.0, 20.0, 60.0]),
                             triac_pct=np.array([40.0, 47.5, 40.0]), source="steps.csv")
    safety = {"safe_triac_pct": 30.0}
    with pytest.raises(ScheduleError, match=r"a test needs a \[test\] section"):
        make_test_loop(run_config_from_dict(
            _doc(safety=safety, controller={"model": "m.json"},
                 run={"log": "run.csv", "setpoint_kw": 45.0}), base_dir=tmp_path), schedule)
    cfg = run_config_from_dict(_doc(safety=safety, test={"power_band_kw": [20, 60]}),
                               base_dir=tmp_path)
    with caplog.at_level("INFO", logger="czmpc"):
        make_test_loop(cfg, schedule)
    assert ("open-loop test steps.csv: 60 s of plant time, largest step 7.5 %; band 20..60 kW, "
            "at most 10 s without a usable sample; abort -> 30 %") in caplog.text
