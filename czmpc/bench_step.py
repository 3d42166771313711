"""Step-time benchmark of OffsetFreeMPC on a staircase against the exact model.

Runs the controller in closed loop with a plant that is the model's own difference
equation (``A(q) dP = B(q) f(ds) + C(q) e``, seeded noise), on a setpoint staircase,
and reports wall-clock statistics of `OffsetFreeMPC.step` alone. The plant lives in this
module on purpose: the controller core must not depend on `sim`, and the benchmark
should time the controller, not a simulator.

Run ``python -m czmpc.bench_step`` to print the numbers for the paper-like model at
``N = 50`` (the issue's goal: median <= 0.3 ms, p99 <= 2 ms on the 2-core machine).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from czmpc.controller import OffsetFreeMPC
from czmpc.settings import MPCSettings
from sysid.model import HammersteinModel, OperatingPoint


@dataclass(frozen=True, slots=True, kw_only=True)
class StepTimeStats:
    """Wall-clock statistics of `OffsetFreeMPC.step` [ms].

    Parameters
    ----------
    n_steps :
        Timed steps.
    horizon_steps :
        ``N`` of the controller.
    median_ms, p95_ms, p99_ms, max_ms :
        Quantiles and maximum of the step time [ms].
    mean_iterations :
        Mean OSQP iterations per step.
    n_fallbacks :
        Steps that fell back (should be 0).
    """

    n_steps: int
    horizon_steps: int
    median_ms: float
    p95_ms: float
    p99_ms: float
    max_ms: float
    mean_iterations: float
    n_fallbacks: int


def staircase_setpoint_kw(k: int, *, base_kw: float, step_kw: float = 2.0,
                          period_steps: int = 100, n_levels: int = 5) -> float:
    """Setpoint of a rising-then-falling staircase at sample ``k`` [kW].

    Parameters
    ----------
    k :
        Sample index.
    base_kw :
        Lowest level [kW].
    step_kw :
        Height of one stair [kW].
    period_steps :
        Samples per stair.
    n_levels :
        Stairs up before coming down.
    """
    phase = (k // period_steps) % (2 * n_levels)
    level = phase if phase < n_levels else 2 * n_levels - 1 - phase
    return base_kw + step_kw * level


def measure_step_times(
    model: HammersteinModel, settings: MPCSettings | None = None, n_steps: int = 2000,
    *, rng: np.random.Generator | int | None = 0,
) -> StepTimeStats:
    """Time `OffsetFreeMPC.step` on a staircase against the exact model.

    Parameters
    ----------
    model :
        Controller model and plant.
    settings :
        Controller settings; None for the model's defaults.
    n_steps :
        Closed-loop samples to time.
    rng :
        Seed or generator for the plant's innovation noise (``noise_std_kw``).
    """
    gen = np.random.default_rng(rng)
    mpc = OffsetFreeMPC(model, settings)
    a = [float(v) for v in model.a]
    b = [float(v) for v in model.b]
    c = [float(v) for v in model.c]
    n_hist = max(len(a), len(b), len(c))
    y_hist = [0.0] * n_hist  # y_{k-1}, y_{k-2}, ...
    w_hist = [0.0] * n_hist  # w_{k-1}, ...
    e_hist = [0.0] * n_hist
    noise = gen.standard_normal(n_steps) * model.noise_std_kw
    p_nom = model.operating_point.power_kw
    s_nom = model.operating_point.triac_pct
    times = np.empty(n_steps)
    iterations = np.empty(n_steps)
    clock = time.perf_counter
    for k in range(n_steps):
        e = float(noise[k])
        y = e
        for i in range(1, len(a)):
            y -= a[i] * y_hist[i - 1]
        for i in range(1, len(b)):
            y += b[i] * w_hist[i - 1]
        for i in range(1, len(c)):
            y += c[i] * e_hist[i - 1]
        setpoint = staircase_setpoint_kw(k, base_kw=p_nom - 4.0)
        t0 = clock()
        s = mpc.step(p_nom + y, setpoint)
        times[k] = clock() - t0
        last = mpc.last_step
        iterations[k] = 0 if last is None else last.n_iterations
        w = float(model.input_nonlinearity(s - s_nom))
        y_hist = [y, *y_hist[:-1]]
        w_hist = [w, *w_hist[:-1]]
        e_hist = [e, *e_hist[:-1]]
    ms = times * 1e3
    return StepTimeStats(
        n_steps=n_steps, horizon_steps=mpc.settings.horizon_steps,
        median_ms=float(np.median(ms)), p95_ms=float(np.percentile(ms, 95)),
        p99_ms=float(np.percentile(ms, 99)), max_ms=float(ms.max()),
        mean_iterations=float(iterations.mean()), n_fallbacks=mpc.n_fallbacks,
    )


def paper_model() -> HammersteinModel:
    """The paper's final ARMAX-block Hammerstein model (eq. 30 shape, DESIGN.md values)."""
    return HammersteinModel(
        kind="hammerstein", linear_block="armax", ts_s=2.0,
        operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
        a=np.array([1.0, -0.99]), b=np.array([0.0, 1.0, -0.991]), c=np.array([1.0, -0.9]),
        input_poly=np.array([1.35, -0.0065]),
        noise_std_kw=0.0134, input_range_pct=(20.0, 70.0),
    )


def main() -> None:
    """Print step-time statistics for N = 50 with and without rate limit."""
    model = paper_model()
    base = MPCSettings.default_for(model).with_updates(horizon_steps=50)
    cases = {
        "N=50 default": base,
        "N=50 rate 2 %/step": base.with_updates(max_move_pct_per_step=2.0),
        "N=50 rate + soft max": base.with_updates(max_move_pct_per_step=2.0,
                                                  soft_power_max_kw=52.0),
    }
    for name, settings in cases.items():
        stats = measure_step_times(model, settings, n_steps=2000, rng=0)
        print(  # noqa: T201 - this is the benchmark's report
            f"{name:24s} median {stats.median_ms:.3f} ms  p95 {stats.p95_ms:.3f} ms  "
            f"p99 {stats.p99_ms:.3f} ms  max {stats.max_ms:.3f} ms  "
            f"iters {stats.mean_iterations:.1f}  fallbacks {stats.n_fallbacks}"
        )


if __name__ == "__main__":
    main()
