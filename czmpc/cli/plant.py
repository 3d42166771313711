"""The plant link's tools: `czmpc plant serve` (a simulated plant) and `czmpc plant history`.

`czmpc plant history` reads a plant server's history into a run log ('czmpc plant
history --help'). `czmpc plant serve` serves a simulated plant over OPC UA: 'heater' the
virtual CZ heater, 'model' the plant of a model file, one sample every Ts / time_scale
wall seconds whether a controller keeps up or not. Nodes (ns=2): Heater.Power [kW]
(read; Bad during a sensor fault), Heater.TriacCommand [%] (write), Heater.TriacApplied
[%], Heater.PowerSetpoint [kW], Heater.Heartbeat (write), Heater.Mode (OFF/PREDICT/ON),
Heater.WatchdogTripped, Heater.PlantTime_s [s], Heater.GridVoltage [-] (the grid
voltage relative to nominal over the last sample: the scenario's grid events) and
Heater.SetpointPreview [kW] (an array of the scenario's coming setpoints, element 0 the
next sample, --setpoint-preview-s long; empty without --scenario); typed as a PLC types
them with --node-types plc. A run config for it names them as [nodes]
grid_voltage_factor and setpoint_preview_kw (docs/guides/plant_link.rst). When the
heartbeat stops for --watchdog-s, the TRIAC goes to --safe-triac-pct. Without --policy
it serves on 127.0.0.1 only (--insecure overrides that for an isolated test network);
with --policy it admits only the trusted client certificates and the configured users.
Guide: docs/guides/plant_link.rst (nodes, PLC types, "Secure the link to a real
plant"); a plant that differs from its model: docs/guides/commission.rst and sim.drift.
Exit codes: 0 stopped (duration or Ctrl-C), 2 bad options or a refused address.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from czmpc.cli import _argtypes, _plant_history, _variation
from czmpc.runtime.security import MODES, SECURE_POLICIES

if TYPE_CHECKING:
    from czmpc.runtime.served import ServeOptions

NAME = "plant"
HELP = ("serve the virtual CZ heater or a model plant over OPC UA (plant serve); read a "
        "plant server's history into a run log (plant history)")


def register(parser: argparse.ArgumentParser) -> None:
    """Add the actions 'serve' and 'history' and their options."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    _plant_history.register(sub.add_parser(
        "history", help="read the power and applied-input history from the plant's OPC UA "
                        "server into a run log", description=_plant_history.__doc__))
    p = sub.add_parser("serve", help="serve a plant on an OPC UA endpoint",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--plant", choices=("heater", "model"), default="heater",
                   help="'heater': the virtual CZ heater; 'model': the model's own equation "
                        "(needs --model) (default: heater)")
    p.add_argument("--model", metavar="MODEL.json", type=Path, default=None,
                   help="model file for --plant model (default: the shipped CZ heater model)")
    p.add_argument("--endpoint", default="opc.tcp://127.0.0.1:4840/czmpc/",
                   help="opc.tcp://HOST:PORT/PATH (default: opc.tcp://127.0.0.1:4840/czmpc/)")
    p.add_argument("--time-scale", metavar="X", type=_argtypes.number(at_least=1.0),
                   default=1.0, help="plant samples per Ts of wall time (default: 1)")
    p.add_argument("--scenario", metavar="NAME|FILE.toml", default=None,
                   help="publish its setpoints and apply its grid events and sensor faults")
    p.add_argument("--seed", metavar="N", type=_argtypes.non_negative_int, default=0,
                   help="seed of the plant noise and random faults (default: 0)")
    p.add_argument("--no-noise", action="store_true", help="noise-free plant")
    p.add_argument("--initial-triac-pct", metavar="PCT",
                   type=_argtypes.percent, default=None,
                   help="start in steady state at this TRIAC input [%%] (default: the "
                        "model's operating point for --plant model, 45 %% for the heater)")
    p.add_argument("--watchdog-s", metavar="S", type=_argtypes.seconds,
                   default=10.0, help="heartbeat silence [plant s] that trips the watchdog "
                                      "(default: 10)")
    p.add_argument("--safe-triac-pct", metavar="PCT",
                   type=_argtypes.percent, default=0.0,
                   help="TRIAC input [%%] the watchdog applies (default: 0)")
    p.add_argument("--duration-s", metavar="S", type=_argtypes.seconds,
                   default=None, help="stop after this plant time [s] (default: run until Ctrl-C)")
    p.add_argument("--setpoint-kw", metavar="KW", type=_argtypes.number(unit="kW"),
                   default=45.0, help="initial value of Heater.PowerSetpoint [kW] (default: 45)")
    p.add_argument("--setpoint-preview-s", metavar="S", type=_argtypes.seconds, default=60.0,
                   help="how far ahead Heater.SetpointPreview holds the scenario's setpoints "
                        "[plant s] (default: 60)")
    p.add_argument("--node-types", choices=("czmpc", "plc"), default="czmpc",
                   help="data types of the nodes: 'czmpc' (Double, Int64 heartbeat, String "
                        "mode) or 'plc' (Float, UInt16 heartbeat, Int16 mode), as a PLC's "
                        "server types them (default: czmpc)")
    p.add_argument("--log", metavar="PLANT.csv", type=Path, default=None,
                   help="write the plant log: one row per sample with the true power beside "
                        "the published one, the applied input and the wall time (columns "
                        "plant_time_s, wall_time_s, triac_applied_pct, power_true_kw, "
                        "power_measured_kw, quality, watchdog_tripped)")
    p.add_argument("--historize", metavar="SQLITE_FILE", nargs="?", type=Path,
                   const=True, default=None,
                   help="historize Heater.Power and Heater.TriacApplied for OPC UA HistoryRead "
                        "('czmpc plant history'): in memory, or in SQLITE_FILE when given")
    p.add_argument("--history-page-values", metavar="N", type=_argtypes.positive_int,
                   default=10000, help="most values one HistoryRead returns before a "
                                       "continuation point (default: 10000)")
    sec = p.add_argument_group("security (see above)")
    sec.add_argument("--policy", choices=("None", *SECURE_POLICIES), default="None",
                     help="security policy of the only endpoint offered (default: None, allowed "
                          "on loopback only)")
    sec.add_argument("--mode", choices=MODES, default="SignAndEncrypt",
                     help="message security mode (default: SignAndEncrypt)")
    sec.add_argument("--certificate", metavar="CERT.der", type=Path, default=None,
                     help="the server's application instance certificate")
    sec.add_argument("--private-key", metavar="KEY.pem", type=Path, default=None,
                     help="its private key (mode 600)")
    sec.add_argument("--trusted-client", metavar="CERT.der", type=Path, action="append",
                     default=[], help="a client certificate to admit (repeatable)")
    sec.add_argument("--trusted-client-dir", metavar="DIR", type=Path, default=None,
                     help="admit every *.der / *.pem certificate in DIR")
    sec.add_argument("--user", metavar="NAME", default=None,
                     help="the controller's user: the only one that may write the command and "
                          "the heartbeat")
    sec.add_argument("--password-env", metavar="VAR", default=None,
                     help="environment variable that holds --user's password")
    sec.add_argument("--operator", metavar="NAME=VAR", action="append", default=[],
                     help="another user, password in environment variable VAR; may write the "
                          "setpoint and the mode only (repeatable)")
    sec.add_argument("--insecure", action="store_true",
                     help="serve without security on a non-loopback address (isolated test "
                          "networks only; warns on every start)")
    _variation.add_variation_options(p)


def run(args: argparse.Namespace) -> int:
    """Run the action: read the history, or serve the plant."""
    if args.action == "history":
        return _plant_history.run(args)
    return _serve(args)


def _serve(args: argparse.Namespace) -> int:
    """Check the security, build the plant and serve it until the duration or Ctrl-C."""
    from czmpc.runtime.security import check_serve_address, parse_server_security
    from czmpc.runtime.served import ARRAY_NODES, NODE_TYPES, ServedPlant, ServeOptions
    from czmpc.shipped import shipped_path
    from sim.drift import DriftingPlant, vary_heater, vary_model_plant
    from sim.heater import HeaterParams, VirtualHeater
    from sim.model_plant import ModelPlant
    from sim.protocols import Plant
    from sim.scenario import load_scenario
    from sysid.modelfile import load_model

    # Security first: a refused endpoint is never bound, and no plant is built for it.
    security = parse_server_security(
        policy=args.policy, mode=args.mode, certificate=args.certificate,
        private_key=args.private_key, trusted_clients=tuple(args.trusted_client),
        trusted_client_dir=args.trusted_client_dir, user=args.user,
        password_env=args.password_env, operators=tuple(args.operator))
    warning = check_serve_address(args.endpoint, security, insecure=args.insecure)
    if warning is not None:
        print(warning, file=sys.stderr, flush=True)
    scenario = None if args.scenario is None else load_scenario(args.scenario)
    variation = _variation.variation(args)
    plant: Plant
    if args.plant == "heater":
        params = HeaterParams(sensor_noise_std_kw=0.0, grid_wander_std=0.0) if args.no_noise \
            else HeaterParams()
        if args.initial_triac_pct is not None:
            params = dataclasses.replace(params, initial_triac_pct=args.initial_triac_pct)
        plant = (VirtualHeater(params, rng=args.seed) if variation.is_nominal
                 else vary_heater(variation, params, rng=args.seed))
        initial = params.initial_triac_pct
    else:
        model = load_model(args.model or shipped_path("cz_heater_model.json"))
        mp: ModelPlant | DriftingPlant = (
            ModelPlant(model, noise=not args.no_noise, initial_triac_pct=args.initial_triac_pct)
            if variation.is_nominal else
            vary_model_plant(model, variation, noise=not args.no_noise,
                             initial_triac_pct=args.initial_triac_pct))
        mp.reset(args.seed)
        plant, initial = mp, mp.initial_triac_pct
    options = ServeOptions(endpoint=args.endpoint, time_scale=args.time_scale,
                           watchdog_s=args.watchdog_s, safe_triac_pct=args.safe_triac_pct,
                           duration_s=args.duration_s, setpoint_kw=args.setpoint_kw,
                           security=security, log_path=args.log, node_types=args.node_types,
                           historize=args.historize is not None,
                           history_path=(args.historize if isinstance(args.historize, Path)
                                         else None),
                           history_page_values=args.history_page_values,
                           setpoint_preview_s=args.setpoint_preview_s)
    served = ServedPlant(plant, initial_triac_pct=initial, options=options, scenario=scenario,
                         seed=args.seed, log=lambda m: print(m, file=sys.stderr, flush=True))
    types = ", ".join(f"{n} {t}{'[]' if n in ARRAY_NODES else ''}"
                      for n, t in NODE_TYPES[args.node_types].items())
    print(f"serving the {args.plant} plant on {args.endpoint} (Ts {plant.ts_s:g} s, time scale "
          f"{args.time_scale:g}; {variation.describe()}; {args.node_types} node types: "
          f"{types}); security: "
          f"{'none (policy None, anonymous)' if security is None else security.describe()}; "
          f"{_history_words(options)}Ctrl-C stops", file=sys.stderr, flush=True)
    try:
        asyncio.run(served.serve())
    except KeyboardInterrupt:
        print("plant: stopped", file=sys.stderr)
    return 0


def _history_words(options: ServeOptions) -> str:
    """What the start line says of the history: where it is kept, or nothing."""
    from czmpc.runtime.served import HISTORIZED_NODES

    if not options.historize:
        return ""
    where = "in memory" if options.history_path is None else f"in {options.history_path}"
    return (f"history of {', '.join(HISTORIZED_NODES)} {where} (HistoryRead pages of "
            f"{options.history_page_values} values); ")
