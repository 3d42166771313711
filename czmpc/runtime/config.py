"""The run configuration of `czmpc run` (a TOML file) and the recipe (schedule) file.

Every table and key is checked against `_TABLES`: an unknown key, a wrong type or a value
out of range raises `RunConfigError` naming the key. docs/reference/run_config.rst lists
the keys (generated from `_TABLES`), the node forms (an id, or a table with a raw/value
scaling applied both ways) and a complete example. Relative paths are taken relative to
the config file's directory.
"""

from __future__ import annotations

import bisect
import csv
import dataclasses
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from czmpc.config_text import did_you_mean, shown
from czmpc.errors import CzmpcError
from czmpc.runtime.node_types import LinearScale, NodeSpec, NodeValueError, parse_node_spec
from czmpc.runtime.security import INSECURE_LOOPBACK, SecuritySettings, parse_security


class RunConfigError(CzmpcError, ValueError):
    """A run configuration or recipe file that cannot be used."""


@dataclass(frozen=True, slots=True, kw_only=True)
class NodeIds:
    """OPC UA node ids (strings such as ``"ns=2;s=Heater.Power"``); None: not used.

    ``scales`` holds the optional raw/value scaling of a node, by its key.
    """

    power_kw: str
    triac_pct: str
    applied_triac_pct: str | None = None
    setpoint_kw: str | None = None
    heartbeat: str | None = None
    mode: str | None = None
    model_health: str | None = None
    owner: str | None = None
    status: str | None = None
    mode_in_effect: str | None = None
    stale_alarm: str | None = None
    predicted_power_kw: str | None = None
    target_triac_pct: str | None = None
    watchdog: str | None = None
    setpoint_preview_kw: str | None = None
    grid_voltage_factor: str | None = None
    scales: Mapping[str, LinearScale] = dataclasses.field(default_factory=dict)

    def specs(self) -> dict[str, NodeSpec]:
        """The configured nodes by key, with their scaling (unused keys left out)."""
        return {key: NodeSpec(node_id, self.scales.get(key))
                for key in NODE_KEYS if (node_id := getattr(self, key)) is not None}


#: The ``[nodes]`` keys, in the order of `NodeIds`.
NODE_KEYS = tuple(f.name for f in dataclasses.fields(NodeIds) if f.name != "scales")

_TABLES: dict[str, tuple[str, ...]] = {
    "plant": ("endpoint", "ts_s", "time_scale", "max_sample_age_s", "connect_timeout_s",
              "align_to_plant", "reject_repeated_samples", "max_refused_writes", "security"),
    "nodes": NODE_KEYS,
    "controller": ("model", "settings", "candidate"),
    "run": ("duration_s", "setpoint_kw", "schedule", "setpoint_preview_s", "log", "rotate",
            "rotate_mb"),
    "safety": ("action", "safe_triac_pct"),
    "test": ("power_band_kw", "max_bad_quality_s"),
    "logging": ("syslog", "facility"),
}

#: Default of ``[test] max_bad_quality_s`` [plant s]: five samples at Ts = 2 s; longer
#: blind stretches during an open-loop test leave the heater unwatched.
DEFAULT_MAX_BAD_QUALITY_S = 10.0
#: Default of ``[plant] max_refused_writes``: five samples of refused commands in a row
#: (10 s at Ts = 2 s, as long as the default test's blind stretch) stop the run.
DEFAULT_MAX_REFUSED_WRITES = 5


@dataclass(frozen=True, slots=True, kw_only=True)
class Schedule:
    """A recipe: setpoint ``setpoints_kw[i]`` [kW] from ``times_s[i]`` [s] of the run on."""

    times_s: tuple[float, ...]
    setpoints_kw: tuple[float, ...]

    def setpoint_at(self, time_s: float) -> float:
        """The setpoint [kW] in force at run time ``time_s`` [s] (the first before it starts)."""
        return self.setpoints_kw[max(0, bisect.bisect_right(self.times_s, time_s) - 1)]

    def setpoints_after(self, time_s: float, ts_s: float, n_samples: int) -> tuple[float, ...]:
        """The setpoints [kW] of the ``n_samples`` samples after run time ``time_s`` [s].

        Element ``i`` is `setpoint_at` ``(time_s + (i + 1) * ts_s)``: the setpoint the
        sample ``k + 1 + i`` will take when ``time_s`` is sample ``k``'s time (the loop's
        ``setpoint_preview_kw``). Empty for ``n_samples <= 0``.
        """
        return tuple(self.setpoint_at(time_s + (i + 1) * ts_s) for i in range(max(0, n_samples)))


@dataclass(frozen=True, slots=True, kw_only=True)
class ExperimentLimits:
    """The safety limits of an open-loop or closed-loop test (``[test]``).

    Parameters
    ----------
    power_band_kw :
        ``(lo, hi)`` [kW]: a Good measurement outside this band aborts the test.
    max_bad_quality_s :
        Longest tolerated stretch of samples without a usable measurement (Bad,
        Uncertain, stale or disconnected) [plant s]; a longer one aborts the test.
    """

    power_band_kw: tuple[float, float]
    max_bad_quality_s: float = DEFAULT_MAX_BAD_QUALITY_S

    def violation(self, power_kw: float, quality: str, bad_run_s: float) -> str | None:
        """Why the test must stop now, or None.

        Parameters
        ----------
        power_kw :
            Measured power [kW] of this sample (NaN when not usable).
        quality :
            Its quality word (``"good"`` or why not).
        bad_run_s :
            Plant time [s] covered by the current stretch of unusable samples,
            this one included (0 for a Good sample).
        """
        lo, hi = self.power_band_kw
        if quality == "good" and not lo <= power_kw <= hi:
            side = "below" if power_kw < lo else "above"
            return (f"measured power {power_kw:.3f} kW is {side} the test band "
                    f"[{lo:g}, {hi:g}] kW ([test] power_band_kw)")
        if quality != "good" and bad_run_s > self.max_bad_quality_s:
            return (f"no usable measurement for {bad_run_s:g} s (quality {quality}), longer than "
                    f"[test] max_bad_quality_s = {self.max_bad_quality_s:g} s")
        return None


@dataclass(frozen=True, slots=True, kw_only=True)
class RunConfig:
    """A checked run configuration (module docstring for the keys and their units)."""

    endpoint: str
    ts_s: float
    time_scale: float
    max_sample_age_s: float
    connect_timeout_s: float
    nodes: NodeIds
    model_path: Path | None
    settings_path: Path | None
    duration_s: float | None
    setpoint_kw: float | None
    schedule: Schedule | None
    log_path: Path
    safe_action: str
    safe_triac_pct: float | None
    security: SecuritySettings = INSECURE_LOOPBACK
    test_limits: ExperimentLimits | None = None
    source_path: Path | None = None
    candidate_path: Path | None = None
    align_to_plant: bool = True
    reject_repeated_samples: bool = True
    max_refused_writes: int = DEFAULT_MAX_REFUSED_WRITES
    syslog: str | None = None
    syslog_facility: str = "daemon"
    rotate: str = "none"
    rotate_bytes: int | None = None
    #: ``log_path`` is a directory: each run writes its own timestamped file there.
    log_per_run: bool = False
    #: ``[run] setpoint_preview_s``: how far ahead the controller is told the setpoint [s];
    #: 0 with an array node: all of it.
    setpoint_preview_s: float = 0.0

    @property
    def period_s(self) -> float:
        """Wall-clock period of the loop [s]: ``ts_s / time_scale``."""
        return self.ts_s / self.time_scale

    @property
    def preview_samples(self) -> int:
        """Samples of setpoint preview: ``round(setpoint_preview_s / ts_s)`` (0: none, or the
        array node's whole length)."""
        return round(self.setpoint_preview_s / self.ts_s)


def _bool(table: dict[str, Any], key: str, where: str, *, default: bool) -> bool:
    value = table.get(key, default)
    if not isinstance(value, bool):
        raise RunConfigError(f"{where}.{key}: expected true or false; got {shown(value)}")
    return value


def _num(table: dict[str, Any], key: str, where: str, *, default: float | None = None,
         positive: bool = False, minimum: float | None = None,
         maximum: float | None = None) -> float | None:
    if key not in table:
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise RunConfigError(f"{where}.{key}: expected a finite number; got {shown(value)}")
    value = float(value)
    if positive and value <= 0.0:
        raise RunConfigError(f"{where}.{key}: expected a number > 0; got {value:g}")
    if minimum is not None and value < minimum:
        raise RunConfigError(f"{where}.{key}: expected a number >= {minimum:g}; got {value:g}")
    if maximum is not None and value > maximum:
        raise RunConfigError(f"{where}.{key}: expected a number <= {maximum:g}; got {value:g}")
    return value


def _str(table: dict[str, Any], key: str, where: str, *, required: bool = False) -> str | None:
    if key not in table:
        if required:
            raise RunConfigError(f"{where}.{key}: missing (required)")
        return None
    value = table[key]
    if not isinstance(value, str) or not value.strip():
        raise RunConfigError(f"{where}.{key}: expected a non-empty string; got {shown(value)}")
    return value


def load_schedule(path: Path) -> Schedule:
    """Read a recipe CSV with a header ``time_s,setpoint_kw`` and increasing times.

    Raises
    ------
    RunConfigError
        A missing column, a non-number, or times that do not increase.
    """
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise RunConfigError(f"run.schedule: cannot read {path}: {exc.strerror}") from exc
    times: list[float] = []
    values: list[float] = []
    for i, row in enumerate(rows, start=2):
        try:
            t, sp = float(row["time_s"]), float(row["setpoint_kw"])
        except (KeyError, TypeError, ValueError) as exc:
            raise RunConfigError(
                f"run.schedule: {path} line {i}: expected columns time_s [s], setpoint_kw [kW] "
                f"with numbers; got {shown(row)}") from exc
        if not (math.isfinite(t) and math.isfinite(sp)) or (times and t <= times[-1]):
            raise RunConfigError(
                f"run.schedule: {path} line {i}: expected finite values and increasing time_s; "
                f"got time_s={t:g}, setpoint_kw={sp:g}")
        times.append(t)
        values.append(sp)
    if not times:
        raise RunConfigError(f"run.schedule: {path} has no rows (header time_s,setpoint_kw)")
    return Schedule(times_s=tuple(times), setpoints_kw=tuple(values))


def run_config_from_dict(doc: dict[str, Any], *, base_dir: Path) -> RunConfig:
    """Check a parsed configuration; relative paths are resolved against ``base_dir``."""
    for name in doc:
        if name not in _TABLES:
            raise RunConfigError(f"{name}: unknown table{did_you_mean(name, _TABLES)}; "
                                 f"expected one of {', '.join(_TABLES)}")
    tables: dict[str, dict[str, Any]] = {}
    for name, keys in _TABLES.items():
        table = doc.get(name, {})
        if not isinstance(table, dict):
            raise RunConfigError(f"{name}: expected a table; got {shown(table)}")
        for key in table:
            if key not in keys:
                raise RunConfigError(f"{name}.{key}: unknown key{did_you_mean(key, keys)}; "
                                     f"expected one of {', '.join(keys)}")
        tables[name] = table
    plant, nodes, ctrl, run, safety, test, logging_table = (tables[n] for n in _TABLES)
    syslog, facility = _syslog(logging_table)
    endpoint = _str(plant, "endpoint", "plant", required=True) or ""
    if not endpoint.startswith("opc.tcp://"):
        raise RunConfigError(f"plant.endpoint: expected opc.tcp://HOST:PORT/...; got {shown(endpoint)}")
    ts_s = _num(plant, "ts_s", "plant", positive=True)
    if ts_s is None:
        raise RunConfigError("plant.ts_s: missing (required)")
    time_scale = _num(plant, "time_scale", "plant", default=1.0, minimum=1.0, maximum=1000.0)
    max_age = _num(plant, "max_sample_age_s", "plant", default=2.0 * ts_s, positive=True)
    conn_to = _num(plant, "connect_timeout_s", "plant", default=2.0, positive=True)
    align = _bool(plant, "align_to_plant", "plant", default=True)
    reject_repeated = _bool(plant, "reject_repeated_samples", "plant", default=True)
    max_refused = _num(plant, "max_refused_writes", "plant",
                       default=DEFAULT_MAX_REFUSED_WRITES, minimum=1.0)
    if max_refused is not None and max_refused != int(max_refused):
        raise RunConfigError(f"plant.max_refused_writes: expected a whole number >= 1; "
                             f"got {max_refused:g}")
    node_ids = _node_ids(nodes)
    # [controller] may be absent (an open-loop test needs no model); if given, it names one.
    model = _str(ctrl, "model", "controller", required="controller" in doc)
    settings = _str(ctrl, "settings", "controller")
    candidate = _str(ctrl, "candidate", "controller")   # [controller] requires model
    duration = _num(run, "duration_s", "run", positive=True)
    setpoint = _num(run, "setpoint_kw", "run")
    schedule_name = _str(run, "schedule", "run")
    if setpoint is not None and schedule_name is not None:
        raise RunConfigError("run.schedule: give either run.setpoint_kw or run.schedule, not both")
    if (model is not None and setpoint is None and schedule_name is None
            and node_ids.setpoint_kw is None):
        raise RunConfigError(
            "run.setpoint_kw: missing; give nodes.setpoint_kw, run.setpoint_kw or run.schedule")
    preview_s = float(_num(run, "setpoint_preview_s", "run", default=0.0, minimum=0.0) or 0.0)
    _check_preview(preview_s, ts_s, schedule=schedule_name, array_node=node_ids.setpoint_preview_kw)
    log = _str(run, "log", "run") or "run.csv"
    rotate = _str(run, "rotate", "run") or "none"
    if rotate not in ("none", "daily"):
        raise RunConfigError(f"run.rotate: expected 'none' or 'daily'; got {shown(rotate)}")
    rotate_mb = _num(run, "rotate_mb", "run", positive=True)
    action = _str(safety, "action", "safety") or "hold"
    if action not in ("hold", "ramp"):
        raise RunConfigError(f"safety.action: expected 'hold' or 'ramp'; got {shown(action)}")
    safe = _num(safety, "safe_triac_pct", "safety", minimum=0.0, maximum=100.0)
    if action == "ramp" and safe is None:
        raise RunConfigError("safety.safe_triac_pct: required when safety.action = 'ramp'")
    limits = _test_limits(test) if "test" in doc else None
    if limits is not None and safe is None:
        raise RunConfigError("safety.safe_triac_pct: required with [test] (an aborted test moves "
                             "the TRIAC there at the rate limit)")
    # Last, so that a plain key error is reported first.
    security_table = plant.get("security")
    if security_table is not None and not isinstance(security_table, dict):
        raise RunConfigError(f"plant.security: expected a table; got {shown(security_table)}")
    security = parse_security(security_table, endpoint=endpoint, base_dir=base_dir)
    return RunConfig(
        endpoint=endpoint, ts_s=ts_s, time_scale=float(time_scale or 1.0),
        max_sample_age_s=float(max_age or 2.0 * ts_s), connect_timeout_s=float(conn_to or 2.0),
        nodes=node_ids, model_path=None if model is None else base_dir / model,
        settings_path=None if settings is None else base_dir / settings,
        duration_s=duration, setpoint_kw=setpoint,
        schedule=None if schedule_name is None else load_schedule(base_dir / schedule_name),
        log_path=base_dir / log,
        log_per_run=log.endswith(("/", "\\")) or (base_dir / log).is_dir(),
        safe_action=action, safe_triac_pct=safe, security=security,
        test_limits=limits,
        candidate_path=None if candidate is None else base_dir / candidate,
        align_to_plant=align, reject_repeated_samples=reject_repeated,
        max_refused_writes=int(max_refused or DEFAULT_MAX_REFUSED_WRITES),
        syslog=syslog, syslog_facility=facility, rotate=rotate,
        rotate_bytes=None if rotate_mb is None else max(1, round(rotate_mb * 1e6)),
        setpoint_preview_s=preview_s,
    )


def _check_preview(preview_s: float, ts_s: float, *, schedule: str | None,
                   array_node: str | None) -> None:
    """``[run] setpoint_preview_s`` needs one source of the coming setpoints: the recipe
    file (a run czmpc owns) or the array node (a recipe the DCS owns), not both."""
    if schedule is not None and array_node is not None:
        raise RunConfigError(
            "nodes.setpoint_preview_kw: give either run.schedule (czmpc owns the recipe) or "
            "nodes.setpoint_preview_kw (the DCS owns it and writes the coming setpoints), not both")
    if preview_s > 0.0 and schedule is None and array_node is None:
        raise RunConfigError(
            f"run.setpoint_preview_s: {preview_s:g} s of preview needs the coming setpoints: "
            "give run.schedule (a recipe CSV) or nodes.setpoint_preview_kw (an array node)")
    if 0.0 < preview_s < 0.5 * ts_s:
        raise RunConfigError(
            f"run.setpoint_preview_s: expected 0 or at least half a sample "
            f"({0.5 * ts_s:g} s at plant.ts_s = {ts_s:g} s); got {preview_s:g}")


#: Syslog facilities ``[logging] facility`` accepts.
SYSLOG_FACILITIES = ("user", "daemon", "local0", "local1", "local2", "local3", "local4", "local5",
                     "local6", "local7")


def _syslog(table: dict[str, Any]) -> tuple[str | None, str]:
    """``[logging]``: the syslog address (a socket path or HOST:PORT) and facility."""
    address = _str(table, "syslog", "logging")
    if address is not None and not address.startswith("/"):
        host, _, port = address.rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise RunConfigError(f"logging.syslog: expected a socket path such as /dev/log or "
                                 f"HOST:PORT (UDP); got {shown(address)}")
    facility = _str(table, "facility", "logging") or "daemon"
    if facility not in SYSLOG_FACILITIES:
        raise RunConfigError(f"logging.facility: expected one of {', '.join(SYSLOG_FACILITIES)}; "
                             f"got {shown(facility)}")
    return address, facility


def _node_ids(table: dict[str, Any]) -> NodeIds:
    """``[nodes]``: each a node id string or a table with the id and its scaling."""
    for key in ("power_kw", "triac_pct"):
        if key not in table:
            raise RunConfigError(f"nodes.{key}: missing (required)")
    specs: dict[str, NodeSpec] = {}
    for key, value in table.items():
        try:
            specs[key] = parse_node_spec(value, f"nodes.{key}")
        except NodeValueError as exc:
            raise RunConfigError(str(exc)) from None
    ids = {key: spec.node_id for key, spec in specs.items()}
    scales = {key: spec.scale for key, spec in specs.items() if spec.scale is not None}
    return NodeIds(power_kw=ids.pop("power_kw"), triac_pct=ids.pop("triac_pct"), scales=scales,
                   **ids)


def _test_limits(table: dict[str, Any]) -> ExperimentLimits:
    band = table.get("power_band_kw")
    if band is None:
        raise RunConfigError("test.power_band_kw: missing (required in [test]); give [LO, HI] in kW")
    if (not isinstance(band, list) or len(band) != 2
            or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                       for v in band)
            or not band[0] < band[1]):
        raise RunConfigError(
            f"test.power_band_kw: expected [LO, HI] in kW with finite LO < HI; got {shown(band)}")
    max_bad = _num(table, "max_bad_quality_s", "test", default=DEFAULT_MAX_BAD_QUALITY_S,
                   minimum=0.0)
    return ExperimentLimits(power_band_kw=(float(band[0]), float(band[1])),
                      max_bad_quality_s=float(DEFAULT_MAX_BAD_QUALITY_S if max_bad is None
                                              else max_bad))


def load_run_config(path: Path) -> RunConfig:
    """Read and check a run configuration TOML file (module docstring)."""
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise RunConfigError(f"{path}: not valid TOML: {exc}") from exc
    except OSError as exc:
        raise RunConfigError(f"{path}: cannot read: {exc.strerror}") from exc
    try:
        config = run_config_from_dict(doc, base_dir=path.resolve().parent)
    except RunConfigError as exc:
        raise RunConfigError(f"{path}: {exc}") from None
    return dataclasses.replace(config, source_path=path.resolve())


__all__ = ["DEFAULT_MAX_BAD_QUALITY_S", "DEFAULT_MAX_REFUSED_WRITES", "NODE_KEYS",
           "ExperimentLimits", "NodeIds", "RunConfig", "RunConfigError", "Schedule",
           "load_run_config", "load_schedule", "run_config_from_dict"]
