"""czmpc.pid.controller: the velocity law, bumpless row changes, anti-windup, its transfer function."""

from __future__ import annotations

import math

import numpy as np
import pytest

from czmpc.pid.controller import ScheduledPID, TableSchedule
from czmpc.pid.discretization import controller_frequency_response
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.rules import PIDTuning
from sim.protocols import Controller

PID = PIDTuning(kc_pct_per_kw=0.4, ti_s=5.0, td_s=3.0, td_filter_s=0.5, setpoint_weight=0.6)
TWO_ROWS = TableSchedule(breakpoints_pct=(0.0, 50.0),
                         tunings=(PIDTuning(kc_pct_per_kw=0.2, ti_s=4.0),
                                  PIDTuning(kc_pct_per_kw=0.5, ti_s=4.0)))


def _one_row(tuning: PIDTuning) -> TableSchedule:
    return TableSchedule(breakpoints_pct=(0.0,), tunings=(tuning,))


def test_matches_the_position_form_pid_written_out() -> None:
    # position form: u = u0 + Kc (b r - y) + Kc Ts/Ti sum_{j<k} e_j + Kc D, with the filtered
    # derivative D_k = (Tf D_{k-1} - Td (y_k - y_{k-1}))/(Tf + Ts) and D = 0 at the start
    ts = 2.0
    pid = ScheduledPID(schedule=_one_row(PID), ts_s=ts, initial_triac_pct=40.0,
                       triac_limits_pct=(-1e6, 1e6))
    assert isinstance(pid, Controller)
    rng = np.random.default_rng(3)
    ys, rs = 45 + rng.normal(size=30), 45 + np.repeat([0.0, 2.0, 1.0], 10)
    integral, d, y_prev = 0.0, 0.0, math.nan
    for y, r in zip(ys, rs, strict=True):
        if not math.isnan(y_prev):
            d = (PID.td_filter_s * d - PID.td_s * (y - y_prev)) / (PID.td_filter_s + ts)
        expected = 40.0 + PID.kc_pct_per_kw * (PID.setpoint_weight * r - y + integral + d)
        got = pid.step(power_kw=float(y), setpoint_kw=float(r))
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-11)
        integral += ts / PID.ti_s * (r - y)
        y_prev = y


def test_a_row_change_under_a_steady_error_moves_only_by_the_integral() -> None:
    # constant error 1 kW: the row changes from Kc 0.2 to 0.5 as the input crosses 50 %; the
    # velocity form moves by the integral increment Kc Ts/Ti e of the previous step only (no
    # step of (0.5 - 0.2) * 1 % when the gain changes)
    start = 49.75
    pid = ScheduledPID(schedule=TWO_ROWS, ts_s=2.0, initial_triac_pct=start)
    u = [start] + [pid.step(power_kw=40.0, setpoint_kw=41.0) for _ in range(6)]
    rows = [TWO_ROWS.row_at(v) for v in u]
    assert rows[0] == 0 and rows[-1] == 1
    kc = [0.2, 0.5]
    expected = [kc[rows[k - 2]] * 2.0 / 4.0 * 1.0 for k in range(2, len(u))]
    np.testing.assert_allclose(np.diff(u)[1:], expected, rtol=1e-9, atol=1e-12)
    legacy = ScheduledPID(schedule=TWO_ROWS, ts_s=2.0, initial_triac_pct=start, bumpless=False)
    jumps = np.diff([start] + [legacy.step(power_kw=40.0, setpoint_kw=41.0) for _ in range(6)])
    # the positional law adds (0.5 - 0.2) * 1 % to the integral move where the row changes
    assert max(jumps[1:]) == pytest.approx(0.1 + 0.3, abs=1e-12)


def test_no_windup_at_the_triac_limit_and_rate_limit_respected() -> None:
    pid = ScheduledPID(schedule=_one_row(PIDTuning(kc_pct_per_kw=1.0, ti_s=2.0)), ts_s=2.0,
                       initial_triac_pct=60.0, triac_limits_pct=(0.0, 70.0),
                       max_move_pct_per_step=3.0)
    u = [pid.step(power_kw=60.0, setpoint_kw=100.0) for _ in range(100)]
    assert u[:3] == [63.0, 66.0, 69.0] and u[-1] == 70.0
    assert pid.last_step is not None and pid.last_step.saturated
    # the error reverses: the input leaves the limit at once (nothing wound up)
    assert pid.step(power_kw=60.0, setpoint_kw=59.0) < 70.0


def test_a_missing_sample_holds_the_input_and_keeps_the_state() -> None:
    a = ScheduledPID(schedule=_one_row(PID), ts_s=2.0, initial_triac_pct=45.0)
    b = ScheduledPID(schedule=_one_row(PID), ts_s=2.0, initial_triac_pct=45.0)
    first = a.step(power_kw=44.0, setpoint_kw=45.0)
    assert b.step(power_kw=44.0, setpoint_kw=45.0) == first
    assert a.step(power_kw=math.nan, setpoint_kw=45.0) == first
    assert a.last_step is not None and not a.last_step.measurement_used
    assert a.step(power_kw=44.5, setpoint_kw=45.0) == b.step(power_kw=44.5, setpoint_kw=45.0)
    a.reset()
    assert a.step(power_kw=44.0, setpoint_kw=45.0) == first


def test_transfer_function_is_the_law_run_step_by_step() -> None:
    # (1 - z^-1) C(z) is the impulse response of the moves of the law to y = -delta
    ts, n = 2.0, 4096
    pid = ScheduledPID(schedule=_one_row(PID), ts_s=ts, initial_triac_pct=0.0,
                       triac_limits_pct=(-1e9, 1e9))
    y = np.zeros(n + 1)
    y[1] = -1.0  # after one sample at rest, so the derivative has a previous measurement
    u = np.array([pid.step(power_kw=float(v), setpoint_kw=0.0) for v in y])
    moves = np.diff(u)
    w = np.linspace(0.01, 0.99, 9) * np.pi / ts
    dtft = np.array([np.sum(moves * np.exp(-1j * wi * ts * np.arange(n))) for wi in w])
    expected = (1 - np.exp(-1j * w * ts)) * controller_frequency_response(PID, ts, w, "forward")
    # setpoint weight acts on r only (r = 0 here)
    np.testing.assert_allclose(dtft, expected, rtol=1e-10, atol=1e-12)


def test_table_and_controller_refuse_bad_values() -> None:
    with pytest.raises(PIDTuningError, match=r"strictly increasing.*\[50.0, 40.0\]"):
        TableSchedule(breakpoints_pct=(50.0, 40.0), tunings=TWO_ROWS.tunings)
    with pytest.raises(PIDTuningError, match="one tuning per breakpoint"):
        TableSchedule(breakpoints_pct=(50.0,), tunings=TWO_ROWS.tunings)
    with pytest.raises(PIDTuningError, match=r"initial_triac_pct: expected a value in \[0, 70\]"):
        ScheduledPID(schedule=TWO_ROWS, ts_s=2.0, initial_triac_pct=80.0,
                     triac_limits_pct=(0.0, 70.0))
    with pytest.raises(PIDTuningError, match="max_move_pct_per_step"):
        ScheduledPID(schedule=TWO_ROWS, ts_s=2.0, initial_triac_pct=50.0,
                     max_move_pct_per_step=0.0)
    with pytest.raises(PIDTuningError, match=r"td_filter_s.*got 0.0"):
        PIDTuning(kc_pct_per_kw=1.0, ti_s=1.0, td_s=1.0, td_filter_s=0.0)
