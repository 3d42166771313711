"""Helpers of the commissioning tests: a served plant as a subprocess, configs (imported as
commissioning_rig)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from benchmarks._serving import free_loopback_port as free_port  # noqa: F401  (the tests import it from here)
from benchmarks._serving import serving
from czmpc.runtime.served import SERVED_NODE_IDS

#: Every loopback test runs the plant at this many samples per Ts (period 2 s / 50 = 40 ms).
TIME_SCALE = 50.0
#: The journey tests identify a model from the loopback test: at 40 ms periods an OPC UA
#: read-step-write (about 25 ms median, 76 ms p99, BENCHMARKS.md) overruns often enough
#: to corrupt the identification now and then; at 100 ms it does not. So their plant
#: samples every 5 s (`fast_heater_model` at ``ts_s = JOURNEY_TS_S``: the same
#: difference equation, so the same journey in samples), at a time scale of 50.
JOURNEY_TS_S = 5.0
JOURNEY_TIME_SCALE = 50.0

NODES = {k: SERVED_NODE_IDS[k]
         for k in ("power_kw", "triac_pct", "applied_triac_pct", "heartbeat", "mode")}


@contextlib.contextmanager
def served_plant(tmp_path: Path, *args: str, duration_s: float,
                 time_scale: float = TIME_SCALE) -> Iterator[str]:
    """``czmpc plant serve ARGS`` on a free loopback port (output in ``serve.log``)."""
    with serving(*args, output=tmp_path / "serve.log", time_scale=time_scale,
                 duration_s=duration_s) as endpoint:
        yield endpoint


def write_config(tmp_path: Path, endpoint: str, *, band_kw: tuple[float, float],
                 safe_triac_pct: float = 40.0, model: str | None = None,
                 extra: str = "", time_scale: float = TIME_SCALE, ts_s: float = 2.0) -> Path:
    """A run config for the served plant (no [controller] unless ``model``)."""
    nodes = "\n".join(f'{k} = "{v}"' for k, v in NODES.items())
    text = (f'[plant]\nendpoint = "{endpoint}"\nts_s = {ts_s:g}\ntime_scale = {time_scale:g}\n'
            f"max_sample_age_s = 1.0\n[nodes]\n{nodes}\n"
            + (f'[controller]\nmodel = "{model}"\n[run]\nsetpoint_kw = 45.0\nlog = "run.csv"\n'
               if model else '[run]\nlog = "run.csv"\n')
            + f"[safety]\nsafe_triac_pct = {safe_triac_pct:g}\n"
            f"[test]\npower_band_kw = [{band_kw[0]:g}, {band_kw[1]:g}]\nmax_bad_quality_s = 10.0\n"
            + extra)
    path = tmp_path / "run.toml"
    path.write_text(text, encoding="utf-8")
    return path


def write_schedule(path: Path, times_s: list[float], triac_pct: list[float]) -> Path:
    """A time_s,triac_pct schedule file."""
    rows = "".join(f"{t:g},{u:g}\n" for t, u in zip(times_s, triac_pct, strict=True))
    path.write_text("time_s,triac_pct\n" + rows, encoding="utf-8")
    return path


def fast_heater_model(path: Path, ts_s: float = 2.0) -> Path:
    """A model plant shaped like the shipped heater model but ~6 times faster (for CI).

    Its slow mode has a1 = -0.95 (time constant -Ts / ln 0.95 = 39 s at Ts = 2 s, against
    about 250 s for the shipped model; `fast_tau_s`), b2 = -0.96 (static gain 0.8 of the
    instantaneous one, as the heater's sag), the shipped f(ds) and C, noise std 0.05 kW.
    """
    import json

    from czmpc.shipped import shipped_path

    doc = json.loads(shipped_path("cz_heater_model.json").read_text(encoding="utf-8"))
    doc.update({"A": [1.0, -0.95], "B": [0.0, 1.0, -0.96], "noise_std_kw": 0.05,
                "covariance": None, "ts_s": ts_s})
    doc.pop("covariance")
    doc["provenance"] = {"what": "test plant: the shipped heater model made faster"}
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


def fast_tau_s(ts_s: float = 2.0) -> float:
    """Time constant of `fast_heater_model`'s slow mode [s]: -Ts / ln 0.95."""
    import math

    return -ts_s / math.log(0.95)


#: ... at Ts = 2 s (39 s).
FAST_TAU_S = 39.0
