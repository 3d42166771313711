"""
Commissioning a served heater: from a bare rig to a running MPC
===============================================================

The whole journey of ``czmpc commission --switch-on`` (:doc:`/guides/commission`),
against the virtual heater served over OPC UA by ``czmpc plant serve`` in a process of
its own on 127.0.0.1, as a hardware-in-the-loop rig would serve it. The heater's gain is
0.8 of the shipped model's (``--gain-factor 0.8``): the shipped model is not this
heater's model, so the journey has to find one. It

1. designs a multilevel test over 35..60 % for a time constant guessed at 250 s,
2. applies it through the plant link with the run loop (heartbeat, safety band, quality),
3. identifies a model from the log (orders chosen on held-out data),
4. checks it (``czmpc check-model``: fit, residuals, gain, a closed-loop Monte Carlo),
5. and, on a ``ready`` verdict, switches the MPC on for a recipe of setpoints,
   bumplessly from the input the plant applies at that moment.

The plant runs 40 times faster than real time (50 ms per 2 s sample), so the 50 min
test and the 30 min run take about 2 min of wall time. The served plant writes its own
log (``--log``) with the *true* power, which no controller sees; the figure draws it.
"""

import csv
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from czmpc.commissioning.journey import JourneyPlan, commission
from czmpc.runtime.config import load_run_config
from czmpc.runtime.served import SERVED_NODE_IDS

TIME_SCALE = 40.0
work = Path(tempfile.mkdtemp(prefix="czmpc-commission-"))
recipe = work / "recipe.csv"
recipe.write_text("time_s,setpoint_kw\n0,38\n600,42\n1200,46\n", encoding="utf-8")

plan = JourneyPlan(range_pct=(35.0, 60.0), tau_s=250.0, out_dir=work / "out", kind="multilevel",
                   duration_s=3000.0, max_step_pct=5.0, switch_on=True, run_duration_s=1800.0,
                   mc_runs=5)
# ``czmpc plant serve`` in a process of its own, on a free port of 127.0.0.1.
with socket.socket() as sock:
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
endpoint = f"opc.tcp://127.0.0.1:{port}/czmpc/"
server = subprocess.Popen(
    [sys.executable, "-m", "czmpc.cli", "plant", "serve", "--endpoint", endpoint,
     "--time-scale", f"{TIME_SCALE:g}", "--plant", "heater", "--gain-factor", "0.8",
     "--seed", "3", "--log", str(work / "plant.csv"), "--watchdog-s", "600",
     "--safe-triac-pct", "45"],
    stdout=open(work / "serve.log", "w"), stderr=subprocess.STDOUT)
while server.poll() is None:                  # wait until it listens
    with socket.socket() as sock:
        if sock.connect_ex(("127.0.0.1", port)) == 0:
            break
    time.sleep(0.2)
try:
    # The run config: the served heater's nodes, the recipe, a safety band for the test.
    nodes = "\n".join(f'{k} = "{SERVED_NODE_IDS[k]}"'
                      for k in ("power_kw", "triac_pct", "applied_triac_pct", "heartbeat"))
    (work / "run.toml").write_text(
        f'[plant]\nendpoint = "{endpoint}"\nts_s = 2\ntime_scale = {TIME_SCALE:g}\n'
        f'max_sample_age_s = 4\n[nodes]\n{nodes}\n[run]\nlog = "run.csv"\n'
        f'schedule = "{recipe}"\n[safety]\nsafe_triac_pct = 45\n'
        "[test]\npower_band_kw = [15, 80]\nmax_bad_quality_s = 60.0\n", encoding="utf-8")
    config = load_run_config(work / "run.toml")
    result = commission(config, plan, progress=print)
finally:
    server.send_signal(signal.SIGINT)     # it writes its log and exits (1-2 s when idle)
    try:
        server.wait(60)
    except subprocess.TimeoutExpired:     # a machine too busy to let it finish
        server.kill()
        server.wait()

print(f"journey ended: {result.stage}; verdict {result.check.verdict if result.check else None}; "
      f"held-out fit {result.fit_pct if result.fit_pct is not None else float('nan'):.1f} %")
for reason in result.check.reasons if result.check else ():
    print("  reason:", reason)

# %%
# The test and the run, from the two run logs, with the true power from the plant's log
# (lined up by wall time). Time is plant time from the start of the test.


def columns(path, *names):
    with open(path, newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh) if r.get(names[0])]
    return [np.array([float(r[n]) for r in rows]) for n in names]


plant_wall, plant_true = columns(work / "plant.csv", "wall_time_s", "power_true_kw")
test_wall, test_power, test_input = columns(result.out_dir / "test_run.csv", "wall_time_s",
                                            "power_kw", "applied_triac_pct")
t0 = test_wall[0]


def plant_time_h(wall):
    return (wall - t0) * TIME_SCALE / 3600.0


fig, (ax_p, ax_u) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
ax_p.plot(plant_time_h(test_wall), test_power, lw=0.7, color="C1", label="measured (test)")
ax_u.plot(plant_time_h(test_wall), test_input, lw=0.8, color="C0", label="test input")
if result.stage == "switched on":
    run_wall, run_power, run_sp, run_input = columns(
        result.out_dir / "run.csv", "wall_time_s", "power_kw", "setpoint_kw", "triac_pct")
    ax_p.plot(plant_time_h(run_wall), run_power, lw=0.7, color="C2", label="measured (MPC on)")
    ax_p.step(plant_time_h(run_wall), run_sp, where="post", color="k", lw=1.0, label="setpoint")
    ax_u.plot(plant_time_h(run_wall), run_input, lw=0.8, color="C2", label="MPC command")
    ax_p.axvspan(plant_time_h(test_wall[-1]), plant_time_h(run_wall[0]), color="0.9",
                 label="identify + check")
ax_p.plot(plant_time_h(plant_wall), plant_true, lw=0.6, color="0.3", ls=":",
          label="true power (plant log)")
ax_p.set_ylabel("power P [kW]")
ax_p.set_title(f"commissioning through OPC UA: verdict "
               f"{result.check.verdict if result.check else 'none'}, {result.stage}")
ax_p.legend(fontsize=7, ncol=2)
ax_u.set_ylabel("TRIAC input s [%]")
ax_u.set_xlabel("plant time [h]")
ax_u.legend(fontsize=7)
fig.tight_layout()

# %%
# The journey leaves every file a commissioning engineer needs in its output
# directory: the designed test, the test's run log and provenance, the model with its
# check verdict beside it, the identification report, ``commissioning.md`` with its
# figures, and the MPC's run log after switch-on.
print(sorted(p.name for p in result.out_dir.iterdir()))
