"""Model-health monitor: one-step residuals of the model, their correlation with past data, a stale alarm.

The controller's innovations (`czmpc.mismatch`) come from an estimator whose
integrating disturbance absorbs model error and whose tuning colours them slightly even
for a perfect model. So this monitor runs the model's own one-step predictor beside the
controller: for a correct model its residuals are exactly white with ``noise_std_kw``.

Notation
--------
``y_k`` measured power deviation ``P_k - P_nom`` [kW]; ``w_k = f(s_k - s_nom)`` the
input through the model's nonlinearity [kW-equivalent], ``s_k`` the TRIAC input applied
over ``(t_k, t_{k+1}]`` [%]; ``A, B, C`` the model's polynomials in ``q^-1``.

Residual (one-step prediction error of the model, docs/reference/model_file.rst)::

    C(q) e_k = A(q) y_k - B(q) w_k

Under a correct model ``e_k`` is white, ``N(0, sigma^2)``, ``sigma = noise_std_kw``,
independent of everything measured before ``k``. A model whose ``A`` or ``B`` no longer
match the plant leaves in ``e_k`` exactly ``psi_k' (theta_plant - theta_model)``, with
the past data filtered by ``1/C`` (the prediction-error gradient)::

    psi_k = [ y_{k-1} .. y_{k-na},  w_{k-1} .. w_{k-nb-m} ] / C(q)

(``m`` extra input lags catch a longer delay). The test regresses the window's
residuals on ``psi`` and a constant (the regression F test of Ljung's cross-correlation
test; the score test of Basseville and Nikiforov, *Detection of Abrupt Changes*, 1993,
ch. 9)::

    F = (RSS_0 - RSS_1) / q  /  (RSS_1 / (n - r)),     q = r - 1 = rank of psi (centred)

Under a correct model ``F ~ F(q, n - r)`` exactly (Gaussian ``e``, regressors fixed by
the past). The constant absorbs a slow output offset and the noise level is estimated
in the window, so neither raises an alarm.

**The rule.** Every `HealthSettings.test_every_samples` residuals, over the last
`HealthSettings.window_samples` (at least half of them present): the stale alarm is
raised when ``P(F(q, n - r) > F) < false_alarm_per_test`` and latched until
`ModelHealthMonitor.reset`. By the union bound, a correct model raises a false alarm
over a duration ``D`` with probability at most
``D / (Ts * test_every_samples) * false_alarm_per_test``
(`HealthSettings.false_alarm_bound`): at the defaults and ``Ts = 2 s``,
``720 tests/day * 1e-6 = 7.2e-4`` per day.

With the input held constant ``psi`` drops in rank: a stale model is then invisible
(and harmless to a constant setpoint, held offset-free by the integrating disturbance).
Reported beside it (`czmpc.mismatch.InnovationMonitor` on these residuals): the mean
over its standard error, the variance over ``sigma^2``, the lag-1 correlation, and the
drift of the controller's disturbance estimate over the window.

**Two references.** Against the model (``baseline_samples = 0``): any mismatch alarms,
also one from the start; on the model's own plant a 25 % gain loss in minutes and a
doubled time constant within 30 min (BENCHMARKS.md), the virtual heater's structural
mismatch within about an hour. Against a baseline (``baseline_samples = N``): each test
is a partial F test (Chow) of whether the window's regression coefficients differ from
those of the first ``N`` residuals (constants free), so only a *change* alarms, at some
cost in detection power. `czmpc run` uses the baseline (`RUNTIME_HEALTH`).

The published ``health`` is ``F / F_limit`` of the latest test: 1 or above is the alarm.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy import special

from czmpc.errors import SettingsError
from czmpc.inversion import evaluate
from czmpc.mismatch import InnovationMonitor, monitored_noise_std_kw
from sysid._typing import FloatArray
from sysid.model import HammersteinModel
from sysid.polynomials import roots_z

#: A predictor transient (start, missing sample) has decayed when it is this fraction of its size.
TRANSIENT_DECAY = 1e-3
#: Singular values below this fraction of the largest (centred, scaled regressors) do not count.
RANK_RTOL = 1e-9


@dataclass(frozen=True, slots=True, kw_only=True)
class HealthSettings:
    """How the model-health monitor tests (module docstring for the rule).

    Parameters
    ----------
    window_samples :
        Residuals in the test window [samples] (default 900: 30 min at Ts = 2 s).
    test_every_samples :
        Residuals between two tests [samples] (default 60: 2 min at Ts = 2 s).
    false_alarm_per_test :
        Probability that one test alarms on a correct model [-].
    extra_input_lags :
        Input lags tested beyond the model's ``B`` (a longer delay shows there).
    residual_lags :
        Past residuals ``e_{k-1} .. e_{k-p}`` in both regressions as nuisance terms, so
        noise the model does not describe (a slow grid wander) is not mismatch.
    baseline_samples :
        0: test against the model. ``N > 0``: test for a change since the first ``N``
        residuals (module notes).

    Raises
    ------
    SettingsError
        A value out of range.
    """

    window_samples: int = 900
    test_every_samples: int = 60
    false_alarm_per_test: float = 1e-6
    extra_input_lags: int = 2
    residual_lags: int = 0
    baseline_samples: int = 0

    def __post_init__(self) -> None:
        for name, low in (("window_samples", 20), ("test_every_samples", 1),
                          ("extra_input_lags", 0), ("residual_lags", 0),
                          ("baseline_samples", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise SettingsError(f"HealthSettings.{name} must be an int >= {low}; got {value!r}")
        alpha = self.false_alarm_per_test
        if not (isinstance(alpha, float | int) and 0.0 < alpha < 0.5):
            raise SettingsError(
                f"HealthSettings.false_alarm_per_test must be in (0, 0.5); got {alpha!r}")

    def false_alarm_bound(self, duration_s: float, ts_s: float) -> float:
        """Upper bound of the probability of a false alarm over ``duration_s`` [-].

        Parameters
        ----------
        duration_s :
            Plant time [s].
        ts_s :
            Sampling time [s].

        Returns
        -------
        float
            ``min(1, n_tests * false_alarm_per_test)``, ``n_tests = duration_s / (ts_s *
            test_every_samples)`` (union bound; overlapping windows make it pessimistic).
        """
        n_tests = math.floor(duration_s / (ts_s * self.test_every_samples))
        return min(1.0, n_tests * self.false_alarm_per_test)


#: What `czmpc run` uses: the change test against the first 30 min (at Ts = 2 s) of the run.
RUNTIME_HEALTH = HealthSettings(baseline_samples=900)


@dataclass(frozen=True, slots=True, kw_only=True)
class ModelHealth:
    """The monitor's view after one sample (module docstring).

    Parameters
    ----------
    k :
        Samples seen (0-based index of this one).
    residual_kw :
        One-step prediction residual ``e_k`` [kW]; NaN if none (missing sample, start).
    predicted_kw :
        The model's one-step prediction of this sample's power [kW] (NaN at the start).
    n_samples :
        Residuals in the window.
    mean_z :
        Window mean of the residuals over its standard error under ``noise_std_kw`` [-].
    variance_ratio :
        Window variance of the residuals over ``noise_std_kw^2`` [-].
    lag1_correlation :
        Lag-1 autocorrelation of the residuals in the window [-].
    f_statistic :
        F of the latest test (NaN before the first) [-].
    f_limit :
        The alarm limit of the latest test ``F(q, n - r)`` quantile at ``1 - alpha`` [-].
    p_value :
        ``P(F(q, n - r) > f_statistic)`` of the latest test [-].
    dof :
        ``q``: regressor directions the latest test had (input excitation).
    health :
        ``f_statistic / f_limit`` (0 before the first test): >= 1 is an alarm [-].
    disturbance_drift_kw :
        Change of the controller's disturbance estimate over the window [kW] (or NaN).
    stale_alarm :
        The latched stale-model alarm.
    alarm_reason :
        Why the alarm was raised ("" if not).
    """

    k: int
    residual_kw: float
    predicted_kw: float
    n_samples: int
    mean_z: float
    variance_ratio: float
    lag1_correlation: float
    f_statistic: float
    f_limit: float
    p_value: float
    dof: int
    health: float
    disturbance_drift_kw: float
    stale_alarm: bool
    alarm_reason: str

    def status(self) -> str:
        """A short text for a live status line."""
        alarm = " STALE-MODEL ALARM" if self.stale_alarm else ""
        return f"health={self.health:.2f}{alarm}"


def _settle_samples(c: FloatArray) -> int:
    """Samples until a transient of ``1/C`` has decayed to `TRANSIENT_DECAY`."""
    roots = roots_z(c)
    if roots.size == 0:
        return 1
    rho = float(np.max(np.abs(roots)))
    if rho <= 0.0:
        return len(c)
    return max(len(c), math.ceil(math.log(TRANSIENT_DECAY) / math.log(rho)))


class ModelHealthMonitor:
    """The model's one-step predictor and the stale-model test, one sample per `update`.

    Parameters
    ----------
    model :
        The model the controller runs on.
    settings :
        Window, test interval and false-alarm rate.

    Examples
    --------
    >>> from czmpc.shipped import shipped_path
    >>> from sysid.modelfile import load_model
    >>> monitor = ModelHealthMonitor(load_model(shipped_path("cz_heater_model.json")))
    >>> monitor.update(power_kw=29.27, input_triac_pct=33.0).stale_alarm
    False
    """

    def __init__(self, model: HammersteinModel, settings: HealthSettings | None = None) -> None:
        self.model = model
        self.settings = HealthSettings() if settings is None else settings
        self.ts_s = model.ts_s
        self._p_nom = model.operating_point.power_kw
        self._s_nom = model.operating_point.triac_pct
        self._c = np.asarray(model.c, dtype=float)
        self._poly = tuple(float(v) for v in model.input_poly)
        self._a_t, self._b_t, self._c_t = (tuple(float(v) for v in np.asarray(p, dtype=float))
                                           for p in (model.a, model.b, model.c))
        self._na = len(self._a_t) - 1
        self._nw = len(self._b_t) - 1 + self.settings.extra_input_lags
        self._settle = _settle_samples(self._c)
        self.reset()

    def reset(self) -> None:
        """Forget the past and clear the alarm."""
        s = self.settings
        n_hist = max(self._na, len(self._b_t) - 1, len(self._c) - 1, self._nw,
                     s.residual_lags) + 1
        self._y: deque[float] = deque([0.0] * n_hist, maxlen=n_hist)    # y_{k-1}, y_{k-2}, ...
        self._w: deque[float] = deque([0.0] * n_hist, maxlen=n_hist)    # w_{k-1}, ...
        self._e: deque[float] = deque([0.0] * n_hist, maxlen=n_hist)
        self._fy: deque[float] = deque([0.0] * n_hist, maxlen=n_hist)   # (y / C)_{k-1}, ...
        self._fw: deque[float] = deque([0.0] * n_hist, maxlen=n_hist)
        self._rows: deque[tuple[float, ...]] = deque(maxlen=s.window_samples)
        self._d: deque[float] = deque(maxlen=s.window_samples)
        self._stats = InnovationMonitor(window_samples=s.window_samples,
                                        sigma_kw=monitored_noise_std_kw(self.model),
                                        min_samples=2)
        self._last_stats = self._stats.stats(0.0)
        self._k = -1
        self._started = False
        self._since_gap = 0
        self._new_rows = 0
        self._baseline: list[tuple[float, ...]] = []
        self._last_w = 0.0
        self._f = math.nan
        self._f_limit = math.nan
        self._p = math.nan
        self._dof = 0
        self._limits: dict[tuple[int, int], float] = {}
        self.stale_alarm = False
        self.alarm_reason = ""
        self.alarm_k: int | None = None

    def _y_hat(self, w_newest: float) -> float:
        """``y_hat = -sum a_i y_{k-i} + sum b_j w_{k-j} + sum c_i e_{k-i}`` [kW], ``w_newest`` acting."""
        a, b, c = self._a_t, self._b_t, self._c_t
        y_hat = 0.0
        for i in range(1, len(a)):
            y_hat -= a[i] * self._y[i - 1]
        for j in range(1, len(b)):
            y_hat += b[j] * (w_newest if j == 1 else self._w[j - 2])
        for i in range(1, len(c)):
            y_hat += c[i] * self._e[i - 1]
        return y_hat

    def predict_next_kw(self, input_triac_pct: float) -> float:
        """The power [kW] the model predicts for the next sample if ``input_triac_pct``
        acts until then (NaN before the first measured sample)."""
        if not self._started or not math.isfinite(input_triac_pct):
            return math.nan
        return self._p_nom + self._y_hat(evaluate(self._poly, input_triac_pct - self._s_nom))

    def update(self, power_kw: float, input_triac_pct: float,
               disturbance_kw: float = math.nan) -> ModelHealth:
        """Take the sample ``y_k`` and the input applied before it; test when due.

        Parameters
        ----------
        power_kw :
            Measured power at sample ``k`` [kW]; NaN (missing) skips the residual.
        input_triac_pct :
            TRIAC input applied over ``(t_{k-1}, t_k]`` [%] (the previous command); NaN:
            unknown, the previous one is kept.
        disturbance_kw :
            The controller's disturbance estimate as a steady power effect [kW]; NaN if
            not known.

        Returns
        -------
        ModelHealth
        """
        self._k += 1
        w_prev = (evaluate(self._poly, input_triac_pct - self._s_nom)
                  if math.isfinite(input_triac_pct) else self._last_w)
        self._last_w = w_prev
        measured = math.isfinite(power_kw)
        if not self._started:
            if not measured:
                return self._view(math.nan, math.nan)
            y0 = power_kw - self._p_nom
            # start in the steady state of the first sample (a transient decays in `_settle`)
            for hist, value in ((self._y, y0), (self._w, w_prev), (self._e, 0.0),
                                (self._fy, y0 / float(np.sum(self._c))),
                                (self._fw, w_prev / float(np.sum(self._c)))):
                for i in range(len(hist)):
                    hist[i] = value
            self._started = True
            self._since_gap = 0
            return self._view(math.nan, math.nan)
        y_hat = self._y_hat(w_prev)
        self._w.appendleft(w_prev)
        c = self._c_t
        psi = tuple(self._e[i] for i in range(self.settings.residual_lags)) + tuple(
            self._fy[i] for i in range(self._na)) + tuple(self._fw[j] for j in range(self._nw))
        if measured:
            y = power_kw - self._p_nom
            e = y - y_hat
            self._since_gap += 1
        else:
            y, e = y_hat, 0.0
            self._since_gap = 0
        self._y.appendleft(y)
        self._e.appendleft(e)
        fy = y - sum(c[i] * self._fy[i - 1] for i in range(1, len(c)))
        fw = w_prev - sum(c[i] * self._fw[i - 1] for i in range(1, len(c)))
        self._fy.appendleft(fy)
        self._fw.appendleft(fw)
        residual = math.nan
        if measured and self._since_gap > self._settle:
            residual = e
            row = (e, *psi)
            if len(self._baseline) < self.settings.baseline_samples:
                self._baseline.append(row)
            else:
                self._rows.append(row)
                self._new_rows += 1
            if math.isfinite(disturbance_kw):
                self._d.append(disturbance_kw)
            self._last_stats = self._stats.update(e, disturbance_kw=0.0)
        else:
            self._last_stats = self._stats.update(None, disturbance_kw=0.0)
        if (self._new_rows >= self.settings.test_every_samples
                and len(self._rows) >= self.settings.window_samples // 2):
            self._new_rows = 0
            if self.settings.baseline_samples:
                self._test_change()
            else:
                self._test()
        return self._view(residual, self._p_nom + y_hat)

    def _test_change(self) -> None:
        """Partial F test: did the data regressors' coefficients change since the baseline?

        Full model: each period (baseline, window) its own constant, residual-lag and data
        coefficients; restricted: the data coefficients shared. Under no change
        ``F ~ F(q, n - r_full)``.
        """
        p = self.settings.residual_lags
        base = np.asarray(self._baseline, dtype=float)
        now = np.asarray(self._rows, dtype=float)
        parts = [block - block.mean(axis=0) for block in (base, now)]
        scale = np.sqrt(sum(np.sum(c[:, 1:] ** 2, axis=0) for c in parts))
        scale[scale == 0.0] = 1.0
        n_b, n_w = len(base), len(now)
        e = np.concatenate([parts[0][:, 0], parts[1][:, 0]])
        nb = parts[0][:, 1:1 + p] / scale[:p]
        nw = parts[1][:, 1:1 + p] / scale[:p]
        xb = parts[0][:, 1 + p:] / scale[p:]
        xw = parts[1][:, 1 + p:] / scale[p:]
        m = xb.shape[1]
        zeros_b = np.zeros((n_b, p + m))
        zeros_w = np.zeros((n_w, p + m))
        full = np.block([[np.hstack([nb, xb]), zeros_b], [zeros_w, np.hstack([nw, xw])]])
        restricted = np.block([[nb, np.zeros((n_b, p)), xb], [np.zeros((n_w, p)), nw, xw]])

        def rss_rank(z: FloatArray) -> tuple[float, int]:
            u, sv, _ = np.linalg.svd(z, full_matrices=False)
            r = int(np.sum(sv > RANK_RTOL * max(float(sv[0]) if sv.size else 0.0, 1e-300)))
            proj = u[:, :r].T @ e
            return float(e @ e - proj @ proj), r

        rss_full, r_full = rss_rank(full)
        rss_restr, r_restr = rss_rank(restricted)
        q = r_full - r_restr
        dof_den = n_b + n_w - r_full - 2   # the two constants
        if q <= 0 or dof_den < 1 or rss_full <= 0.0:
            self._f, self._p, self._dof = 0.0, 1.0, max(q, 0)
            return
        f_stat = ((rss_restr - rss_full) / q) / (rss_full / dof_den)
        self._conclude(f_stat, q, dof_den, n_w, "the residuals' relation to past inputs and "
                       "outputs changed since the baseline")

    def _conclude(self, f_stat: float, q: int, dof_den: int, n: int, finding: str) -> None:
        """Record a partial F test of ``q`` directions; latch the alarm when it exceeds its limit."""
        self._f, self._dof = f_stat, q
        key = (q, dof_den)
        if key not in self._limits:
            self._limits[key] = float(special.fdtri(q, dof_den, 1.0 - self.settings.false_alarm_per_test))
        self._f_limit = self._limits[key]
        self._p = float(special.fdtrc(q, dof_den, f_stat))
        if f_stat > self._f_limit and not self.stale_alarm:
            self.stale_alarm = True
            self.alarm_k = self._k
            self.alarm_reason = (
                f"stale model: {finding} (F = {f_stat:.3g} > {self._f_limit:.3g}, p = "
                f"{self._p:.2g} < {self.settings.false_alarm_per_test:g}, {q} directions, "
                f"{n} samples)")

    def _test(self) -> None:
        rows = np.asarray(self._rows, dtype=float)
        p = self.settings.residual_lags
        n = len(rows)
        centred = rows - rows.mean(axis=0)
        e = centred[:, 0]
        scale = np.sqrt(np.sum(centred[:, 1:] ** 2, axis=0))
        scale[scale == 0.0] = 1.0
        nuisance = centred[:, 1:1 + p] / scale[:p]
        tested = centred[:, 1 + p:] / scale[p:]
        # restricted: constant + past residuals; full: + the data regressors (partial F)
        u0, s0, _ = np.linalg.svd(nuisance, full_matrices=False) if p else (
            np.zeros((n, 0)), np.zeros(0), None)
        r0 = int(np.sum(s0 > RANK_RTOL * s0[0])) if s0.size else 0
        basis0 = u0[:, :r0]
        resid0 = e - basis0 @ (basis0.T @ e)
        tested_perp = tested - basis0 @ (basis0.T @ tested)
        rss0 = float(resid0 @ resid0)
        if rss0 <= 0.0 or not np.any(tested_perp):
            self._f, self._p, self._dof = 0.0, 1.0, 0
            return
        u, sv, _ = np.linalg.svd(tested_perp, full_matrices=False)
        q = int(np.sum(sv > RANK_RTOL * max(float(sv[0]), 1e-300)))
        proj = u[:, :q].T @ resid0
        explained = float(proj @ proj)
        rss1 = max(rss0 - explained, 1e-300)
        dof_den = n - q - r0 - 1
        if q == 0 or dof_den < 1:
            self._f, self._p, self._dof = 0.0, 1.0, q
            return
        f_stat = (explained / q) / (rss1 / dof_den)
        self._conclude(f_stat, q, dof_den, n, "residuals correlate with past inputs and outputs")

    def _view(self, residual: float, predicted_kw: float) -> ModelHealth:
        st = self._last_stats
        drift = (self._d[-1] - self._d[0]) if len(self._d) >= 2 else math.nan
        health = 0.0
        if math.isfinite(self._f) and math.isfinite(self._f_limit) and self._f_limit > 0.0:
            health = self._f / self._f_limit
        return ModelHealth(
            k=max(self._k, 0), residual_kw=residual, predicted_kw=predicted_kw,
            n_samples=st.n_samples, mean_z=st.mean_z,
            variance_ratio=st.variance_ratio, lag1_correlation=st.lag1_correlation,
            f_statistic=self._f, f_limit=self._f_limit, p_value=self._p, dof=self._dof,
            health=health, disturbance_drift_kw=drift, stale_alarm=self.stale_alarm,
            alarm_reason=self.alarm_reason)


__all__ = ["RUNTIME_HEALTH", "HealthSettings", "ModelHealth", "ModelHealthMonitor"]
