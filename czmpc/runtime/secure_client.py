"""Open an OPC UA client session with the security a `SecuritySettings` asks for, or say why not.

First ``GetEndpoints`` on an unsecured discovery channel: the server must offer the
configured policy and mode with the pinned certificate, byte for byte; then the secure
channel and session with czmpc's certificate and user. Each refusal is a configuration
error (`SecurityRejectedError`, exit 2) within ``timeout_s``, never retried with a weaker
policy; no TCP connection or no answer is a network fault (`PlantUnreachableError`).
"""

from __future__ import annotations

import asyncio
import hashlib
from typing import Any

from czmpc.errors import CzmpcError
from czmpc.runtime._opcua import asyncua as load_asyncua
from czmpc.runtime.pki import application_uri
from czmpc.runtime.security import SecuritySettings

#: asyncua's client (typed loosely: asyncua is an optional dependency).
Client = Any

#: Security policy URIs of the OPC UA specification, by the names the config uses.
POLICY_URIS = {
    "None": "http://opcfoundation.org/UA/SecurityPolicy#None",
    "Basic256Sha256": "http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256",
    "Aes128_Sha256_RsaOaep": "http://opcfoundation.org/UA/SecurityPolicy#Aes128_Sha256_RsaOaep",
    "Aes256_Sha256_RsaPss": "http://opcfoundation.org/UA/SecurityPolicy#Aes256_Sha256_RsaPss",
}
#: Default bound on every network wait of a connection attempt [s].
CONNECT_TIMEOUT_S = 5.0


class SecurityRejectedError(CzmpcError):
    """The plant refused the link's security, or the link refused the plant: fix the config."""


class PlantUnreachableError(CzmpcError, ConnectionError):
    """The plant's server could not be reached (network fault: retry with backoff)."""


def thumbprint(der: bytes) -> str:
    """SHA-1 thumbprint of a DER certificate, hex, as OPC UA tools show it."""
    return hashlib.sha1(der, usedforsecurity=False).hexdigest()


def _mode_name(mode: object) -> str:
    return str(getattr(mode, "name", mode))


def _policy_name(uri: str) -> str:
    return uri.rsplit("#", 1)[-1]


def explain_status(code_name: str, settings: SecuritySettings) -> str | None:
    """Plain words for an OPC UA status code that means a security rejection, else None.

    Parameters
    ----------
    code_name :
        Status code name, e.g. ``"BadCertificateUntrusted"``.
    settings :
        The settings the connection used (named in the message; never the password).
    """
    if code_name.startswith("BadCertificate"):
        return (f"the server refused czmpc's certificate {settings.certificate} ({code_name}): "
                f"have its administrator add it to the server's trusted certificates")
    if code_name in {"BadUserAccessDenied", "BadIdentityTokenRejected", "BadIdentityTokenInvalid",
                     "BadUserSignatureInvalid"}:
        who = f"user {settings.username!r}" if settings.username else "an anonymous session"
        hint = (f"check the password in ${settings.password_env}" if settings.username
                else "set username and password_env in [plant.security]")
        return f"the server rejected {who} ({code_name}): {hint}"
    if code_name in {"BadSecurityPolicyRejected", "BadSecurityModeRejected", "BadSecurityChecksFailed"}:
        return (f"the server rejected the secure channel {settings.policy} {settings.mode} "
                f"({code_name})")
    return None


async def check_endpoint(client: Client, settings: SecuritySettings) -> None:
    """Step 1: the server offers the policy and mode, and presents the pinned certificate.

    Raises
    ------
    SecurityRejectedError
        No matching endpoint, or another server certificate than the pinned one.
    """
    endpoints = await client.connect_and_get_server_endpoints()
    ua = load_asyncua().ua
    wanted_mode = (getattr(ua.MessageSecurityMode, settings.mode) if settings.secure
                   else ua.MessageSecurityMode.None_)
    wanted_uri = POLICY_URIS[settings.policy]
    match = [ep for ep in endpoints if ep.SecurityPolicyUri == wanted_uri and ep.SecurityMode == wanted_mode]
    if not match:
        offered = sorted({f"{_policy_name(ep.SecurityPolicyUri)} {_mode_name(ep.SecurityMode)}"
                          for ep in endpoints})
        raise SecurityRejectedError(
            f"no matching endpoint: the server offers {offered}, the config asks for "
            f"{settings.describe()}; czmpc does not fall back to a weaker policy")
    if not settings.secure:
        return
    if settings.server_certificate is None:
        raise SecurityRejectedError(f"{settings.policy}: no server_certificate pinned in [plant.security]")
    pinned = settings.server_certificate.read_bytes()
    # ServerCertificate may be a chain: the server's own certificate comes first.
    presented = bytes(match[0].ServerCertificate or b"")[: len(pinned)]
    if presented != pinned:
        raise SecurityRejectedError(
            f"the server presents another certificate (SHA-1 {thumbprint(presented)}) "
            f"than the one pinned in server_certificate = {settings.server_certificate} "
            f"(SHA-1 {thumbprint(pinned)}); if the server's certificate was renewed, pin the new one")


async def connect(endpoint: str, settings: SecuritySettings, *,
                  timeout_s: float = CONNECT_TIMEOUT_S) -> Client:
    """Open a session to ``endpoint`` with ``settings``; return the connected client.

    Parameters
    ----------
    endpoint :
        ``opc.tcp://host:port/path``.
    settings :
        From `czmpc.runtime.security.parse_security`.
    timeout_s :
        Bound on each network wait [s].

    Raises
    ------
    SecurityRejectedError
        A security rejection (see the module docstring): do not retry.
    PlantUnreachableError
        The server did not answer or refused the TCP connection: retry with backoff.
    """
    asyncua = load_asyncua()
    client = asyncua.Client(endpoint, timeout=timeout_s)
    checked = False   # the server answered the discovery request and is the pinned one
    if settings.secure and (settings.certificate is None or settings.private_key is None):
        raise SecurityRejectedError(f"{settings.policy}: [plant.security] needs certificate and private_key")
    try:
        await asyncio.wait_for(check_endpoint(client, settings), timeout_s * 2)
        checked = True
        if settings.secure and settings.certificate is not None:
            uri = application_uri(settings.certificate.read_bytes())
            if uri is not None:
                client.application_uri = uri
            policy = getattr(asyncua.crypto.security_policies,
                             "SecurityPolicy" + settings.policy.replace("_", ""))
            await client.set_security(
                policy, str(settings.certificate), str(settings.private_key),
                server_certificate=str(settings.server_certificate),
                mode=getattr(asyncua.ua.MessageSecurityMode, settings.mode))
        if settings.username is not None and settings.password is not None:
            client.set_user(settings.username)
            client.set_password(settings.password.reveal())
        await asyncio.wait_for(client.connect(), timeout_s * 2)
    except SecurityRejectedError:
        raise
    except asyncua.ua.UaStatusCodeError as exc:
        name = type(exc).__name__
        reason = explain_status(name, settings)
        if reason is not None:
            raise SecurityRejectedError(reason) from None
        raise PlantUnreachableError(f"{endpoint}: the server answered {name}") from None
    except (TimeoutError, OSError) as exc:
        if checked and settings.secure and isinstance(exc, TimeoutError):
            # The endpoint check passed, so the server is there and is ours: a secure
            # channel that then never opens is a handshake the server dropped.
            raise SecurityRejectedError(
                f"{endpoint}: the server dropped the {settings.policy} {settings.mode} handshake "
                f"without an answer (it may not trust czmpc's certificate {settings.certificate})"
            ) from None
        raise PlantUnreachableError(f"{endpoint}: {type(exc).__name__}: {exc or 'no answer'}") from None
    return client


__all__ = [
    "CONNECT_TIMEOUT_S",
    "POLICY_URIS",
    "PlantUnreachableError",
    "SecurityRejectedError",
    "check_endpoint",
    "connect",
    "explain_status",
    "thumbprint",
]
