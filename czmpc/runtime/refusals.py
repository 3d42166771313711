"""What a Bad status code in a read or write response means for the run, and what to fix.

A Bad status for a node in a write response is a *refusal*, not a lost link. Three kinds
(`kind_of`):

``configuration``
    Will not go away by itself (no such node, read-only, this user refused, another
    type, out of range): the run stops at once (exit 2) with the fix (`fix_for`).
``link``
    The session or channel is gone: the link is reopened with backoff.
``transient``
    Any other Bad code (the PLC busy, a resource locked, a device fault): counted and
    logged; ``[plant] max_refused_writes`` in a row stop the run safely (exit 1).
"""

from __future__ import annotations

#: Codes that retrying cannot cure: the configuration (czmpc's or the server's) must change.
CONFIGURATION_CODES = frozenset({
    "BadTypeMismatch", "BadNotWritable", "BadUserAccessDenied", "BadNodeIdUnknown",
    "BadNodeIdInvalid", "BadOutOfRange", "BadAttributeIdInvalid", "BadWriteNotSupported",
    "BadNotSupported", "BadNotReadable", "BadIndexRangeInvalid", "BadDataEncodingUnsupported",
    "BadSecurityModeInsufficient", "BadNodeClassInvalid", "BadIdentityTokenRejected",
    "BadIdentityTokenInvalid", "BadNotImplemented", "BadServiceUnsupported",
})
#: Codes that mean the session or its channel is gone (the link, not the node).
LINK_CODES = frozenset({
    "BadSessionIdInvalid", "BadSessionClosed", "BadSessionNotActivated",
    "BadSecureChannelIdInvalid", "BadSecureChannelClosed", "BadSecureChannelTokenUnknown",
    "BadConnectionClosed", "BadServerNotConnected", "BadNotConnected", "BadTimeout",
    "BadRequestTimeout", "BadCommunicationError", "BadDisconnect", "BadTcpInternalError",
    "BadServerHalted", "BadShutdown", "BadNoCommunication", "BadConnectionRejected",
    "BadRequestInterrupted", "BadEndOfStream",
})


def kind_of(code_name: str) -> str:
    """``"configuration"``, ``"link"`` or ``"transient"`` for a Bad code's name."""
    if code_name in CONFIGURATION_CODES:
        return "configuration"
    if code_name in LINK_CODES:
        return "link"
    return "transient"


def fix_for(code_name: str, *, key: str, node: str, type_name: str | None = None,
            user: str | None = None) -> str:
    """One sentence: what to change so that the server accepts the node.

    Parameters
    ----------
    code_name :
        The status code's name.
    key :
        The run config's key of the node (``triac_pct``).
    node :
        The node id (and scaling) as configured.
    type_name :
        The node's DataType, when known.
    user :
        The session's user name (None: anonymous).
    """
    where = f"[nodes] {key} = {node}"
    who = f"user {user!r}" if user else "an anonymous session"
    if code_name in ("BadNodeIdUnknown", "BadNodeIdInvalid"):
        return (f"the server has no node {node}: copy the id of {key} from the server's address "
                f"space (an OPC UA browser shows it) into {where.split(' = ')[0]}")
    if code_name == "BadNotWritable":
        return (f"{node} is read-only on the server: point {key} at the PLC's writable tag, or "
                "make this one writable in the PLC's OPC UA settings")
    if code_name == "BadUserAccessDenied":
        return (f"the server does not let {who} write {node}: give that user write access on "
                "the server, or set another user in [plant.security]")
    if code_name == "BadTypeMismatch":
        kind = f" of type {type_name}" if type_name else ""
        return (f"the server refused the value's type for {node}{kind}: point {key} at a numeric "
                "tag, or add raw = [LO, HI], value = [LO, HI] scaling for an integer tag")
    if code_name == "BadOutOfRange":
        return (f"the server refused the value as out of {node}'s range: check the node's "
                f"engineering range on the server and the scaling of {key}")
    if code_name == "BadNotReadable":
        return f"the server does not let {who} read {node}: give that user read access"
    return f"{code_name} on {node} will not clear by itself: check {where} and the server"


__all__ = ["CONFIGURATION_CODES", "LINK_CODES", "fix_for", "kind_of"]
