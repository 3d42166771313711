"""`czmpc plant history` against czmpc's served plant historizing on loopback, and its grid rules.

The loopback test serves the model plant (`czmpc plant serve --historize FILE.sqlite`,
its own process, time scale 50) with a sensor fault in the middle, drives its command node
with a seeded generalized binary noise, then runs the real command and compares its
log sample for sample with (a) the server's history read independently with asyncua's
own `read_raw_history` and (b) the plant log, which records every published sample.
"""

from __future__ import annotations

import asyncio
import csv
import datetime as dt
import json
import math
from pathlib import Path

import asyncua
import numpy as np
import pytest
from asyncua import ua
from plant_rig import TIME_SCALE, free_port, with_served

from benchmarks._serving import serving
from czmpc.cli import main
from czmpc.cli._plant_history import utc_time
from czmpc.runtime.history import NodeHistory, align_history, grid_slots, read_node_history
from czmpc.runtime.node_types import NodeSpec
from czmpc.runtime.runlog import read_run_log
from czmpc.runtime.secure_client import connect
from czmpc.runtime.security import INSECURE_LOOPBACK
from czmpc.runtime.served import SERVED_NODE_IDS, ServedPlant, ServeOptions
from czmpc.shipped import shipped_path
from sim.model_plant import ModelPlant
from sysid.modelfile import load_model

TS_S = 2.0
PERIOD_S = TS_S / TIME_SCALE
#: Samples driven: enough for identify's orders search around a 20-sample gap.
N_DRIVEN = 420
#: The sensor fault: plant time [s] and length [s] (20 samples of Bad quality).
FAULT_AT_S, FAULT_S = 500.0, 40.0
#: The plant log prints the published power with 9 significant digits.
PLANT_LOG_RTOL = 1e-8


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _gbn_commands(rng: np.random.Generator) -> list[tuple[int, float]]:
    """(hold [samples], command [%]) pairs adding up to `N_DRIVEN` samples."""
    steps: list[tuple[int, float]] = []
    total = 0
    level = 45.0
    while total < N_DRIVEN:
        hold = int(rng.integers(4, 16))
        level = round(float(np.clip(level + rng.choice([-1, 1]) * rng.uniform(4, 10), 30, 60)), 1)
        steps.append((hold, level))
        total += hold
    return steps


async def _drive(endpoint: str, steps: list[tuple[int, float]]) -> None:
    async with asyncua.Client(endpoint, timeout=5.0) as client:
        node = client.get_node(SERVED_NODE_IDS["triac_pct"])
        for hold, level in steps:
            await node.write_value(ua.DataValue(ua.Variant(level, ua.VariantType.Double)))
            await asyncio.sleep(hold * PERIOD_S)


async def _historized(endpoint: str, start: dt.datetime, end: dt.datetime,
                      ) -> dict[str, list[ua.DataValue]]:
    """The served plant's history, read with asyncua's own client code (not czmpc's)."""
    async with asyncua.Client(endpoint, timeout=5.0) as client:
        return {key: await client.get_node(SERVED_NODE_IDS[key]).read_raw_history(start, end)
                for key in ("power_kw", "applied_triac_pct")}


def _write_config(path: Path, endpoint: str, power_node: str) -> Path:
    path.write_text(
        f'[plant]\nendpoint = "{endpoint}"\nts_s = {TS_S}\ntime_scale = {TIME_SCALE}\n'
        f'[nodes]\npower_kw = "{power_node}"\ntriac_pct = "{SERVED_NODE_IDS["triac_pct"]}"\n'
        f'applied_triac_pct = "{SERVED_NODE_IDS["applied_triac_pct"]}"\n', encoding="utf-8")
    return path


def _stamp(dv: ua.DataValue) -> float:
    ts = dv.SourceTimestamp
    return (ts if ts.tzinfo else ts.replace(tzinfo=dt.UTC)).timestamp()


@pytest.mark.slow
@pytest.mark.realtime
def test_history_returns_what_the_plant_historized_and_identify_reads_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = tmp_path / "fault.toml"
    scenario.write_text(
        'name = "sensor fault"\nduration_s = 4000.0\nts_s = 2.0\ninitial_setpoint_kw = 45.0\n'
        f'[[fault]]\nkind = "missing_samples"\nat_s = {FAULT_AT_S}\nduration_s = {FAULT_S}\n',
        encoding="utf-8")
    plant_log = tmp_path / "plant.csv"
    steps = _gbn_commands(np.random.default_rng(11))
    with serving("--plant", "model", "--seed", "3", "--scenario", str(scenario),
                 "--log", str(plant_log), "--historize", str(tmp_path / "history.sqlite"),
                 "--history-page-values", "64",
                 output=tmp_path / "serve.out", time_scale=TIME_SCALE) as endpoint:
        start = dt.datetime.now(dt.UTC)
        asyncio.run(_drive(endpoint, steps))
        end = dt.datetime.now(dt.UTC)
        config = _write_config(tmp_path / "run.toml", endpoint, SERVED_NODE_IDS["power_kw"])
        out = tmp_path / "history.csv"
        window = ["--from", start.isoformat(), "--to", end.isoformat().replace("+00:00", "Z")]
        assert main(["plant", "history", str(config), *window, "--out", str(out),
                     "--page-values", "100"]) == 0
        # a client page below the server's: asyncua ends a full page without a
        # continuation point, and the read resumes from the last time stamp
        out_small = tmp_path / "history_small_pages.csv"
        assert main(["plant", "history", str(config), *window, "--out", str(out_small),
                     "--page-values", "30"]) == 0
        # never over an earlier output, unless --force
        assert main(["plant", "history", str(config), *window, "--out", str(out)]) == 2
        assert "exists: give another --out, or --force" in capsys.readouterr().err
        # a node the server does not historize: exit 2 naming the node and the fix
        unhistorized = _write_config(tmp_path / "bad.toml", endpoint, "ns=2;s=Heater.PlantTime_s")
        assert main(["plant", "history", str(unhistorized), *window, "--out",
                     str(tmp_path / "none.csv")]) == 2
        err = capsys.readouterr().err
        assert "Heater.PlantTime_s" in err and "enable historizing for that tag" in err
        historized = asyncio.run(_historized(endpoint, start, end))

    rows = _rows(out)
    meta = json.loads(out.with_suffix(".meta.json").read_text(encoding="utf-8"))
    assert meta["kind"] == "history" and meta["endpoint"] == endpoint
    # continuation points: the server pages after 64 values, so ~420 values take 7+ requests
    power_values = historized["power_kw"]
    assert meta["values"]["power_kw"] == len(power_values) > N_DRIVEN * 0.9
    assert meta["continuation_points"]["power_kw"] >= len(power_values) // 64 >= 5
    assert meta["requests"]["power_kw"] == meta["continuation_points"]["power_kw"] + 1
    small_meta = json.loads(out_small.with_suffix(".meta.json").read_text(encoding="utf-8"))
    assert small_meta["resumed_requests"]["power_kw"] >= len(power_values) // 30 - 1
    assert out_small.read_text(encoding="utf-8") == out.read_text(encoding="utf-8")

    # (a) sample for sample: every historized power value is one row, in order, exact
    sampled = [r for r in rows if r["quality"] != "missing"]
    assert len(sampled) == len(power_values)
    for row, dv in zip(sampled, power_values, strict=True):
        assert float(row["wall_time_s"]) == pytest.approx(_stamp(dv), abs=1e-6)
        if dv.StatusCode.is_good():
            assert row["quality"] == "good" and float(row["power_kw"]) == dv.Value.Value
        else:
            assert row["quality"] == "bad" and row["power_kw"] == "nan"
    applied_times = np.array([_stamp(dv) for dv in historized["applied_triac_pct"]])

    # (b) the plant log: each row at its plant sample index, the fault's samples gaps
    plant = _rows(plant_log)
    plant_power = np.array([float(r["power_measured_kw"]) for r in plant])
    first_good = next(r for r in rows if r["quality"] == "good")
    k0 = int(np.flatnonzero(np.isclose(plant_power, float(first_good["power_kw"]),
                                       rtol=PLANT_LOG_RTOL, atol=0.0))[0]) - int(first_good["k"])
    fault = range(int(FAULT_AT_S / TS_S), int((FAULT_AT_S + FAULT_S) / TS_S))
    n_good = 0
    for row in rows:
        k = k0 + int(row["k"])
        if row["quality"] == "good":
            n_good += 1
            assert plant[k]["quality"] == "good" and k not in fault
            np.testing.assert_allclose(float(row["power_kw"]), plant_power[k],
                                       rtol=PLANT_LOG_RTOL, atol=0.0)
            # the applied input that produced this sample, as the plant applied it (asyncua
            # returns no bounding value: unknown until its first change in the range)
            applied = float(row["applied_triac_pct"])
            assert applied == float(plant[k]["triac_applied_pct"]) or (
                math.isnan(applied) and applied_times[0] > float(row["wall_time_s"]))
        else:
            assert k in fault or plant[k]["quality"] == "good"   # bad only in the fault
    in_range = range(k0, k0 + len(rows))
    assert all(k in in_range for k in fault)
    assert all(rows[k - k0]["quality"] in ("bad", "missing") for k in fault)
    assert sum(1 for r in rows if r["quality"] == "bad") == 1   # the status change; then none
    print(f"history: {len(rows)} rows, {n_good} good, {len(power_values)} power values; plant "
          f"published {sum(1 for k in in_range if plant[k]['quality'] == 'good')} good samples "
          f"in the range; {meta['requests']['power_kw']} requests, "
          f"{meta['continuation_points']['power_kw']} continuation points")

    # identify reads the output: two segments around the fault
    data = read_run_log(out)
    assert data.n_segments == 2
    assert main(["identify", str(out), "--out", str(tmp_path / "identified")]) == 0
    assert (tmp_path / "identified" / "model.json").is_file()


def _history(key: str, times_s: list[float], values: list[float],
             qualities: list[str] | None = None) -> NodeHistory:
    return NodeHistory(key=key, node_id=key, epoch_s=tuple(times_s), values=tuple(values),
                       qualities=tuple(qualities or ["good"] * len(times_s)), n_requests=1)


def test_a_backlog_stamped_at_once_takes_the_slots_before_the_next_sample() -> None:
    # samples 0..7 every 1 s; 3, 4, 5 published late together at 5.4 s; 7 missing
    times = np.array([0.0, 1.0, 2.0, 5.4, 5.4, 5.4, 6.0, 8.0]) + 1e9
    slots, moved = grid_slots(times, 1.0, 1e9)
    assert slots.tolist() == [0, 1, 2, 3, 4, 5, 6, 8] and moved == 2


def test_align_marks_missing_and_bad_slots_as_gaps_and_holds_the_inputs() -> None:
    t0 = 1.7e9 + 0.013   # a phase off the whole second
    power = _history("power_kw", [t0, t0 + 1.02, t0 + 1.98, t0 + 4.01],
                     [40.0, 41.0, math.nan, 43.0], ["good", "good", "bad", "good"])
    # changes only: 30 % from before the range, 35 % from sample 2 on (stamped just after it)
    applied = _history("applied_triac_pct", [t0 - 50.0, t0 + 2.0001], [30.0, 35.0])
    aligned = align_history(power, applied, period_s=1.0)
    assert aligned.quality == ("good", "good", "bad", "missing", "good")
    np.testing.assert_array_equal(aligned.power_kw, [40.0, 41.0, np.nan, np.nan, 43.0])
    np.testing.assert_array_equal(aligned.applied_triac_pct, [30.0, 30.0, 35.0, 35.0, 35.0])
    assert np.isnan(aligned.triac_pct).all()
    # a command written between samples 1 and 2 acts from sample 1 to 2
    command = _history("triac_pct", [t0 + 1.5], [50.0])
    aligned = align_history(power, command=command, period_s=1.0)
    np.testing.assert_array_equal(aligned.triac_pct, [np.nan, 50.0, 50.0, 50.0, 50.0])


@pytest.mark.slow
@pytest.mark.realtime
def test_history_in_memory_pages_by_continuation_points_and_by_resumed_requests() -> None:
    plant = ModelPlant(load_model(shipped_path("cz_heater_model.json")), noise=True)
    plant.reset(5)
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/czmpc/"
    served = ServedPlant(plant, initial_triac_pct=45.0, options=ServeOptions(
        endpoint=endpoint, time_scale=TIME_SCALE, watchdog_s=None, historize=True,
        history_page_values=10))
    power = NodeSpec(SERVED_NODE_IDS["power_kw"])

    async def body() -> None:
        start = dt.datetime.now(dt.UTC)
        await asyncio.sleep(40 * PERIOD_S)
        end = dt.datetime.now(dt.UTC)
        client = await connect(endpoint, INSECURE_LOOPBACK, timeout_s=5.0)
        try:
            node = client.get_node(power.node_id)
            reference = [(_stamp(dv), dv.Value.Value)
                         for dv in await node.read_raw_history(start, end)]
            # the server's page (10) is below the client's: continuation points
            paged = await read_node_history(client, "power_kw", power, start=start, end=end,
                                            page_values=100, deadline_s=5.0)
            # the client's page (4) is below the server's: full pages without one, resumed
            resumed = await read_node_history(client, "power_kw", power, start=start, end=end,
                                              page_values=4, deadline_s=5.0)
        finally:
            await client.disconnect()
        assert len(reference) >= 30
        for history in (paged, resumed):
            assert list(zip(history.epoch_s, history.values, strict=True)) == reference
        assert paged.n_continuations == (len(reference) - 1) // 10 and paged.n_resumed == 0
        assert resumed.n_resumed >= len(reference) // 4 - 1 and resumed.n_continuations == 0

    asyncio.run(with_served(served, body()))


def test_history_refuses_a_bad_range_and_says_when_the_plant_is_unreachable(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert utc_time("2026-11-26T06:00:00") == dt.datetime(2026, 11, 26, 6, tzinfo=dt.UTC)
    assert utc_time("2026-11-26T08:00:00+02:00") == dt.datetime(2026, 11, 26, 6, tzinfo=dt.UTC)
    config = _write_config(tmp_path / "run.toml", f"opc.tcp://127.0.0.1:{free_port()}/czmpc/",
                           SERVED_NODE_IDS["power_kw"])
    out = str(tmp_path / "h.csv")
    assert main(["plant", "history", str(config), "--from", "2026-11-26T07:00:00Z", "--to",
                 "2026-11-26T06:00:00Z", "--out", out]) == 2
    assert "--from must be before --to" in capsys.readouterr().err
    with pytest.raises(SystemExit) as usage:
        main(["plant", "history", str(config), "--from", "yesterday", "--to", "2026-11-26T06:00:00Z",
              "--out", out])
    assert usage.value.code == 2
    assert "expected an ISO 8601 time in UTC" in capsys.readouterr().err
    # nobody listens on that port: a network fault, exit 1, and nothing written
    assert main(["plant", "history", str(config), "--from", "2026-11-26T05:00:00Z", "--to",
                 "2026-11-26T06:00:00Z", "--out", out]) == 1
    assert "czmpc: error:" in capsys.readouterr().err
    assert not (tmp_path / "h.csv").exists()
