"""Mode machine: the pure transition function, alone and inside the controller."""

from __future__ import annotations

import functools
import math

import pytest
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule

from czmpc.controller import OffsetFreeMPC
from czmpc.modes import Mode, ModeTransition, Status, transition
from czmpc.settings import MPCSettings, ReliabilitySettings
from sysid.model import HammersteinModel

MODES = list(Mode)


@pytest.mark.parametrize("current", MODES)
@pytest.mark.parametrize("requested", MODES)
@pytest.mark.parametrize("ready", [False, True])
def test_transition_table(current: Mode, requested: Mode, ready: bool) -> None:
    new, reason = transition(current, requested, estimator_ready=ready)
    if requested is Mode.ON and current is not Mode.ON and not ready:
        assert new is current and reason.startswith("refused")
    else:
        assert new is requested
    assert reason


def test_a_request_that_is_no_mode_is_refused() -> None:
    new, reason = transition(Mode.ON, "auto", estimator_ready=True)  # type: ignore[arg-type]
    assert new is Mode.ON and reason.startswith("refused")


class PureModeMachine(RuleBasedStateMachine):
    """The transition function never reaches ON without a warm estimator."""

    def __init__(self) -> None:
        super().__init__()
        self.mode = Mode.OFF
        self.warm = 0

    @rule(requested=st.sampled_from(MODES), need=st.integers(0, 3))
    def request(self, requested: Mode, need: int) -> None:
        before = self.mode
        self.mode, _ = transition(self.mode, requested, estimator_ready=self.warm >= need)
        if self.mode is Mode.ON and before is not Mode.ON:
            assert self.warm >= need
        if self.mode is Mode.OFF:
            self.warm = 0

    @rule()
    def valid_sample(self) -> None:
        if self.mode is not Mode.OFF:
            self.warm += 1

    @invariant()
    def mode_is_a_mode(self) -> None:
        assert isinstance(self.mode, Mode)


TestPureModeMachine = PureModeMachine.TestCase
TestPureModeMachine.settings = settings(max_examples=60, stateful_step_count=30, deadline=None)


@functools.cache
def _controller(model: HammersteinModel) -> OffsetFreeMPC:
    rel = ReliabilitySettings(initial_mode="off", warmup_samples=3, transition_log_size=4)
    s = MPCSettings.default_for(model).with_updates(max_move_pct_per_step=2.0, reliability=rel)
    return OffsetFreeMPC(model, s)


class ControllerModeMachine(RuleBasedStateMachine):
    """In the controller: never acts outside ON; ON only after warm-up; log bounded."""

    model: HammersteinModel

    def __init__(self) -> None:
        super().__init__()
        self.mpc = _controller(self.model)
        self.mpc.reset()
        self.manual = 45.0
        self.valid_since_restart = 0
        self.logged: list[ModeTransition] = []

    @rule(requested=st.sampled_from(MODES))
    def request(self, requested: Mode) -> None:
        before = self.mpc.mode
        record = self.mpc.request_mode(requested)
        after: Mode = self.mpc.mode
        assert record.from_mode is before and record.to_mode is after
        assert record.accepted == (before is not after)
        if after is Mode.ON and before is not Mode.ON:
            assert self.valid_since_restart >= 3
        if Mode.OFF in (before, after):  # entering OFF, or leaving it: a restart
            self.valid_since_restart = 0
        self.logged.append(record)

    @rule(power=st.one_of(st.floats(40.0, 50.0), st.just(math.nan)),
          manual=st.floats(30.0, 60.0))
    def step(self, power: float, manual: float) -> None:
        mode = self.mpc.mode
        s = self.mpc.step(power, 47.0, applied_triac_pct=self.manual if mode is not Mode.ON
                          else None)
        last = self.mpc.last_step
        assert last is not None and last.mode is mode and math.isfinite(s)
        if mode is Mode.ON:
            lo, hi = self.mpc.triac_limits_pct
            assert lo <= s <= hi
            self.manual = s
        else:
            assert s == self.manual  # nothing applied: the caller's input comes back
            assert last.status is Status.HELD
            self.manual = manual
        if mode is not Mode.OFF and last.measurement_used:
            self.valid_since_restart += 1

    @rule()
    def drain(self) -> None:
        drained = self.mpc.drain_transitions()
        assert list(drained) == self.logged[-4:]  # the newest, bounded by the log size
        self.logged = []
        assert self.mpc.drain_transitions() == ()


@pytest.fixture
def controller_machine(paper_armax_model: HammersteinModel) -> type[ControllerModeMachine]:
    ControllerModeMachine.model = paper_armax_model
    return ControllerModeMachine


def test_controller_mode_machine(controller_machine: type[ControllerModeMachine]) -> None:
    from hypothesis.stateful import run_state_machine_as_test

    run_state_machine_as_test(
        controller_machine,
        settings=settings(max_examples=40, stateful_step_count=40, deadline=None))


def test_off_to_on_is_refused_until_predict_warmed_up(paper_armax_model: HammersteinModel,
                                                      ) -> None:
    mpc = _controller(paper_armax_model)
    mpc.reset()
    assert mpc.mode is Mode.OFF
    assert not mpc.request_mode("on").accepted
    assert mpc.request_mode(Mode.PREDICT).accepted
    for _ in range(2):
        mpc.step(45.0, 47.0)
    assert not mpc.request_mode(Mode.ON).accepted
    mpc.step(45.0, 47.0)
    record = mpc.request_mode(Mode.ON)
    now: Mode = mpc.mode
    assert record.accepted and now is Mode.ON
    s = mpc.step(45.0, 47.0)
    last = mpc.last_step
    assert last is not None and last.transition == record and last.mode is Mode.ON
    assert abs(s - 45.0) <= 2.0 + 1e-9  # bumpless from the held input
    log = mpc.drain_transitions()
    assert [t.accepted for t in log] == [False, True, False, True]
