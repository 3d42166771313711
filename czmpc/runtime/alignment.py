"""Read just after the plant publishes: the loop's phase against the plant's sample clock.

A loop that reads just before the plant's step writes after that step on some periods
and before it on others: the input delay jitters by a sample (docs/guides/plant_link.rst,
section 4). The *phase* of a read is the sample's age ``now - SourceTimestamp`` as a
share of the period, modulo 1; `read_phase` is its circular mean over `WINDOW` good
samples and, outside `BAND`, `alignment_shift_s` the shift of the schedule (less than a
period) that moves the reads to `TARGET_PHASE` within the plant's period: later when the
loop reads too early, earlier when it reads too late, so that no plant sample goes
unread (a later schedule past the next publication would skip one). Spread phases (concentration below
`MIN_CONCENTRATION`: another publishing rate, jumping clocks) leave the schedule alone.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Sequence

#: Where the loop reads [share of the period after the plant published]: late enough that
#: jitter cannot put a read before the publication, early enough to write long before the
#: next step.
TARGET_PHASE = 0.2
#: Read phases inside this band [share of the period] are left alone.
BAND = (0.05, 0.5)
#: Good samples whose phases make one estimate.
WINDOW = 8
#: Smallest length of the mean phase vector (1: every phase equal; 0: spread evenly).
MIN_CONCENTRATION = 0.8


def read_phase(ages_s: Sequence[float], period_s: float) -> float | None:
    """The circular mean of ``(age / period) mod 1`` over `ages_s`, or None.

    Parameters
    ----------
    ages_s :
        Ages ``now - SourceTimestamp`` of samples when the loop read them [wall s].
    period_s :
        The loop's (and the plant's) period [wall s], > 0.

    Returns
    -------
    float or None
        The read phase in ``[0, 1)``, or None when the phases are spread (the length
        of their mean unit vector is below `MIN_CONCENTRATION`).

    Raises
    ------
    ValueError
        No ages, a non-finite age, or a period that is not positive.
    """
    if not (math.isfinite(period_s) and period_s > 0.0):
        raise ValueError(f"read_phase: period_s must be a finite number > 0; got {period_s!r}")
    if not ages_s or not all(math.isfinite(a) for a in ages_s):
        raise ValueError(f"read_phase: expected finite ages; got {list(ages_s)!r}")
    mean = sum(cmath.exp(2j * math.pi * a / period_s) for a in ages_s) / len(ages_s)
    if abs(mean) < MIN_CONCENTRATION:
        return None
    return (cmath.phase(mean) / (2.0 * math.pi)) % 1.0


def alignment_shift_s(phase: float, period_s: float) -> float | None:
    """How far to shift the loop's schedule so that reads come at `TARGET_PHASE`.

    Parameters
    ----------
    phase :
        The current read phase (`read_phase`), in ``[0, 1)``.
    period_s :
        The period [wall s].

    Returns
    -------
    float or None
        ``(TARGET_PHASE - phase) * period_s`` [wall s]: positive delays the schedule (a
        read just after the publication), negative brings it forward (a read late in the
        period); either way the reads stay in the plant's period, so the plant sample
        between them is read. None when `phase` lies inside `BAND`.
    """
    if BAND[0] <= phase <= BAND[1]:
        return None
    return (TARGET_PHASE - phase) * period_s
