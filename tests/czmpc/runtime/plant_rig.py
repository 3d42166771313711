"""Helpers of the plant-link loop tests: loopback ports, configs (imported as plant_rig)."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from pathlib import Path
from typing import Any, TypeVar

import pytest

from benchmarks._serving import free_loopback_port as free_port  # noqa: F401  (the tests import it from here)
from czmpc.runtime.config import RunConfig, run_config_from_dict
from czmpc.runtime.served import SERVED_NODE_IDS
from czmpc.shipped import shipped_path

pytest.importorskip("asyncua")

#: Every loopback test runs the plant at this many samples per Ts (period 2 s / 50 = 40 ms).
TIME_SCALE = 50.0


#: The served plant's nodes of the controller's state and lease (`STATE_NODES` tests).
STATE_KEYS = ("owner", "status", "mode_in_effect", "stale_alarm", "predicted_power_kw",
              "target_triac_pct", "watchdog")


#: The served plant's nodes of the coming setpoints and the grid voltage (issue 40's tests
#: configure them; the others run as a controller that is told neither).
CONTEXT_KEYS = ("setpoint_preview_kw", "grid_voltage_factor")


def served_nodes() -> dict[str, str]:
    """Node ids of czmpc's served plant: the signals (no model health, state, lease, preview
    or voltage)."""
    return {k: v for k, v in SERVED_NODE_IDS.items()
            if k != "model_health" and k not in STATE_KEYS and k not in CONTEXT_KEYS}


def make_config(tmp_path: Path, port: int, *, nodes: dict[str, str] | None = None,
                duration_s: float = 200.0, run: dict[str, object] | None = None,
                safety: dict[str, object] | None = None) -> RunConfig:
    """A run configuration for a loopback server on ``port``."""
    doc: dict[str, object] = {
        "plant": {"endpoint": f"opc.tcp://127.0.0.1:{port}/czmpc/", "ts_s": 2.0,
                  "time_scale": TIME_SCALE, "max_sample_age_s": 1.0},
        "nodes": served_nodes() if nodes is None else nodes,
        "controller": {"model": str(shipped_path("cz_heater_model.json"))},
        "run": {"duration_s": duration_s, "log": "run.csv", **(run or {})},
    }
    if safety is not None:
        doc["safety"] = safety
    return run_config_from_dict(doc, base_dir=tmp_path)


T = TypeVar("T")


async def with_served(served: Any, body: Awaitable[T]) -> T:
    """Run `body` while `served` (anything with ``serve()`` and a ``ready`` event) serves."""
    task = asyncio.create_task(served.serve())
    try:
        await asyncio.wait_for(served.ready.wait(), 20.0)
        return await body
    finally:
        task.cancel()
        try:
            await task
        except asyncio.CancelledError:
            pass


def write_run_toml(tmp_path: Path, port: int, *, duration_s: float, log: str = "run.csv",
                   extra: str = "", connect_timeout_s: float | None = None) -> Path:
    """``tmp_path/run.toml`` for `czmpc run` against czmpc's served plant on ``port``
    (setpoint 31 kW; ``extra``: more TOML at the end, e.g. a [safety] table)."""
    nodes = "\n".join(f'{k} = "{v}"' for k, v in served_nodes().items() if k != "setpoint_kw")
    timeout = "" if connect_timeout_s is None else f"connect_timeout_s = {connect_timeout_s}\n"
    path = tmp_path / "run.toml"
    path.write_text(
        f'[plant]\nendpoint = "opc.tcp://127.0.0.1:{port}/czmpc/"\nts_s = 2.0\n'
        f"time_scale = {TIME_SCALE}\nmax_sample_age_s = 1.0\n{timeout}[nodes]\n{nodes}\n"
        f'[controller]\nmodel = "{shipped_path("cz_heater_model.json")}"\n'
        f'[run]\nduration_s = {duration_s}\nsetpoint_kw = 31.0\nlog = "{log}"\n{extra}\n',
        encoding="utf-8")
    return path
