"""`czmpc plant serve` security: loopback unless secured, trusted clients, users, write rights.

The secured served plant runs in the test's event loop on 127.0.0.1 (a free port) with
the rig's PKI: Basic256Sha256 SignAndEncrypt, the controller's certificate trusted, the
controller's user and one operator. Each client tries one thing; the server's command
node is read on the server side to show that a refused write left no trace.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua
from asyncua.client.client import Client
from opcua_rig import (
    OPERATOR,
    OPERATOR_ENV,
    OPERATOR_PASSWORD,
    PASSWORD,
    PASSWORD_ENV,
    USER,
    Pki,
    free_port,
    run_async,
)

from czmpc.cli import main
from czmpc.errors import SettingsError
from czmpc.runtime.secure_client import SecurityRejectedError, connect
from czmpc.runtime.security import (
    ServerSecurity,
    check_serve_address,
    parse_security,
    parse_server_security,
)
from czmpc.runtime.served import ServedPlant, ServeOptions
from czmpc.shipped import shipped_path
from sim.model_plant import ModelPlant
from sysid.modelfile import load_model

#: Time within which a refused `plant serve` must have exited [s] (interpreter start-up
#: and imports included; the refusal itself needs no network wait).
REFUSAL_BOUND_S = 15.0
#: Command the test writes; the plant starts elsewhere, so a refused write is visible.
PROBE_TRIAC_PCT = 47.5
ENV = {PASSWORD_ENV: PASSWORD, OPERATOR_ENV: OPERATOR_PASSWORD}
#: Runs `czmpc` with socket binding replaced by a refusal that says "BIND <address>" on
#: stderr: a test sees whether and where the server would have listened, and nothing
#: ever listens (so no test opens a non-loopback port).
GUARDED_CLI = [sys.executable, "-c", (
    "import errno, socket, sys\n"
    "def bind(self, address):\n"
    "    sys.stderr.write(f'BIND {address}\\n'); sys.stderr.flush()\n"
    "    raise OSError(errno.EACCES, 'test guard: binding refused')\n"
    "socket.socket.bind = bind\n"
    "from czmpc.cli import main\n"
    "sys.exit(main())\n")]


def _guarded_serve(*args: str) -> tuple[int, str, float]:
    t0 = time.monotonic()
    proc = subprocess.run([*GUARDED_CLI, "plant", "serve", "--plant", "model", "--no-noise",
                           "--duration-s", "4", *args], capture_output=True, text=True,
                          timeout=60, env={"PATH": "/usr/bin:/bin"})
    return proc.returncode, proc.stderr, time.monotonic() - t0


@pytest.mark.parametrize("host", ["0.0.0.0", "192.0.2.10", "plant-pc.example"])
def test_non_loopback_without_security_exits_2_before_binding(host: str) -> None:
    code, err, elapsed_s = _guarded_serve("--endpoint", f"opc.tcp://{host}:{free_port()}/czmpc/")
    assert code == 2, err
    assert "czmpc: error: --endpoint" in err and "not a loopback address" in err
    assert "--policy Basic256Sha256" in err and "--insecure" in err
    assert "BIND" not in err and "Traceback" not in err
    assert elapsed_s < REFUSAL_BOUND_S


def test_insecure_on_a_non_loopback_address_warns_then_goes_on_to_bind() -> None:
    code, err, _ = _guarded_serve("--endpoint", f"opc.tcp://0.0.0.0:{free_port()}/czmpc/",
                                  "--insecure")
    warning = err.index("WARNING: --insecure")
    assert "anyone who can reach this address can write" in err
    assert "BIND ('0.0.0.0'" in err and err.index("BIND") > warning   # the guard refused it
    assert code == 2 and "czmpc: error:" in err and "test guard" in err   # the guard's OSError


def test_insecure_on_loopback_starts_serves_and_warns_on_every_start() -> None:
    for _ in range(2):
        port = free_port()
        proc = subprocess.run(
            [sys.executable, "-m", "czmpc.cli", "plant", "serve", "--plant", "model", "--no-noise",
             "--endpoint", f"opc.tcp://127.0.0.1:{port}/czmpc/", "--time-scale", "50",
             "--duration-s", "4", "--insecure"],
            capture_output=True, text=True, timeout=60, env={"PATH": "/usr/bin:/bin"})
        assert proc.returncode == 0, proc.stderr
        assert proc.stderr.count("WARNING: --insecure") == 1
        assert "plant: stopped after 4 s of plant time" in proc.stderr


def test_refusal_happens_before_any_server_exists(monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    def never(*_args: Any, **_kw: Any) -> Any:
        raise AssertionError("a server was created for a refused endpoint")

    monkeypatch.setattr(ServedPlant, "__init__", never)
    monkeypatch.setattr(ServedPlant, "serve", never)
    assert main(["plant", "serve", "--endpoint", "opc.tcp://0.0.0.0:4840/czmpc/"]) == 2
    assert "not a loopback address" in capsys.readouterr().err


def test_server_security_options_are_checked(pki: Pki, tmp_path: Path) -> None:
    base: dict[str, Any] = dict(policy="Basic256Sha256", certificate=pki.server_cert,
                                private_key=pki.server_key, trusted_clients=(pki.client_cert,),
                                user=USER, password_env=PASSWORD_ENV, environ=ENV)
    security = parse_server_security(**base)
    assert security is not None and security.controller_user.name == USER
    assert PASSWORD not in repr(security) and PASSWORD not in security.describe()
    bad: list[tuple[dict[str, Any], str]] = [
        ({"user": None}, "admits only configured users"),
        ({"trusted_clients": ()}, "only trusted client certificates"),
        ({"environ": {}}, f"{PASSWORD_ENV} is not set"),
        ({"policy": "Basic128Rsa15"}, "--policy must be one of"),
        ({"operators": ("no-equals-sign",)}, "NAME=ENV_VAR"),
        ({"operators": (f"{USER}={OPERATOR_ENV}",)}, "given twice"),
        ({"private_key": None}, "--private-key"),
    ]
    for change, says in bad:
        with pytest.raises(SettingsError, match=says):
            parse_server_security(**{**base, **change})
    with pytest.raises(SettingsError, match="need a security policy"):
        parse_server_security(policy="None", user=USER, password_env=PASSWORD_ENV, environ=ENV)
    loose = tmp_path / "loose.pem"
    loose.write_bytes(pki.server_key.read_bytes())
    loose.chmod(0o644)
    with pytest.raises(SettingsError, match="chmod 600"):
        parse_server_security(**{**base, "private_key": loose})
    assert check_serve_address("opc.tcp://0.0.0.0:4840/", security, insecure=False) is None
    with pytest.raises(SettingsError, match="contradicts"):
        check_serve_address("opc.tcp://127.0.0.1:4840/", security, insecure=True)


# --- A secured served plant, in process --------------------------------------------------

def _security(pki: Pki) -> ServerSecurity:
    security = parse_server_security(
        policy="Basic256Sha256", certificate=pki.server_cert, private_key=pki.server_key,
        trusted_clients=(pki.client_cert,), user=USER, password_env=PASSWORD_ENV,
        operators=(f"{OPERATOR}={OPERATOR_ENV}",), environ=ENV)
    assert security is not None
    return security


async def _against_secured_plant(pki: Pki, body: Callable[[str, ServedPlant], Awaitable[Any]]) -> Any:
    plant = ModelPlant(load_model(shipped_path("cz_heater_model.json")), noise=False)
    plant.reset(0)
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/czmpc/"
    served = ServedPlant(plant, initial_triac_pct=plant.initial_triac_pct, options=ServeOptions(
        endpoint=endpoint, time_scale=50.0, watchdog_s=None, security=_security(pki)))
    task = asyncio.create_task(served.serve())
    try:
        await asyncio.wait_for(served.ready.wait(), 20.0)
        return await body(endpoint, served)
    finally:
        task.cancel()
        try:
            await task
        except asyncio.CancelledError:
            pass


def _client_settings(pki: Pki, *, user: str | None = USER, password: str = PASSWORD,
                     cert: Path | None = None, key: Path | None = None) -> Any:
    table: dict[str, object] = {
        "policy": "Basic256Sha256", "mode": "SignAndEncrypt",
        "certificate": str(cert or pki.client_cert), "private_key": str(key or pki.client_key),
        "server_certificate": str(pki.server_cert)}
    if user is not None:
        table |= {"username": user, "password_env": "PW"}
    return parse_security(table, endpoint="opc.tcp://127.0.0.1:1/", base_dir=pki.dir,
                          environ={"PW": password})


async def _command(served: ServedPlant) -> float:
    return float(await served._nodes["TriacCommand"].read_value())


def _status_name(exc: BaseException) -> str:
    return type(exc).__name__


def test_controller_user_writes_command_and_heartbeat_but_not_the_setpoint(pki: Pki) -> None:
    async def body(endpoint: str, served: ServedPlant) -> tuple[float, int, str, float]:
        client = await connect(endpoint, _client_settings(pki), timeout_s=3.0)
        try:
            await client.get_node("ns=2;s=Heater.TriacCommand").write_value(PROBE_TRIAC_PCT)
            await client.get_node("ns=2;s=Heater.Heartbeat").write_value(
                ua.Variant(7, ua.VariantType.Int64))
            with pytest.raises(ua.uaerrors.UaStatusCodeError) as refused:
                await client.get_node("ns=2;s=Heater.PowerSetpoint").write_value(99.0)
        finally:
            await client.disconnect()
        return (await _command(served), int(await served._nodes["Heartbeat"].read_value()),
                _status_name(refused.value),
                float(await served._nodes["PowerSetpoint"].read_value()))

    command, heartbeat, refusal, setpoint = run_async(_against_secured_plant(pki, body))
    assert command == PROBE_TRIAC_PCT and heartbeat == 7
    assert refusal == "BadUserAccessDenied" and setpoint == 45.0


def test_operator_cannot_write_the_command_node(pki: Pki) -> None:
    async def body(endpoint: str, served: ServedPlant) -> tuple[str, float, float]:
        before = await _command(served)
        client = await connect(endpoint, _client_settings(pki, user=OPERATOR,
                                                          password=OPERATOR_PASSWORD), timeout_s=3.0)
        try:
            await client.get_node("ns=2;s=Heater.PowerSetpoint").write_value(44.0)
            with pytest.raises(ua.uaerrors.UaStatusCodeError) as refused:
                await client.get_node("ns=2;s=Heater.TriacCommand").write_value(PROBE_TRIAC_PCT)
            with pytest.raises(ua.uaerrors.UaStatusCodeError):
                await client.get_node("ns=2;s=Heater.Heartbeat").write_value(
                    ua.Variant(1, ua.VariantType.Int64))
        finally:
            await client.disconnect()
        assert await _command(served) == before
        return (_status_name(refused.value), before,
                float(await served._nodes["PowerSetpoint"].read_value()))

    refusal, before, setpoint = run_async(_against_secured_plant(pki, body))
    assert refusal == "BadUserAccessDenied"
    assert before != PROBE_TRIAC_PCT and setpoint == 44.0


async def _anonymous_write(endpoint: str, pki: Pki, *, secure_channel: bool,
                           user: str | None = None, password: str | None = None) -> BaseException:
    """Try to connect and write the command with asyncua alone; return what stopped it."""
    client = Client(endpoint, timeout=3.0)
    if secure_channel:
        await client.set_security_string(
            f"Basic256Sha256,SignAndEncrypt,{pki.client_cert},{pki.client_key},{pki.server_cert}")
        client.application_uri = "urn:test:czmpc"
    if user is not None:
        client.set_user(user)
        client.set_password(password or "")
    try:
        await client.connect()
    except Exception as exc:  # what refused the session
        return exc
    try:
        await client.get_node("ns=2;s=Heater.TriacCommand").write_value(PROBE_TRIAC_PCT)
    except Exception as exc:
        return exc
    finally:
        await client.disconnect()
    raise AssertionError("the write was accepted")


@pytest.mark.parametrize(("secure_channel", "user", "refusal"), [
    (True, None, "BadIdentityTokenRejected"),     # anonymous tokens are not accepted
    (False, None, "BadIdentityTokenRejected"),
    (False, USER, "BadUserAccessDenied"),         # no session without a trusted channel
], ids=["anonymous-over-trusted-secure-channel", "anonymous-unencrypted",
        "right-password-over-an-unencrypted-channel"])
def test_anonymous_or_unencrypted_writes_are_refused(pki: Pki, secure_channel: bool,
                                                     user: str | None, refusal: str,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    # A hostile client ignores the endpoints the server offers (asyncua's own client
    # would stop at "no matching endpoint" before the server had to say no): it goes on
    # with the only endpoint there is, over whatever channel it opened.
    monkeypatch.setattr(Client, "find_endpoint", staticmethod(lambda eps, _mode, _uri: eps[0]))

    async def body(endpoint: str, served: ServedPlant) -> tuple[BaseException, float]:
        exc = await _anonymous_write(endpoint, pki, secure_channel=secure_channel, user=user,
                                     password=PASSWORD)
        return exc, await _command(served)

    exc, command = run_async(_against_secured_plant(pki, body))
    assert command != PROBE_TRIAC_PCT
    assert _status_name(exc) == refusal, repr(exc)


@pytest.mark.parametrize(("change", "says"), [
    ({"cert": "rogue"}, "BadCertificateUntrusted"),
    ({"password": "wrong-password"}, "BadUserAccessDenied"),
], ids=["untrusted-client-certificate", "wrong-password"])
def test_untrusted_certificate_or_wrong_password_is_rejected(pki: Pki, change: dict[str, str],
                                                             says: str) -> None:
    kwargs: dict[str, Any] = {}
    if change.get("cert") == "rogue":
        kwargs = {"cert": pki.rogue_cert, "key": pki.rogue_key}
    if "password" in change:
        kwargs["password"] = change["password"]

    async def body(endpoint: str, served: ServedPlant) -> tuple[str, float]:
        with pytest.raises(SecurityRejectedError) as info:
            await connect(endpoint, _client_settings(pki, **kwargs), timeout_s=3.0)
        return str(info.value), await _command(served)

    message, command = run_async(_against_secured_plant(pki, body))
    assert says in message and command != PROBE_TRIAC_PCT
    assert PASSWORD not in message
