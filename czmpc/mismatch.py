"""Model-mismatch diagnostic: windowed innovation statistics against the noise model.

With a correct model the innovations ``eps_k`` are white with standard deviation
``sigma_eps`` (the model's ``noise_std_kw`` times the estimator's predicted innovation
std). Over the last ``n`` used samples the monitor reports

* ``mean_z = mean(eps) / (sigma_eps / sqrt(n))``: about N(0, 1); large for a biased
  sensor or an offset not yet absorbed by the integrating disturbance;
* ``variance_ratio = var(eps) / sigma_eps^2``: about 1; raised by a noisier plant or
  un-modelled dynamics;
* ``lag1_correlation``: about 0 (std ``1/sqrt(n)``); drifted dynamics colour it.

The estimator turns a persistent sensor bias or gain drift into ``d``, so
``|d| > disturbance_limit_kw`` flags it even after the innovations are white again.
Nothing here changes the control. A noise-free model (``noise_std_kw = 0``) is monitored
with `monitored_noise_std_kw`: a millionth of its output span, so the statistics stay
finite and any real noise flags the model's claim.
"""

from __future__ import annotations

import math
import sys
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from czmpc._records import record_from_fields
from sysid.model import HammersteinModel

#: A noise-free model's monitored innovation std, as a fraction of its output span.
NOISE_FREE_STD_FRACTION = 1e-6
#: Smallest monitored standard deviation: its square is still a normal float.
_MIN_MONITORED_STD = math.sqrt(sys.float_info.min)


def monitored_noise_std_kw(model: HammersteinModel) -> float:
    """The innovation standard deviation the monitors divide by [output unit].

    Parameters
    ----------
    model :
        The controller's model.

    Returns
    -------
    float
        ``noise_std_kw``, at least `NOISE_FREE_STD_FRACTION` times the model's
        steady-state output span over its input range and the square root of the
        smallest normal float (the Kalman gain does not depend on it, docs/theory.rst, C1).
    """
    lo, hi = model.input_range_pct
    power_kw = model.steady_state_power_kw(np.linspace(lo, hi, 101))
    span_kw = float(np.ptp(power_kw)) if np.all(np.isfinite(power_kw)) else 0.0
    return max(model.noise_std_kw, NOISE_FREE_STD_FRACTION * span_kw, _MIN_MONITORED_STD)


@dataclass(frozen=True, kw_only=True)
class MismatchStats:
    """Windowed innovation statistics (module notes).

    Parameters
    ----------
    n_samples :
        Innovations in the window.
    mean_kw :
        Their mean [kW].
    std_kw :
        Their standard deviation [kW].
    mean_z :
        Mean over its standard error under the noise model [-].
    variance_ratio :
        Variance over the noise model's innovation variance [-].
    lag1_correlation :
        Lag-1 autocorrelation [-].
    disturbance_kw :
        The disturbance estimate's steady power effect [kW].
    biased :
        ``|mean_z| > z_limit`` or ``|disturbance_kw| > disturbance_limit_kw``.
    drifted :
        ``variance_ratio > variance_limit`` or ``|lag1| > z_limit / sqrt(n)``.

    Notes
    -----
    `InnovationMonitor` makes one per step and most are never read: its records hold the
    window's sums, and every field is computed at the first read (`window_statistics`).
    """

    n_samples: int
    mean_kw: float
    std_kw: float
    mean_z: float
    variance_ratio: float
    lag1_correlation: float
    disturbance_kw: float
    biased: bool
    drifted: bool

    @property
    def flagged(self) -> bool:
        """True if either flag is raised."""
        return self.biased or self.drifted

    if not TYPE_CHECKING:  # (type checkers still see only the fields)
        def __getattr__(self, name: str) -> Any:
            # Reached only for a field not in __dict__ yet: a record of the sums (class notes).
            sums = None if name.startswith("__") else self.__dict__.pop("_window_sums", None)
            if sums is None:
                raise AttributeError(f"'MismatchStats' object has no attribute {name!r}")
            self.__dict__.update(window_statistics(*sums))
            return getattr(self, name)


def window_statistics(
    n: int, total: float, total_sq: float, n_pairs: int, total_pairs: float,
    disturbance_kw: float, monitor: InnovationMonitor,
) -> dict[str, Any]:
    """Every field of `MismatchStats`, in order, from the window's running sums.

    Parameters
    ----------
    n, total, total_sq :
        Innovations in the window, their sum [kW] and sum of squares [kW^2].
    n_pairs, total_pairs :
        Consecutive pairs in the window and the sum of their products [kW^2].
    disturbance_kw :
        The disturbance estimate's steady power effect [kW].
    monitor :
        The thresholds and ``sigma_kw``.
    """
    if n == 0:
        return {"n_samples": 0, "mean_kw": 0.0, "std_kw": 0.0, "mean_z": 0.0,
                "variance_ratio": 0.0, "lag1_correlation": 0.0,
                "disturbance_kw": disturbance_kw, "biased": False, "drifted": False}
    mean = total / n
    var = max(0.0, total_sq / n - mean * mean)
    sigma = monitor.sigma_kw
    mean_z = mean / (sigma / math.sqrt(n))
    var_ratio = var / (sigma * sigma)
    lag1 = (total_pairs / n_pairs - mean * mean) / var if n_pairs > 0 and var > 0.0 else 0.0
    enough = n >= monitor.min_samples
    d_flag = (monitor.disturbance_limit_kw is not None
              and abs(disturbance_kw) > monitor.disturbance_limit_kw)
    biased = d_flag or (enough and abs(mean_z) > monitor.z_limit)
    drifted = enough and (var_ratio > monitor.variance_limit
                          or abs(lag1) * math.sqrt(n) > monitor.z_limit)
    return {"n_samples": n, "mean_kw": mean, "std_kw": math.sqrt(var), "mean_z": mean_z,
            "variance_ratio": var_ratio, "lag1_correlation": lag1,
            "disturbance_kw": disturbance_kw, "biased": biased, "drifted": drifted}


class InnovationMonitor:
    """Running innovation statistics over a window of used samples.

    Parameters
    ----------
    window_samples :
        Window length [samples] (>= 2).
    sigma_kw :
        Innovation standard deviation the noise model predicts [kW] (> 0).
    min_samples :
        No flag is raised with fewer samples in the window.
    z_limit :
        Threshold on ``|mean_z|`` and on ``|lag1| sqrt(n)``.
    variance_limit :
        Threshold on ``variance_ratio``.
    disturbance_limit_kw :
        Threshold on ``|disturbance_kw|``; None disables that flag.

    The thresholds are fixed at construction (its records read them lazily).
    """

    def __init__(self, *, window_samples: int, sigma_kw: float, min_samples: int = 30,
                 z_limit: float = 4.0, variance_limit: float = 4.0,
                 disturbance_limit_kw: float | None = None) -> None:
        self.window_samples = window_samples
        self.sigma_kw = sigma_kw
        self.min_samples = min_samples
        self.z_limit = z_limit
        self.variance_limit = variance_limit
        self.disturbance_limit_kw = disturbance_limit_kw
        self.reset()

    def reset(self) -> None:
        """Empty the window."""
        self._buf: deque[float] = deque(maxlen=self.window_samples)
        self._pairs: deque[float] = deque(maxlen=self.window_samples - 1)
        self._sum = 0.0
        self._sum2 = 0.0
        self._sum_pair = 0.0
        self._last: float | None = None
        self._since_resum = 0

    def _resum(self) -> None:
        """Recompute the running sums from the window (removes accumulated rounding)."""
        self._sum = math.fsum(self._buf)
        self._sum2 = math.fsum(e * e for e in self._buf)
        self._sum_pair = math.fsum(self._pairs)
        self._since_resum = 0

    def update(self, innovation_kw: float | None, *, disturbance_kw: float) -> MismatchStats:
        """Add one innovation (None for a sample not used) and return the statistics.

        A sample not used breaks the lag-1 chain but keeps the window.
        """
        if innovation_kw is not None and math.isfinite(innovation_kw):
            e = float(innovation_kw)
            if len(self._buf) == self._buf.maxlen:
                old = self._buf[0]
                self._sum -= old
                self._sum2 -= old * old
            self._buf.append(e)
            self._sum += e
            self._sum2 += e * e
            if self._last is not None:
                if len(self._pairs) == self._pairs.maxlen:
                    self._sum_pair -= self._pairs[0]
                pair = self._last * e
                self._pairs.append(pair)
                self._sum_pair += pair
            self._last = e
            self._since_resum += 1
            if self._since_resum >= self.window_samples:
                self._resum()
        else:
            self._last = None
        return self.stats(disturbance_kw)

    def stats(self, disturbance_kw: float) -> MismatchStats:
        """Statistics of the current window (computed when first read, `MismatchStats`)."""
        return record_from_fields(MismatchStats, {"_window_sums": (
            len(self._buf), self._sum, self._sum2, len(self._pairs), self._sum_pair,
            disturbance_kw, self)})


__all__ = ["NOISE_FREE_STD_FRACTION", "InnovationMonitor", "MismatchStats",
           "monitored_noise_std_kw", "window_statistics"]
