"""`czmpc run --test` on loopback against `czmpc plant serve` (time scale 50, bounded).

The served plant is a model plant (noise on; `commissioning_rig.fast_heater_model` for
the identification, so that a short staircase settles), so the identified model can
be compared with the truth.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from commissioning_rig import (
    FAST_TAU_S,
    fast_heater_model,
    served_plant,
    write_config,
    write_schedule,
)

from czmpc.cli import main
from czmpc.shipped import shipped_path
from sysid.design import ExcitationSpec, design_test_signal
from sysid.modelfile import load_model

pytest.importorskip("asyncua")
pytestmark = [pytest.mark.slow, pytest.mark.realtime]

#: Mean static gain over the test band [kW/%] of the identified model against the served
#: model's: 550 samples of a 4-level staircase held 4 time constants each pin it to a
#: few %; at a time scale of 50 on a busy machine the loop's 40 ms period overruns
#: (skipped periods are gaps, reads straddle plant ticks), which costs accuracy
#: (measured: 4 % off with 133 overruns in 554 periods); a model of the wrong sign,
#: units or input column misses by far more.
STATIC_GAIN_RTOL = 0.15


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_a_short_test_completes_and_its_log_identifies(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    spec = ExcitationSpec(ts_s=2.0, lo_pct=38.0, hi_pct=52.0, tau_s=FAST_TAU_S,
                          duration_s=1100.0, kind="steps", degree=2, max_step_pct=5.0)
    sig = design_test_signal(spec, np.random.default_rng(0))
    sched = write_schedule(tmp_path / "test.csv", list(sig.time_s), list(sig.triac_pct))
    plant_model = fast_heater_model(tmp_path / "plant.json")
    with served_plant(tmp_path, "--plant", "model", "--model", str(plant_model),
                      "--initial-triac-pct", "45", duration_s=3000.0) as endpoint:
        cfg = write_config(tmp_path, endpoint, band_kw=(20.0, 70.0))
        code = main(["run", str(cfg), "--test", str(sched)])
    assert code == 0
    rows = _rows(tmp_path / "run.csv")
    data = [r for r in rows if r["k"]]
    assert data[-1]["event"] == "end of schedule"
    assert float(data[-1]["time_s"]) >= 1100.0
    # bumpless: from the plant's 45 % to the schedule's 38 % in moves of at most 5 %
    u = [float(r["triac_pct"]) for r in data]
    assert abs(u[0] - 45.0) <= 5.0 + 1e-9
    assert max(abs(b - a) for a, b in zip(u, u[1:], strict=False)) <= 5.0 + 1e-9
    assert {r["status"] for r in data} <= {"LEAD_IN", "TEST"}
    meta = json.loads((tmp_path / "run.meta.json").read_text(encoding="utf-8"))
    assert meta["kind"] == "open-loop test" and len(meta["schedule_sha256"]) == 64

    out = tmp_path / "id"
    code = main(["identify", str(tmp_path / "run.csv"), "--out", str(out), "--orders", "paper",
                 "--allow-unconverged"])
    assert code == 0
    assert "czmpc run log (open-loop test)" in capsys.readouterr().err
    model = load_model(out / "model.json")
    truth = load_model(plant_model)
    band = np.array([38.0, 52.0])
    gain_id = np.diff(model.steady_state_power_kw(band))[0] / 14.0
    gain_true = np.diff(truth.steady_state_power_kw(band))[0] / 14.0
    assert gain_id == pytest.approx(gain_true, rel=STATIC_GAIN_RTOL)
    prov = model.provenance.preprocessing[0]
    assert prov["what"] == "czmpc run log"
    assert prov["schedule_sha256"] == meta["schedule_sha256"]
    assert prov["start_utc"] == meta["start_utc"]


def test_a_test_leaving_the_band_aborts_to_the_safe_value(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    # up to 60 %: the served model's power passes 50 kW on the way (about 1.3 kW/%)
    sched = write_schedule(tmp_path / "test.csv", [0.0, 20.0, 200.0], [45.0, 60.0, 45.0])
    with served_plant(tmp_path, "--plant", "model", "--initial-triac-pct", "45",
                      duration_s=1200.0) as endpoint:
        cfg = write_config(tmp_path, endpoint, band_kw=(30.0, 50.0), safe_triac_pct=30.0)
        code = main(["run", str(cfg), "--test", str(sched)])
    assert code == 1
    err = capsys.readouterr().err
    assert "test aborted" in err and "above the test band" in err
    rows = _rows(tmp_path / "run.csv")
    # other events (the loop moving its reads to just after the plant publishes) may be
    # logged too; exactly one abort
    aborts = [r["event"] for r in rows if r["event"].startswith("ABORT")]
    assert len(aborts) == 1 and aborts[0].startswith("ABORT: measured power")
    abort_at = next(i for i, r in enumerate(rows) if r["event"].startswith("ABORT"))
    assert float(rows[abort_at]["power_kw"]) > 50.0
    # then the safe ramp to 30 % at the schedule's largest step (15 %) per sample
    ramp = [float(r["triac_pct"]) for r in rows[abort_at + 1:]]
    assert all(r["status"] == "SAFE_RAMP" for r in rows[abort_at + 1:])
    assert ramp[-1] == 30.0
    moves = np.abs(np.diff([float(rows[abort_at]["triac_pct"]), *ramp]))
    assert moves.max() <= 15.0 + 1e-9


def test_a_dithered_mpc_run_identifies_as_closed_loop_data(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = str(shipped_path("cz_heater_model.json"))
    with served_plant(tmp_path, "--plant", "model", "--initial-triac-pct", "45",
                      duration_s=3000.0) as endpoint:
        cfg = write_config(tmp_path, endpoint, band_kw=(20.0, 70.0), model=model)
        # seed 12 switches the dither 5 times in its first 200 samples (p = Ts / 249 s)
        code = main(["run", str(cfg), "--dither-pct", "1.5", "--dither-seed", "12",
                     "--duration-s", "600"])
    assert code == 0
    err = capsys.readouterr().err
    assert "GBN dither on the MPC's input" in err
    meta = json.loads((tmp_path / "run.meta.json").read_text(encoding="utf-8"))
    assert meta["closed_loop"] is True and meta["dither"]["amplitude_pct"] == 1.5
    rows = [r for r in _rows(tmp_path / "run.csv") if r["k"]]
    # each switch moves the input by 2 x 1.5 % less the MPC's reaction, within the
    # runtime rate limit (1.6 %/sample for the shipped model's 33..65 % range) of the
    # input the plant reported applied in that period (the controller's reference: a
    # write that lands after the plant's step leaves the previous command unapplied, and
    # the next command may then differ from it by the rate limit and that gap; seen once,
    # 1.6032 %). Moves between consecutive periods only: after an overrun the loop skips
    # periods of plant time.
    k = np.array([int(r["k"]) for r in rows])
    u = np.array([float(r["triac_pct"]) for r in rows])
    applied = np.array([float(r["applied_triac_pct"]) for r in rows])
    moves = np.abs(np.diff(u))[np.diff(k) == 1]
    assert np.count_nonzero(moves > 1.0) >= 3
    from_applied = np.abs(u - applied)[np.isfinite(applied)]
    assert from_applied.size >= len(rows) - 2
    assert from_applied.max() <= 1.6 + 1e-6
    out = tmp_path / "id"
    code = main(["identify", str(tmp_path / "run.csv"), "--out", str(out), "--orders", "paper",
                 "--allow-unconverged"])
    assert code == 0
    err = capsys.readouterr().err
    assert "CLOSED-LOOP DATA" in err
    prov = load_model(out / "model.json").provenance.preprocessing[0]
    assert prov["closed_loop"] is True and prov["dither"]["where"] == "input"


def test_a_long_bad_quality_stretch_aborts_the_test(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    # the served plant's sensor drops out (Bad quality) for 60 s from 300 s of plant time
    scenario = tmp_path / "dropout.toml"
    scenario.write_text(
        'name = "dropout"\ndescription = "sensor dropout"\nduration_s = 3000\nts_s = 2.0\n'
        "plant_noise = true\ninitial_setpoint_kw = 45.0\ninitial_triac_pct = 45.0\n"
        '[[fault]]\nkind = "missing_samples"\nat_s = 300\nduration_s = 60\n', encoding="utf-8")
    sched = write_schedule(tmp_path / "test.csv", [0.0, 100.0, 900.0], [45.0, 47.0, 45.0])
    with served_plant(tmp_path, "--plant", "model", "--initial-triac-pct", "45", "--scenario",
                      str(scenario), duration_s=2900.0) as endpoint:
        cfg = write_config(tmp_path, endpoint, band_kw=(20.0, 70.0), safe_triac_pct=40.0)
        code = main(["run", str(cfg), "--test", str(sched)])
    assert code == 1
    assert "max_bad_quality_s" in capsys.readouterr().err
    rows = _rows(tmp_path / "run.csv")
    abort_at = next(i for i, r in enumerate(rows) if r["event"].startswith("ABORT"))
    assert rows[abort_at]["quality"] == "bad"
    # aborted once the Bad stretch exceeded 10 s of plant time (rows may skip periods
    # after overruns on a busy machine, so plant time is what counts)
    last_good = max(i for i in range(abort_at) if rows[i]["quality"] == "good")
    bad_s = float(rows[abort_at]["time_s"]) - float(rows[last_good]["time_s"])
    assert 10.0 < bad_s <= 20.0
    assert float(rows[-1]["triac_pct"]) == 40.0 and rows[-1]["status"] == "SAFE_RAMP"
