"""A plant served as an OPC UA server: the virtual CZ heater or a model plant.

The plant advances on its own clock, one sample every ``ts_s / time_scale`` wall
seconds, whether the controller keeps up or not (as a real puller does). Nodes, all in
namespace ``urn:czmpc:plant`` with string ids (``ns=2;s=Heater.Power`` on a fresh
server)::

    Heater.Power            Double  read    measured power [kW]; Bad quality during a
                                            sensor fault, source timestamp = sample time
    Heater.TriacCommand     Double  write   TRIAC command [%] (clipped to 0..100)
    Heater.TriacApplied     Double  read    TRIAC input applied over the last sample [%]
    Heater.PowerSetpoint    Double  r/w     setpoint [kW] (the scenario's, if one is given)
    Heater.Heartbeat        Int64   write   counter the controller increments every step
    Heater.Mode             String  r/w     OFF / PREDICT / ON (operator's choice)
    Heater.WatchdogTripped  Boolean read    True while the watchdog holds the safe input
    Heater.PlantTime_s      Double  read    plant time [s]
    Heater.ModelHealth      Double  write   the controller's model-health figure [-]
                                            (`czmpc.health`; >= 1: stale-model alarm)
    Heater.Owner            String  r/w     the controller's lease (its identity)
    Heater.MPCStatus        String  write   controller status GOOD/PREDICTED/.../SHED
    Heater.MPCMode          String  write   mode in effect OFF/PREDICT/ON
    Heater.StaleAlarm       Boolean write   the stale-model alarm
    Heater.Predicted        Double  write   power predicted for the next sample [kW]
    Heater.TargetTriac      Double  write   the MPC's target input [%]
    Heater.MPCWatchdog      Int64   write   czmpc's own watchdog counter
    Heater.GridVoltage      Double  read    grid voltage relative to nominal [-] applied
                                            over the last sample (the scenario's grid
                                            events; 1 without), published with the power
    Heater.SetpointPreview  Double[] read   setpoints [kW] of the coming samples, element
                                            0 the next sample, ``ServeOptions.
                                            setpoint_preview_s`` long (the scenario's
                                            recipe; empty without one)

``ServeOptions.node_types = "plc"`` types them as a PLC does (`NODE_TYPES`).

Watchdog (as a PLC has one): after ``watchdog_s`` [plant s] without a new heartbeat the
applied input moves to ``safe_triac_pct`` and ``WatchdogTripped`` turns True. It arms at
the first heartbeat; a new heartbeat and a new command re-arm it.

Security (``ServeOptions.security``): one endpoint with the configured policy and mode;
a client needs a trusted certificate (byte for byte, checked again against the secure
channel's) and a configured user's password, and writes only its user's nodes; each
refusal is logged, never a password (docs/guides/plant_link.rst). Without: policy None,
anonymous.

Plant log (``ServeOptions.log_path``, `PLANT_LOG_COLUMNS`): one row per sample with the
*true* power no controller sees. History (``ServeOptions.historize``): every change of
`HISTORIZED_NODES`, in memory or SQLite, for HistoryRead (docs/guides/history.rst).
"""

from __future__ import annotations

import asyncio
import csv
import datetime as dt
import hmac
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from czmpc.modes import Mode
from czmpc.runtime._opcua import asyncua
from czmpc.runtime.pki import application_uri
from czmpc.runtime.security import ServerSecurity
from sim.disturbances import exogenous_at, fault_profile
from sim.protocols import NOMINAL, Exogenous, Plant
from sim.scenario import Scenario

NAMESPACE_URI = "urn:czmpc:plant"
#: Each ``Heater.*`` node: its name, its run config ``[nodes]`` key (None: none), and its
#: type in the ``"czmpc"`` and the ``"plc"`` profile.
_NODES = (
    ("Power", "power_kw", "Double", "Float"),
    ("TriacCommand", "triac_pct", "Double", "Float"),
    ("TriacApplied", "applied_triac_pct", "Double", "Float"),
    ("PowerSetpoint", "setpoint_kw", "Double", "Float"),
    ("Heartbeat", "heartbeat", "Int64", "UInt16"),
    ("Mode", "mode", "String", "Int16"),
    ("WatchdogTripped", None, "Boolean", "Boolean"),
    ("PlantTime_s", None, "Double", "Float"),
    ("ModelHealth", "model_health", "Double", "Float"),
    ("Owner", "owner", "String", "String"),
    ("MPCStatus", "status", "String", "Int16"),
    ("MPCMode", "mode_in_effect", "String", "Int16"),
    ("StaleAlarm", "stale_alarm", "Boolean", "Boolean"),
    ("Predicted", "predicted_power_kw", "Double", "Float"),
    ("TargetTriac", "target_triac_pct", "Double", "Float"),
    ("MPCWatchdog", "watchdog", "Int64", "UInt16"),
    ("GridVoltage", "grid_voltage_factor", "Double", "Float"),
    ("SetpointPreview", "setpoint_preview_kw", "Double", "Float"),
)
#: The nodes that hold a one-dimensional array (ValueRank 1) of their type.
ARRAY_NODES = frozenset({"SetpointPreview"})
#: The served plant's node ids by the run config's ``[nodes]`` keys (``ns=2``: the
#: namespace `NAMESPACE_URI` is the first one a fresh server registers).
SERVED_NODE_IDS = {key: f"ns=2;s=Heater.{name}" for name, key, *_ in _NODES if key is not None}
#: The OPC UA data type of each node, by profile: ``"czmpc"`` (the default) and ``"plc"``.
NODE_TYPES: dict[str, dict[str, str]] = {
    profile: {name: types[i] for name, _, *types in _NODES}
    for i, profile in enumerate(("czmpc", "plc"))}
#: Columns of the plant log: plant time [s], wall-clock time of the sample [s since the
#: epoch, as a run log's ``wall_time_s``], TRIAC input applied over the sample [%], true
#: and published power [kW], ``good`` or ``bad`` quality, and the watchdog's state (0/1).
PLANT_LOG_COLUMNS = ("plant_time_s", "wall_time_s", "triac_applied_pct", "power_true_kw",
                     "power_measured_kw", "quality", "watchdog_tripped")
#: The nodes ``ServeOptions.historize`` historizes.
HISTORIZED_NODES = ("Power", "TriacApplied")


@dataclass(frozen=True, slots=True, kw_only=True)
class ServeOptions:
    """How the plant is served.

    Parameters
    ----------
    endpoint :
        ``opc.tcp://HOST:PORT/PATH``.
    time_scale :
        Plant samples per ``ts_s`` of wall time (>= 1).
    watchdog_s :
        Heartbeat silence [plant s] after which the safe input is applied; None: off.
    safe_triac_pct :
        The watchdog's input [%].
    duration_s :
        Stop after this plant time [s]; None: until cancelled.
    setpoint_kw :
        Initial value of the setpoint node [kW].
    security :
        Policy, certificates and users (module docstring); None: no security.
    log_path :
        Plant log (CSV, `PLANT_LOG_COLUMNS`, one row per sample); None: none.
    node_types :
        ``"czmpc"`` (Double, Int64, String) or ``"plc"`` (Float, UInt16, Int16): `NODE_TYPES`.
    historize :
        Historize `HISTORIZED_NODES` for OPC UA HistoryRead (module docstring).
    history_path :
        With ``historize``: the SQLite file of the history (kept across restarts); None:
        in memory.
    history_page_values :
        Most values one HistoryRead returns before a continuation point (>= 1).
    setpoint_preview_s :
        How far ahead ``Heater.SetpointPreview`` holds the scenario's setpoints [plant s]
        (>= 0; ``round(setpoint_preview_s / ts_s)`` elements, fewer near the scenario's end).
    """

    endpoint: str
    time_scale: float = 1.0
    watchdog_s: float | None = 10.0
    safe_triac_pct: float = 0.0
    duration_s: float | None = None
    setpoint_kw: float = 45.0
    security: ServerSecurity | None = None
    log_path: Path | None = None
    node_types: str = "czmpc"
    historize: bool = False
    history_path: Path | None = None
    history_page_values: int = 10000
    setpoint_preview_s: float = 60.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.setpoint_preview_s) and self.setpoint_preview_s >= 0.0):
            raise ValueError(f"setpoint_preview_s: expected a finite number >= 0; "
                             f"got {self.setpoint_preview_s!r}")
        if self.node_types not in NODE_TYPES:
            raise ValueError(f"node_types: expected one of {sorted(NODE_TYPES)}; "
                             f"got {self.node_types!r}")
        if self.history_page_values < 1:
            raise ValueError(f"history_page_values: expected an integer >= 1; "
                             f"got {self.history_page_values!r}")


def _utcnow() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


class ServedPlant:
    """A `sim.protocols.Plant` behind an OPC UA server (module docstring for the nodes).

    Parameters
    ----------
    plant :
        The plant (already reset); its ``ts_s`` is the sampling time.
    initial_triac_pct :
        The input the plant sits at [%] (published as command and applied).
    options :
        Endpoint, time scale, watchdog.
    scenario :
        Optional: its setpoints are published, its grid events and sensor faults applied.
    seed :
        Seed of the scenario's random sensor faults.
    log :
        Called with a line of text on notable events (watchdog, stop, each refused login,
        session or write: who and why, never a password).
    """

    def __init__(self, plant: Plant, *, initial_triac_pct: float, options: ServeOptions,
                 scenario: Scenario | None = None, seed: int = 0,
                 log: Callable[[str], None] | None = None) -> None:
        self.plant = plant
        self.options = options
        self.scenario = scenario
        self.ts_s = float(plant.ts_s)
        self._triac_pct = float(initial_triac_pct)
        self._log = log or (lambda _msg: None)
        self.k = 0
        self.watchdog_tripped = False
        self.n_watchdog_trips = 0
        self.silent_samples_at_trip = 0
        self._faults = None
        if scenario is not None:
            self._faults = fault_profile(scenario.faults, n_steps=scenario.n_steps,
                                         ts_s=self.ts_s, rng=np.random.default_rng(seed))
            self._setpoints = scenario.setpoint_profile_kw()
        self._nodes: dict[str, Any] = {}
        self._server: Any = None
        self.ready = asyncio.Event()

    def _vtype(self, name: str) -> Any:
        ua = asyncua().ua
        return getattr(ua.VariantType, NODE_TYPES[self.options.node_types][name])

    async def _add(self, folder: Any, idx: int, name: str, value: Any, writable: bool) -> None:
        ua = asyncua().ua
        vtype = self._vtype(name)
        if vtype == ua.VariantType.Int16 and isinstance(value, str):
            value = list(Mode).index(Mode[value])        # an INT mode: 0 OFF, 1 PREDICT, 2 ON
        node = await folder.add_variable(ua.NodeId(f"Heater.{name}", idx), name,
                                         ua.Variant(value, vtype), datatype=ua.NodeId(vtype.value, 0))
        if name in ARRAY_NODES:
            await node.write_attribute(ua.AttributeIds.ValueRank, ua.DataValue(
                ua.Variant(ua.ValueRank.OneDimension, ua.VariantType.Int32)))
            await node.write_attribute(ua.AttributeIds.ArrayDimensions, ua.DataValue(
                ua.Variant([0], ua.VariantType.UInt32)))
        if writable:
            await node.set_writable()
        self._nodes[name] = node

    async def _publish(self, name: str, value: Any, *, good: bool = True) -> None:
        ua = asyncua().ua
        vtype = self._vtype(name)
        status = ua.StatusCode(ua.StatusCodes.Good if good else ua.StatusCodes.BadSensorFailure)
        dv = ua.DataValue(ua.Variant(value, vtype), StatusCode=status,
                          SourceTimestamp=_utcnow(), ServerTimestamp=_utcnow())
        await self._nodes[name].write_value(dv)

    async def _read(self, name: str) -> Any:
        return await self._nodes[name].read_value()

    def _exogenous(self) -> Exogenous:
        if self.scenario is None:
            return NOMINAL
        return exogenous_at(self.scenario.disturbances, self.k, self.ts_s)

    def setpoints_ahead_kw(self) -> list[float]:
        """The scenario's setpoints [kW] of the samples after the current one, element 0 the
        next, `ServeOptions.setpoint_preview_s` long (cut at the scenario's end; empty
        without a scenario): what ``Heater.SetpointPreview`` holds."""
        if self.scenario is None:
            return []
        n = round(self.options.setpoint_preview_s / self.ts_s)
        return [float(x) for x in self._setpoints[self.k + 1:self.k + 1 + n]]

    async def serve(self) -> None:
        """Run the server until ``options.duration_s`` of plant time or cancellation."""
        aua = asyncua()
        ua = aua.ua
        security = self.options.security
        server = aua.Server() if security is None else aua.Server(
            user_manager=_UserManager(security, self._log))
        if self.options.historize:
            server.iserver.history_manager.set_storage(_history_storage(self.options))
        await server.init()
        server.set_endpoint(self.options.endpoint)
        server.set_server_name("czmpc served plant")
        if security is None:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        idx = await server.register_namespace(NAMESPACE_URI)
        if security is not None:
            await _secure(server, security, idx, self._log)
        folder = await server.nodes.objects.add_object(ua.NodeId("Heater", idx), "Heater")
        sp0 = float(self._setpoints[0]) if self.scenario is not None else self.options.setpoint_kw
        plc = self.options.node_types == "plc"
        for name, value, writable in (
                ("Power", float(self.plant.true_power_kw), False),
                ("TriacCommand", self._triac_pct, True), ("TriacApplied", self._triac_pct, False),
                ("PowerSetpoint", sp0, True), ("Heartbeat", 0, True), ("Mode", "ON", True),
                ("WatchdogTripped", False, False), ("PlantTime_s", 0.0, False),
                ("ModelHealth", 0.0, True),
                # the controller's state, written by czmpc run for the HMI ([nodes] state keys)
                ("Owner", "", True), ("MPCStatus", 7 if plc else "", True),
                ("MPCMode", "OFF", True), ("StaleAlarm", False, True), ("Predicted", 0.0, True),
                ("TargetTriac", 0.0, True), ("MPCWatchdog", 0, True),
                ("GridVoltage", float(self._exogenous().grid_voltage_factor), False),
                ("SetpointPreview", self.setpoints_ahead_kw(), False)):
            await self._add(folder, idx, name, value, writable)
        self._server = server
        log_file: IO[str] | None = None
        if self.options.log_path is not None:
            self.options.log_path.parent.mkdir(parents=True, exist_ok=True)
            log_file = open(self.options.log_path, "w", newline="", encoding="utf-8")  # noqa: SIM115
        try:
            async with server:
                if self.options.historize:
                    await server.historize_node_data_change(
                        [self._nodes[name] for name in HISTORIZED_NODES], period=None, count=0)
                self.ready.set()
                await self._run_clock(log_file)
        finally:
            if log_file is not None:
                log_file.close()

    async def _run_clock(self, log_file: IO[str] | None) -> None:
        log = None if log_file is None else csv.writer(log_file)
        if log is not None and log_file is not None:
            log.writerow(PLANT_LOG_COLUMNS)
            log.writerow(self._log_row(float(self.plant.true_power_kw), good=True))
            log_file.flush()
        period = self.ts_s / self.options.time_scale
        wd_samples = (None if self.options.watchdog_s is None
                      else max(1, math.ceil(self.options.watchdog_s / self.ts_s)))
        last_hb = await self._read("Heartbeat")
        last_cmd = float(await self._read("TriacCommand"))
        silent = 0
        armed = False  # a watchdog watches a controller once one has shown up
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        n_end = (None if self.options.duration_s is None
                 else round(self.options.duration_s / self.ts_s))
        while n_end is None or self.k < n_end:
            await asyncio.sleep(max(0.0, t0 + (self.k + 1) * period - loop.time()))
            hb = await self._read("Heartbeat")
            cmd = float(await self._read("TriacCommand"))
            silent = 0 if hb != last_hb else silent + 1
            armed = armed or hb != last_hb
            last_hb = hb
            if armed and wd_samples is not None and silent >= wd_samples and not self.watchdog_tripped:
                self.watchdog_tripped = True
                self.n_watchdog_trips += 1
                self.silent_samples_at_trip = silent
                self._log(f"watchdog: no heartbeat for {silent * self.ts_s:g} s of plant time; "
                          f"TRIAC -> safe {self.options.safe_triac_pct:g} %")
            elif self.watchdog_tripped and silent == 0 and cmd != last_cmd:
                self.watchdog_tripped = False
                self._log("watchdog: heartbeat and command back; re-armed")
            last_cmd = cmd
            if self.watchdog_tripped:
                self._triac_pct = self.options.safe_triac_pct
            elif math.isfinite(cmd):
                self._triac_pct = min(100.0, max(0.0, cmd))
            exogenous = self._exogenous()
            measured = float(self.plant.step(self._triac_pct, exogenous))
            self.k += 1
            good = math.isfinite(measured)
            if self._faults is not None and self.k < len(self._faults.missing):
                good = good and not bool(self._faults.missing[self.k])
                measured += float(self._faults.spike_kw[self.k])
                await self._publish("PowerSetpoint", float(self._setpoints[self.k]))
            # the voltage that acted over the sample just measured (a plant's own, with the
            # heater's slow grid wander, where it has one) and the coming setpoints, before
            # the power: a read keyed to the power's timestamp finds them current
            await self._publish("GridVoltage", float(getattr(
                self.plant, "grid_voltage_factor", exogenous.grid_voltage_factor)))
            await self._publish("SetpointPreview", self.setpoints_ahead_kw())
            await self._publish("Power", measured if good else 0.0, good=good)
            await self._publish("TriacApplied", self._triac_pct)
            await self._publish("WatchdogTripped", self.watchdog_tripped)
            await self._publish("PlantTime_s", self.k * self.ts_s)
            if log is not None and log_file is not None:
                log.writerow(self._log_row(measured, good=good))
                log_file.flush()
        self._log(f"plant: stopped after {self.k * self.ts_s:g} s of plant time")

    def _log_row(self, measured_kw: float, *, good: bool) -> tuple[object, ...]:
        """One row of the plant log (`PLANT_LOG_COLUMNS`) for the current sample."""
        return (f"{self.k * self.ts_s:.6g}", f"{time.time():.6f}", f"{self._triac_pct:.6g}",
                f"{float(self.plant.true_power_kw):.9g}", f"{measured_kw:.9g}",
                "good" if good else "bad", int(self.watchdog_tripped))


def _history_storage(options: ServeOptions) -> Any:
    """asyncua's history storage for ``options``: a SQLite file, or memory."""
    page = options.history_page_values
    if options.history_path is None:
        from asyncua.server.history import HistoryDict

        return HistoryDict(max_history_data_response_size=page)
    from asyncua.server.history_sql import HistorySQLite

    base: Any = HistorySQLite   # asyncua's storages are untyped

    class SQLiteHistory(base):  # type: ignore[misc]
        """One table per node, named ``2_Heater.Power``: asyncua 2.1 names it by the
        repr of a string id (``2_'Heater.Power'``), which its own table-name check refuses."""

        def _get_table_name(self, node_id: Any) -> str:
            return f"{node_id.NamespaceIndex}_{node_id.Identifier}"

    options.history_path.parent.mkdir(parents=True, exist_ok=True)
    return SQLiteHistory(str(options.history_path), max_history_data_response_size=page)


def _load_der(path: Any) -> bytes:
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding

    data = path.read_bytes()
    if data.lstrip().startswith(b"-----BEGIN"):
        return x509.load_pem_x509_certificate(data).public_bytes(Encoding.DER)
    return bytes(data)


class _UserManager:
    """asyncua user manager: configured users over a channel with a trusted certificate;
    every refused login is logged (user name and reason, never the password)."""

    def __init__(self, security: ServerSecurity, log: Callable[[str], None]) -> None:
        self._users = {u.name: u for u in security.users}
        self._trusted = frozenset(_load_der(p) for p in security.trusted_clients)
        self._log = log

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> Any:
        from asyncua.crypto.permission_rules import User, UserRole

        who = f"user {username!r}" if username else "an anonymous client"
        # the secure channel's peer certificate: empty on an unsecured (discovery) channel
        if not certificate:
            self._log(f"security: refused login of {who}: no secure channel")
            return None
        if bytes(certificate) not in self._trusted:
            self._log(f"security: refused login of {who}: untrusted client certificate")
            return None
        user = self._users.get(username or "")
        if user is None or password is None or not hmac.compare_digest(
                password.encode(), user.password.reveal().encode()):
            self._log(f"security: refused login of {who}: unknown user or wrong password")
            return None
        return User(role=UserRole.User, name=user.name)


def _permission_rules(security: ServerSecurity, idx: int, log: Callable[[str], None]) -> Any:
    """asyncua permission ruleset: users' service set, writes only to each user's nodes."""
    from asyncua.common.utils import Buffer
    from asyncua.crypto.permission_rules import SimpleRoleRuleset
    from asyncua.ua.ua_binary import struct_from_binary

    ua = asyncua().ua
    write_id = ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)
    writable = {u.name: frozenset(ua.NodeId(f"Heater.{n}", idx) for n in u.writable_nodes)
                for u in security.users}

    base: Any = SimpleRoleRuleset   # asyncua's rulesets are untyped

    class Rules(base):  # type: ignore[misc]
        def check_validity(self, user: Any, action_type_id: Any, body: Any) -> bool:
            if not super().check_validity(user, action_type_id, body):
                return False
            if action_type_id != write_id:
                return True
            allowed = writable.get(getattr(user, "name", None) or "", frozenset())
            copy = body.copy() if isinstance(body, Buffer) else Buffer(bytes(body))
            params = struct_from_binary(ua.WriteParameters, copy)
            denied = [w.NodeId.Identifier for w in params.NodesToWrite
                      if w.NodeId not in allowed or w.AttributeId != ua.AttributeIds.Value]
            if denied:
                log(f"security: refused write by user {getattr(user, 'name', None)!r} to "
                    f"{', '.join(map(str, denied))} (BadUserAccessDenied)")
            return not denied

    rules: Any = Rules
    return rules()


async def _secure(server: Any, security: ServerSecurity, idx: int,
                  log: Callable[[str], None]) -> None:
    """Offer only the configured policy, trusted client certificates and configured users."""
    aua = asyncua()
    ua = aua.ua
    from asyncua.common.utils import ServiceError
    from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

    policy_type = getattr(ua.SecurityPolicyType,
                          f"{security.policy.replace('_', '')}_{security.mode}")
    server.set_security_policy([policy_type], permission_ruleset=_permission_rules(security, idx, log))
    server.set_identity_tokens([ua.UserNameIdentityToken])
    cert_der = _load_der(security.certificate)
    uri = application_uri(cert_der)
    if uri is not None:
        await server.set_application_uri(uri)
    await server.load_certificate(str(security.certificate))
    await server.load_private_key(str(security.private_key))
    trusted = frozenset(_load_der(p) for p in security.trusted_clients)
    # time range, application URI, key usage and client role, without a trust store:
    checks = CertificateValidator(CertificateValidatorOptions.EXT_VALIDATION
                                  | CertificateValidatorOptions.PEER_CLIENT)

    async def validate(cert: Any, app_description: Any) -> None:
        from cryptography.hazmat.primitives.serialization import Encoding

        client = app_description.ApplicationUri
        if cert.public_bytes(Encoding.DER) not in trusted:
            log(f"security: refused session of client {client!r}: untrusted certificate "
                f"(BadCertificateUntrusted)")
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
        try:
            await checks.validate(cert, app_description)
        except ServiceError as exc:   # expired, another URI, or not a client's key usage
            log(f"security: refused session of client {client!r}: "
                f"{ua.StatusCode(exc.code).name}")
            raise

    server.set_certificate_validator(validate)


__all__ = ["ARRAY_NODES", "HISTORIZED_NODES", "NAMESPACE_URI", "NODE_TYPES", "ServeOptions",
           "ServedPlant"]
