"""Fuzzing the generated C against the Python controller: random models, settings, faults.

Each case draws a model within the model contract (stable A of order 1-2, delay 1-2,
B(1) > 0, C stable, f of degree 1-3 monotone on its range, random operating point and
noise), random settings (horizon, weights, disturbance model, rate limit, soft limits,
every reliability guard on or off, an OSQP iteration cap that may bite), builds its C
step, and replays both controllers through `tests.codegen.replay.fault_replay` with a
random stream (noise, spikes, gaps, stuck runs, bad setpoints, previews, voltage, modes).

Required of every step (issue 42): `tests.codegen.replay.Comparison`'s checks (TRIAC
within 1e-6 %, equal iteration counts, mode, status, fallback). Measured: every step
bit-equal, since the C's OSQP is set up from the exact problem (OSQP's generator prints
"%.20f") and the Python controller sums its products in the C's order (`czmpc.ordered`).

As a benchmark (prints the counts; ``--steps`` per case)::

    python -m tests.codegen.fuzz --cases 400 --steps 2500 --seed 1   # 1e6 steps
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from czmpc.codegen import CController
from czmpc.controller import OffsetFreeMPC
from czmpc.errors import CzmpcError
from czmpc.settings import MPCSettings, OSQPOptions, ReliabilitySettings
from sysid.errors import SysidError
from sysid.model import HammersteinModel, OperatingPoint
from tests.codegen.replay import Comparison, StepBuilder, fault_replay


def random_model(rng: np.random.Generator) -> HammersteinModel:
    """A model within the contract (module notes)."""
    poles = [rng.uniform(0.5, 0.995)] + ([rng.uniform(0.0, 0.9)] if rng.random() < 0.4 else [])
    a = np.poly(poles)
    delay = 1 if rng.random() < 0.7 else 2
    b = [0.0] * delay + [1.0, rng.uniform(-0.95, 0.5)]
    c = [1.0, rng.uniform(-0.9, 0.5)]
    linear = rng.random() < 0.2
    degree = 1 if linear else int(rng.integers(2, 4))
    poly = [rng.uniform(0.5, 2.0), rng.uniform(-0.01, 0.004), rng.uniform(-2e-5, 2e-5)][:degree]
    s_nom = rng.uniform(35.0, 55.0)
    lo, hi = s_nom - rng.uniform(5.0, 25.0), s_nom + rng.uniform(5.0, 25.0)
    return HammersteinModel(
        kind="linear" if linear else "hammerstein", linear_block="armax", ts_s=2.0,
        operating_point=OperatingPoint(triac_pct=s_nom, power_kw=rng.uniform(20.0, 80.0)),
        a=list(a), b=b, c=c, input_poly=poly, noise_std_kw=rng.uniform(0.0, 0.05),
        input_range_pct=(lo, hi))


def random_settings(model: HammersteinModel, rng: np.random.Generator) -> MPCSettings:
    """Random settings around `MPCSettings.default_for` (module notes)."""
    base = MPCSettings.default_for(model)
    p_nom = model.operating_point.power_kw

    def maybe(value: float) -> float | None:
        return value if rng.random() < 0.5 else None

    return base.with_updates(
        horizon_steps=int(rng.integers(3, 41)),
        move_weight=float(10 ** rng.uniform(-3, 0)),
        input_target_weight=float(10 ** rng.uniform(-4, -1)),
        disturbance_model="input" if rng.random() < 0.4 else "output",
        disturbance_noise=float(10 ** rng.uniform(-2, 0)),
        validity_margin_pct=float(rng.uniform(0.0, 5.0)),
        max_move_pct_per_step=maybe(float(rng.uniform(0.3, 4.0))),
        soft_power_max_kw=maybe(p_nom + float(rng.uniform(3.0, 20.0))),
        soft_power_min_kw=maybe(p_nom - float(rng.uniform(3.0, 20.0))),
        osqp=OSQPOptions(max_iter=int(rng.choice([25, 200, 4000]))),
        reliability=ReliabilitySettings(
            spike_gate_k_sigma=maybe(float(rng.uniform(4.0, 12.0))),
            max_change_kw_per_sample=maybe(float(rng.uniform(1.0, 10.0))),
            power_max_kw=maybe(p_nom + float(rng.uniform(30.0, 100.0))),
            setpoint_ramp_kw_per_s=maybe(float(rng.uniform(0.05, 2.0))),
            setpoint_filter_time_s=maybe(float(rng.uniform(1.0, 20.0))),
            shed_triac_pct=maybe(float(model.operating_point.triac_pct)),
            stuck_samples=int(rng.choice([0, 4, 10])),
            level_change_k_sigma=maybe(10.0),
            max_predicted_samples=int(rng.integers(5, 80)),
            max_bad_solves=int(rng.integers(1, 6)),
            reopen_after_samples=int(rng.integers(0, 5))))


@dataclass
class FuzzResult:
    """What a fuzz run found."""

    n_cases: int = 0
    n_rejected_designs: int = 0
    n_bad: int = 0
    total: Comparison = field(default_factory=Comparison)
    max_iterations: int = 0
    bad: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """One paragraph of counts."""
        share = self.total.n_bit_equal / max(self.total.n_steps, 1)
        return (f"{self.n_cases} cases ({self.n_rejected_designs} random designs refused by "
                f"the controller and redrawn), {self.total.summary()}; bit-equal share "
                f"{share:.6f}; cases with a difference: {self.n_bad}; largest iteration "
                f"count {self.max_iterations}")


def fuzz(builder: StepBuilder, *, n_cases: int, n_steps: int, seed: int,
         progress: Callable[[str], None] | None = None, solver: str = "osqp") -> FuzzResult:
    """Run ``n_cases`` random controllers for ``n_steps`` each (module notes); ``progress``
    is called with the counts after every case. ``solver``: `MPCSettings.solver` of every
    case (the same random draws either way)."""
    rng = np.random.default_rng(seed)
    out = FuzzResult()
    while out.n_cases < n_cases:
        try:
            model = random_model(rng)
            settings = random_settings(model, rng).with_updates(solver=solver)
            py = OffsetFreeMPC(model, settings)
        except (CzmpcError, SysidError):
            out.n_rejected_designs += 1
            continue
        directory = builder.build(model, settings, name=f"fuzz{out.n_cases:05d}")
        c = CController(directory / "libczmpc.so")
        cmp, _ = fault_replay(py, c, n_steps=n_steps, rng=rng, expect_modes=False)
        out.n_cases += 1
        out.max_iterations = max(out.max_iterations, cmp.max_iterations_py)
        if cmp.mismatches:
            out.n_bad += 1
            out.bad.append(f"case {out.n_cases - 1}: {cmp.mismatches[:3]}")
        out.total.merge(cmp)
        if progress is not None:
            progress(f"case {out.n_cases - 1}: {cmp.summary()}; so far: {out.summary()}")
        for p in directory.glob("*.o"):      # keep the disk use of 1e6 steps small
            if not p.name.startswith("osqp_"):
                p.unlink()
    return out


def main() -> None:  # pragma: no cover - the benchmark entry point
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=400)
    parser.add_argument("--steps", type=int, default=2500)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--progress", action="store_true", help="a line of counts per case")
    parser.add_argument("--solver", choices=("osqp", "daqp"), default="osqp")
    args = parser.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="czmpc_fuzz_") as tmp:
        result = fuzz(StepBuilder(Path(tmp)), n_cases=args.cases, n_steps=args.steps, seed=args.seed,
                      progress=(lambda line: print(line, flush=True)) if args.progress else None,
                      solver=args.solver)
    print(result.summary())
    for line in result.bad[:20]:
        print("  ", line)
    print(f"wall time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":  # pragma: no cover
    main()
