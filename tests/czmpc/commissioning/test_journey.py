"""`czmpc commission` on loopback: from a bare (served) heater to a running MPC.

The served plant is `commissioning_rig.fast_heater_model` sampled every 5 s (time
constant 97 s) at a time scale of 50 (100 ms periods), so each journey takes about a
minute of wall time.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from commissioning_rig import (
    JOURNEY_TIME_SCALE,
    JOURNEY_TS_S,
    fast_heater_model,
    fast_tau_s,
    served_plant,
    write_config,
)

from czmpc.commissioning.journey import JourneyPlan, commission
from czmpc.runtime.config import load_run_config
from czmpc.runtime.runlog import read_run_meta

pytest.importorskip("asyncua")
pytestmark = [pytest.mark.slow, pytest.mark.realtime]

#: The issue's offset-free bound: |mean error| over the last 20 samples [kW].
OFFSET_FREE_ATOL_KW = 0.1
#: The band the test visits [%]: at least `czmpc.commissioning.check.GOOD_RANGE_PCT` wide,
#: so that its width is no condition on the verdict.
RANGE_PCT = (36.0, 54.0)
#: The served plant's watchdog [plant s]: 12 samples. Its default (10 s, 5 samples at Ts
#: 2 s) is 0.2 s of wall time at Ts 5 s and a time scale of 50, which one slow step on a
#: busy machine exceeds: the plant then sat at its safe input until the next move.
WATCHDOG_S = "60"
#: Held-out fit [%] the identified model reaches on the noise-light fast plant
#: (measured 91 % with overruns at a time scale of 50 on a busy machine).
MIN_FIT_PCT = 75.0


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_commission_then_switch_on_tracks_offset_free(tmp_path: Path) -> None:
    plant = fast_heater_model(tmp_path / "plant.json", ts_s=JOURNEY_TS_S)
    with served_plant(tmp_path, "--plant", "model", "--model", str(plant), "--initial-triac-pct",
                      "45", "--safe-triac-pct", "40", "--watchdog-s", WATCHDOG_S,
                      duration_s=50000.0, time_scale=JOURNEY_TIME_SCALE) as endpoint:
        path = write_config(tmp_path, endpoint, band_kw=(20.0, 70.0),
                            time_scale=JOURNEY_TIME_SCALE, ts_s=JOURNEY_TS_S)
        path.write_text(path.read_text(encoding="utf-8").replace(
            '[run]\nlog = "run.csv"\n', '[run]\nlog = "run.csv"\nsetpoint_kw = 44.0\n'),
            encoding="utf-8")
        config = load_run_config(path)
        plan = JourneyPlan(range_pct=RANGE_PCT, tau_s=fast_tau_s(JOURNEY_TS_S),
                           out_dir=tmp_path / "out", kind="steps", max_step_pct=5.0,
                           switch_on=True, run_duration_s=750.0, mc_runs=5)
        result = commission(config, plan)
    out = tmp_path / "out"
    # the real check-model verdict on the commissioned model: measured 'ready' in 9 of 9
    # loopback journeys once validation scored no fitted initial state (before: 'ready
    # with conditions' in about one of eight, a cancelling pole-zero pair chosen)
    assert result.check is not None and result.check.verdict == "ready", result.check
    assert result.stage == "switched on" and result.ok, result.messages
    assert any(p.name.startswith("model") and p.name.endswith(".check.json")
               for p in out.iterdir())   # the verdict file beside the model
    assert result.fit_pct is not None and result.fit_pct > MIN_FIT_PCT
    for name in ("test.csv", "test_run.csv", "test_run.meta.json", "model.json",
                 "identification/report.md", "commissioning.md", "figures/test.png",
                 "figures/fit.png", "run.csv"):
        assert (out / name).is_file(), name
    report = (out / "commissioning.md").read_text(encoding="utf-8")
    assert "**ready**" in report and "switched on" in report
    rows = [r for r in _rows(out / "run.csv") if r["k"]]
    assert read_run_meta(out / "run.csv")["kind"] == "MPC run after commissioning"
    # bumpless: the MPC's first move starts from the input the plant applied
    rate = 0.05 * (RANGE_PCT[1] - RANGE_PCT[0])   # rate limit: 5 % of the input range/sample
    first_applied = float(rows[0]["applied_triac_pct"])
    assert abs(float(rows[0]["triac_pct"]) - first_applied) <= rate + 1e-6
    power = np.array([float(r["power_kw"]) for r in rows[-20:] if r["quality"] == "good"])
    assert power.size >= 15
    assert abs(float(power.mean()) - 44.0) < OFFSET_FREE_ATOL_KW
