"""
The Hammerstein model against the linear model
==============================================

The paper's point (secs. 6-7): a linear model fits well near one operating point, but
the heater's gain falls as the input rises (Table 3), so over the whole experiment the
Hammerstein model, with one more parameter, simulates the power much better. Both shipped
models were identified from the shipped experiment.
"""

import matplotlib.pyplot as plt
import numpy as np

import sysid
from czmpc.shipped import ARMAX_MODEL_JSON, EXPERIMENT_CSV, HAMMERSTEIN_MODEL_JSON, shipped_path

data = sysid.read_csv(shipped_path(EXPERIMENT_CSV))
models = {
    "Hammerstein (eq. 30)": sysid.load_model(shipped_path(HAMMERSTEIN_MODEL_JSON)),
    "linear ARMAX": sysid.load_model(shipped_path(ARMAX_MODEL_JSON)),
}
for name, model in models.items():
    v = sysid.ballistic_mse(model, data)
    fit = sysid.fit_percent(data.power_kw, sysid.simulate(model, data))
    print(f"{name:22s} V = {v:.4f} kW^2   fit = {fit:.1f} %")

# %%
# Static nonlinearity: the instantaneous gain ``df/ds`` of each model over the input
# range of the experiment. The linear model has one gain everywhere.
fig, ax_g = plt.subplots(figsize=(6, 3.5))
for name, model in models.items():
    op = model.operating_point.triac_pct
    s_pct = np.linspace(*model.input_range_pct, 200)
    ds = s_pct - op
    slope = sum(i * p * ds ** (i - 1) for i, p in enumerate(model.input_poly, start=1))
    ax_g.plot(s_pct, slope * np.ones_like(s_pct), label=name)
ax_g.set_xlabel("TRIAC input s [%]")
ax_g.set_ylabel("instantaneous gain df/ds [kW/%]")
ax_g.legend()
fig.tight_layout()

# %%
# Ballistic simulation errors over the experiment: the linear model's error grows as the
# input moves away from the operating point.
fig, ax_e = plt.subplots(figsize=(8, 3.5))
for name, model in models.items():
    ax_e.plot(data.time_s, data.power_kw - sysid.simulate(model, data), lw=0.6, label=name)
ax_e.set_xlabel("time [s]")
ax_e.set_ylabel("measured - simulated power [kW]")
ax_e.legend()
fig.tight_layout()
