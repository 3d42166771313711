"""`czmpc run` with [plant.security]: config errors and security rejections exit 2 in seconds."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from opcua_rig import PASSWORD, PASSWORD_ENV, USER, Pki, secured_server

from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

pytestmark = pytest.mark.realtime

#: The issue's bound on the time to a security verdict [s].
VERDICT_BOUND_S = 10.0


def _config(tmp_path: Path, endpoint: str, security: str) -> Path:
    path = tmp_path / "run.toml"
    path.write_text(f"""
[plant]
endpoint = "{endpoint}"
ts_s = 2.0
time_scale = 50.0
{security}
[nodes]
power_kw = "ns=2;s=Rig.Power"
triac_pct = "ns=2;s=Rig.Command"
[controller]
model = "{shipped_path(HAMMERSTEIN_MODEL_JSON)}"
[run]
duration_s = 10.0
setpoint_kw = 45.0
log = "{tmp_path / 'run.csv'}"
""", encoding="utf-8")
    return path


def _security(pki: Pki, **extra: str) -> str:
    keys = {"policy": "Basic256Sha256", "mode": "SignAndEncrypt", "certificate": str(pki.client_cert),
            "private_key": str(pki.client_key), "server_certificate": str(pki.server_cert),
            "username": USER, "password_env": PASSWORD_ENV, **extra}
    return "[plant.security]\n" + "".join(f'{k} = "{v}"\n' for k, v in keys.items())


def _czmpc_run(config: Path, password: str) -> tuple[int, str, float]:
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "czmpc.cli", "run", str(config)],
                          capture_output=True, text=True, timeout=60,
                          env={"PATH": "/usr/bin:/bin", PASSWORD_ENV: password})
    return proc.returncode, proc.stdout + proc.stderr, time.monotonic() - t0


def test_password_in_the_config_file_exits_2_naming_password_env(pki: Pki, tmp_path: Path) -> None:
    config = _config(tmp_path, "opc.tcp://10.20.30.40:4840/", _security(pki, password=PASSWORD))
    code, out, _ = _czmpc_run(config, PASSWORD)
    assert code == 2 and "password_env" in out and PASSWORD not in out


def test_no_security_table_for_a_remote_plant_exits_2(tmp_path: Path) -> None:
    code, out, _ = _czmpc_run(_config(tmp_path, "opc.tcp://10.20.30.40:4840/", ""), PASSWORD)
    assert code == 2 and "not a loopback address" in out


def test_wrong_password_against_a_secured_plant_exits_2_within_seconds(pki: Pki, tmp_path: Path) -> None:
    ready = threading.Event()
    stop = threading.Event()
    endpoint: list[str] = []

    async def serve() -> None:
        async with secured_server(pki) as (url, _):
            endpoint.append(url)
            ready.set()
            while not stop.is_set():
                await asyncio.sleep(0.05)

    thread = threading.Thread(target=lambda: asyncio.run(asyncio.wait_for(serve(), 60.0)), daemon=True)
    thread.start()
    try:
        assert ready.wait(20.0)
        config = _config(tmp_path, endpoint[0], _security(pki))
        code, out, elapsed_s = _czmpc_run(config, "wrong-password")
    finally:
        stop.set()
        thread.join(10.0)
    assert code == 2, out
    assert "rejected user 'mpc-operator' (BadUserAccessDenied)" in out
    assert elapsed_s < VERDICT_BOUND_S + 5.0    # + interpreter and model start-up
    assert "wrong-password" not in out and PASSWORD not in out
    assert not (tmp_path / "run.csv").exists() or PASSWORD not in (tmp_path / "run.csv").read_text()
