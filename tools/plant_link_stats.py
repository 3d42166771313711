"""Numbers for BENCHMARKS.md "Plant link" from `czmpc run` logs (see that section).

usage: python tools/plant_link_stats.py RUN.csv [SCENARIO.toml SEED]

Prints the loop lateness and read-step-write latency (median, p99, max) [ms] of a log;
with a scenario and seed also the tracking IAE [kW s] of the measured power per setpoint
step through OPC UA and in process (same scenario, seed, controller settings), over the
same window after each setpoint change (the log's own setpoint column marks the change).
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np


def _pct(values: np.ndarray) -> str:
    ms = values * 1e3
    return (f"median {np.median(ms):.2f} ms, p99 {np.percentile(ms, 99):.2f} ms, "
            f"max {ms.max():.2f} ms (n = {ms.size})")


def _iae_after_changes(sp: np.ndarray, p: np.ndarray, ts_s: float, window: int) -> list[float]:
    changes = [i for i in range(1, sp.size) if sp[i] != sp[i - 1]]
    out = []
    for i in changes:
        seg = slice(i, min(sp.size, i + window))
        out.append(float(np.sum(np.abs(sp[seg] - p[seg])) * ts_s))
    return out


def main(argv: list[str]) -> int:
    with open(argv[0], newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh) if r["k"] != ""]
    late = np.array([float(r["lateness_s"]) for r in rows])
    lat = np.array([float(r["step_latency_s"]) for r in rows])
    print(f"lateness: {_pct(late)}")
    print(f"read-step-write latency: {_pct(lat)}")
    if len(argv) < 3:
        return 0
    from czmpc.campaigns.simulation import run_simulation
    from czmpc.settings import MPCSettings
    from czmpc.shipped import shipped_path
    from sim.scenario import load_scenario
    from sysid.modelfile import load_model

    model = load_model(shipped_path("cz_heater_model.json"))
    scenario = load_scenario(Path(argv[1]))
    window = 140
    sp = np.array([float(r["setpoint_kw"]) for r in rows])
    p = np.array([float(r["power_kw"]) for r in rows])
    link = _iae_after_changes(sp, p, 2.0, window)
    out = run_simulation(model, scenario, plant="heater", seed=int(argv[2]),
                         settings=MPCSettings.default_for(model))
    traj = out.result
    sp_i = np.asarray(traj.setpoint_kw)
    p_i = np.asarray(traj.power_measured_kw)
    inproc = _iae_after_changes(sp_i, p_i, 2.0, window)
    for j, (a, b) in enumerate(zip(link, inproc, strict=False)):
        print(f"step {j + 1}: IAE over {window * 2} s: OPC UA {a:.1f} kW s, "
              f"in process {b:.1f} kW s, ratio {a / b:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
