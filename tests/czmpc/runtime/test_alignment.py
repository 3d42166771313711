"""The loop's read phase against the plant's sample clock (czmpc.runtime.alignment)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from czmpc.runtime.alignment import (
    BAND,
    MIN_CONCENTRATION,
    TARGET_PHASE,
    alignment_shift_s,
    read_phase,
)

PERIOD_S = 0.1


def test_read_phase_is_the_circular_mean_across_the_wrap() -> None:
    # ages just below and just above whole periods: phases 0.95 and 0.05 average to 0,
    # where an arithmetic mean of the phases would say 0.5
    ages = [0.095, 0.105, 0.195, 0.205]
    phase = read_phase(ages, PERIOD_S)
    assert phase is not None
    assert min(phase, 1.0 - phase) < 1e-9
    # a plain case, against numpy's angle of the mean unit vector
    rng = np.random.default_rng(1)
    ages = list(0.037 + 0.004 * rng.standard_normal(8))
    expected = np.angle(np.mean(np.exp(2j * np.pi * np.array(ages) / PERIOD_S))) / (2 * np.pi)
    assert read_phase(ages, PERIOD_S) == pytest.approx(expected % 1.0, abs=1e-12)


def test_spread_phases_give_no_estimate() -> None:
    ages = [PERIOD_S * i / 8 for i in range(8)]       # evenly around the circle: length 0
    assert read_phase(ages, PERIOD_S) is None
    # just concentrated enough: two phases 0.1 apart have a mean vector of length
    # cos(pi * 0.1) = 0.951 > MIN_CONCENTRATION; 0.45 apart, cos(0.45 pi) = 0.156 < it
    assert read_phase([0.0, 0.01], PERIOD_S) is not None
    assert math.cos(math.pi * 0.45) < MIN_CONCENTRATION
    assert read_phase([0.0, 0.045], PERIOD_S) is None


def test_a_shift_moves_the_reads_to_the_target_inside_the_plants_period() -> None:
    # read at 0.9 of the period after the plant published: its next step is 10 % of a
    # period away, so a write may land on either side of it. The reads come 0.7 of a
    # period sooner; 0.3 later would pass the next publication and leave a sample unread
    assert alignment_shift_s(0.9, PERIOD_S) == pytest.approx(-0.7 * PERIOD_S, rel=1e-12)
    assert alignment_shift_s(0.01, PERIOD_S) == pytest.approx((TARGET_PHASE - 0.01) * PERIOD_S)
    for phase in (0.0, 0.04, 0.51, 0.75, 0.999):
        moved = phase + alignment_shift_s(phase, PERIOD_S) / PERIOD_S   # type: ignore[operator]
        assert moved == pytest.approx(TARGET_PHASE, abs=1e-12)         # never across a publication
    for phase in (BAND[0], TARGET_PHASE, BAND[1]):
        assert alignment_shift_s(phase, PERIOD_S) is None


@pytest.mark.parametrize(("ages", "period"), [([], 0.1), ([math.nan], 0.1), ([0.1], 0.0)])
def test_bad_arguments_are_refused(ages: list[float], period: float) -> None:
    with pytest.raises(ValueError, match="read_phase"):
        read_phase(ages, period)
