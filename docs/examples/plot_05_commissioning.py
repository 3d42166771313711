"""
Commissioning a heater: design a test, run it, identify, compare
================================================================

Before the MPC goes on a new heater, the heater is identified from a test designed for
it: `sysid.design.design_test_signal` (``czmpc design-test`` on the command line) makes a
staircase across the band the controller will use, each level held several time
constants, then generalized binary noise whose mean switching time equals the plant's
time constant. Here the "plant" is the virtual heater of `sim`, the prior knowledge is the
shipped model, and the identified model is compared with that prior and with the heater's
true steady-state curve.

To keep this example short the test assumes a time constant of 120 s (8,000 s of test);
``czmpc design-test --prior model.json`` takes the prior model's slowest pole (256 s here)
and asks for at least 16,350 s, which is what a real commissioning should use
(:doc:`/guides/commission`).
"""

import matplotlib.pyplot as plt
import numpy as np

import sim
import sysid
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.heater import steady_state
from sysid.design import ExcitationSpec, design_test_signal

prior = sysid.load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))
spec = ExcitationSpec(ts_s=prior.ts_s, lo_pct=35.0, hi_pct=60.0, tau_s=120.0,
                      duration_s=8000.0, max_step_pct=5.0)
test = design_test_signal(spec, np.random.default_rng(0))
print(f"test: {test.triac_pct.size} samples, staircase levels {test.levels_pct.tolist()} %, "
      f"each held {spec.hold_samples * spec.ts_s:g} s, then GBN")


def run_on_heater(triac_pct: np.ndarray, seed: int) -> sysid.Dataset:
    """Apply the set-points to the virtual heater (one per sample) and log the power."""
    params = sim.HeaterParams(ts_s=spec.ts_s, initial_triac_pct=float(triac_pct[0]))
    heater = sim.VirtualHeater(params, rng=seed)
    power_kw = [heater.reset(seed)]
    power_kw += [heater.step(float(u)) for u in triac_pct[:-1]]
    time_s = spec.ts_s * np.arange(triac_pct.size)
    return sysid.Dataset(time_s=time_s, triac_pct=triac_pct.astype(float),
                         power_kw=np.asarray(power_kw), ts_s=spec.ts_s)


log = run_on_heater(test.triac_pct, seed=11)

# %%
# Identify with the paper's route and orders (as ``czmpc identify --orders paper``):
result = sysid.run_paper_pipeline(log, orders="paper")
model = result.final.model


def time_constant_s(m: sysid.HammersteinModel) -> float:
    return float(-m.ts_s / np.log(max(abs(np.roots(m.a)))))


for name, m in (("prior (shipped)", prior), ("identified", model)):
    slope = float(m.input_nonlinearity_slope(0.0))
    print(f"{name:16s} static gain {m.linear_static_gain:.3f}, time constant "
          f"{time_constant_s(m):.0f} s, f'(0) = {slope:.3f} kW/% at s_nom = "
          f"{m.operating_point.triac_pct:g} %")

# %%
# Validate on a second test the fit never saw (another GBN realisation and noise), and
# compare each model's steady-state power with the heater's true one (the curves agree
# within a fraction of a kW over 30 to 62 kW, so their differences are plotted):
validation = run_on_heater(design_test_signal(spec, np.random.default_rng(1)).triac_pct, seed=12)
fits = {}
for name, m in (("prior", prior), ("identified", model)):
    yhat = sysid.simulate(m, validation)
    err = validation.power_kw - yhat
    fits[name] = 100.0 * (1.0 - np.linalg.norm(err) / np.linalg.norm(
        validation.power_kw - validation.power_kw.mean()))
    print(f"{name:10s} simulation fit on the validation test: {fits[name]:.1f} %")

s_grid = np.linspace(spec.lo_pct, spec.hi_pct, 26)
true_kw = [steady_state(float(s), sim.HeaterParams())[0] for s in s_grid]
fig, axes = plt.subplots(3, 1, figsize=(8, 8))
hours = log.time_s / 3600.0
axes[0].plot(hours, log.triac_pct, lw=0.8, color="C0")
axes[0].set_ylabel("TRIAC input s [%]", color="C0")
ax_p = axes[0].twinx()
ax_p.plot(hours, log.power_kw, lw=0.6, color="C1")
ax_p.set_ylabel("power P [kW]", color="C1")
axes[0].set_xlabel("time [h]")
axes[0].set_title("the designed test on the virtual heater")
print(f"largest steady-state error over {spec.lo_pct:g}..{spec.hi_pct:g} %: prior "
      f"{np.max(np.abs(prior.steady_state_power_kw(s_grid) - true_kw)):.2f} kW, identified "
      f"{np.max(np.abs(model.steady_state_power_kw(s_grid) - true_kw)):.2f} kW")
axes[1].axhline(0.0, color="k", lw=0.8)
axes[1].plot(s_grid, prior.steady_state_power_kw(s_grid) - true_kw, "--", label="prior (shipped model)")
axes[1].plot(s_grid, model.steady_state_power_kw(s_grid) - true_kw, "-", label="identified")
axes[1].set_xlabel("TRIAC input s [%]")
axes[1].set_ylabel("steady power - true [kW]")
axes[1].set_title("steady-state error of each model against the virtual heater")
axes[1].legend(fontsize=8)
vh = validation.time_s / 3600.0
axes[2].plot(vh, validation.power_kw, lw=0.6, color="0.5", label="measured")
axes[2].plot(vh, sysid.simulate(model, validation), lw=0.8,
             label=f"identified ({fits['identified']:.1f} %)")
axes[2].plot(vh, sysid.simulate(prior, validation), lw=0.8, ls="--",
             label=f"prior ({fits['prior']:.1f} %)")
axes[2].set_xlabel("time [h]")
axes[2].set_ylabel("power P [kW]")
axes[2].set_title("validation test: simulated against measured")
axes[2].legend(fontsize=8)
fig.tight_layout()
