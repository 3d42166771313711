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

Watchdog (as a PLC has one): when the heartbeat has not changed for ``watchdog_s``
[plant s], the applied input moves to ``safe_triac_pct`` and ``WatchdogTripped`` turns
True (and a line is printed). It arms at the first heartbeat; a new heartbeat and a new command re-arm it.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from czmpc.runtime._opcua import asyncua
from sim.disturbances import exogenous_at, fault_profile
from sim.protocols import NOMINAL, Exogenous, Plant
from sim.scenario import Scenario

NAMESPACE_URI = "urn:czmpc:plant"


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
    """

    endpoint: str
    time_scale: float = 1.0
    watchdog_s: float | None = 10.0
    safe_triac_pct: float = 0.0
    duration_s: float | None = None
    setpoint_kw: float = 45.0


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
        Called with one line of text on notable events (watchdog, stop).
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

    async def _add(self, folder: Any, idx: int, name: str, value: Any, vtype: Any,
                   writable: bool) -> None:
        ua = asyncua().ua
        node = await folder.add_variable(ua.NodeId(f"Heater.{name}", idx), name,
                                         ua.Variant(value, vtype))
        if writable:
            await node.set_writable()
        self._nodes[name] = node

    async def _publish(self, name: str, value: Any, vtype: Any, *, good: bool = True) -> None:
        ua = asyncua().ua
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

    async def serve(self) -> None:
        """Run the server until ``options.duration_s`` of plant time or cancellation."""
        aua = asyncua()
        ua = aua.ua
        server = aua.Server()
        await server.init()
        server.set_endpoint(self.options.endpoint)
        server.set_server_name("czmpc served plant")
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        idx = await server.register_namespace(NAMESPACE_URI)
        folder = await server.nodes.objects.add_object(ua.NodeId("Heater", idx), "Heater")
        power0 = float(self.plant.true_power_kw)
        sp0 = float(self._setpoints[0]) if self.scenario is not None else self.options.setpoint_kw
        D, B = ua.VariantType.Double, ua.VariantType.Boolean
        await self._add(folder, idx, "Power", power0, D, False)
        await self._add(folder, idx, "TriacCommand", self._triac_pct, D, True)
        await self._add(folder, idx, "TriacApplied", self._triac_pct, D, False)
        await self._add(folder, idx, "PowerSetpoint", sp0, D, True)
        await self._add(folder, idx, "Heartbeat", 0, ua.VariantType.Int64, True)
        await self._add(folder, idx, "Mode", "ON", ua.VariantType.String, True)
        await self._add(folder, idx, "WatchdogTripped", False, B, False)
        await self._add(folder, idx, "PlantTime_s", 0.0, D, False)
        await self._add(folder, idx, "ModelHealth", 0.0, D, True)
        self._server = server
        async with server:
            self.ready.set()
            await self._run_clock()

    async def _run_clock(self) -> None:
        ua = asyncua().ua
        D = ua.VariantType.Double
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
            if hb != last_hb:
                silent = 0
                armed = True
                last_hb = hb
            else:
                silent += 1
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
            measured = float(self.plant.step(self._triac_pct, self._exogenous()))
            self.k += 1
            good = math.isfinite(measured)
            if self._faults is not None and self.k < len(self._faults.missing):
                good = good and not bool(self._faults.missing[self.k])
                measured += float(self._faults.spike_kw[self.k])
                await self._publish("PowerSetpoint", float(self._setpoints[self.k]), D)
            await self._publish("Power", measured if good else 0.0, D, good=good)
            await self._publish("TriacApplied", self._triac_pct, D)
            await self._publish("WatchdogTripped", self.watchdog_tripped, ua.VariantType.Boolean)
            await self._publish("PlantTime_s", self.k * self.ts_s, D)
        self._log(f"plant: stopped after {self.k * self.ts_s:g} s of plant time")


__all__ = ["NAMESPACE_URI", "ServeOptions", "ServedPlant"]
