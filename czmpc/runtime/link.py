"""The client side of the plant link: one OPC UA session, its typed nodes, hard deadlines.

Once per session (`PlantLink.connect`) the link reads every configured node's
``DataType``, ``ValueRank``, access levels and value in one Read request and checks it
against what czmpc does with it (`ROLES`); the result is a `CheckReport` (the table of
``czmpc run --check``), and a run writes nothing until it has passed. Each step then makes
one Read and one Write request, each value a Variant of the node's own type
(`czmpc.runtime.node_types`) without timestamps. A Bad write status is a refusal
(`czmpc.runtime.refusals`), never a lost link. Every call has a hard deadline
(`within`): a call that misses it is abandoned and the socket closed at once
(`PlantLink.abort`), so a server that stops answering never holds the loop longer than
that. Where the server sends no source timestamps the loop uses server timestamps
(`czmpc.runtime.measurement.sample_time`).
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from czmpc.errors import CzmpcError
from czmpc.runtime import refusals
from czmpc.runtime._opcua import asyncua
from czmpc.runtime.config import RunConfig
from czmpc.runtime.node_types import (
    INTEGER_RANGES,
    NUMERIC_TYPES,
    NodeSpec,
    NodeType,
    NodeValueError,
    builtin_type_name,
    encode,
    next_heartbeat,
)
from czmpc.runtime.secure_client import connect as secure_connect

T = TypeVar("T")

#: Largest model-health figure written (the alarm is at >= 1; a larger figure only says
#: "far over the limit", and an integer tag must still carry it).
HEALTH_TOP = 100.0


@dataclass(frozen=True, slots=True)
class NodeRole:
    """What czmpc does with a configured node.

    ``kind``: ``"number"`` (read or written as a number in czmpc's units), ``"counter"``
    (the heartbeat), ``"mode"`` (OFF/PREDICT/ON as text, an integer 0/1/2 or a bool) or
    ``"text"`` (a String), ``"word"`` (an enumeration: its name as text, or its index as an
    integer), ``"flag"`` (a bool, or 0/1 as an integer) or ``"array"`` (a one-dimensional
    array of numbers in czmpc's units).
    ``carries``: values a written number must be able to take (after scaling).
    """

    reads: bool
    writes: bool
    kind: str = "number"
    carries: tuple[float, ...] = ()
    what: str = ""


#: The run config's ``[nodes]`` keys and their roles.
ROLES: dict[str, NodeRole] = {
    "power_kw": NodeRole(reads=True, writes=False, what="measured power [kW]"),
    "triac_pct": NodeRole(reads=False, writes=True, carries=(0.0, 100.0),
                          what="TRIAC command 0..100 [%]"),
    "applied_triac_pct": NodeRole(reads=True, writes=False, what="applied TRIAC input [%]"),
    "setpoint_kw": NodeRole(reads=True, writes=False, what="power setpoint [kW]"),
    "heartbeat": NodeRole(reads=False, writes=True, kind="counter", what="watchdog counter"),
    "mode": NodeRole(reads=True, writes=False, kind="mode", what="operator's mode"),
    "model_health": NodeRole(reads=False, writes=True, carries=(0.0, HEALTH_TOP),
                             what="model-health figure 0..100 [-]"),
    "owner": NodeRole(reads=True, writes=True, kind="text",
                      what="controller's identity (the writer's lease)"),
    # the controller's state, published for the HMI and the historian
    "status": NodeRole(reads=False, writes=True, kind="word",
                       what="controller status (text, or 0 GOOD .. 4 SHED)"),
    "mode_in_effect": NodeRole(reads=False, writes=True, kind="word",
                               what="mode in effect (text, or 0 OFF, 1 PREDICT, 2 ON)"),
    "stale_alarm": NodeRole(reads=False, writes=True, kind="flag",
                            what="stale-model alarm (bool or 0/1)"),
    "predicted_power_kw": NodeRole(reads=False, writes=True, carries=(0.0,),
                                   what="power predicted for the next sample [kW]"),
    "target_triac_pct": NodeRole(reads=False, writes=True, carries=(0.0, 100.0),
                                 what="target TRIAC input 0..100 [%]"),
    "watchdog": NodeRole(reads=False, writes=True, kind="counter",
                         what="czmpc's own watchdog counter"),
    # what the plant tells the controller about the coming samples and the grid
    "setpoint_preview_kw": NodeRole(reads=True, writes=False, kind="array",
                                    what="setpoints of the coming samples [kW], element 0 the "
                                         "next sample"),
    "grid_voltage_factor": NodeRole(reads=True, writes=False,
                                    what="grid voltage relative to nominal [-]"),
}


class CallDeadlineError(TimeoutError):
    """An OPC UA call missed its deadline; it was abandoned and the socket closed."""


class LinkLostError(CzmpcError, ConnectionError):
    """The session or its transport failed (not a refusal): reconnect with backoff."""


async def within(awaitable: Awaitable[T], deadline_s: float, what: str) -> T:
    """Await ``awaitable`` for at most ``deadline_s`` [wall s]; abandon it after that.

    Unlike `asyncio.wait_for`, the call is not awaited after its cancellation: a
    library that swallows the cancellation (asyncua's session close does) cannot
    extend the deadline.

    Raises
    ------
    CallDeadlineError
        The deadline passed (the call is cancelled and left to end by itself).
    """
    task = asyncio.ensure_future(awaitable)
    done, _ = await asyncio.wait({task}, timeout=max(0.0, deadline_s))
    if not done:
        task.cancel()
        task.add_done_callback(_swallow)
        raise CallDeadlineError(f"{what}: no answer within {deadline_s:.3g} s")
    return task.result()


def _swallow(task: asyncio.Future[Any]) -> None:
    if not task.cancelled():
        task.exception()


@dataclass(frozen=True, slots=True)
class NodeCheck:
    """One configured node as the server has it, and whether czmpc can use it.

    ``problem`` is None for a usable node; otherwise it names the code or the type
    and what to change. ``code`` is the OPC UA status the problem amounts to.
    """

    key: str
    node: str
    type_name: str = "-"
    value_rank: str = "-"
    access: str = "-"
    timestamps: str = "-"
    problem: str | None = None
    code: str | None = None
    note: str = ""


@dataclass(frozen=True, slots=True)
class CheckReport:
    """The pre-flight check of every configured node (`PlantLink.connect`)."""

    endpoint: str
    checks: tuple[NodeCheck, ...]

    @property
    def ok(self) -> bool:
        """True when every node can be used."""
        return all(c.problem is None for c in self.checks)

    @property
    def problems(self) -> tuple[NodeCheck, ...]:
        """The nodes that cannot be used."""
        return tuple(c for c in self.checks if c.problem is not None)

    def table(self) -> str:
        """The check as a plain-text table, one row per node, then the problems' fixes."""
        head = ("node", "node id", "DataType", "rank", "access", "timestamps", "verdict")
        rows = [head] + [(c.key, c.node, c.type_name, c.value_rank, c.access, c.timestamps,
                          "ok" if c.problem is None else f"FAIL {c.code or ''}".strip())
                         for c in self.checks]
        widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
        lines = ["  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)).rstrip()
                 for r in rows]
        lines.insert(1, "  ".join("-" * w for w in widths))
        for c in self.checks:
            if c.problem is not None:
                lines.append(f"{c.key}: {c.problem}")
            elif c.note:
                lines.append(f"{c.key}: note: {c.note}")
        return "\n".join(lines)


def _access_words(readable: bool, writable: bool) -> str:
    return ("r" if readable else "-") + ("w" if writable else "-")


def _held(dv: Any) -> Any:
    """The Python value a DataValue holds (None: no Variant)."""
    return None if dv.Value is None else dv.Value.Value


def _timestamps(dv: Any) -> str:
    if dv.SourceTimestamp is not None:
        return "source"
    return "server only" if dv.ServerTimestamp is not None else "none"


def check_node(key: str, spec: NodeSpec, values: Mapping[str, Any], *,
               user: str | None, command_readable_needed: bool = False) -> tuple[NodeCheck,
                                                                                NodeType | None]:
    """Judge one node from its read attributes (``values``: attribute name -> DataValue).

    Pure: the attributes come from one Read request (`PlantLink.connect`).
    """
    ua = asyncua().ua
    role = ROLES[key]
    node = spec.describe()
    value_dv = values["Value"]
    status = value_dv.StatusCode
    if status is not None and status.name in ("BadNodeIdUnknown", "BadNodeIdInvalid"):
        return NodeCheck(key, node, problem=f"{status.name}: " + refusals.fix_for(
            status.name, key=key, node=node), code=status.name), None
    dtype = _held(values["DataType"])
    type_name = None if dtype is None else builtin_type_name(dtype.NamespaceIndex, dtype.Identifier)
    held = value_dv.Value.VariantType.name if value_dv.Value is not None else None
    note = ""
    if type_name is None and held in NUMERIC_TYPES | {"Boolean", "String"}:
        note = f"DataType {dtype.to_string() if dtype is not None else '?'}: written as {held}, " \
               "the type of the value it holds"
        type_name = held
    type_name = type_name or (dtype.to_string() if dtype is not None else "unknown")
    rank = -1 if _held(values["ValueRank"]) is None else int(_held(values["ValueRank"]))
    bits = {name: int(_held(values[name]) or 0) for name in ("AccessLevel", "UserAccessLevel")}
    read_bit, write_bit = 1 << ua.AccessLevel.CurrentRead, 1 << ua.AccessLevel.CurrentWrite
    node_writable = bool(bits["AccessLevel"] & write_bit)
    readable = bool(bits["UserAccessLevel"] & read_bit)
    writable = bool(bits["UserAccessLevel"] & write_bit)
    info = NodeType(type_name, rank, readable, writable)
    common = {"key": key, "node": node, "type_name": type_name, "value_rank": str(rank),
              "access": _access_words(readable, writable), "timestamps": _timestamps(value_dv)}

    def fail(code: str | None, text: str) -> tuple[NodeCheck, NodeType | None]:
        return NodeCheck(**common, problem=text, code=code, note=note), info

    if role.kind == "array":
        if rank not in (-3, -2, 0, 1):
            return fail("BadTypeMismatch", f"{node} has ValueRank {rank}: point {key} at a "
                                           "one-dimensional array tag (ValueRank 1)")
    elif not info.scalar:
        return fail("BadTypeMismatch", f"{node} is an array (ValueRank {rank}): point {key} at a "
                                       "scalar tag")
    for code, refused, who in (("BadNotWritable", role.writes and not node_writable, None),
                               ("BadUserAccessDenied", role.writes and not writable, user),
                               ("BadNotReadable", (role.reads or command_readable_needed)
                                and not readable, user)):
        if refused:
            return fail(code, f"{code}: " + refusals.fix_for(code, key=key, node=node, user=who))
    reason = _carry_problem(role, info, spec)
    if reason is not None:
        return fail("BadTypeMismatch", f"{type_name} cannot carry the {role.what}: {reason}")
    if role.writes and role.kind == "number" and info.type_name in INTEGER_RANGES \
            and spec.scale is None:
        note = (f"an integer tag without scaling carries whole units (steps of 1 in "
                f"{role.what}): add raw = [LO, HI], value = [LO, HI] for a finer step")
    if key == "power_kw" and value_dv.SourceTimestamp is None:
        note = ("no source timestamp: sample times fall back to the server timestamp"
                if value_dv.ServerTimestamp is not None else
                "no timestamps at all: stale and repeated samples cannot be detected")
    return NodeCheck(**common, note=note), info


#: The non-integer types an enumeration kind accepts, and what to say when a node is neither.
_ENUM_TYPES = {
    "word": (("String",), "a STRING or INT tag is needed"),
    "flag": (("String", "Boolean"), "a BOOL or INT tag is needed"),
    "mode": (("String", "Boolean"), "a mode is text (OFF/PREDICT/ON), an integer 0/1/2 or a bool"),
}


def _carry_problem(role: NodeRole, info: NodeType, spec: NodeSpec) -> str | None:
    """Why a node of this type cannot carry the role's values, or None."""
    if role.kind == "counter":
        if spec.scale is not None:
            return "a heartbeat takes no scaling: remove raw/value"
        try:
            next_heartbeat(0, info.type_name)
        except NodeValueError as exc:
            return f"{exc}; point heartbeat at an integer or BOOL tag"
        return None
    if role.kind == "text":
        return None if info.type_name == "String" else "a STRING tag is needed"
    if role.kind in _ENUM_TYPES:
        texts, needed = _ENUM_TYPES[role.kind]
        return None if info.type_name in texts or info.type_name in INTEGER_RANGES else needed
    if not info.numeric:
        return "a number is needed: point it at a REAL (Float) or INT tag"
    for value in role.carries:
        try:
            encode(value, info.type_name, spec.scale)
        except NodeValueError as exc:
            fix = ("add raw = [LO, HI], value = [LO, HI] scaling" if spec.scale is None
                   else "correct its raw/value scaling")
            return f"{value:g} does not fit: {exc}; {fix}"
    return None


class PlantLink:
    """One client session with the configured nodes, their types, and hard deadlines.

    Parameters
    ----------
    config :
        The run configuration (endpoint, security, ``[nodes]``, timeouts).
    """

    _ATTRIBUTES = ("Value", "DataType", "ValueRank", "AccessLevel", "UserAccessLevel")

    def __init__(self, config: RunConfig) -> None:
        self.config = config
        self.specs: dict[str, NodeSpec] = config.nodes.specs()
        self.client: Any = None
        self.types: dict[str, NodeType] = {}
        #: The values the nodes held when the session opened (heartbeat, applied input).
        self.initial: dict[str, Any] = {}
        self._ids: dict[str, Any] = {}

    @property
    def connected(self) -> bool:
        """True while a session is open."""
        return self.client is not None

    @property
    def user(self) -> str | None:
        """The session's user name (None: anonymous)."""
        return self.config.security.username

    async def connect(self, deadline_s: float) -> CheckReport:
        """Open a session and check every node (module docstring) within ``deadline_s``.

        The session stays open even when the check fails (``--check`` and the run decide).

        Raises
        ------
        SecurityRejectedError
            The server refused the security (a configuration error).
        LinkLostError
            No session within the deadline, or the server is unreachable.
        """
        cfg = self.config
        try:
            self.client = await within(
                secure_connect(cfg.endpoint, cfg.security, timeout_s=cfg.connect_timeout_s),
                deadline_s, f"connect to {cfg.endpoint}")
        except (CallDeadlineError, ConnectionError) as exc:
            raise LinkLostError(str(exc)) from None
        ua = asyncua().ua
        try:
            self._ids = {key: ua.NodeId.from_string(spec.node_id) for key, spec in self.specs.items()}
        except Exception as exc:  # noqa: BLE001 - asyncua raises several types for bad ids
            self.abort()
            raise NodeValueError(f"[nodes]: a node id cannot be parsed: {exc}") from None
        params = self._read_params([(key, attr) for key in self.specs
                                    for attr in self._ATTRIBUTES])
        results = await self._call(self.client.uaclient.read(params), "read the nodes' attributes",
                                   deadline_s)
        checks: list[NodeCheck] = []
        self.types, self.initial = {}, {}
        n = len(self._ATTRIBUTES)
        needs_command_read = "applied_triac_pct" not in self.specs
        for i, (key, spec) in enumerate(self.specs.items()):
            values = dict(zip(self._ATTRIBUTES, results[i * n:(i + 1) * n], strict=True))
            check, info = check_node(key, spec, values, user=self.user,
                                     command_readable_needed=key == "triac_pct" and needs_command_read)
            checks.append(check)
            if info is not None:
                self.types[key] = info
            value_dv = values["Value"]
            if value_dv.StatusCode is None or value_dv.StatusCode.is_good():
                self.initial[key] = _held(value_dv)
        return CheckReport(cfg.endpoint, tuple(checks))

    async def _call(self, awaitable: Awaitable[T], what: str, deadline_s: float) -> T:
        """One call under a deadline; a missed deadline or a transport fault loses the link."""
        ua = asyncua().ua
        try:
            return await within(awaitable, deadline_s, what)
        except ua.UaStatusCodeError as exc:
            name = type(exc).__name__
            if refusals.kind_of(name) == "link":
                self.abort()
                raise LinkLostError(f"{what}: {name}") from None
            raise
        except (CallDeadlineError, OSError, ConnectionError, asyncio.IncompleteReadError) as exc:
            self.abort()
            text = str(exc) or ("no answer in time" if isinstance(exc, TimeoutError)
                                else "the connection closed")
            raise LinkLostError(f"{what}: {text} ({type(exc).__name__})") from None

    def _read_params(self, reads: list[tuple[str, str]]) -> Any:
        """ReadParameters of (key, attribute name) pairs, with both timestamps."""
        ua = asyncua().ua
        return ua.ReadParameters(TimestampsToReturn=ua.TimestampsToReturn.Both, NodesToRead=[
            ua.ReadValueId(NodeId=self._ids[key], AttributeId=getattr(ua.AttributeIds, attr))
            for key, attr in reads])

    async def read(self, keys: tuple[str, ...], deadline_s: float) -> dict[str, Any]:
        """One Read request of the nodes' values (with both timestamps); key -> DataValue."""
        ua = asyncua().ua
        params = self._read_params([(key, "Value") for key in keys])
        try:
            results = await self._call(self.client.uaclient.read(params), "read", deadline_s)
        except ua.UaStatusCodeError as exc:   # a service-level refusal of the whole read
            raise LinkLostError(f"read: {type(exc).__name__}") from None
        return dict(zip(keys, results, strict=True))

    def variant(self, key: str, value: float | bool | str) -> Any:
        """The Variant of node ``key``'s own type that carries ``value`` (after scaling).

        Raises
        ------
        NodeValueError
            The node's type cannot carry the value.
        """
        return self._variant(key, encode(value, self.types[key].type_name, self.specs[key].scale))

    def _variant(self, key: str, raw: Any) -> Any:
        """A Variant of node ``key``'s own type holding ``raw`` as is."""
        ua = asyncua().ua
        return ua.Variant(raw, getattr(ua.VariantType, self.types[key].type_name))

    async def write(self, values: Mapping[str, Any], deadline_s: float) -> dict[str, str | None]:
        """One Write request: key -> Variant; returns key -> None (accepted) or a Bad code name.

        A Bad status on the whole request (the service result) counts for every node.

        Raises
        ------
        LinkLostError
            A transport fault, a missed deadline, or a link code (`refusals.LINK_CODES`).
        """
        if not values:
            return {}
        ua = asyncua().ua
        # the value alone: no status code and no timestamps (S7 servers refuse those)
        params = ua.WriteParameters(NodesToWrite=[
            ua.WriteValue(NodeId=self._ids[key], AttributeId=ua.AttributeIds.Value,
                          Value=ua.DataValue(variant, StatusCode=None))
            for key, variant in values.items()])
        try:
            codes = await self._call(self.client.uaclient.write(params), "write", deadline_s)
        except ua.UaStatusCodeError as exc:
            return dict.fromkeys(values, type(exc).__name__)
        return {key: (None if code.is_good() else code.name)
                for key, code in zip(values, codes, strict=True)}

    def next_count(self, key: str, current: Any) -> Any:
        """The Variant of counter ``key`` (heartbeat, watchdog) after ``current``, in its type."""
        return self._variant(key, next_heartbeat(current, self.types[key].type_name))

    def word(self, key: str, name: str, codes: Mapping[str, int]) -> Any:
        """The Variant of an enumeration node ``key``: ``name`` on a String node, else its code
        (``codes``, -1 for a name not in it) in the node's integer type, or a bool."""
        type_name = self.types[key].type_name
        value: float | bool | str = name if type_name == "String" else codes.get(name, -1)
        if type_name == "Boolean":
            value = bool(codes.get(name, 0))
        return self._variant(key, encode(value, type_name))

    def abort(self) -> None:
        """Close the session's socket at once and stop the client's tasks (no goodbye)."""
        client, self.client = self.client, None
        if client is not None:
            abort_client(client)

    async def close(self, deadline_s: float) -> None:
        """Close the session politely within ``deadline_s``, else abort it."""
        client, self.client = self.client, None
        if client is not None:
            await close_client(client, deadline_s)


def abort_client(client: Any) -> None:
    """Close an asyncua client's socket at once and stop its tasks (no goodbye)."""
    for name in ("_stale_watchdog_task", "_supervisor_task", "_renew_channel_task"):
        task = getattr(client, name, None)
        if isinstance(task, asyncio.Task) and not task.done():
            task.cancel()
    try:
        client.disconnect_socket()
    except Exception:  # noqa: BLE001 - the socket is gone either way
        pass


async def close_client(client: Any, deadline_s: float) -> None:
    """Close an asyncua client's session politely within ``deadline_s``, else abort it."""
    try:
        await within(client.disconnect(), deadline_s, "disconnect")
    except Exception:  # noqa: BLE001 - a missed deadline or a dead link: abort
        abort_client(client)


async def preflight(config: RunConfig) -> CheckReport:
    """Connect with the configured security, check every node, close (``czmpc run --check``).

    Raises
    ------
    SecurityRejectedError
        The server refused the security (exit 2).
    LinkLostError
        The server could not be reached within four connect timeouts.
    """
    link = PlantLink(config)
    try:
        return await link.connect(4.0 * config.connect_timeout_s)
    finally:
        await link.close(config.connect_timeout_s)


__all__ = ["HEALTH_TOP", "ROLES", "CallDeadlineError", "CheckReport", "LinkLostError",
           "NodeCheck", "NodeRole", "PlantLink", "abort_client", "check_node", "close_client",
           "preflight", "within"]
