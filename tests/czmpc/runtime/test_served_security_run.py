"""A secured end-to-end run: `czmpc plant serve --policy ...` and `czmpc run` as processes.

Both processes run on 127.0.0.1 (a free port) at a time scale of 20, with the rig's PKI:
the plant serves Basic256Sha256 SignAndEncrypt, trusts the controller's certificate and
knows the controller's user; the run config pins the plant's certificate and reads the
password from the environment. The password is fresh and random for each run, so that
finding it anywhere is a leak and never a coincidence.
"""

from __future__ import annotations

import csv
import os
import secrets
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
from opcua_rig import OPERATOR_ENV, PASSWORD_ENV, USER, Pki, free_port, served_security_args

from czmpc.runtime.config import load_run_config
from czmpc.shipped import shipped_path

pytestmark = [pytest.mark.slow, pytest.mark.realtime]

CLI = [sys.executable, "-m", "czmpc.cli"]
#: Plant samples per Ts of wall time (the issue asks for >= 20): a 100 ms period.
TIME_SCALE = 20.0
#: The recipe: 31 kW, then a step to 34 kW at 80 s of plant time; 300 s in all.
STEP_AT_S, BEFORE_KW, AFTER_KW, DURATION_S = 80.0, 31.0, 34.0, 300.0
#: Steady-state band [kW] (mean of the 30 s before the step, and of the last 30 samples)
#: on the noise-free model plant: the controller is offset-free, so what is left is the
#: residue of the slow mode's transient and sample-phase jitter between the two
#: processes' clocks (measured: 0.002 kW); 0.05 kW is 0.15 % of the setpoint and under 2 %
#: of the 3 kW step, the band of the unsecured loopback tracking test.
SECURE_TRACKING_ATOL_KW = 0.05
#: Bound on waiting for the served plant to listen [s] (interpreter and imports included).
LISTEN_BOUND_S = 30.0
EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "plant_link"


@dataclass(frozen=True)
class SecuredRun:
    out_dir: Path
    password: str
    operator_password: str
    code: int
    run_out: str
    run_err: str
    serve_out: str
    serve_err: str


def _wait_listening(port: int, server: subprocess.Popen[str]) -> None:
    end = time.monotonic() + LISTEN_BOUND_S
    while time.monotonic() < end:
        if server.poll() is not None:
            raise RuntimeError(f"plant serve ended with {server.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.2)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {LISTEN_BOUND_S} s")


def _config(out_dir: Path, port: int, pki: Pki) -> Path:
    (out_dir / "recipe.csv").write_text(
        f"time_s,setpoint_kw\n0,{BEFORE_KW}\n{STEP_AT_S:g},{AFTER_KW}\n", encoding="utf-8")
    path = out_dir / "secure.toml"
    path.write_text(f"""
[plant]
endpoint = "opc.tcp://127.0.0.1:{port}/czmpc/"
ts_s = 2.0
time_scale = {TIME_SCALE}
max_sample_age_s = 1.0
[plant.security]
policy = "Basic256Sha256"
mode = "SignAndEncrypt"
certificate = "{pki.client_cert}"
private_key = "{pki.client_key}"
server_certificate = "{pki.server_cert}"
username = "{USER}"
password_env = "{PASSWORD_ENV}"
[nodes]
power_kw = "ns=2;s=Heater.Power"
triac_pct = "ns=2;s=Heater.TriacCommand"
applied_triac_pct = "ns=2;s=Heater.TriacApplied"
heartbeat = "ns=2;s=Heater.Heartbeat"
mode = "ns=2;s=Heater.Mode"
[controller]
model = "{shipped_path('cz_heater_model.json')}"
[run]
duration_s = {DURATION_S}
schedule = "recipe.csv"
log = "run.csv"
""", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def secured_run(pki: Pki, tmp_path_factory: pytest.TempPathFactory) -> SecuredRun:
    out_dir = tmp_path_factory.mktemp("secured_run")
    password, operator_password = (f"pw-{secrets.token_urlsafe(18)}",
                                   f"op-{secrets.token_urlsafe(18)}")
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), PASSWORD_ENV: password,
           OPERATOR_ENV: operator_password}
    port = free_port()
    server = subprocess.Popen(
        [*CLI, "plant", "serve", "--plant", "model", "--no-noise",
         "--endpoint", f"opc.tcp://127.0.0.1:{port}/czmpc/", "--time-scale", str(TIME_SCALE),
         "--duration-s", "2000", "--watchdog-s", "1000", *served_security_args(pki)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=out_dir)
    try:
        _wait_listening(port, server)
        run = subprocess.run([*CLI, "run", str(_config(out_dir, port, pki))], capture_output=True,
                             text=True, timeout=180, env=env, cwd=out_dir)
    finally:
        server.kill()
        serve_out, serve_err = server.communicate(timeout=20)
    return SecuredRun(out_dir, password, operator_password, run.returncode, run.stdout, run.stderr,
                      serve_out, serve_err)


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_secured_run_tracks_a_setpoint_step_and_exits_0(secured_run: SecuredRun) -> None:
    assert secured_run.code == 0, secured_run.run_err
    assert "Basic256Sha256 SignAndEncrypt, pinned server certificate, user 'mpc-operator'" \
        in secured_run.run_err
    assert f"controller user {USER!r}" in secured_run.serve_err
    rows = _rows(secured_run.out_dir / "run.csv")
    assert len(rows) >= 0.9 * DURATION_S / 2.0
    assert sum(r["written"] == "1" for r in rows) >= 0.9 * len(rows)
    before = [float(r["power_kw"]) for r in rows
              if r["quality"] == "good" and STEP_AT_S - 30.0 <= float(r["time_s"]) < STEP_AT_S]
    tail = [float(r["power_kw"]) for r in rows[-30:] if r["quality"] == "good"]
    assert len(before) > 10 and len(tail) > 20
    assert abs(sum(before) / len(before) - BEFORE_KW) < SECURE_TRACKING_ATOL_KW
    assert abs(sum(tail) / len(tail) - AFTER_KW) < SECURE_TRACKING_ATOL_KW


def test_the_password_is_in_no_file_and_no_output(secured_run: SecuredRun) -> None:
    files = [p for p in secured_run.out_dir.rglob("*") if p.is_file()]
    assert {p.name for p in files} >= {"run.csv", "secure.toml", "recipe.csv"}
    outputs = {"run stdout": secured_run.run_out, "run stderr": secured_run.run_err,
               "serve stdout": secured_run.serve_out, "serve stderr": secured_run.serve_err}
    for secret in (secured_run.password, secured_run.operator_password):
        leaks = [str(p) for p in files if secret.encode() in p.read_bytes()]
        leaks += [name for name, text in outputs.items() if secret in text]
        assert not leaks
    assert secured_run.run_err and secured_run.serve_err   # both processes did speak


def test_the_shipped_secure_example_config_loads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  pki: Pki) -> None:
    example = EXAMPLES / "run_secure.toml"
    # the example names pki/ files relative to itself: give it a copy with the rig's PKI
    (tmp_path / "pki" / "own").mkdir(parents=True)
    (tmp_path / "pki" / "trusted").mkdir()
    for src, dst in ((pki.client_cert, "own/czmpc.der"), (pki.client_key, "own/czmpc.pem"),
                     (pki.server_cert, "trusted/plant.der")):
        (tmp_path / "pki" / dst).write_bytes(src.read_bytes())
    (tmp_path / "pki" / "own" / "czmpc.pem").chmod(0o600)
    text = example.read_text(encoding="utf-8").replace(
        '"../../data/cz_heater_model.json"', f'"{shipped_path("cz_heater_model.json")}"')
    config_path = tmp_path / "run_secure.toml"
    config_path.write_text(text, encoding="utf-8")
    monkeypatch.setenv("CZMPC_OPCUA_PASSWORD", "from-the-environment")
    config = load_run_config(config_path)
    assert config.security.policy == "Basic256Sha256" and config.security.mode == "SignAndEncrypt"
    assert config.security.username == "mpc-operator"
    assert config.security.server_certificate == tmp_path / "pki" / "trusted" / "plant.der"
    assert config.security.password is not None
    assert config.security.password.reveal() == "from-the-environment"
    assert "password =" not in text
