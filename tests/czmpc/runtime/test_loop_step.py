"""A loop step without a server: judge a read, decide, count refusals; run meta and step times."""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
from plant_rig import make_config

import czmpc
from czmpc.controller import OffsetFreeMPC
from czmpc.modes import Mode
from czmpc.runtime.logfiles import RUN_META_FORMAT, meta_path, open_run_log
from czmpc.runtime.loop import RECENT_STEPS, ControlLoop, MPCDriver, StepTimes
from czmpc.runtime.node_types import NodeSpec
from czmpc.runtime.step import (
    Decision,
    Sample,
    Transitions,
    decide,
    judge,
    refused_in_row,
    transitions,
)
from czmpc.settings import MPCSettings
from czmpc.shipped import shipped_path
from sysid.modelfile import load_model

ua = pytest.importorskip("asyncua").ua

SHIPPED = shipped_path("cz_heater_model.json")
SPECS = {k: NodeSpec(node_id=f"ns=2;s={k}")
         for k in ("power_kw", "setpoint_kw", "mode", "applied_triac_pct")}
#: `[plant] max_sample_age_s` of these steps [s].
MAX_AGE_S = 1.0
TS_S = 2.0


def _dv(value: object, *, age_s: float = 0.0, status: int = 0) -> object:
    variant = (ua.Variant(value, ua.VariantType.Double) if isinstance(value, float)
               else ua.Variant(value))
    source = dt.datetime.now(dt.UTC) - dt.timedelta(seconds=age_s)
    return ua.DataValue(variant, StatusCode=ua.StatusCode(status), SourceTimestamp=source)


def _read(power_kw: float, *, age_s: float = 0.0, **others: object) -> Sample:
    values = {"power_kw": _dv(power_kw, age_s=age_s), **{k: _dv(v) for k, v in others.items()}}
    return judge(values, SPECS, max_age_s=MAX_AGE_S, previous_time=None)


def _mpc(**reliability: object) -> OffsetFreeMPC:
    model = load_model(SHIPPED)
    settings = MPCSettings.default_for(model)
    return OffsetFreeMPC(model, dataclasses.replace(settings, reliability=dataclasses.replace(
        settings.reliability, **reliability)))


def test_judge_reads_quality_mode_setpoint_and_applied_input() -> None:
    good = _read(44.0)
    assert good == Sample(power_kw=44.0, quality="good", time=good.time, age_s=good.age_s)
    assert good.age_s is not None and 0.0 <= good.age_s < MAX_AGE_S
    stale = _read(44.0, age_s=5.0)
    assert math.isnan(stale.power_kw) and stale.quality == "stale" and stale.age_s is None
    sample = _read(44.0, mode=2, setpoint_kw=47.5, applied_triac_pct=41.0)
    assert (sample.mode, sample.setpoint_kw, sample.applied_triac_pct) == (Mode.ON, 47.5, 41.0)
    assert _read(44.0, mode=False).mode is Mode.OFF and _read(44.0, mode=" predict").mode \
        is Mode.PREDICT and _read(44.0, mode=7).mode is None
    bad = judge({"power_kw": _dv(44.0, status=0x80000000), "setpoint_kw": _dv(47.0, status=0x80000000)},
                SPECS, max_age_s=MAX_AGE_S, previous_time=None)
    assert bad.quality == "bad" and bad.setpoint_kw is None
    first = _read(44.0)
    again = judge({"power_kw": _dv(44.0)}, SPECS, max_age_s=MAX_AGE_S, previous_time=first.time
                  + dt.timedelta(seconds=1))
    assert again.quality == "repeated" and math.isnan(again.power_kw)
    # the applied input read at a (re)connect wins over the node; no link: disconnected
    fresh = judge({"power_kw": _dv(44.0), "applied_triac_pct": _dv(41.0)}, SPECS,
                  max_age_s=MAX_AGE_S, previous_time=None, connect_applied_pct=39.0)
    assert fresh.applied_triac_pct == 39.0
    gone = judge(None, SPECS, max_age_s=MAX_AGE_S, previous_time=first.time)
    assert gone.quality == "disconnected" and gone.time == first.time


def test_stale_samples_are_missing_and_the_mpc_sheds_to_its_safe_input() -> None:
    safe_pct, predicted = 30.0, 3
    mpc = _mpc(max_predicted_samples=predicted, shed_triac_pct=safe_pct)
    driver = MPCDriver(mpc)
    rate = mpc.settings.max_move_pct_per_step
    state, said, last = Transitions(), [], math.nan
    decisions: list[Decision] = []
    noise_kw = np.random.default_rng(3).normal(0.0, 0.05, size=80)   # not a stuck sensor
    for k in range(80):
        fresh = k < 20 or k >= 60
        sample = _read(45.0 + float(noise_kw[k]), age_s=0.0 if fresh else 5.0)
        assert sample.quality == ("good" if fresh else "stale")
        d = decide(driver, sample, setpoint_kw=45.0, last_command_pct=last, allow_on=True)
        state, events = transitions(state, k, TS_S, d)
        said += [(k, level, text) for level, text in events]
        decisions.append(d)
        last = d.command_pct
    statuses = [d.status for d in decisions]
    assert statuses[20:20 + predicted] == ["PREDICTED"] * predicted
    assert statuses[20 + predicted] == "SHED" and set(statuses[20 + predicted:60]) == {"SHED"}
    assert decisions[59].command_pct == pytest.approx(safe_pct, abs=1e-9)
    moves = np.abs(np.diff([d.command_pct for d in decisions[19:60]]))
    assert rate is not None and moves.max() <= rate + 1e-9
    assert all(d.write for d in decisions)        # ON: the safe input is written too
    shed = [(k, lvl) for k, lvl, text in said if text.startswith("shedding at")]
    assert shed == [(20 + predicted, logging.WARNING)]
    resumed = [text for _, _, text in said if text.startswith("resumed")]
    assert len(resumed) == 1 and f"after {(60 - 20 - predicted) * TS_S:.0f} s shed" in resumed[0]


def test_on_is_refused_until_the_rule_allows_it_and_the_change_is_said() -> None:
    driver = MPCDriver(_mpc(initial_mode="predict"))
    state, last = Transitions(), 43.0
    for k in range(10):          # the operator asks for ON; the rule says no
        d = decide(driver, _read(45.0, mode="ON"), setpoint_kw=45.0, last_command_pct=last,
                   allow_on=False)
        state, events = transitions(state, k, TS_S, d)
        assert d.mode is Mode.PREDICT and not d.write and events == ()
        # outside ON the operator drives the TRIAC: the input acting is the last one
        assert d.applied_triac_pct == last and d.applied_before_pct == last
        last = d.command_pct
    d = decide(driver, _read(45.0, mode="ON"), setpoint_kw=45.0, last_command_pct=last,
               allow_on=True)
    state, events = transitions(state, 10, TS_S, d)
    assert d.mode is Mode.ON and d.write
    assert events == ((logging.INFO, "mode PREDICT -> ON at t=20s"),)
    assert state == Transitions(shed_at_k=None, mode=Mode.ON)


def test_refused_commands_abort_after_max_in_a_row_and_an_accepted_one_resets() -> None:
    codes = ["BadTimeout", "BadTimeout", None, "BadTimeout", "BadTimeout", "BadResourceUnavailable"]
    in_row, counts, aborts = 0, [], []
    for code in codes:
        in_row, abort = refused_in_row(code, in_row, 3)
        counts.append(in_row)
        aborts.append(abort)
    assert counts == [1, 2, 0, 1, 2, 3]
    assert aborts[:-1] == [None] * 5
    assert aborts[-1] == ("3 command writes in a row refused (last BadResourceUnavailable; "
                          "[plant] max_refused_writes = 3)")


def test_the_run_meta_carries_the_czmpc_version_and_the_model_hash(tmp_path: Path) -> None:
    config = make_config(tmp_path, 4840)
    loop = ControlLoop(config, OffsetFreeMPC(load_model(SHIPPED)))
    log = open_run_log(config.log_path, loop._meta())
    log.close()
    meta = json.loads(meta_path(config.log_path).read_text(encoding="utf-8"))
    assert meta["format"] == RUN_META_FORMAT
    assert meta["czmpc_version"] == czmpc.__version__ != ""
    assert meta["model"] == str(SHIPPED)
    assert meta["model_sha256"] == hashlib.sha256(SHIPPED.read_bytes()).hexdigest()


def test_step_times_stay_bounded_and_match_numpy() -> None:
    values = np.random.default_rng(7).gamma(2.0, 0.004, size=100_000)
    times = StepTimes()
    for v in values:
        times.add(float(v))
    assert times.count == values.size
    assert len(times.recent_s) == RECENT_STEPS      # bounded: the last RECENT_STEPS only
    assert times.max_s == values.max()              # exact: max of the same floats
    assert times.recent_max_s == values[-RECENT_STEPS:].max()
    assert list(times.recent_s) == values[-RECENT_STEPS:].tolist()
    assert StepTimes().recent_max_s == 0.0 and StepTimes().max_s == 0.0
