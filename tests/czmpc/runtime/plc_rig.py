"""Rig of the interop tests: a PLC-typed OPC UA server on node-opcua, and `czmpc run` as a user runs it.

The server (plc_server/plc_server.js, node-opcua pinned in plc_server/package-lock.json,
installed by ``make test`` with ``npm ci``) is another stack than asyncua and than czmpc.
It types its nodes as a PLC does (Float, UInt16, Int16, Boolean, String) and uses
Siemens-style node ids. It listens on 127.0.0.1 only, stops by itself after
`WALL_LIMIT_S`, and logs one JSON line per event (every write with the data type
czmpc wrote, refusals, hangs, sessions, plant samples).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from opcua_rig import PASSWORD, PASSWORD_ENV, USER, Pki, run_async

from benchmarks._serving import free_loopback_port
from czmpc.shipped import shipped_path

SERVER_DIR = Path(__file__).resolve().parent / "plc_server"
#: The server stops by itself after this long [wall s], whatever the tests do.
WALL_LIMIT_S = 900.0
#: Plant samples per Ts of wall time (Ts 2 s: a period of 80 ms).
TIME_SCALE = 25.0
#: A user of the secured endpoint who may read but not write.
VIEWER = "viewer"
VIEWER_PASSWORD = "v1ewer-Pa55-never-logged"
VIEWER_ENV = "CZMPC_TEST_VIEWER_PASSWORD"

#: The nodes as the PLC's server has them (namespace 3).
POWER = 'ns=3;s="DB_Heater"."Power"'
COMMAND = 'ns=3;s="DB_Heater"."TriacCmd"'
COMMAND_RAW = 'ns=3;s="DB_Heater"."TriacRaw"'
COMMAND_READ_ONLY = 'ns=3;s="DB_Heater"."TriacCmdRO"'
COMMAND_BOOLEAN = 'ns=3;s="DB_Heater"."TriacCmdBool"'
APPLIED = 'ns=3;s="DB_Heater"."TriacApplied"'
SETPOINT = 'ns=3;s="DB_Heater"."Setpoint"'
HEALTH = 'ns=3;s="DB_Heater"."ModelHealth"'
HEARTBEAT = "ns=3;i=1001"
MODE_STRING = "ns=3;i=1002"
MODE_INT16 = "ns=3;i=1003"
CONTROL = 'ns=3;s="Test"."Control"'


@dataclass
class PlcServer:
    """A running node-opcua PLC server (`plc_server`)."""

    endpoint: str
    events_path: Path
    pki: Pki
    process: subprocess.Popen[str]

    def control(self, **order: Any) -> None:
        """Arm a fault or set the heartbeat (plc_server.js, node Test.Control)."""
        from asyncua import Client, ua

        async def write() -> None:
            async with Client(self.endpoint, timeout=5.0) as client:
                node = client.get_node(CONTROL)
                await node.write_value(ua.DataValue(ua.Variant(json.dumps(order),
                                                               ua.VariantType.String),
                                                    StatusCode=None))

        run_async(write())

    def events(self, since: float = 0.0, ev: str | None = None) -> list[dict[str, Any]]:
        """The server's events after wall time ``since`` [s since the epoch], of kind ``ev``."""
        out = []
        for line in self.events_path.read_text(encoding="utf-8").splitlines():
            event = json.loads(line)
            if event["t"] >= since and (ev is None or event["ev"] == ev):
                out.append(event)
        return out


def _node() -> str:
    node = shutil.which("node")
    if node is None or not (SERVER_DIR / "node_modules" / "node-opcua").is_dir():
        raise RuntimeError(f"node-opcua is not installed in {SERVER_DIR}: run 'make test' "
                           "(it runs 'npm ci' there from the lockfile)")
    return node


@contextlib.contextmanager
def plc_server(tmp: Path, pki: Pki) -> Iterator[PlcServer]:
    """Start the PLC server on a free loopback port; stop it (SIGTERM) afterwards."""
    port = free_loopback_port()
    events = tmp / "plc_events.jsonl"
    config = {
        "port": port, "model": str(shipped_path("cz_heater_model.json")), "ts_s": 2.0,
        "time_scale": TIME_SCALE, "initial_triac_pct": 45.0, "setpoint_kw": 45.0,
        "heartbeat_start": 65530, "wall_limit_s": WALL_LIMIT_S, "events": str(events),
        "security": {
            "pki_dir": str(tmp / "plc_pki"), "certificate": str(pki.server_cert),
            "private_key": str(pki.server_key), "trusted_client": str(pki.client_cert),
            "users": {USER: {"password": PASSWORD, "write": True},
                      VIEWER: {"password": VIEWER_PASSWORD, "write": False}},
        },
    }
    (tmp / "plc_server.json").write_text(json.dumps(config), encoding="utf-8")
    node = _node()   # refuses first: a log opened before it leaked into a later test
    log = open(tmp / "plc_server.log", "w", encoding="utf-8")  # noqa: SIM115
    process = subprocess.Popen([node, str(SERVER_DIR / "plc_server.js"),
                                str(tmp / "plc_server.json")], stdout=subprocess.PIPE,
                               stderr=log, text=True, cwd=SERVER_DIR)
    try:
        assert process.stdout is not None
        deadline = time.monotonic() + 90.0
        endpoint = None
        while endpoint is None and time.monotonic() < deadline:
            line = process.stdout.readline()
            if not line:
                break
            if line.startswith("READY "):
                endpoint = line.split()[1]
        if endpoint is None:
            raise RuntimeError(f"the PLC server did not start: see {tmp / 'plc_server.log'}")
        yield PlcServer(endpoint, events, pki, process)
    finally:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(10.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5.0)
        if process.stdout is not None:
            process.stdout.close()
        log.close()


def write_config(path: Path, server: PlcServer, *, nodes: dict[str, Any],
                 secure_user: str | None = None, plant: dict[str, Any] | None = None,
                 run: dict[str, Any] | None = None, safety: dict[str, Any] | None = None) -> Path:
    """A run configuration TOML for the PLC server (what a user writes)."""
    def value(v: Any) -> str:
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, str):
            return "'" + v + "'"          # a TOML literal string keeps the id's quotes
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    tables: dict[str, dict[str, Any]] = {
        "plant": {"endpoint": server.endpoint, "ts_s": 2.0, "time_scale": TIME_SCALE,
                  "max_sample_age_s": 1.0, "connect_timeout_s": 1.0, **(plant or {})},
        "nodes": nodes,
        "controller": {"model": str(shipped_path("cz_heater_model.json"))},
        "run": {"log": str(path.with_suffix(".csv")), **(run or {})},
        "safety": safety or {"action": "hold"},
    }
    lines = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        lines.extend(f"{k} = {value(v)}" for k, v in table.items())
        if name == "plant" and secure_user is not None:
            pki = server.pki
            env = PASSWORD_ENV if secure_user == USER else VIEWER_ENV
            lines += ["[plant.security]", "policy = 'Basic256Sha256'", "mode = 'SignAndEncrypt'",
                      f"certificate = {value(str(pki.client_cert))}",
                      f"private_key = {value(str(pki.client_key))}",
                      f"server_certificate = {value(str(pki.server_cert))}",
                      f"username = {value(secure_user)}", f"password_env = {value(env)}"]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def czmpc(*args: str) -> list[str]:
    """The command line of ``czmpc ARGS`` in this interpreter."""
    return [sys.executable, "-m", "czmpc.cli", *args]


def czmpc_env() -> dict[str, str]:
    """The environment of a ``czmpc`` subprocess: both users' passwords, no terminal."""
    return {**os.environ, PASSWORD_ENV: PASSWORD, VIEWER_ENV: VIEWER_PASSWORD}
