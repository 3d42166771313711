"""
The offset-free MPC on a grid-voltage sag
=========================================

The grid voltage sags by 3 % for ten minutes at a constant 45 kW setpoint (the shipped
``voltage_sag`` scenario). Heater power scales with the square of the voltage, so about
2.7 kW go at once; the controller's integrating disturbance picks the loss up and the
MPC raises the TRIAC input to hold the setpoint, then takes it back when the voltage
recovers. The plant is the virtual heater, not the controller's model: there is model
mismatch as well. The heater starts in steady state at the setpoint, and the controller is
told which input it holds (``initial_triac_pct``), as ``czmpc simulate --plant heater`` does.
"""

import matplotlib.pyplot as plt

import czmpc
import sim
import sysid
from czmpc.campaigns.build import heater_steady_state_triac_pct
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

model = sysid.load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))
scenario = sim.load_scenario("voltage_sag")
s0_pct = heater_steady_state_triac_pct(scenario.initial_setpoint_kw)
heater = sim.VirtualHeater(sim.HeaterParams(initial_triac_pct=s0_pct))
mpc = czmpc.OffsetFreeMPC(model, czmpc.MPCSettings.default_for(model).with_updates(initial_triac_pct=s0_pct))
run = sim.run_closed_loop(heater, mpc, scenario, rng=7)
metrics = sim.compute_metrics(run)
print(scenario.description)
print(f"IAE = {metrics.iae_kw_s:.1f} kW s, largest steady-state error = "
      f"{metrics.max_abs_steady_state_error_kw:.3f} kW, limit violations = {metrics.n_limit_violations}")

# %%
# Power, TRIAC input and the controller's disturbance estimate:
disturbance_kw = [d.disturbance_power_kw if d is not None else float("nan") for d in run.diagnostics or []]
fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 6))
minutes = run.time_s / 60.0
axes[0].plot(minutes, run.power_measured_kw, lw=0.5, color="0.6", label="measured")
axes[0].plot(minutes, run.power_true_kw, lw=1.0, label="true")
axes[0].plot(minutes, run.setpoint_kw, "k--", lw=0.8, label="setpoint")
axes[0].set_ylabel("power P [kW]")
axes[0].legend(loc="lower right")
axes[1].plot(minutes, run.triac_pct, lw=1.0)
axes[1].set_ylabel("TRIAC input s [%]")
axes[2].plot(minutes, disturbance_kw, lw=1.0)
axes[2].set_ylabel("disturbance d [kW]")
axes[2].set_xlabel("time [min]")
fig.tight_layout()
