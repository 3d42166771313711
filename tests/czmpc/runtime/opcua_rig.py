"""Rig of the plant-link tests: a PKI made with czmpc's own `pki` and a secured server.

The secured server is an independent asyncua server written here (not czmpc's served
plant): Basic256Sha256 SignAndEncrypt only, one trusted client certificate, one user.
It listens on 127.0.0.1 on a free port and stops with the test.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks._serving import free_loopback_port as free_port
from czmpc.runtime.pki import create_application_certificate

USER = "mpc-operator"
PASSWORD = "s3cret-Pa55-never-logged"
PASSWORD_ENV = "CZMPC_TEST_OPCUA_PASSWORD"
COMMAND_NODE = "ns=2;s=Rig.Command"


@dataclass(frozen=True)
class Pki:
    dir: Path
    client_cert: Path
    client_key: Path
    server_cert: Path
    server_key: Path
    rogue_cert: Path
    rogue_key: Path
    other_server_cert: Path


def make_pki(root: Path) -> Pki:
    client = create_application_certificate(root, app_uri="urn:test:czmpc", host="127.0.0.1")
    server = create_application_certificate(root, app_uri="urn:test:plant", host="127.0.0.1",
                                            name="server", role="server")
    rogue = create_application_certificate(root, app_uri="urn:test:czmpc", host="127.0.0.1", name="rogue")
    other = create_application_certificate(root, app_uri="urn:test:plant", host="127.0.0.1",
                                           name="other_server", role="server")
    return Pki(root, client.certificate, client.private_key, server.certificate, server.private_key,
               rogue.certificate, rogue.private_key, other.certificate)


@contextlib.asynccontextmanager
async def secured_server(pki: Pki) -> AsyncIterator[tuple[str, Any]]:
    """Yield (endpoint, command node) of a running secured server."""
    from asyncua import Server, ua
    from asyncua.crypto.permission_rules import User, UserRole
    from asyncua.crypto.truststore import TrustStore
    from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
    from asyncua.server.user_managers import UserManager

    class OneUser(UserManager):
        def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                     certificate: Any = None) -> User | None:
            if username == USER and password == PASSWORD:
                return User(role=UserRole.User, name=username)
            return None

    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/secured/"
    server = Server(user_manager=OneUser())
    await server.init()
    server.set_endpoint(endpoint)
    await server.set_application_uri("urn:test:plant")
    server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
    server.set_identity_tokens([ua.UserNameIdentityToken])
    await server.load_certificate(str(pki.server_cert))
    await server.load_private_key(str(pki.server_key))
    trusted = pki.dir / "server_trusted"
    trusted.mkdir(exist_ok=True)
    (trusted / "czmpc.der").write_bytes(pki.client_cert.read_bytes())
    store = TrustStore([trusted], [])
    await store.load()
    server.set_certificate_validator(CertificateValidator(
        CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT, store))
    ns = await server.register_namespace("urn:test:rig")
    rig = await server.nodes.objects.add_object(ns, "Rig")
    command = await rig.add_variable(ua.NodeId("Rig.Command", ns), "Command", 0.0)
    await command.set_writable()
    async with server:
        yield endpoint, command


def run_async(coro: Any, timeout_s: float = 30.0) -> Any:
    """Run a coroutine to completion, bounded in time (a hung test fails, never hangs)."""
    return asyncio.run(asyncio.wait_for(coro, timeout_s))


#: A second user of the served plant: an operator, who may not write the command.
OPERATOR = "shift-lead"
OPERATOR_PASSWORD = "0perator-Pa55-never-logged"
OPERATOR_ENV = "CZMPC_TEST_OPERATOR_PASSWORD"


def served_security_args(pki: Pki) -> list[str]:
    """`czmpc plant serve` options of a secured plant: the rig's PKI, USER and OPERATOR."""
    return ["--policy", "Basic256Sha256", "--mode", "SignAndEncrypt",
            "--certificate", str(pki.server_cert), "--private-key", str(pki.server_key),
            "--trusted-client", str(pki.client_cert), "--user", USER, "--password-env", PASSWORD_ENV,
            "--operator", f"{OPERATOR}={OPERATOR_ENV}"]
