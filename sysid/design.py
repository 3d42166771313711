"""Design of open-loop identification test signals for the triac input (pure numpy).

A test signal is a sequence of triac set-points ``triac_pct`` sampled every ``ts_s``:

``steps``
    Up-and-down staircase across ``[lo_pct, hi_pct]``: at least ``degree + 2`` levels (a
    degree-``d`` f needs ``d + 1`` to be determined, one more to check it), each visited
    up and down so that static gain and drift can be told apart, each held
    ``HOLD_TAUS`` time constants (a first-order step response is then within
    ``exp(-4) < 2 %`` of its final value).
``gbn``
    Generalized binary noise (Tulleken 1990, "Generalized binary noise test-signal
    concept for improved identification-experiment design", Automatica 26(1), 37-49):
    each sample switches between two levels with probability ``p_sw``. Its
    autocorrelation is ``(1 - 2 p_sw)^|k|``, flat in spectrum up to about
    ``omega_c = 2 p_sw / ts_s = 2 / T_sw`` rad/s (``T_sw = ts_s / p_sw`` the mean
    switching time). Rule: ``T_sw = tau_s``, the corner at twice the plant bandwidth
    ``1 / tau_s`` (Ljung, System Identification, 2nd ed., ch. 13: input power up to and
    somewhat beyond the process bandwidth).
``mixed`` (default)
    The staircase, then GBN around the middle of the band for the rest of the duration.
``multilevel``
    For short tests of slow plants: it switches about once per time constant, as the
    GBN, but to another of ``n_levels`` levels each time, so it excites f at every level
    (a binary signal: at two points) and the dynamics over the GBN's band (Godfrey,
    ed., Perturbation Signals for System Identification, Prentice Hall 1993, ch. 7-8).
    Needing no settled holds, it fits a plant with tau = 600 s into 2 h where ``mixed``
    needs 8 h. Shortest duration: ``MIN_MULTILEVEL_ROUNDS`` rounds of the levels,
    ``tau_s`` per visit on average.

    The order search estimates on the first half and validates on the second, so each
    half makes a whole number of shuffled rounds through the levels (as many as give
    holds nearest ``tau_s`` on average), with hold times spread evenly within
    ``MULTILEVEL_HOLD_SPREAD`` of their mean in random order. Geometric holds (GBN) of
    mean tau could hold one level 142 s in one half and 1,254 s in the other of a 2 h
    test, and a model of the first half then extrapolates f on the second. A jump
    larger than ``max_step_pct`` is ramped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from sysid._typing import FloatArray
from sysid.errors import SysidError

__all__ = [
    "HOLD_TAUS", "KINDS", "MIN_GBN_TAUS", "MIN_MULTILEVEL_ROUNDS", "MULTILEVEL_HOLD_SPREAD",
    "ExcitationSignal",
    "ExcitationSpec", "SignalDesignError", "design_test_signal", "shortest_duration_s",
]

HOLD_TAUS = 4.0
"""Hold time of every staircase level, in time constants (first-order settling to 2 %)."""
MIN_GBN_TAUS = 20.0
"""Shortest GBN part of a mixed signal, in time constants (about 20 switches)."""

MIN_MULTILEVEL_ROUNDS = 2
"""Shortest multilevel signal, in rounds through all its levels (each level reached from
two predecessors)."""
MULTILEVEL_HOLD_SPREAD = 0.5
"""Multilevel holds spread evenly within this fraction of their mean (about ``tau_s``):
from half a time constant (shorter barely shows in f) to 1.5 (longer leaves the other
levels short in a 2 h test)."""

Kind = Literal["steps", "gbn", "mixed", "multilevel"]
#: Every kind `design_test_signal` builds (the CLI's choices).
KINDS: tuple[str, ...] = ("steps", "gbn", "mixed", "multilevel")


class SignalDesignError(SysidError, ValueError):
    """The requested test signal cannot be built (bad band, too short, ...)."""


@dataclass(frozen=True)
class ExcitationSpec:
    """What the test must do.

    Parameters
    ----------
    ts_s : float
        Sampling time [s].
    lo_pct, hi_pct : float
        Band of triac set-points the test may visit [%].
    tau_s : float
        Dominant time constant of the plant, prior guess [s].
    duration_s : float
        Length of the test [s].
    max_step_pct : float
        Largest allowed jump between two consecutive samples [%].
    kind : {"steps", "gbn", "mixed", "multilevel"}
        Signal kind (see module docstring).
    degree : int
        Degree of the input polynomial f to be identified (``degree + 2`` levels at least).
    """

    ts_s: float
    lo_pct: float
    hi_pct: float
    tau_s: float
    duration_s: float
    max_step_pct: float = 100.0
    kind: Kind = "mixed"
    degree: int = 3

    def __post_init__(self) -> None:
        for name in ("ts_s", "tau_s", "duration_s", "max_step_pct"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise SignalDesignError(f"{name} must be a finite number > 0; got {value!r}")
        if not (math.isfinite(self.lo_pct) and math.isfinite(self.hi_pct)
                and 0.0 <= self.lo_pct < self.hi_pct <= 100.0):
            raise SignalDesignError(
                f"range must satisfy 0 <= LO < HI <= 100 %; got {self.lo_pct!r} .. {self.hi_pct!r}")
        if self.kind not in KINDS:
            raise SignalDesignError(f"kind must be one of {', '.join(KINDS)}; got {self.kind!r}")
        if self.degree < 1:
            raise SignalDesignError(f"degree must be >= 1; got {self.degree!r}")
        if self.duration_s < 2 * self.ts_s:
            raise SignalDesignError(f"duration_s must cover at least 2 samples; got {self.duration_s!r}")

    @property
    def n_samples(self) -> int:
        """Number of samples in the test."""
        return int(math.floor(self.duration_s / self.ts_s)) + 1

    @property
    def n_levels(self) -> int:
        """Levels: ``degree + 2`` at least; a staircase has more if ``max_step_pct``
        demands it (a multilevel signal ramps its larger jumps instead)."""
        if self.kind == "multilevel":
            return self.degree + 2
        by_step = math.ceil((self.hi_pct - self.lo_pct) / self.max_step_pct) + 1
        return max(self.degree + 2, by_step)

    @property
    def hold_samples(self) -> int:
        """Samples each staircase level is held."""
        return max(1, math.ceil(HOLD_TAUS * self.tau_s / self.ts_s))

    @property
    def multilevel_rounds_per_half(self) -> int:
        """Rounds through the levels in each half of a multilevel test: as many as give
        holds nearest ``tau_s`` on average (at least one)."""
        half_s = (self.n_samples // 2) * self.ts_s
        return max(1, round(half_s / (self.tau_s * self.n_levels)))

    @property
    def multilevel_mean_hold_s(self) -> float:
        """Mean hold of a multilevel test [s]: half the test over one half's visits."""
        return (self.n_samples // 2) * self.ts_s / (self.multilevel_rounds_per_half
                                                    * self.n_levels)

    @property
    def gbn_switch_probability(self) -> float:
        """Per-sample switching probability ``p_sw = ts_s / T_sw`` with ``T_sw = tau_s``."""
        return min(0.5, self.ts_s / self.tau_s)


@dataclass(frozen=True)
class ExcitationSignal:
    """A designed test signal and what it shows.

    Attributes
    ----------
    time_s, triac_pct : ndarray
        Sample times [s] and set-points [%].
    levels_pct : ndarray
        Staircase or multilevel levels [%] (empty for a pure GBN signal).
    steps_samples : int
        Samples of the staircase part (it comes first).
    """

    spec: ExcitationSpec
    time_s: FloatArray
    triac_pct: FloatArray
    levels_pct: FloatArray
    steps_samples: int

    def hold_times_s(self, *, at_levels: bool = False) -> FloatArray:
        """Lengths of the constant stretches of the signal [s] (last one included).

        ``at_levels``: only the stretches at one of ``levels_pct`` (not a ramp's steps).
        """
        starts = np.concatenate(([0], np.flatnonzero(np.diff(self.triac_pct) != 0.0) + 1))
        holds = np.diff(np.concatenate((starts, [self.triac_pct.size]))).astype(float) * self.spec.ts_s
        if not at_levels:
            return holds
        return holds[np.isclose(self.triac_pct[starts][:, None], self.levels_pct[None, :]).any(axis=1)]

    def spectrum(self) -> tuple[FloatArray, FloatArray]:
        """One-sided periodogram of the mean-removed signal: frequency [rad/s], power [%^2 s]."""
        u = self.triac_pct - self.triac_pct.mean()
        ts = self.spec.ts_s
        power = np.asarray(np.abs(np.fft.rfft(u)) ** 2 * ts / u.size, dtype=np.float64)
        omega = np.asarray(2.0 * math.pi * np.fft.rfftfreq(u.size, ts), dtype=np.float64)
        return omega, power

    def power_fraction_below(self, omega_rad_s: float) -> float:
        """Fraction of the signal power (mean removed) at frequencies <= ``omega_rad_s``."""
        omega, power = self.spectrum()
        total = float(power[1:].sum())
        if total == 0.0:
            return 0.0
        return float(power[1:][omega[1:] <= omega_rad_s].sum()) / total

    def summary(self) -> str:
        """Multi-line description: levels, hold times vs tau, spectrum vs bandwidth, duration."""
        spec = self.spec
        holds = self.hold_times_s(at_levels=spec.kind == "multilevel")   # ramps are no holds
        band = 1.0 / spec.tau_s
        lines = [
            f"kind {spec.kind}: {self.triac_pct.size} samples at Ts = {spec.ts_s:g} s, "
            f"duration {self.time_s[-1]:g} s = {self.time_s[-1] / spec.tau_s:.1f} tau "
            f"(tau = {spec.tau_s:g} s)",
            f"range visited: {self.triac_pct.min():g} .. {self.triac_pct.max():g} %, "
            f"largest jump {np.abs(np.diff(self.triac_pct)).max():g} % (limit {spec.max_step_pct:g} %)",
            f"distinct levels visited: {np.unique(self.triac_pct).size}"]
        if self.levels_pct.size and spec.kind == "multilevel":
            lines.append("levels [%]: " + ", ".join(f"{v:g}" for v in self.levels_pct)
                         + ", visited in shuffled rounds")
        elif self.levels_pct.size:
            lines.append("staircase levels [%]: " + ", ".join(f"{v:g}" for v in self.levels_pct)
                         + f"; each held {spec.hold_samples * spec.ts_s:g} s = {HOLD_TAUS:g} tau")
        lines.append(f"hold times: min {holds.min():g} s ({holds.min() / spec.tau_s:.2f} tau), "
                     f"median {np.median(holds):g} s ({np.median(holds) / spec.tau_s:.2f} tau), "
                     f"max {holds.max():g} s ({holds.max() / spec.tau_s:.2f} tau)")
        if spec.kind == "multilevel":
            mean_s = spec.multilevel_mean_hold_s
            lines.append(f"multilevel mean switching time T_sw = {mean_s:g} s "
                         f"({mean_s / spec.tau_s:.2f} tau; holds drawn in "
                         f"{1 - MULTILEVEL_HOLD_SPREAD:g} .. {1 + MULTILEVEL_HOLD_SPREAD:g} T_sw); "
                         f"{spec.multilevel_rounds_per_half} round(s) of the levels in each "
                         f"half of the test")
        elif spec.kind != "steps":
            lines.append(f"GBN mean switching time T_sw = "
                         f"{spec.ts_s / spec.gbn_switch_probability:g} s "
                         f"(p_sw = {spec.gbn_switch_probability:.4g} per sample)")
        lines.append(f"plant bandwidth 1/tau = {band:.4g} rad/s; signal power below it "
                     f"{100 * self.power_fraction_below(band):.1f} %, below 2/tau "
                     f"{100 * self.power_fraction_below(2 * band):.1f} %")
        return "\n".join(lines)


def _staircase(spec: ExcitationSpec) -> tuple[FloatArray, FloatArray]:
    """The up-and-down staircase and its levels."""
    levels = np.linspace(spec.lo_pct, spec.hi_pct, spec.n_levels)
    order = np.concatenate((np.arange(levels.size), np.arange(levels.size - 2, -1, -1)))
    return np.repeat(levels[order], spec.hold_samples), levels


def _gbn(spec: ExcitationSpec, n: int, start_high: bool, rng: np.random.Generator) -> FloatArray:
    """``n`` samples of GBN around the band's middle."""
    mid = 0.5 * (spec.lo_pct + spec.hi_pct)
    amp = min(0.25 * (spec.hi_pct - spec.lo_pct), 0.5 * spec.max_step_pct)
    switches = rng.random(n) < spec.gbn_switch_probability
    switches[0] = False
    sign = np.where(np.cumsum(switches) % 2 == 0, 1.0, -1.0) * (1.0 if start_high else -1.0)
    return mid + amp * sign


def _ramp(start_pct: float, end_pct: float, max_step_pct: float) -> FloatArray:
    """Intermediate samples from ``start_pct`` to ``end_pct`` in jumps <= ``max_step_pct``."""
    n = math.ceil(abs(end_pct - start_pct) / max_step_pct)
    return np.linspace(start_pct, end_pct, n + 1)[1:-1] if n > 1 else np.zeros(0)


def _level_sequence(n_levels: int, n_visits: int, after: int | None,
                    rng: np.random.Generator) -> list[int]:
    """``n_visits`` level indices in shuffled rounds, never one level twice in a row
    (a round starting at ``after``, or the previous round's last level, is rotated)."""
    order: list[int] = []
    while len(order) < n_visits:
        round_ = [int(i) for i in rng.permutation(n_levels)]
        last = order[-1] if order else after
        if last is not None and round_[0] == last:
            round_.append(round_.pop(0))
        order += round_
    return order[:n_visits]


def _hold_samples(n_visits: int, total: int, rng: np.random.Generator) -> FloatArray:
    """``n_visits`` hold lengths [samples] summing to ``total``, in random order: evenly
    spread over ``1 +- MULTILEVEL_HOLD_SPREAD`` times their mean, rounded down with the
    leftover samples to the largest remainders."""
    exact = (total / n_visits) * (1.0 + MULTILEVEL_HOLD_SPREAD
                                  * np.linspace(-1.0, 1.0, n_visits))[rng.permutation(n_visits)]
    holds = np.maximum(np.floor(exact), 1.0)
    short = total - int(holds.sum())
    if short > 0:
        holds[np.argsort(holds - exact)[:short]] += 1.0
    return holds


def _multilevel(spec: ExcitationSpec, n: int, rng: np.random.Generator) -> FloatArray:
    """``n`` samples of multilevel noise: whole rounds of the levels in each half."""
    levels = np.linspace(spec.lo_pct, spec.hi_pct, spec.n_levels)
    half_samples = (n // 2, n - n // 2)
    half_visits = spec.multilevel_rounds_per_half * levels.size
    first = _level_sequence(levels.size, half_visits, None, rng)
    second = _level_sequence(levels.size, half_visits, first[-1], rng)
    holds = np.concatenate([_hold_samples(half_visits, m, rng) for m in half_samples])
    target = np.repeat(levels[np.asarray(first + second)], holds.astype(int))
    u = np.empty(n)
    u[0] = target[0]
    for k in range(1, n):   # ramp jumps above max_step_pct (the target is held meanwhile)
        u[k] = u[k - 1] + float(np.clip(target[k] - u[k - 1], -spec.max_step_pct,
                                        spec.max_step_pct))
    return u


def shortest_duration_s(spec: ExcitationSpec) -> float:
    """Shortest test [s] `design_test_signal` accepts for ``spec``'s kind and band.

    ``steps``: ``2 n_levels - 1`` holds of ``HOLD_TAUS`` tau; ``mixed``: that plus
    ``MIN_GBN_TAUS`` tau of GBN; ``gbn``: ``MIN_GBN_TAUS`` tau; ``multilevel``:
    ``MIN_MULTILEVEL_ROUNDS`` rounds of ``n_levels`` visits of one tau.
    """
    stairs_s = ((2 * spec.n_levels - 1) * spec.hold_samples - 1) * spec.ts_s
    return {"steps": stairs_s, "gbn": MIN_GBN_TAUS * spec.tau_s,
            "mixed": stairs_s + MIN_GBN_TAUS * spec.tau_s,
            "multilevel": MIN_MULTILEVEL_ROUNDS * spec.n_levels * spec.tau_s}[spec.kind]


def design_test_signal(spec: ExcitationSpec, rng: np.random.Generator) -> ExcitationSignal:
    """Build the test signal of ``spec``; ``rng`` drives the GBN and multilevel parts.

    Raises
    ------
    SignalDesignError
        A duration shorter than `shortest_duration_s`.
    """
    n = spec.n_samples
    need_s = shortest_duration_s(spec)
    levels: FloatArray = np.zeros(0)
    if spec.kind == "gbn":
        if need_s > spec.duration_s:
            raise SignalDesignError(
                f"duration_s = {spec.duration_s:g} s is too short for a gbn test: "
                f"{MIN_GBN_TAUS:g} tau of {spec.tau_s:g} s need at least {math.ceil(need_s):d} s; "
                "give a longer test or a shorter --tau-s")
        u = _gbn(spec, n, True, rng)
        steps_n = 0
    elif spec.kind == "multilevel":
        if need_s > spec.duration_s:
            raise SignalDesignError(
                f"duration_s = {spec.duration_s:g} s is too short for a multilevel test: "
                f"{MIN_MULTILEVEL_ROUNDS} rounds of {spec.n_levels} levels at one tau = "
                f"{spec.tau_s:g} s per visit need at least {math.ceil(need_s):d} s")
        u = _multilevel(spec, n, rng)
        levels = np.linspace(spec.lo_pct, spec.hi_pct, spec.n_levels)
        steps_n = 0
    else:
        stairs, levels = _staircase(spec)
        steps_n = stairs.size
        if need_s > spec.duration_s:
            raise SignalDesignError(
                f"duration_s = {spec.duration_s:g} s is too short for a {spec.kind} test with "
                f"{levels.size} levels held {HOLD_TAUS:g} tau = {spec.hold_samples * spec.ts_s:g} s each"
                + (f" plus {MIN_GBN_TAUS:g} tau of GBN" if spec.kind == "mixed" else "")
                + f"; give at least {math.ceil(need_s):d} s, a shorter --tau-s or fewer levels")
        if spec.kind == "steps":
            u = np.concatenate((stairs, np.full(n - steps_n, stairs[-1])))
        else:   # a ramp joins the staircase's last level to the GBN's low one
            gbn = _gbn(spec, n - steps_n, False, rng)
            ramp = _ramp(float(stairs[-1]), float(gbn[0]), spec.max_step_pct)
            u = np.concatenate((stairs, ramp, gbn))
    time_s = np.arange(n, dtype=float) * spec.ts_s
    return ExcitationSignal(spec=spec, time_s=time_s, triac_pct=np.asarray(u, dtype=float)[:n],
                      levels_pct=levels, steps_samples=steps_n)
