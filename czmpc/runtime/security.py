"""OPC UA channel security of the plant link: the ``[plant.security]`` table, checked.

`parse_security` makes the table a frozen `SecuritySettings` and refuses, before any
connection, what an OT security officer would: no table (or ``policy = "None"``) on a
non-loopback endpoint, a ``password`` key (it comes from the variable ``password_env``
names, held in a `Secret`), a private key others can read, a missing file, an unknown key
(docs/reference/plant_security.rst). The served plant's side: `parse_server_security`
and `check_serve_address` (no unsecured non-loopback endpoint is ever bound).
"""

from __future__ import annotations

import ipaddress
import os
import stat
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit

from czmpc.config_text import choices, shown
from czmpc.errors import SettingsError

#: Security policies accepted (OPC UA names without the URI prefix); Basic256Sha256 is
#: the floor (Basic128Rsa15 and Basic256 use SHA-1, deprecated by the OPC Foundation).
SECURE_POLICIES = ("Basic256Sha256", "Aes128_Sha256_RsaOaep", "Aes256_Sha256_RsaPss")
#: Message security modes: signed, or signed and encrypted.
MODES = ("SignAndEncrypt", "Sign")
#: The keys of ``[plant.security]``, exactly (issue 18).
SECURITY_KEYS = ("policy", "mode", "certificate", "private_key", "server_certificate",
                 "username", "password_env")

Policy = Literal["None", "Basic256Sha256", "Aes128_Sha256_RsaOaep", "Aes256_Sha256_RsaPss"]
Mode = Literal["SignAndEncrypt", "Sign"]


class Secret:
    """A string that never shows itself in ``repr``, ``str`` or f-strings.

    Parameters
    ----------
    value :
        The secret (a password).
    """

    __slots__ = ("_value",)

    def __init__(self, value: str) -> None:
        self._value = value

    def reveal(self) -> str:
        """The secret itself: call only where it is handed to the OPC UA client."""
        return self._value

    def __repr__(self) -> str:
        return "Secret('********')"

    __str__ = __repr__

    def __format__(self, spec: str) -> str:
        return repr(self)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Secret) and other._value == self._value

    def __hash__(self) -> int:
        return hash(("Secret", self._value))


def is_loopback_endpoint(endpoint: str) -> bool:
    """Whether an ``opc.tcp://host:port/...`` endpoint names this machine's loopback."""
    host = urlsplit(endpoint).hostname or ""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True, kw_only=True)
class SecuritySettings:
    """Validated security of one OPC UA client connection.

    Parameters
    ----------
    policy :
        Security policy name (`SECURE_POLICIES`, or ``"None"`` on loopback only).
    mode :
        ``"SignAndEncrypt"`` or ``"Sign"``; ignored for policy ``"None"``.
    certificate, private_key :
        czmpc's application instance certificate (DER) and its private key (PEM).
    server_certificate :
        The server certificate pinned for this plant (DER); another one is refused.
    username :
        OPC UA user name, or None for an anonymous session.
    password, password_env :
        The user's password and the environment variable it came from.
    """

    policy: Policy
    mode: Mode = "SignAndEncrypt"
    certificate: Path | None = None
    private_key: Path | None = None
    server_certificate: Path | None = None
    username: str | None = None
    password: Secret | None = field(default=None, repr=False)
    password_env: str | None = None

    @property
    def secure(self) -> bool:
        """True unless the policy is ``"None"``."""
        return self.policy != "None"

    def describe(self) -> str:
        """One line for logs and status: policy, mode, user; never the password."""
        if not self.secure:
            return "no security (policy None; loopback only)"
        user = f"user {shown(self.username)}" if self.username else "anonymous"
        return f"{self.policy} {self.mode}, pinned server certificate, {user}"


#: What a run without a ``[plant.security]`` table gets (loopback only).
INSECURE_LOOPBACK = SecuritySettings(policy="None")


def _one_of(value: object, allowed: Sequence[str], option: str) -> None:
    if value not in allowed:
        raise SettingsError(f"{option} must be one of {choices(allowed)}; got {shown(value)}")


def _file(table: Mapping[str, object], key: str, base_dir: Path, where: str) -> Path:
    value = table.get(key)
    if not isinstance(value, str) or not value:
        raise SettingsError(f"{where}.{key} must name a file; got {shown(value)}")
    path = Path(value)
    path = path if path.is_absolute() else base_dir / path
    if not path.is_file():
        raise SettingsError(f"{where}.{key}: no such file {path}")
    return path


def check_private_key_permissions(path: Path, *, where: str = "plant.security.private_key") -> None:
    """Refuse a private key file that users other than its owner may read or write.

    Parameters
    ----------
    path :
        The key file.
    where :
        Config location named in the message.

    Raises
    ------
    SettingsError
        The file's mode grants group or others any permission.
    """
    if os.name != "posix":  # pragma: no cover - POSIX modes only
        return
    mode = stat.S_IMODE(path.stat().st_mode)
    if mode & 0o077:
        raise SettingsError(
            f"{where}: {path} is accessible by other users (mode {mode:o}); a private key must "
            f"be readable by its owner only: run 'chmod 600 {path}'")


def parse_security(table: Mapping[str, object] | None, *, endpoint: str, base_dir: Path,
                   environ: Mapping[str, str] | None = None) -> SecuritySettings:
    """Validate a run config's ``[plant.security]`` table against its endpoint.

    Parameters
    ----------
    table :
        The table as read from TOML, or None when the config has none.
    endpoint :
        The ``[plant].endpoint`` URL it secures.
    base_dir :
        Directory of relative file names (the config file's).
    environ :
        Environment to read the password from (default ``os.environ``).

    Returns
    -------
    SecuritySettings
        `INSECURE_LOOPBACK` for no table on a loopback endpoint.

    Raises
    ------
    SettingsError
        Every refusal the module docstring lists, naming the key and what to do.
    """
    where = "plant.security"
    if table is None:
        if not is_loopback_endpoint(endpoint):
            raise SettingsError(
                f"plant.endpoint {shown(endpoint)} is not a loopback address and the config has no "
                f"[plant.security] table: czmpc connects without security only to 127.0.0.1; "
                f"add [plant.security] with policy, mode, certificate, private_key and "
                f"server_certificate (make them with 'czmpc pki create')")
        return INSECURE_LOOPBACK
    if "password" in table:
        raise SettingsError(
            f"{where}.password: a password must not be written into the config file; remove it, "
            f"set password_env = \"NAME\" and put the password into the environment variable NAME")
    unknown = sorted(set(table) - set(SECURITY_KEYS))
    if unknown:
        raise SettingsError(f"{where}: unknown key(s) {unknown}; allowed: {choices(SECURITY_KEYS)}")
    policy = table.get("policy")
    if policy == "None":
        if not is_loopback_endpoint(endpoint):
            raise SettingsError(
                f"{where}.policy = \"None\" is allowed only for a loopback endpoint; "
                f"{shown(endpoint)} needs one of {choices(SECURE_POLICIES)}")
        return INSECURE_LOOPBACK
    _one_of(policy, [*SECURE_POLICIES, "None"], f"{where}.policy")
    mode = table.get("mode", "SignAndEncrypt")
    _one_of(mode, MODES, f"{where}.mode")
    certificate = _file(table, "certificate", base_dir, where)
    private_key = _file(table, "private_key", base_dir, where)
    check_private_key_permissions(private_key)
    server_certificate = _file(table, "server_certificate", base_dir, where)
    username = table.get("username")
    if username is not None and (not isinstance(username, str) or not username):
        raise SettingsError(f"{where}.username must be a non-empty string; got {shown(username)}")
    password_env = table.get("password_env")
    password: Secret | None = None
    if username is not None:
        if not isinstance(password_env, str) or not password_env:
            raise SettingsError(
                f"{where}: username {shown(username)} needs password_env = \"NAME\", the environment "
                f"variable that holds the password")
        password = _password(username, password_env, os.environ if environ is None else environ,
                             f"{where}.password_env")
    elif password_env is not None:
        raise SettingsError(f"{where}.password_env is set but username is not; add username")
    return SecuritySettings(
        policy=policy,  # type: ignore[arg-type]
        mode=mode,  # type: ignore[arg-type]
        certificate=certificate, private_key=private_key, server_certificate=server_certificate,
        username=username, password=password,
        password_env=password_env if isinstance(password_env, str) else None)


# --- The served plant's side (``czmpc plant serve``) ------------------------------------

#: Nodes of the served plant that only the controller's user may write.
CONTROLLER_NODES = ("TriacCommand", "Heartbeat", "ModelHealth", "Owner", "MPCStatus", "MPCMode",
                    "StaleAlarm", "Predicted", "TargetTriac", "MPCWatchdog")
#: Nodes of the served plant that an operator user may write (setpoint, manual mode).
OPERATOR_NODES = ("PowerSetpoint", "Mode")


@dataclass(frozen=True, kw_only=True)
class PlantUser:
    """A user who may log in to the served plant.

    Parameters
    ----------
    name :
        OPC UA user name.
    password, password_env :
        The password, and the environment variable it came from.
    controller :
        True for the controller's user (writes `CONTROLLER_NODES`); False for an
        operator (writes `OPERATOR_NODES`).
    """

    name: str
    password: Secret = field(repr=False)
    password_env: str
    controller: bool

    @property
    def writable_nodes(self) -> tuple[str, ...]:
        """Names of the ``Heater.*`` nodes this user may write."""
        return CONTROLLER_NODES if self.controller else OPERATOR_NODES


@dataclass(frozen=True, kw_only=True)
class ServerSecurity:
    """Validated security of the served plant's OPC UA server.

    Parameters
    ----------
    policy :
        One of `SECURE_POLICIES` (the only endpoint the server offers).
    mode :
        ``"SignAndEncrypt"`` or ``"Sign"``.
    certificate, private_key :
        The server's application instance certificate (DER) and key (PEM, mode 0600).
    trusted_clients :
        DER certificates of the client applications admitted (matched exactly).
    users :
        Who may log in; exactly one of them is the controller's user.
    """

    policy: Policy
    mode: Mode
    certificate: Path
    private_key: Path
    trusted_clients: tuple[Path, ...]
    users: tuple[PlantUser, ...]

    @property
    def controller_user(self) -> PlantUser:
        """The user who may write the command and the heartbeat."""
        return next(u for u in self.users if u.controller)

    def describe(self) -> str:
        """One line for the start-up message; never a password."""
        operators = [u.name for u in self.users if not u.controller]
        extra = f", operator(s) {operators} (setpoint, mode)" if operators else ""
        return (f"{self.policy} {self.mode}, {len(self.trusted_clients)} trusted client "
                f"certificate(s), controller user {shown(self.controller_user.name)} (command, "
                f"heartbeat){extra}, anonymous refused")


def _password(name: str, env_name: str, env: Mapping[str, str], option: str) -> Secret:
    if not env_name or not env_name.replace("_", "").isalnum():
        raise SettingsError(f"{option}: expected the name of an environment variable; got {shown(env_name)}")
    value = env.get(env_name)
    if not value:
        raise SettingsError(f"{option}: the environment variable {env_name} is not set (or empty); "
                            f"export it with the password of user {shown(name)}")
    return Secret(value)


def _trusted_clients(files: tuple[Path, ...], directory: Path | None) -> tuple[Path, ...]:
    found = list(files)
    for path in files:
        if not path.is_file():
            raise SettingsError(f"--trusted-client: no such file {path}")
    if directory is not None:
        if not directory.is_dir():
            raise SettingsError(f"--trusted-client-dir: no such directory {directory}")
        found += sorted(p for p in directory.iterdir()
                        if p.is_file() and p.suffix.lower() in {".der", ".pem"})
    if not found:
        raise SettingsError("a secured plant admits only trusted client certificates: give "
                            "--trusted-client CERT.der (the controller's, from 'czmpc pki create') "
                            "or --trusted-client-dir DIR")
    return tuple(found)


def parse_server_security(
    *, policy: str, mode: str = "SignAndEncrypt", certificate: Path | None = None,
    private_key: Path | None = None, trusted_clients: tuple[Path, ...] = (),
    trusted_client_dir: Path | None = None, user: str | None = None,
    password_env: str | None = None, operators: tuple[str, ...] = (),
    environ: Mapping[str, str] | None = None,
) -> ServerSecurity | None:
    """Validate the served plant's security options (``czmpc plant serve``).

    Parameters
    ----------
    policy :
        ``"None"`` or one of `SECURE_POLICIES`.
    mode :
        One of `MODES`.
    certificate, private_key :
        The server's certificate (DER) and private key (PEM, owner-only).
    trusted_clients, trusted_client_dir :
        Client certificates admitted, and a directory whose ``*.der`` / ``*.pem`` are too.
    user, password_env :
        The controller's user and the environment variable holding its password.
    operators :
        Further users as ``NAME=ENV_VAR``; they may write the setpoint and the mode only.
    environ :
        Environment to read passwords from (default ``os.environ``).

    Returns
    -------
    ServerSecurity or None
        None for policy ``"None"`` (no other option given).

    Raises
    ------
    SettingsError
        A missing file, a key readable by others, no trusted client, no user, an unset
        password variable, a duplicate user, or security options with policy ``"None"``.
    """
    given = [opt for opt, v in (("--certificate", certificate), ("--private-key", private_key),
                                ("--trusted-client", trusted_clients),
                                ("--trusted-client-dir", trusted_client_dir), ("--user", user),
                                ("--password-env", password_env), ("--operator", operators)) if v]
    if policy == "None":
        if given:
            raise SettingsError(f"{', '.join(given)} need a security policy: add --policy "
                                f"{SECURE_POLICIES[0]} (a password never travels unencrypted)")
        return None
    _one_of(policy, [*SECURE_POLICIES, "None"], "--policy")
    _one_of(mode, MODES, "--mode")
    if certificate is None or private_key is None:
        raise SettingsError(f"--policy {policy} needs the server's --certificate and --private-key "
                            f"(make them with 'czmpc pki create --role server')")
    for option, path in (("--certificate", certificate), ("--private-key", private_key)):
        if not path.is_file():
            raise SettingsError(f"{option}: no such file {path}")
    check_private_key_permissions(private_key, where="--private-key")
    clients = _trusted_clients(trusted_clients, trusted_client_dir)
    if not user or not password_env:
        raise SettingsError(f"--policy {policy} admits only configured users: give --user NAME (the "
                            f"controller's) and --password-env VAR (the variable holding its password)")
    env = os.environ if environ is None else environ
    users = [PlantUser(name=user, password=_password(user, password_env, env, "--password-env"),
                       password_env=password_env, controller=True)]
    for spec in operators:
        name, sep, var = spec.partition("=")
        if not sep or not name or not var:
            raise SettingsError(f"--operator: expected NAME=ENV_VAR; got {shown(spec)}")
        if any(u.name == name for u in users):
            raise SettingsError(f"--operator: user {shown(name)} is given twice")
        users.append(PlantUser(name=name, password=_password(name, var, env, "--operator"),
                               password_env=var, controller=False))
    return ServerSecurity(policy=policy,  # type: ignore[arg-type]
                          mode=mode,  # type: ignore[arg-type]
                          certificate=certificate, private_key=private_key,
                          trusted_clients=clients, users=tuple(users))


def check_serve_address(endpoint: str, security: ServerSecurity | None, *, insecure: bool) -> str | None:
    """Refuse to serve an unsecured plant beyond loopback (before anything binds); the
    warning for ``--insecure``.

    Parameters
    ----------
    endpoint :
        ``opc.tcp://HOST:PORT/PATH`` the server would listen on.
    security :
        From `parse_server_security` (None: no security).
    insecure :
        The operator's explicit ``--insecure``.

    Returns
    -------
    str or None
        The warning to print (on every start with ``--insecure``), else None.

    Raises
    ------
    SettingsError
        A non-loopback endpoint without security and without ``--insecure``, or
        ``--insecure`` together with a security policy.
    """
    if insecure and security is not None:
        raise SettingsError("--insecure contradicts --policy: drop one of them")
    if insecure:
        return (f"WARNING: --insecure: serving {endpoint} with no security (policy None, anonymous "
                f"users): anyone who can reach this address can write the heater's TRIAC command")
    if security is None and not is_loopback_endpoint(endpoint):
        raise SettingsError(
            f"--endpoint {shown(endpoint)} is not a loopback address: a plant served on another "
            f"interface needs --policy {SECURE_POLICIES[0]} with --certificate, --private-key, "
            f"--trusted-client and --user/--password-env (or, on an isolated test network only, "
            f"--insecure)")
    return None


__all__ = [
    "CONTROLLER_NODES",
    "INSECURE_LOOPBACK",
    "MODES",
    "OPERATOR_NODES",
    "PlantUser",
    "SECURE_POLICIES",
    "SECURITY_KEYS",
    "Secret",
    "SecuritySettings",
    "ServerSecurity",
    "check_private_key_permissions",
    "check_serve_address",
    "is_loopback_endpoint",
    "parse_security",
    "parse_server_security",
]
