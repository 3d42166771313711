"""Step analysis: find the input steps of a record and their instantaneous gains (Table 3).

The paper (sec. 7.3) reads the nonlinearity off the data before fitting anything: the
immediate jump of the output over the size of each input step, the *instantaneous*
gain ``r`` [kW/%], falls as the operating point rises (Table 3: 1.35, 1.31, 1.23,
1.14 kW/%). Any SISO log works: the units are the `Dataset`'s ``input_unit`` and
``output_unit``.

Notation
--------
``u_k``  input at sample ``k`` (``Dataset.triac_pct``, unit ``Dataset.input_unit``)
``y_k``  output at sample ``k`` (``Dataset.power_kw``, unit ``Dataset.output_unit``)
``nk``   delay in samples (``delay_steps``): ``u_k`` first shows in ``y_{k+nk}``

A step at sample ``k`` is a change ``|u_k - u_{k-1}| > min_step``. Its instantaneous
gain is (paper eq. 15, with ``nk = 1``)::

    r = (y_{k+nk} - y_{k+nk-1}) / (u_k - u_{k-1})
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from sysid._arrays import robust_std
from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.data import Dataset
from sysid.errors import IdentificationError

#: Default step threshold as a fraction of the input's range (max - min): a staircase
#: moves by a few percent of its span, a logger's rounding or jitter by far less.
DEFAULT_STEP_FRACTION_OF_RANGE = 0.05

#: The default threshold is also at least this many robust standard deviations of the
#: sample-to-sample input change (a 5-sigma Gaussian excursion: once in 1.7 million).
DEFAULT_STEP_NOISE_SIGMAS = 5.0


@dataclass(frozen=True, kw_only=True)
class InputStep:
    """One step of the input and the output's immediate response to it.

    Parameters
    ----------
    k :
        Sample index at which the input takes its new value (``u_k != u_{k-1}``).
    time_s :
        Time of sample ``k`` [s].
    triac_before_pct, triac_after_pct :
        Input before (``u_{k-1}``) and after (``u_k``) the step [input unit].
    power_before_kw, power_after_kw :
        Output just before the step shows (``y_{k+nk-1}``) and the first that shows it
        (``y_{k+nk}``) [output unit].
    gain_kw_per_pct :
        Instantaneous gain ``r`` (module docstring) [output unit per input unit].
    """

    k: int
    time_s: float
    triac_before_pct: float
    triac_after_pct: float
    power_before_kw: float
    power_after_kw: float
    gain_kw_per_pct: float

    @property
    def step_pct(self) -> float:
        """Size of the input step ``u_k - u_{k-1}`` [%]."""
        return self.triac_after_pct - self.triac_before_pct


def default_step_threshold(
    triac_pct: FloatArray, *, segment_starts: tuple[int, ...] = (0,)
) -> float:
    """Smallest input change counted as a step when none is given.

    Parameters
    ----------
    triac_pct :
        Input signal, shape ``(n_samples,)`` [any unit].
    segment_starts :
        First sample of each segment, starting with 0 (`sysid.data.Dataset`); changes
        across a segment boundary are left out of ``sigma``.

    Returns
    -------
    float
        ``max(0.05 * (max - min), 5 * sigma)`` [input unit], ``sigma`` the robust (MAD)
        standard deviation of the sample-to-sample changes (0 for a staircase).
    """
    u = np.asarray(triac_pct, dtype=float)
    if u.size < 2:
        return 0.0
    changes = np.diff(u)
    if len(segment_starts) > 1:
        changes = np.delete(changes, np.asarray(segment_starts[1:], dtype=int) - 1)
    sigma = robust_std(changes)
    span = float(np.max(u) - np.min(u))
    return max(DEFAULT_STEP_FRACTION_OF_RANGE * span, DEFAULT_STEP_NOISE_SIGMAS * sigma)


def detect_steps(
    data: Dataset, *, min_step: float | None = None, delay_steps: int = 1
) -> tuple[InputStep, ...]:
    """Find every input step of a record and its instantaneous gain (paper Table 3).

    Parameters
    ----------
    data :
        The record (raw or preprocessed; the paper's Table 3 uses the preprocessed one).
    min_step :
        An input change between two samples larger than this is a step [input unit];
        default `default_step_threshold`.
    delay_steps :
        Delay ``nk`` from input to output in samples (1 for the CZ heater, sec. 6.1).

    Returns
    -------
    tuple of InputStep
        The steps in time order, except those whose response ``y_{k+nk}`` falls after
        the end of their segment and changes across a segment boundary. Steps closer
        together than ``nk`` samples share output samples; their gains then mix.

    Raises
    ------
    IdentificationError
        `min_step` negative or not finite, or `delay_steps` not an int ``>= 0``.

    Examples
    --------
    >>> import numpy as np
    >>> from sysid.data import Dataset
    >>> data = Dataset(time_s=np.arange(6) * 2.0, triac_pct=[45, 45, 50, 50, 50, 50],
    ...                power_kw=[45, 45, 45, 51.75, 51.7, 51.65], ts_s=2.0)
    >>> [round(step.gain_kw_per_pct, 2) for step in detect_steps(data)]
    [1.35]
    """
    delay_steps = checked_int(delay_steps, 0, "detect_steps: delay_steps")
    if min_step is None:
        threshold = default_step_threshold(data.triac_pct, segment_starts=data.segment_starts)
    else:
        threshold = float(min_step)
        if not (math.isfinite(threshold) and threshold >= 0.0):
            raise IdentificationError(
                f"detect_steps: min_step must be a finite number >= 0; got {min_step!r}")
    u, y = data.triac_pct, data.power_kw
    candidates = np.flatnonzero(np.abs(np.diff(u)) > threshold) + 1
    # each sample's segment end: no step across a boundary
    seg_end = np.repeat([hi for _, hi in data.segment_bounds()],
                        [hi - lo for lo, hi in data.segment_bounds()])
    starts = set(data.segment_starts)
    steps = []
    for k in candidates.tolist():
        after = k + delay_steps
        if k in starts or after >= seg_end[k]:
            continue
        before = after - 1
        steps.append(InputStep(
            k=k, time_s=float(data.time_s[k]), triac_before_pct=float(u[k - 1]),
            triac_after_pct=float(u[k]), power_before_kw=float(y[before]),
            power_after_kw=float(y[after]),
            gain_kw_per_pct=float(y[after] - y[before]) / float(u[k] - u[k - 1])))
    return tuple(steps)


def format_step_table(
    steps: tuple[InputStep, ...] | list[InputStep],
    *,
    input_unit: str = "%",
    output_unit: str = "kW",
) -> str:
    """Render steps as a fixed-width text table, one line per step (deprecated).

    .. deprecated:: 0.2.0
        Tables for people are laid out by `czmpc.reports.tables.format_table` (one
        formatter for text and Markdown); ``czmpc inspect`` uses it. This function
        keeps working, with a `DeprecationWarning`, until 0.3.0.

    Parameters
    ----------
    steps :
        Steps from `detect_steps`.
    input_unit, output_unit :
        Units shown in the header (``Dataset.input_unit`` and ``output_unit``).

    Returns
    -------
    str
        The table, ending with a newline (one line saying so when there are no steps).
    """
    warnings.warn("sysid.steps.format_step_table is deprecated since 0.2.0 and goes in 0.3.0; "
                  "use czmpc.reports.tables.format_table", DeprecationWarning, stacklevel=2)
    if not steps:
        return "no input steps found\n"
    gain_unit = f"{output_unit}/{input_unit}"
    header = (
        f"{'k':>6}  {'time [s]':>9}  {'input [' + input_unit + ']':>18}  "
        f"{'output [' + output_unit + ']':>20}  {'r [' + gain_unit + ']':>12}")
    rows = [f"{step.k:>6}  {step.time_s:>9.1f}  "
            f"{step.triac_before_pct:>7.2f} -> {step.triac_after_pct:>7.2f}  "
            f"{step.power_before_kw:>8.3f} -> {step.power_after_kw:>8.3f}  "
            f"{step.gain_kw_per_pct:>12.4f}" for step in steps]
    return "\n".join([header, *rows]) + "\n"


__all__ = [
    "DEFAULT_STEP_FRACTION_OF_RANGE", "DEFAULT_STEP_NOISE_SIGMAS", "InputStep",
    "default_step_threshold", "detect_steps", "format_step_table"
]
