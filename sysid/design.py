"""Design of open-loop identification test signals for the triac input (pure numpy).

A test signal is a sequence of triac set-points ``triac_pct`` sampled every ``ts_s``.
Three kinds:

``steps``
    Up-and-down staircase across the band ``[lo_pct, hi_pct]``: at least ``degree + 2``
    levels (a degree-``d`` polynomial f needs ``d + 1`` distinct levels to be determined,
    one more to check it), each visited on the way up and on the way down so that
    hysteresis-free static gain and drift can be told apart.  Each level is held
    ``HOLD_TAUS`` time constants (the step response of a first-order plant is within
    ``exp(-4) < 2 %`` of its final value after 4 time constants).
``gbn``
    Generalized binary noise (Tulleken 1990, "Generalized binary noise test-signal
    concept for improved identification-experiment design", Automatica 26(1), 37-49): at each
    sample the signal switches between two levels with probability ``p_sw``.  Its
    autocorrelation is ``(1 - 2 p_sw)^|k|``, so its spectrum is flat up to about
    ``omega_c = 2 p_sw / ts_s = 2 / T_sw`` rad/s, where ``T_sw = ts_s / p_sw`` is the mean
    switching time.  Rule used here: ``T_sw = tau_s``, which places the corner at twice
    the plant bandwidth ``1 / tau_s`` (Ljung, System Identification, 2nd ed., ch. 13:
    put the input power where the model must be accurate, i.e. up to and somewhat beyond
    the bandwidth of the process).
``mixed`` (default)
    The staircase followed by GBN around the middle of the band for the rest of the
    duration.
``multilevel``
    Generalized multilevel noise for short tests of slow plants: it switches with the
    GBN's probability ``p_sw = ts_s / tau_s``, but to another of the staircase's
    ``n_levels`` levels each time (levels drawn in shuffled rounds, so every level is
    visited equally often; a jump larger than ``max_step_pct`` is ramped). A binary
    signal excites only two points of the static nonlinearity f; a multilevel one
    excites f at every level and the dynamics over the same band as the GBN (Godfrey,
    ed., Perturbation Signals for System Identification, Prentice Hall 1993, ch. 7-8 on
    multilevel signals for nonlinear systems). It needs no settled holds, so it fits
    a plant with tau = 600 s into 2 h where ``mixed`` needs 8 h. Shortest duration:
    ``MIN_MULTILEVEL_ROUNDS`` rounds of the levels, ``tau_s`` per visit on average.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from sysid._typing import FloatArray
from sysid.errors import SysidError

__all__ = [
    "HOLD_TAUS", "KINDS", "MIN_GBN_TAUS", "MIN_MULTILEVEL_ROUNDS", "ExcitationSignal",
    "ExcitationSpec", "SignalDesignError", "design_test_signal", "shortest_duration_s",
]

HOLD_TAUS = 4.0
"""Hold time of every staircase level, in time constants (first-order settling to 2 %)."""
MIN_GBN_TAUS = 20.0
"""Shortest GBN part of a mixed signal, in time constants (about 20 switches)."""

MIN_MULTILEVEL_ROUNDS = 2
"""Shortest multilevel signal, in rounds through all its levels (each level visited
twice, from two predecessors: f is seen from both directions on average)."""

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
        Degree of the input polynomial f to be identified; the staircase has at least
        ``degree + 2`` levels.
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

    def hold_times_s(self) -> FloatArray:
        """Lengths of the constant stretches of the signal [s] (last one included)."""
        change = np.flatnonzero(np.diff(self.triac_pct) != 0.0) + 1
        edges = np.concatenate(([0], change, [self.triac_pct.size]))
        return np.diff(edges).astype(float) * self.spec.ts_s

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
        holds = self.hold_times_s()
        band = 1.0 / spec.tau_s
        lines = [
            f"kind {spec.kind}: {self.triac_pct.size} samples at Ts = {spec.ts_s:g} s, "
            f"duration {self.time_s[-1]:g} s = {self.time_s[-1] / spec.tau_s:.1f} tau "
            f"(tau = {spec.tau_s:g} s)",
            f"range visited: {self.triac_pct.min():g} .. {self.triac_pct.max():g} %, "
            f"largest jump {np.abs(np.diff(self.triac_pct)).max():g} % (limit {spec.max_step_pct:g} %)",
            f"distinct levels visited: {np.unique(self.triac_pct).size}",
        ]
        if self.levels_pct.size and spec.kind == "multilevel":
            lines.append("levels [%]: " + ", ".join(f"{v:g}" for v in self.levels_pct)
                         + ", visited in shuffled rounds")
        elif self.levels_pct.size:
            lines.append("staircase levels [%]: " + ", ".join(f"{v:g}" for v in self.levels_pct)
                         + f"; each held {spec.hold_samples * spec.ts_s:g} s = {HOLD_TAUS:g} tau")
        lines.append(f"hold times: min {holds.min():g} s ({holds.min() / spec.tau_s:.2f} tau), "
                     f"median {np.median(holds):g} s ({np.median(holds) / spec.tau_s:.2f} tau), "
                     f"max {holds.max():g} s ({holds.max() / spec.tau_s:.2f} tau)")
        if spec.kind != "steps":
            what = "multilevel" if spec.kind == "multilevel" else "GBN"
            lines.append(f"{what} mean switching time T_sw = "
                         f"{spec.ts_s / spec.gbn_switch_probability:g} s "
                         f"(p_sw = {spec.gbn_switch_probability:.4g} per sample)")
        lines.append(f"plant bandwidth 1/tau = {band:.4g} rad/s; signal power below it "
                     f"{100 * self.power_fraction_below(band):.1f} %, below 2/tau "
                     f"{100 * self.power_fraction_below(2 * band):.1f} %")
        return "\n".join(lines)


def _staircase(spec: ExcitationSpec) -> tuple[FloatArray, FloatArray]:
    levels = np.linspace(spec.lo_pct, spec.hi_pct, spec.n_levels)
    order = np.concatenate((np.arange(levels.size), np.arange(levels.size - 2, -1, -1)))
    return np.repeat(levels[order], spec.hold_samples), levels


def _gbn(spec: ExcitationSpec, n: int, start_high: bool, rng: np.random.Generator) -> FloatArray:
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


def _multilevel(spec: ExcitationSpec, n: int, rng: np.random.Generator) -> FloatArray:
    levels = np.linspace(spec.lo_pct, spec.hi_pct, spec.n_levels)
    switches = rng.random(n) < spec.gbn_switch_probability
    switches[0] = False
    order: list[int] = []
    while len(order) < int(switches.sum()) + 1:   # shuffled rounds, never the same level twice
        round_ = list(rng.permutation(levels.size))
        if order and round_[0] == order[-1]:
            round_.append(round_.pop(0))
        order += round_
    target = levels[np.asarray(order)[np.cumsum(switches)]]
    u = np.empty(n)
    u[0] = target[0]
    for k in range(1, n):   # ramp jumps above max_step_pct (the target is held meanwhile)
        u[k] = u[k - 1] + float(np.clip(target[k] - u[k - 1], -spec.max_step_pct,
                                        spec.max_step_pct))
    return u


def shortest_duration_s(spec: ExcitationSpec) -> float:
    """Shortest test [s] `design_test_signal` accepts for ``spec``'s kind and band.

    ``steps``: the staircase (``2 n_levels - 1`` holds of ``HOLD_TAUS`` tau); ``mixed``:
    that plus ``MIN_GBN_TAUS`` tau of GBN; ``gbn``: ``MIN_GBN_TAUS`` tau;
    ``multilevel``: ``MIN_MULTILEVEL_ROUNDS`` rounds of ``n_levels`` visits of one tau.
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
        If the duration is shorter than `shortest_duration_s`: it cannot hold the
        staircase (``steps``), the staircase plus ``MIN_GBN_TAUS`` time constants of
        GBN (``mixed``), or ``MIN_MULTILEVEL_ROUNDS`` rounds of the levels
        (``multilevel``).
    """
    n = spec.n_samples
    levels: FloatArray = np.zeros(0)
    if spec.kind == "gbn":
        u = _gbn(spec, n, True, rng)
        steps_n = 0
    elif spec.kind == "multilevel":
        need_s = shortest_duration_s(spec)
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
        need_s = shortest_duration_s(spec)
        if need_s > spec.duration_s:
            raise SignalDesignError(
                f"duration_s = {spec.duration_s:g} s is too short for a {spec.kind} test with "
                f"{levels.size} levels held {HOLD_TAUS:g} tau = {spec.hold_samples * spec.ts_s:g} s each"
                + (f" plus {MIN_GBN_TAUS:g} tau of GBN" if spec.kind == "mixed" else "")
                + f"; give at least {math.ceil(need_s):d} s, a shorter --tau-s or fewer levels")
        if spec.kind == "steps":
            u = np.concatenate((stairs, np.full(n - steps_n, stairs[-1])))
        else:
            # A short ramp joins the staircase's last level (lo) to the GBN's low level
            # so that no jump exceeds max_step_pct.
            gbn = _gbn(spec, n - steps_n, False, rng)
            ramp = _ramp(float(stairs[-1]), float(gbn[0]), spec.max_step_pct)
            u = np.concatenate((stairs, ramp, gbn))
    time_s = np.arange(n, dtype=float) * spec.ts_s
    return ExcitationSignal(spec=spec, time_s=time_s, triac_pct=np.asarray(u, dtype=float)[:n],
                      levels_pct=levels, steps_samples=steps_n)
