"""Helpers of the commissioning tests: a served plant as a subprocess, configs (imported as
commissioning_rig)."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

#: Every loopback test runs the plant at this many samples per Ts (period 2 s / 50 = 40 ms).
TIME_SCALE = 50.0

NODES = {
    "power_kw": "ns=2;s=Heater.Power",
    "triac_pct": "ns=2;s=Heater.TriacCommand",
    "applied_triac_pct": "ns=2;s=Heater.TriacApplied",
    "heartbeat": "ns=2;s=Heater.Heartbeat",
    "mode": "ns=2;s=Heater.Mode",
}


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def served_plant(tmp_path: Path, *args: str, duration_s: float) -> Iterator[str]:
    """Run ``czmpc plant serve ARGS`` on a free loopback port; yield its endpoint.

    The server stops by itself after ``duration_s`` of plant time and is killed when
    the block ends.
    """
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/czmpc/"
    log = open(tmp_path / "serve.log", "w", encoding="utf-8")  # noqa: SIM115
    proc = subprocess.Popen(
        [sys.executable, "-m", "czmpc.cli", "plant", "serve", "--endpoint", endpoint,
         "--time-scale", f"{TIME_SCALE:g}", "--duration-s", f"{duration_s:g}", *args],
        stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        yield endpoint
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)
        log.close()


def write_config(tmp_path: Path, endpoint: str, *, band_kw: tuple[float, float],
                 safe_triac_pct: float = 40.0, model: str | None = None,
                 extra: str = "") -> Path:
    """A run config for the served plant (no [controller] unless ``model``)."""
    nodes = "\n".join(f'{k} = "{v}"' for k, v in NODES.items())
    text = (f'[plant]\nendpoint = "{endpoint}"\nts_s = 2.0\ntime_scale = {TIME_SCALE:g}\n'
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
