"""czmpc.runtime.secure_client against an independent secured asyncua server on 127.0.0.1.

The server (opcua_rig.secured_server) offers Basic256Sha256 SignAndEncrypt only, trusts one
client certificate and knows one user. Each rejection must come back as a
SecurityRejectedError that says which, within 10 s (the issue's bound), never as a retry.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import pytest
from opcua_rig import PASSWORD, PASSWORD_ENV, USER, Pki, free_port, run_async, secured_server

from czmpc.runtime.secure_client import PlantUnreachableError, SecurityRejectedError, connect
from czmpc.runtime.security import INSECURE_LOOPBACK, SecuritySettings, parse_security

pytestmark = pytest.mark.realtime

#: The issue's bound on the time to a security verdict [s].
VERDICT_BOUND_S = 10.0


def _settings(pki: Pki, **change: Any) -> SecuritySettings:
    table: dict[str, object] = {
        "policy": "Basic256Sha256", "mode": "SignAndEncrypt",
        "certificate": str(pki.client_cert), "private_key": str(pki.client_key),
        "server_certificate": str(pki.server_cert), "username": USER, "password_env": PASSWORD_ENV,
    }
    env = {PASSWORD_ENV: change.pop("password", PASSWORD)}
    table.update(change)
    return parse_security(table, endpoint="opc.tcp://127.0.0.1:1/", base_dir=pki.dir, environ=env)


async def _write_and_read_back(pki: Pki, settings: SecuritySettings) -> float:
    async with secured_server(pki) as (endpoint, command):
        client = await connect(endpoint, settings, timeout_s=3.0)
        try:
            node = client.get_node(command.nodeid)
            await node.write_value(47.5)
            return float(await command.read_value())
        finally:
            await client.disconnect()


def test_right_settings_open_a_signed_encrypted_session_and_write(pki: Pki) -> None:
    assert run_async(_write_and_read_back(pki, _settings(pki))) == 47.5


async def _rejection(pki: Pki, settings: SecuritySettings) -> tuple[str, float]:
    async with secured_server(pki) as (endpoint, _):
        t0 = time.monotonic()
        with pytest.raises(SecurityRejectedError) as info:
            await connect(endpoint, settings, timeout_s=3.0)
        return str(info.value), time.monotonic() - t0


@pytest.mark.parametrize(("change", "says"), [
    ({"password": "wrong-password"}, r"rejected user 'mpc-operator' \(BadUserAccessDenied\).*\$CZMPC_TEST"),
    ({"certificate": "own/rogue.der", "private_key": "own/rogue.pem"},
     r"refused czmpc's certificate .*rogue\.der \(BadCertificateUntrusted\).*trusted certificates"),
    ({"server_certificate": "own/other_server.der"}, r"presents another certificate .*pinned"),
    ({"mode": "Sign"}, r"no matching endpoint: the server offers \['Basic256Sha256 SignAndEncrypt'\]"),
], ids=["wrong-password", "untrusted-client-certificate", "wrong-pinned-server-certificate",
        "no-matching-endpoint"])
def test_security_rejections_say_which_within_bound(pki: Pki, change: dict[str, Any], says: str,
                                                    caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    message, elapsed_s = run_async(_rejection(pki, _settings(pki, **change)))
    assert elapsed_s < VERDICT_BOUND_S
    import re
    assert re.search(says, message), message
    assert PASSWORD not in message and PASSWORD not in caplog.text
    assert "wrong-password" not in message


def test_no_security_against_a_secured_server_is_no_matching_endpoint_not_a_downgrade(pki: Pki) -> None:
    async def attempt() -> None:
        async with secured_server(pki) as (endpoint, _):
            with pytest.raises((SecurityRejectedError, PlantUnreachableError)) as info:
                await connect(endpoint, INSECURE_LOOPBACK, timeout_s=2.0)
            assert "Bad" in str(info.value) or "no matching" in str(info.value)
    run_async(attempt())


def test_nothing_listening_is_a_network_fault_to_retry(tmp_path: Path) -> None:
    async def attempt() -> None:
        with pytest.raises(PlantUnreachableError, match="127.0.0.1"):
            await connect(f"opc.tcp://127.0.0.1:{free_port()}/none/", INSECURE_LOOPBACK, timeout_s=1.0)
    run_async(attempt())
