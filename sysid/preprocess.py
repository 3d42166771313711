"""Data preprocessing (paper sec. 5): operating point, deviation variables, outliers.

Each repair returns a *new* `Dataset` (`Dataset.with_signals`) with one more
``preprocessing`` entry (what, where, old and new values), carried into the model's
provenance. Outlier detection only *reports* candidates; the user applies
`interpolate_spike` or `correct_level_shift`, as the paper's authors did.

Notation
--------
``s`` / ``u`` : input (TRIAC signal [%] for the CZ heater; `Dataset.input_unit`).
``P`` / ``y`` : output (heater power [kW]; `Dataset.output_unit`, also that of names
ending in ``_kw``).
``(s_nom, P_nom)`` : operating point (sec. 5.1); ``ds = s - s_nom``, ``dP = P - P_nom``.
``e`` : one-step-ahead residuals of a high-order ARX model (paper Fig. 3, eq. 5).
``sigma`` : robust residual scale ``1.4826 * median(|e - median(e)|)`` (MAD: the
standard deviation of Gaussian residuals, blind to the outliers sought).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt

from sysid._arrays import CLIP_MIN_RUN_SAMPLES, clipped_samples, robust_std
from sysid._arrays import readonly_array as _readonly
from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.data import Dataset
from sysid.errors import DataFileError, IdentificationError
from sysid.linear import arx_least_squares
from sysid.model import OperatingPoint

OperatingPointMethod = Literal["given", "means", "steady"]
OutlierKind = Literal["spike", "level_shift"]

#: Default outlier threshold [robust residual scales]. A Gaussian residual exceeds
#: 5 sigma with probability 5.7e-7, so a 12 500-sample record (the paper's ~7 h at
#: 2 s) yields about 0.007 false candidates.
DEFAULT_OUTLIER_THRESHOLD = 5.0

#: Default input-step threshold [robust scales of the input's first differences]; for
#: a staircase input that scale is 0 and every change is a step.
INPUT_STEP_SIGMAS = 5.0

#: Residual scale (MAD) at or below this fraction of the output's standard deviation
#: means an exact fit up to rounding: nothing to measure outliers against.
EXACT_FIT_RTOL = 1e-9

#: Samples on each side used for the output levels around an outlier candidate.
LEVEL_WINDOW_SAMPLES = 5

#: Flagged samples at most this far apart belong to one event (a spike flags its
#: own sample and the next one, whose prediction used the spike).
EVENT_GAP_SAMPLES = 2

#: Largest level shift repaired without being told, as a share of the output's recorded
#: span: a sensor offset is small against what the process moves (the paper's 0.15 kW is
#: 0.4 % of the shipped experiment's span). A larger "shift" is the process moving in a
#: way ARX(10, 10) does not predict: on the cascaded tanks, filling towards overflow,
#: 18 to 71 % of the span, which subtracting would destroy.
LEVEL_SHIFT_MAX_SPAN_SHARE = 0.05

#: Fewest standard errors (`LevelShiftEstimate.std_error_kw`) a level shift's estimate
#: must lie from zero to be repaired without being told: the evidence the outlier search
#: asks of a residual (`DEFAULT_OUTLIER_THRESHOLD`). Measured: the shipped experiment's
#: sensor shift is 20.8 standard errors; a log whose output the logger holds for three
#: samples (TCLab's, held) gives 75 candidates of at most 4.0, steps of the hold.
LEVEL_SHIFT_MIN_STD_ERRORS = 5.0


def _check_finite(where: str, name: str, value: float, *, positive: bool = False,
                  or_none: bool = False) -> None:
    """Refuse ``value`` unless finite and ``>= 0`` (``> 0`` if ``positive``); ``or_none``
    adds "or None" to the message (the caller lets None pass)."""
    if math.isfinite(value) and (value > 0.0 if positive else value >= 0.0):
        return
    bound = ("> 0" if positive else ">= 0") + (" or None" if or_none else "")
    raise IdentificationError(f"{where}: {name} must be a finite number {bound}; got {value!r}")


# --------------------------------------------------------------------------- operating point


@dataclass(frozen=True, kw_only=True)
class SteadyWindow:
    """A stretch of constant input and settled output (paper sec. 5.1, Fig. 2).

    Parameters
    ----------
    start_sample, stop_sample :
        The window is samples ``start_sample .. stop_sample - 1``.
    start_time_s, end_time_s :
        Times of its first and last sample [s].
    input_spread, output_spread_kw :
        ``max - min`` of the input [input unit] and of the output [output unit].
    output_std_kw :
        Standard deviation of the output [output unit].
    output_drift_kw :
        ``|slope| * (n - 1)``: change across the window of the output's least-squares
        straight line [output unit].
    final_level_kw :
        Mean of the constant-input stretch's last quarter (at least
        `min_window_samples` samples) [output unit].
    settle_limit_kw :
        Band around `final_level_kw` that the moving average stays in, and the
        largest drift accepted [output unit].
    """

    start_sample: int
    stop_sample: int
    start_time_s: float
    end_time_s: float
    input_spread: float
    output_spread_kw: float
    output_std_kw: float
    output_drift_kw: float
    final_level_kw: float
    settle_limit_kw: float

    @property
    def n_samples(self) -> int:
        """Samples in the window."""
        return self.stop_sample - self.start_sample


@dataclass(frozen=True, kw_only=True)
class OperatingPointChoice:
    """The operating point used for detrending and how it was found (paper sec. 5.1).

    Parameters
    ----------
    operating_point :
        ``(s_nom, P_nom)`` in the data set's units.
    method :
        ``"given"``, ``"means"`` or ``"steady"`` (`find_operating_point`).
    window :
        The steady window for ``"steady"``, else None.
    power_offset_kw :
        For ``"means"`` put on the steady-state curve (`sysid.offset`): how far ``P_nom``
        was moved from the sample mean [output unit]; 0 otherwise.
    """

    operating_point: OperatingPoint
    method: OperatingPointMethod
    window: SteadyWindow | None = None
    power_offset_kw: float = 0.0


def _constant_input_runs(u: FloatArray, tol: float) -> list[tuple[int, int]]:
    """Maximal runs ``[a, b)`` in which every input lies within ``tol`` of ``u[a]``."""
    runs: list[tuple[int, int]] = []
    values = u.tolist()
    start, first = 0, values[0] if values else 0.0
    for k in range(1, len(values)):
        if abs(values[k] - first) > tol:
            runs.append((start, k))
            start, first = k, values[k]
    runs.append((start, len(values)))
    return runs


def _settled_start(
    y: FloatArray, a: int, b: int, width: int, limit: float
) -> tuple[int, float, float] | None:
    """``(m, drift, final)`` of the settled part ``[m, b)`` of a constant-input stretch
    ``[a, b)``, or None (the rule of `find_operating_point`'s Notes)."""
    n = b - a
    if n < width:
        return None
    seg = y[a:b]
    final = float(seg[-max(width, n // 4):].mean())
    sums = np.concatenate([[0.0], np.cumsum(seg - final)])
    moving_dev = np.abs(sums[width:] - sums[:-width]) / width  # |mean(seg[i:i+width]) - final|
    outside = np.flatnonzero(moving_dev > limit)
    if outside.size and outside[-1] == moving_dev.size - 1:
        return None
    m = a + (int(outside[-1]) + 1 if outside.size else 0)
    window = y[m:b]
    k = np.arange(window.size, dtype=float) - (window.size - 1) / 2.0
    drift = abs(float(k @ (window - window.mean())) / float(k @ k)) * (window.size - 1)
    return (m, drift, final) if drift <= limit else None


#: A steady window competes for the operating point only if it holds at least this
#: share of the longest one's samples (standard error of its mean at most sqrt(2) times).
MIN_WINDOW_SHARE_OF_LONGEST = 0.5


def _central_window(windows: list[tuple[int, int, float, float]], u: FloatArray
                    ) -> tuple[int, int, float, float]:
    """The eligible window whose mean input is nearest the middle of the input's range."""
    longest = max(stop - start for start, stop, _, _ in windows)
    middle = 0.5 * (float(u.min()) + float(u.max()))
    eligible = [w for w in windows if w[1] - w[0] >= MIN_WINDOW_SHARE_OF_LONGEST * longest]
    return min(eligible, key=lambda w: (abs(float(u[w[0]:w[1]].mean()) - middle),
                                        -(w[1] - w[0]), w[0]))


def find_operating_point(
    data: Dataset,
    *,
    method: OperatingPointMethod,
    given: OperatingPoint | None = None,
    input_tol: float = 0.0,
    min_window_samples: int = 20,
    drift_sigmas: float = 3.0,
    output_atol_kw: float = 0.0,
) -> OperatingPointChoice:
    """Choose the steady operating point ``(s_nom, P_nom)`` for detrending (paper sec. 5.1).

    Parameters
    ----------
    data :
        The record.
    method :
        ``"given"``: use `given` (a known steady state, e.g. the input before the
        experiment). ``"means"``: sample means over the record (the paper's fallback).
        ``"steady"``: means over the most central long steady window (Notes).
    given :
        The operating point for ``method="given"``; must be None otherwise.
    input_tol :
        ``"steady"``: the input counts as constant while it stays within this of
        its value at the start of the stretch [input unit].
    min_window_samples :
        ``"steady"``: fewest samples of a steady window, and the width of the
        moving average that must settle (>= 4).
    drift_sigmas :
        ``"steady"``: the settling band in units of the output's white-noise scale
        ``sigma_y = 1.4826 median|d y - median(d y)| / sqrt(2)`` (``d y`` the first
        differences within segments; robust to steps).
    output_atol_kw :
        ``"steady"``: the settling band's floor [output unit], for slow disturbances
        (the virtual CZ heater's grid wander moves 200-s means by about 0.1 kW:
        ``output_atol_kw=0.1`` finds its 45 % rest) or a quantized output.

    Returns
    -------
    OperatingPointChoice
        The point, the method used and, for ``"steady"``, the window.

    Raises
    ------
    IdentificationError
        Unknown `method`; `given` missing for ``"given"`` or passed with another
        method; negative tolerances; `min_window_samples` < 4; or no steady window.

    Notes
    -----
    The ``"steady"`` rule (a settling-time test): split each segment into maximal
    stretches of constant input (within `input_tol`). In a stretch the final level is
    the mean of its last quarter (at least ``W = min_window_samples`` samples); the
    window runs from the first sample ``m`` after which every ``W``-sample moving
    average of the output stays within ``limit`` of that level to the stretch's end.
    It counts if it holds at least ``W`` samples and its least-squares straight line
    changes by at most ``limit`` across it, with
    ``limit = max(drift_sigmas * sigma_y, output_atol_kw)``.

    Of the windows holding at least `MIN_WINDOW_SHARE_OF_LONGEST` of the longest
    one's samples, the one whose mean input lies nearest the middle of the input
    range wins (the longer, then the earlier, on a tie): the linear models are
    expansions about this point (sec. 5.1) whose errors grow away from it (Fig. 8),
    and a record that starts at rest would otherwise put it at its edge. The point is
    the window's mean input and output. On the shipped experiment (33 .. 65 %) the
    windows at 33 %, 42 %, 45 % (t 8418 .. 10298 s) and 65 % qualify and 45 % wins:
    the paper's (45 %, 45 kW) from t in [8700, 10300] s.
    """
    if method not in ("given", "means", "steady"):
        raise IdentificationError(
            f"find_operating_point: method must be 'given', 'means' or 'steady'; got {method!r}")
    if method == "given":
        if given is None:
            raise IdentificationError(
                "find_operating_point: method='given' needs given=OperatingPoint(...); got None")
        return OperatingPointChoice(operating_point=given, method="given")
    if given is not None:
        raise IdentificationError(
            f"find_operating_point: given is only used with method='given'; got "
            f"method={method!r} and given={given!r}")
    u, y = data.triac_pct, data.power_kw
    if method == "means":
        return OperatingPointChoice(operating_point=_mean_point(u, y), method="means")
    for name, value in (("input_tol", input_tol), ("drift_sigmas", drift_sigmas),
                        ("output_atol_kw", output_atol_kw)):
        _check_finite("find_operating_point", name, value)
    min_window_samples = checked_int(min_window_samples, 4, "find_operating_point: min_window_samples")
    bounds = data.segment_bounds()
    diffs = np.concatenate([np.diff(y[lo:hi]) for lo, hi in bounds])
    sigma_y = robust_std(diffs) / math.sqrt(2.0)
    limit = max(drift_sigmas * sigma_y, output_atol_kw)
    runs = [(lo + a, lo + b) for lo, hi in bounds
            for a, b in _constant_input_runs(u[lo:hi], input_tol)]
    windows = [(found[0], b, found[1], found[2])
               for a, b in runs
               if (found := _settled_start(y, a, b, min_window_samples, limit)) is not None]
    if not windows:
        raise IdentificationError(
            f"find_operating_point(method='steady'), {data.source or '<memory>'}: expected a "
            f"window of at least {min_window_samples} samples with the input constant within "
            f"{input_tol:g} and the output settled (within {limit:.4g} {data.output_unit}); "
            "got none. Use method='means' or 'given', or relax the tolerances")
    start, stop, drift, final = _central_window(windows, u)
    yw, uw = y[start:stop], u[start:stop]
    window = SteadyWindow(
        start_sample=start, stop_sample=stop,
        start_time_s=float(data.time_s[start]), end_time_s=float(data.time_s[stop - 1]),
        input_spread=float(np.ptp(uw)), output_spread_kw=float(np.ptp(yw)),
        output_std_kw=float(np.std(yw)), output_drift_kw=drift, final_level_kw=final,
        settle_limit_kw=limit)
    return OperatingPointChoice(operating_point=_mean_point(uw, yw), method="steady", window=window)


def _mean_point(u: FloatArray, y: FloatArray) -> OperatingPoint:
    """The operating point ``(mean(u), mean(y))``."""
    return OperatingPoint(triac_pct=float(u.mean()), power_kw=float(y.mean()))


def to_deviation(data: Dataset, op: OperatingPoint) -> tuple[FloatArray, FloatArray]:
    """Deviation variables ``ds = s - s_nom``, ``dP = P - P_nom`` (paper sec. 5.1).

    Parameters
    ----------
    data :
        The record (absolute units).
    op :
        ``(s_nom, P_nom)``.

    Returns
    -------
    tuple of FloatArray
        ``(ds, dP)``, each shape ``(n_samples,)``, read-only [input unit], [output unit].
    """
    return (_readonly(data.triac_pct - op.triac_pct), _readonly(data.power_kw - op.power_kw))


# --------------------------------------------------------------------------- outliers


@dataclass(frozen=True, kw_only=True)
class OutlierCandidate:
    """A large-residual event away from input steps: an outlier candidate (paper Figs. 4-5).

    Parameters
    ----------
    sample :
        Onset: the first sample of the event whose residual exceeds the threshold.
    time_s :
        Time of `sample` [s].
    last_sample :
        Last flagged sample of the event (events merge flags <= 2 samples apart).
    residual_kw :
        ARX residual at `sample` [output unit].
    peak_residual_kw :
        The event's residual of largest magnitude, with its sign [output unit].
    opposite_residual_follows :
        True if a residual of opposite sign beyond half the threshold follows within
        2 samples of the onset (a spike the ARX predicted from).
    output_jump_kw :
        Output deviation of largest magnitude over ``sample .. min(last_sample,
        sample + 2)`` from the level before (median of the 5 samples before; the first
        sample itself at the record's start) [output unit].
    persisting_change_kw :
        Level after the event (median of the 5 samples after `last_sample`) minus
        the level before [output unit].
    kind :
        ``"spike"`` if the output comes back (``|persisting| < |jump| / 2``; repair with
        `interpolate_spike`), else ``"level_shift"`` (measure with
        `estimate_level_shift`, repair with `correct_level_shift`).
    """

    sample: int
    time_s: float
    last_sample: int
    residual_kw: float
    peak_residual_kw: float
    opposite_residual_follows: bool
    output_jump_kw: float
    persisting_change_kw: float
    kind: OutlierKind


@dataclass(frozen=True, kw_only=True)
class StepResidual:
    """A large-residual event right after an input step: model imperfection, not an outlier.

    Parameters
    ----------
    sample, last_sample, time_s, peak_residual_kw :
        As for `OutlierCandidate`.
    input_step_sample :
        Sample ``j`` of the input step it follows.
    """

    sample: int
    last_sample: int
    time_s: float
    peak_residual_kw: float
    input_step_sample: int


@dataclass(frozen=True, kw_only=True, eq=False)
class OutlierReport:
    """Outlier candidates from the residuals of a high-order ARX model (paper sec. 5.2).

    Parameters
    ----------
    residuals_kw :
        One-step-ahead ARX residuals aligned with the data's samples, shape
        ``(n_samples,)`` [output unit]; NaN before `first_sample` of each segment.
    first_sample :
        First sample of each segment with a residual, ``max(na, nk + nb - 1)``.
    scale_kw :
        Robust residual scale ``sigma`` (MAD) [output unit].
    threshold, threshold_kw :
        Flagging threshold in units of `scale_kw`, and times `scale_kw` [output unit].
    na, nb, nk :
        ARX orders used.
    input_step_samples, input_step_tol :
        Samples ``j`` at which the input changed by more than the step threshold, and
        that threshold [input unit].
    candidates, step_residuals :
        Events away from input steps, and within the guard after one, in time order.
    clipped_samples :
        Samples in an exactly constant run of at least ``clip_min_run_samples`` at the
        output's record maximum or minimum (a saturated sensor, e.g. the cascaded tanks
        at 10 V): reported, never repaired.
    """

    residuals_kw: FloatArray = field(repr=False)
    first_sample: int
    scale_kw: float
    threshold: float
    threshold_kw: float
    na: int
    nb: int
    nk: int
    input_step_samples: tuple[int, ...]
    input_step_tol: float
    candidates: tuple[OutlierCandidate, ...]
    step_residuals: tuple[StepResidual, ...]
    clipped_samples: tuple[int, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "residuals_kw", _readonly(self.residuals_kw))


def _events(flagged: npt.NDArray[np.intp]) -> list[tuple[int, int]]:
    """Group sorted sample indices into ``(first, last)`` events."""
    events: list[tuple[int, int]] = []
    for k in (int(i) for i in flagged):
        if events and k - events[-1][1] <= EVENT_GAP_SAMPLES:
            events[-1] = (events[-1][0], k)
        else:
            events.append((k, k))
    return events


def find_outlier_candidates(
    data: Dataset,
    *,
    operating_point: OperatingPoint,
    na: int = 10,
    nb: int = 10,
    nk: int = 1,
    threshold: float = DEFAULT_OUTLIER_THRESHOLD,
    step_guard_samples: int = 5,
    input_step_tol: float | None = None,
    clip_min_run_samples: int = CLIP_MIN_RUN_SAMPLES,
) -> OutlierReport:
    """Flag outlier candidates by the residuals of a high-order ARX model (paper sec. 5.2).

    The method of Komperod et al. (2008): fit ARX(na, nb, nk) to the deviation data by
    least squares, flag samples whose one-step-ahead residual exceeds ``threshold *
    sigma``, drop those right after an input step, and guess each event's kind.

    Parameters
    ----------
    data :
        The record (absolute units).
    operating_point :
        ``(s_nom, P_nom)`` for the deviation variables.
    na, nb, nk :
        ARX orders (paper: ``na = nb = 10``).
    threshold :
        Flag ``|e_k| > threshold * sigma`` (``sigma``: module Notation) [-, > 0].
    step_guard_samples :
        An event whose onset lies ``nk .. nk + step_guard_samples`` samples after an
        input step is a `StepResidual`, not a candidate (>= 0).
    input_step_tol :
        An input change ``|u_j - u_{j-1}|`` above this is a step [input unit]; default
        ``5 * 1.4826 * MAD(diff(u))`` (any change of a staircase input).
    clip_min_run_samples :
        Shortest exactly constant run at the output's extreme reported as clipping (>= 2).

    Returns
    -------
    OutlierReport

    Raises
    ------
    IdentificationError
        Bad orders or options; a record too short or unexciting for the ARX orders;
        residuals with zero robust scale (an exact fit; see `EXACT_FIT_RTOL`).

    Notes
    -----
    Kind guess (paper Figs. 4-5): a spike returns to its level, and the ARX predicting
    from it leaves an opposite residual; a level shift has same-sign residuals for 1-3
    samples and the output stays. The rule, ``|persisting_change| < |output_jump| / 2``
    for a spike, assumes a steady output 5 samples either side; an event at the very
    end of the record has no "after" and counts as a level shift.
    """
    where = "find_outlier_candidates"
    na = checked_int(na, 0, f"{where}: na")
    nb = checked_int(nb, 1, f"{where}: nb")
    nk = checked_int(nk, 0, f"{where}: nk")
    step_guard_samples = checked_int(step_guard_samples, 0, f"{where}: step_guard_samples")
    clip_min_run_samples = checked_int(clip_min_run_samples, 2, f"{where}: clip_min_run_samples")
    _check_finite(where, "threshold", threshold, positive=True)
    if input_step_tol is not None:
        _check_finite(where, "input_step_tol", input_step_tol, or_none=True)
    ds, dp = to_deviation(data, operating_point)
    fit = arx_least_squares(dp, ds, na=na, nb=nb, nk=nk, segment_starts=data.segment_starts)
    n0 = fit.first_sample
    e = fit.residuals
    rows = np.concatenate([np.arange(lo + n0, hi) for lo, hi in data.segment_bounds()])
    scale = robust_std(e)
    if scale <= EXACT_FIT_RTOL * float(np.std(dp)):
        raise IdentificationError(
            f"{where}: expected residuals with a positive robust scale (MAD); got {scale:.3g} "
            f"(the ARX({na},{nb},{nk}) fits at least half the samples exactly, to rounding), "
            "so no outlier can be told from the rest")
    residuals = np.full(data.n_samples, np.nan)
    residuals[rows] = e
    du = np.diff(data.triac_pct)
    within = np.ones(du.size, dtype=bool)   # du[j] = u[j+1] - u[j] inside one segment
    within[np.asarray(data.segment_starts[1:], dtype=int) - 1] = False
    step_tol = INPUT_STEP_SIGMAS * robust_std(du[within]) if input_step_tol is None \
        else float(input_step_tol)
    steps = np.flatnonzero((np.abs(du) > step_tol) & within) + 1
    limit = threshold * scale
    candidates: list[OutlierCandidate] = []
    step_residuals: list[StepResidual] = []
    y = data.power_kw
    for first, last in _events(rows[np.abs(e) > limit]):
        peak = first + int(np.argmax(np.abs(residuals[first : last + 1])))
        lags = first - nk - steps
        near = steps[(lags >= 0) & (lags <= step_guard_samples)]
        if near.size:
            step_residuals.append(StepResidual(
                sample=first, last_sample=last, time_s=float(data.time_s[first]),
                peak_residual_kw=float(residuals[peak]), input_step_sample=int(near[-1])))
            continue
        before = float(np.median(y[max(first - LEVEL_WINDOW_SAMPLES, 0) : max(first, 1)]))
        onset = y[first : min(last, first + 2) + 1] - before
        jump = float(onset[np.argmax(np.abs(onset))])
        after_values = y[last + 1 : last + 1 + LEVEL_WINDOW_SAMPLES]
        persisting = float(np.median(after_values)) - before if after_values.size else jump
        follow = residuals[first + 1 : first + 3]
        opposite = bool(np.any((np.sign(follow) == -np.sign(residuals[first]))
                               & (np.abs(follow) > limit / 2)))
        candidates.append(OutlierCandidate(
            sample=first, time_s=float(data.time_s[first]), last_sample=last,
            residual_kw=float(residuals[first]), peak_residual_kw=float(residuals[peak]),
            opposite_residual_follows=opposite, output_jump_kw=jump,
            persisting_change_kw=persisting,
            kind="spike" if abs(persisting) < abs(jump) / 2 else "level_shift"))
    return OutlierReport(
        residuals_kw=residuals, first_sample=n0, scale_kw=scale, threshold=float(threshold),
        threshold_kw=limit, na=na, nb=nb, nk=nk,
        input_step_samples=tuple(int(j) for j in steps), input_step_tol=step_tol,
        candidates=tuple(candidates), step_residuals=tuple(step_residuals),
        clipped_samples=clipped_samples(y, clip_min_run_samples))


# --------------------------------------------------------------------------- repairs


def _record_error(data: Dataset, where: str, message: str) -> DataFileError:
    """An error of the function ``where`` on `data` (naming the record's file)."""
    return DataFileError(f"{where}: {message}", path=data.source)


def _check_finite_argument(data: Dataset, where: str, name: str, value: float) -> None:
    """Refuse a repair's argument ``name`` that is not a finite number."""
    if not math.isfinite(value):
        raise _record_error(data, where, f"{name} must be a finite number; got {value!r}")


def _with_output(data: Dataset, power: FloatArray, what: str, **details: object) -> Dataset:
    """`data` with the output ``power``, the repair recorded as ``{"what": what, ...}``."""
    return data.with_signals(power_kw=power,
                             change={"what": what, "signal": "power_kw", **details})


def _sample_at(data: Dataset, time_s: float, where: str) -> int:
    """Index of the sample at `time_s` (within half a sampling interval)."""
    _check_finite_argument(data, where, "time_s", time_s)
    k = int(np.argmin(np.abs(data.time_s - time_s)))
    if abs(data.time_s[k] - time_s) > 0.5 * data.ts_s:
        raise _record_error(data, where, f"expected a time within the record "
                            f"[{data.time_s[0]:g}, {data.time_s[-1]:g}] s; got {time_s:g} s")
    return k


def interpolate_spike(
    data: Dataset, *, sample: int | None = None, time_s: float | None = None
) -> Dataset:
    """Replace one output sample by the mean of its two neighbours (paper sec. 5.2, Fig. 4).

    Parameters
    ----------
    data :
        The record.
    sample :
        Index of the spike; give exactly one of `sample` and `time_s`.
    time_s :
        Time of the spike [s] (the nearest sample, within half a sampling interval).

    Returns
    -------
    Dataset
        A new data set with ``P[k] = (P[k-1] + P[k+1]) / 2``, recorded in
        ``preprocessing`` as ``{"what": "interpolate_spike", "sample", "time_s",
        "old_value", "new_value"}``.

    Raises
    ------
    DataFileError
        Neither or both of `sample` and `time_s`; a time outside the record; a sample
        without two neighbours in its own segment.
    """
    where = "interpolate_spike"
    if (sample is None) == (time_s is None):
        raise _record_error(data, where, f"give exactly one of sample and time_s; got sample="
                            f"{sample!r}, time_s={time_s!r}")
    if time_s is not None:
        k = _sample_at(data, time_s, where)
    else:
        if isinstance(sample, bool) or not isinstance(sample, (int, np.integer)):
            raise _record_error(data, where, f"sample must be an int; got {sample!r}")
        k = int(sample)
    if not 1 <= k <= data.n_samples - 2:
        raise _record_error(data, where, f"expected a sample with two neighbours, 1 <= sample "
                            f"<= {data.n_samples - 2}; got {k}")
    if k in data.segment_starts or k + 1 in data.segment_starts:
        raise _record_error(
            data, where, f"expected a sample with two neighbours in its own segment; got {k}, "
            f"at a segment boundary (segments start at {list(data.segment_starts)})")
    power = np.array(data.power_kw, copy=True)
    old = float(power[k])
    power[k] = 0.5 * (power[k - 1] + power[k + 1])
    return _with_output(data, power, "interpolate_spike", sample=k,
                        time_s=float(data.time_s[k]), old_value=old, new_value=float(power[k]))


def correct_level_shift(data: Dataset, *, from_time_s: float, shift_kw: float) -> Dataset:
    """Subtract a level shift from the output from a time on (paper sec. 5.2, Fig. 5).

    The paper subtracts 0.15 kW from ``dP(t)`` for all ``t >= 20714 s``.

    Parameters
    ----------
    data :
        The record.
    from_time_s :
        First time affected [s]; ``time_s[0] < from_time_s <= time_s[-1]``.
    shift_kw :
        Shift removed [output unit]: ``P[k] -= shift_kw`` for ``t_k >= from_time_s``.

    Returns
    -------
    Dataset
        A new data set, recorded as ``{"what": "correct_level_shift", "from_time_s",
        "from_sample", "shift_kw", "n_samples_changed"}``.

    Raises
    ------
    DataFileError
        `from_time_s` not finite or outside ``(time_s[0], time_s[-1]]``; `shift_kw`
        not finite.
    """
    where = "correct_level_shift"
    t = data.time_s
    if not (math.isfinite(from_time_s) and t[0] < from_time_s <= t[-1]):
        raise _record_error(data, where, f"expected from_time_s inside the record "
                            f"({t[0]:g}, {t[-1]:g}] s; got {from_time_s!r} s")
    _check_finite_argument(data, where, "shift_kw", shift_kw)
    k0 = int(np.searchsorted(t, from_time_s, side="left"))
    power = np.array(data.power_kw, copy=True)
    power[k0:] -= shift_kw
    return _with_output(data, power, "correct_level_shift", from_time_s=float(from_time_s),
                        from_sample=k0, shift_kw=float(shift_kw),
                        n_samples_changed=int(t.size - k0))


@dataclass(frozen=True, kw_only=True)
class LevelShiftEstimate:
    """Size of a level shift in the output, measured from the data.

    Parameters
    ----------
    shift_kw :
        Estimated shift (after minus before) [output unit].
    std_error_kw :
        Its standard error from the regression residuals [output unit].
    from_sample, from_time_s :
        Onset of the shift.
    before_samples, after_samples :
        ``(start, stop)`` sample ranges used before and after the onset.
    input_constant :
        True if the input did not change over the samples used (else the response to
        it biases the estimate).
    """

    shift_kw: float
    std_error_kw: float
    from_sample: int
    from_time_s: float
    before_samples: tuple[int, int]
    after_samples: tuple[int, int]
    input_constant: bool


def estimate_level_shift(
    data: Dataset,
    from_time_s: float,
    *,
    window_samples: int = 30,
    transition_samples: int = 3,
) -> LevelShiftEstimate:
    """Measure a level shift starting at `from_time_s` by a local line-plus-step fit.

    Parameters
    ----------
    data :
        The record.
    from_time_s :
        Onset of the shift [s] (e.g. `OutlierCandidate.time_s`).
    window_samples :
        Samples used on each side (>= 2; fewer near the ends of the onset's segment).
    transition_samples :
        Samples from the onset left out (>= 0; a shift may take 1-3 samples, Fig. 5).

    Returns
    -------
    LevelShiftEstimate

    Raises
    ------
    DataFileError
        `from_time_s` outside the record.
    IdentificationError
        Bad window options, or fewer than 2 samples on either side.

    Notes
    -----
    Fits ``P_k = alpha + beta (k - k0) + delta [k >= k0] + eps_k`` by least squares
    on ``k0 - w .. k0 - 1`` and ``k0 + m .. k0 + m + w - 1`` (``w`` window, ``m``
    transition); ``delta`` is the shift. The common slope absorbs a slow drift (the
    heater's sag).
    """
    where = "estimate_level_shift"
    w = checked_int(window_samples, 2, f"{where}: window_samples")
    m = checked_int(transition_samples, 0, f"{where}: transition_samples")
    k0 = _sample_at(data, from_time_s, where)
    lo, hi = next((a, b) for a, b in data.segment_bounds() if a <= k0 < b)
    before = (max(k0 - w, lo), k0)
    after = (min(k0 + m, hi), min(k0 + m + w, hi))
    if before[1] - before[0] < 2 or after[1] - after[0] < 2:
        raise IdentificationError(
            f"{where}: expected at least 2 samples before {from_time_s:g} s and 2 after "
            f"the {m}-sample transition; got {before[1] - before[0]} and "
            f"{after[1] - after[0]}")
    k = np.concatenate([np.arange(*before), np.arange(*after)])
    phi = np.column_stack([np.ones(k.size), (k - k0).astype(float), (k >= k0).astype(float)])
    theta, _, _, _ = np.linalg.lstsq(phi, data.power_kw[k], rcond=None)
    res = data.power_kw[k] - phi @ theta
    dof = max(k.size - 3, 1)
    cov = float(res @ res) / dof * np.linalg.inv(phi.T @ phi)
    u_used = data.triac_pct[before[0] : after[1]]
    return LevelShiftEstimate(
        shift_kw=float(theta[2]), std_error_kw=float(math.sqrt(cov[2, 2])),
        from_sample=k0, from_time_s=float(data.time_s[k0]),
        before_samples=before, after_samples=after,
        input_constant=bool(np.ptp(u_used) == 0.0))


__all__ = [
    "DEFAULT_OUTLIER_THRESHOLD", "LEVEL_SHIFT_MAX_SPAN_SHARE", "LEVEL_SHIFT_MIN_STD_ERRORS",
    "LevelShiftEstimate",
    "OperatingPointChoice", "OperatingPointMethod", "OutlierCandidate", "OutlierKind",
    "OutlierReport", "SteadyWindow", "StepResidual", "correct_level_shift",
    "estimate_level_shift", "find_operating_point", "find_outlier_candidates",
    "interpolate_spike", "to_deviation",
]
