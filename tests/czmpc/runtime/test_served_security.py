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
import threading
import time
from collections.abc import Awaitable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua
from asyncua.client.client import Client
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding
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

pytestmark = pytest.mark.realtime

#: Time within which a refused `plant serve` must have exited [s] (interpreter start-up
#: and imports included; the refusal itself needs no network wait).
REFUSAL_BOUND_S = 15.0
#: Command the controller's test writes; the plant starts elsewhere. Each refused write
#: uses its own probe value, so a write that got through would show.
PROBE_TRIAC_PCT = 47.5
#: Bound on the shared secured plant's life [wall s]: it stops by itself after that.
SERVE_BOUND_S = 600.0
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


@pytest.mark.slow
@pytest.mark.parametrize("host", ["0.0.0.0", "plant-pc.example"])
def test_non_loopback_without_security_exits_2_before_binding(host: str) -> None:
    code, err, elapsed_s = _guarded_serve("--endpoint", f"opc.tcp://{host}:{free_port()}/czmpc/")
    assert code == 2, err
    assert "czmpc: error: --endpoint" in err and "not a loopback address" in err
    assert "--policy Basic256Sha256" in err and "--insecure" in err
    assert "BIND" not in err and "Traceback" not in err
    assert elapsed_s < REFUSAL_BOUND_S


@pytest.mark.slow
def test_insecure_on_a_non_loopback_address_warns_then_goes_on_to_bind() -> None:
    code, err, _ = _guarded_serve("--endpoint", f"opc.tcp://0.0.0.0:{free_port()}/czmpc/",
                                  "--insecure")
    warning = err.index("WARNING: --insecure")
    assert "anyone who can reach this address can write" in err
    assert "BIND ('0.0.0.0'" in err and err.index("BIND") > warning   # the guard refused it
    assert code == 2 and "czmpc: error:" in err and "test guard" in err   # the guard's OSError


@pytest.mark.slow
def test_insecure_on_loopback_starts_serves_and_warns() -> None:
    # with the test above, two starts: each one warns (the check runs on every start)
    proc = subprocess.run(
        [sys.executable, "-m", "czmpc.cli", "plant", "serve", "--plant", "model", "--no-noise",
         "--endpoint", f"opc.tcp://127.0.0.1:{free_port()}/czmpc/", "--time-scale", "50",
         "--duration-s", "2", "--insecure"],
        capture_output=True, text=True, timeout=60, env={"PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count("WARNING: --insecure") == 1
    assert "plant: stopped after 2 s of plant time" in proc.stderr


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
    # the controller's certificate is trusted as a PEM file in a directory (the README's
    # walkthrough uses a DER file with --trusted-client: both ways are admitted)
    trusted = pki.dir / "served_trusted"
    trusted.mkdir(exist_ok=True)
    cert = x509.load_der_x509_certificate(pki.client_cert.read_bytes())
    (trusted / "czmpc-cert.pem").write_bytes(cert.public_bytes(Encoding.PEM))
    security = parse_server_security(
        policy="Basic256Sha256", certificate=pki.server_cert, private_key=pki.server_key,
        trusted_client_dir=trusted, user=USER, password_env=PASSWORD_ENV,
        operators=(f"{OPERATOR}={OPERATOR_ENV}",), environ=ENV)
    assert security is not None
    return security


@dataclass
class SecuredPlant:
    """The secured served plant running in its own thread and event loop."""

    endpoint: str
    served: ServedPlant
    loop: asyncio.AbstractEventLoop
    log: list[str]

    def value(self, name: str) -> float:
        """A node's value [unit of the node], read on the server's side."""
        read = asyncio.run_coroutine_threadsafe(self.served._nodes[name].read_value(), self.loop)
        return float(read.result(10.0))

    def log_after(self, mark: int) -> list[str]:
        """Lines logged since ``len(log)`` was ``mark``."""
        return self.log[mark:]


@pytest.fixture(scope="module")
def secured_plant(pki: Pki) -> Iterator[SecuredPlant]:
    """One secured plant for this module's clients (a server's start-up costs seconds)."""
    plant = ModelPlant(load_model(shipped_path("cz_heater_model.json")), noise=False)
    plant.reset(0)
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/czmpc/"
    log: list[str] = []
    served = ServedPlant(plant, initial_triac_pct=plant.initial_triac_pct, options=ServeOptions(
        endpoint=endpoint, time_scale=50.0, watchdog_s=None, duration_s=SERVE_BOUND_S * 50.0,
        security=_security(pki)), log=log.append)
    loops: list[asyncio.AbstractEventLoop] = []
    started = threading.Event()

    async def serve() -> None:
        loops.append(asyncio.get_running_loop())
        task = asyncio.create_task(served.serve())
        await served.ready.wait()
        started.set()
        await task   # ends with duration_s, or is cancelled by the fixture's teardown

    thread = threading.Thread(target=lambda: asyncio.run(_quietly_cancelled(serve())), daemon=True)
    thread.start()
    try:
        assert started.wait(60.0), "the secured plant did not start within 60 s"
        yield SecuredPlant(endpoint, served, loops[0], log)
    finally:
        if loops:
            _cancel_all(loops[0])
        thread.join(20.0)


def _cancel_all(loop: asyncio.AbstractEventLoop) -> None:
    """Cancel every task of ``loop`` from another thread, in one call run by the loop itself
    (cancelling task by task from here raced the loop closing once the first had ended)."""
    def cancel() -> None:
        for task in asyncio.all_tasks():
            task.cancel()

    try:
        loop.call_soon_threadsafe(cancel)
    except RuntimeError:     # closed already: the plant's duration ran out
        pass


async def _quietly_cancelled(coro: Awaitable[None]) -> None:
    try:
        await coro
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


def _status_name(exc: BaseException) -> str:
    return type(exc).__name__


def test_controller_user_writes_command_and_heartbeat_but_not_the_setpoint(
        pki: Pki, secured_plant: SecuredPlant) -> None:
    async def body() -> str:
        client = await connect(secured_plant.endpoint, _client_settings(pki), timeout_s=3.0)
        try:
            await client.get_node("ns=2;s=Heater.TriacCommand").write_value(PROBE_TRIAC_PCT)
            await client.get_node("ns=2;s=Heater.Heartbeat").write_value(
                ua.Variant(7, ua.VariantType.Int64))
            with pytest.raises(ua.uaerrors.UaStatusCodeError) as refused:
                await client.get_node("ns=2;s=Heater.PowerSetpoint").write_value(99.0)
        finally:
            await client.disconnect()
        return _status_name(refused.value)

    mark = len(secured_plant.log)
    assert run_async(body()) == "BadUserAccessDenied"
    assert secured_plant.value("TriacCommand") == PROBE_TRIAC_PCT
    assert secured_plant.value("Heartbeat") == 7
    assert secured_plant.value("PowerSetpoint") != 99.0
    assert secured_plant.log_after(mark) == [
        f"security: refused write by user {USER!r} to Heater.PowerSetpoint (BadUserAccessDenied)"]


def test_operator_cannot_write_the_command_or_heartbeat(pki: Pki, secured_plant: SecuredPlant) -> None:
    probe = 12.5   # this test's own value: a write that got through would show it

    async def body() -> list[str]:
        client = await connect(secured_plant.endpoint, _client_settings(
            pki, user=OPERATOR, password=OPERATOR_PASSWORD), timeout_s=3.0)
        refusals = []
        try:
            await client.get_node("ns=2;s=Heater.PowerSetpoint").write_value(44.0)
            for node, value in (("TriacCommand", ua.Variant(probe, ua.VariantType.Double)),
                                ("Heartbeat", ua.Variant(12345, ua.VariantType.Int64))):
                with pytest.raises(ua.uaerrors.UaStatusCodeError) as refused:
                    await client.get_node(f"ns=2;s=Heater.{node}").write_value(value)
                refusals.append(_status_name(refused.value))
        finally:
            await client.disconnect()
        return refusals

    mark = len(secured_plant.log)
    assert run_async(body()) == ["BadUserAccessDenied", "BadUserAccessDenied"]
    assert secured_plant.value("TriacCommand") != probe
    assert secured_plant.value("Heartbeat") != 12345
    assert secured_plant.value("PowerSetpoint") == 44.0
    assert secured_plant.log_after(mark) == [
        f"security: refused write by user {OPERATOR!r} to Heater.{node} (BadUserAccessDenied)"
        for node in ("TriacCommand", "Heartbeat")]


async def _hostile_write(endpoint: str, pki: Pki, probe: float, *, secure_channel: bool,
                         user: str | None = None, password: str | None = None,
                         app_uri: str = "urn:test:czmpc") -> BaseException:
    """Try to connect and write the command with asyncua alone; return what stopped it."""
    client = Client(endpoint, timeout=3.0)
    if secure_channel:
        await client.set_security_string(
            f"Basic256Sha256,SignAndEncrypt,{pki.client_cert},{pki.client_key},{pki.server_cert}")
        client.application_uri = app_uri
    if user is not None:
        client.set_user(user)
        client.set_password(password or "")
    try:
        await client.connect()
    except Exception as exc:  # what refused the session
        return exc
    try:
        await client.get_node("ns=2;s=Heater.TriacCommand").write_value(probe)
    except Exception as exc:
        return exc
    finally:
        await client.disconnect()
    raise AssertionError("the write was accepted")


@pytest.mark.parametrize(("secure_channel", "user", "refusal", "probe"), [
    (True, None, "BadIdentityTokenRejected", 13.5),     # anonymous tokens are not accepted
    (False, None, "BadIdentityTokenRejected", 14.5),
    (False, USER, "BadUserAccessDenied", 15.5),         # no session without a trusted channel
], ids=["anonymous-over-trusted-secure-channel", "anonymous-unencrypted",
        "right-password-over-an-unencrypted-channel"])
def test_anonymous_or_unencrypted_writes_are_refused(pki: Pki, secured_plant: SecuredPlant,
                                                     secure_channel: bool, user: str | None,
                                                     refusal: str, probe: float,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    # A hostile client ignores the endpoints the server offers (asyncua's own client
    # would stop at "no matching endpoint" before the server had to say no): it goes on
    # with the only endpoint there is, over whatever channel it opened.
    monkeypatch.setattr(Client, "find_endpoint", staticmethod(lambda eps, _mode, _uri: eps[0]))
    mark = len(secured_plant.log)
    exc = run_async(_hostile_write(secured_plant.endpoint, pki, probe,
                                   secure_channel=secure_channel, user=user, password=PASSWORD))
    assert _status_name(exc) == refusal, repr(exc)
    assert secured_plant.value("TriacCommand") != probe
    if user is not None:   # anonymous tokens are refused before any user check
        assert secured_plant.log_after(mark) == [
            f"security: refused login of user {user!r}: no secure channel"]
    assert not any(PASSWORD in line for line in secured_plant.log)


def test_a_trusted_certificate_under_another_application_uri_is_refused(
        pki: Pki, secured_plant: SecuredPlant) -> None:
    mark = len(secured_plant.log)
    exc = run_async(_hostile_write(secured_plant.endpoint, pki, 16.5, secure_channel=True,
                                   user=USER, password=PASSWORD, app_uri="urn:someone-else"))
    assert _status_name(exc) == "BadCertificateUriInvalid", repr(exc)
    assert secured_plant.value("TriacCommand") != 16.5
    assert secured_plant.log_after(mark) == [
        "security: refused session of client 'urn:someone-else': BadCertificateUriInvalid"]


@pytest.mark.parametrize(("change", "says", "logged"), [
    ({"cert": "rogue"}, "BadCertificateUntrusted",
     "security: refused session of client 'urn:test:czmpc': untrusted certificate"),
    ({"password": "wrong-password"}, "BadUserAccessDenied",
     f"security: refused login of user {USER!r}: unknown user or wrong password"),
], ids=["untrusted-client-certificate", "wrong-password"])
def test_untrusted_certificate_or_wrong_password_is_rejected(
        pki: Pki, secured_plant: SecuredPlant, change: dict[str, str], says: str,
        logged: str) -> None:
    kwargs: dict[str, Any] = {}
    if change.get("cert") == "rogue":
        kwargs = {"cert": pki.rogue_cert, "key": pki.rogue_key}
    if "password" in change:
        kwargs["password"] = change["password"]

    async def body() -> str:
        with pytest.raises(SecurityRejectedError) as info:
            await connect(secured_plant.endpoint, _client_settings(pki, **kwargs), timeout_s=3.0)
        return str(info.value)

    mark = len(secured_plant.log)
    message = run_async(body())
    assert says in message and PASSWORD not in message
    assert any(line.startswith(logged) for line in secured_plant.log_after(mark)), secured_plant.log
    assert not any("wrong-password" in line or PASSWORD in line for line in secured_plant.log)


def test_trusted_client_dir_admits_its_certificates(pki: Pki, tmp_path: Path) -> None:
    (tmp_path / "trusted").mkdir()
    (tmp_path / "trusted" / "czmpc.der").write_bytes(pki.client_cert.read_bytes())
    (tmp_path / "trusted" / "notes.txt").write_text("not a certificate", encoding="utf-8")
    security = parse_server_security(
        policy="Basic256Sha256", certificate=pki.server_cert, private_key=pki.server_key,
        trusted_client_dir=tmp_path / "trusted", user=USER, password_env=PASSWORD_ENV, environ=ENV)
    assert security is not None
    assert security.trusted_clients == (tmp_path / "trusted" / "czmpc.der",)
    (tmp_path / "empty").mkdir()
    with pytest.raises(SettingsError, match="only trusted client certificates"):
        parse_server_security(
            policy="Basic256Sha256", certificate=pki.server_cert, private_key=pki.server_key,
            trusted_client_dir=tmp_path / "empty", user=USER, password_env=PASSWORD_ENV,
            environ=ENV)
