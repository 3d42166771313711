"""
The paper's pipeline on the shipped experiment
==============================================

The shipped log is the paper's identification experiment run on the virtual heater
(``czmpc.data/cz_heater_experiment.csv``). `sysid.run_paper_pipeline` runs secs. 5-7 of
the paper on it: operating point, outlier repair, the linear models of Table 2, the step
gains of Table 3 and the Hammerstein route, ending with the Hammerstein model with a noise
model (eq. 30).
"""

import matplotlib.pyplot as plt

import sysid
from czmpc.shipped import EXPERIMENT_CSV, shipped_path

data = sysid.read_csv(shipped_path(EXPERIMENT_CSV))
result = sysid.run_paper_pipeline(data)
model = result.final.model
print(f"{data.time_s.size} samples at Ts = {data.ts_s} s")
print(f"final model: {result.final.label}")
print(f"A = {model.a.round(4).tolist()}, B = {model.b.round(4).tolist()}, C = {model.c.round(4).tolist()}")
print(f"f(ds) coefficients [kW/%, kW/%^2]: {model.input_poly.round(5).tolist()}")
print(f"V = {model.criteria.ballistic_mse_kw2:.4g} kW^2, W = {model.criteria.one_step_mse_kw2:.4g} kW^2")

# %%
# The paper's findings, as measured on these data (the checklist of the report that
# ``czmpc identify`` writes):
from czmpc.reports.identification import findings_checklist  # noqa: E402

for finding in findings_checklist(result):
    print(f"[{finding.verdict}] {finding.claim}\n    paper: {finding.paper}\n    ours:  {finding.ours}")

# %%
# The ballistic simulation of the final model against the preprocessed power (the
# pipeline's data, after the outlier repair):
simulated_kw = sysid.simulate(model, result.data)
fig, (ax_p, ax_s) = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
ax_p.plot(result.data.time_s, result.data.power_kw, lw=0.6, label="measured")
ax_p.plot(result.data.time_s, simulated_kw, lw=0.8, label="Hammerstein, ballistic")
ax_p.set_ylabel("heater power P [kW]")
ax_p.legend()
ax_s.plot(result.data.time_s, result.data.triac_pct, lw=0.8, color="k")
ax_s.set_ylabel("TRIAC input s [%]")
ax_s.set_xlabel("time [s]")
fig.tight_layout()
