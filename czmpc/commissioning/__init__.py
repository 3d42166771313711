"""From a bare heater to a running MPC: the test, the check-model verdict, the journey.

`czmpc.commissioning.test_run` applies a designed input schedule through the runtime
loop (`czmpc run --test`), `czmpc.commissioning.dither` adds a designed dither to the
MPC's input (`czmpc run --dither-pct`), `czmpc.commissioning.journey` runs the whole
commissioning (`czmpc commission`), and `czmpc.commissioning.check` gives the go/no-go
verdict before switch-on (`czmpc check-model`).

Layer 4 (tests/test_architecture.py): imports runtime, campaigns, reports, the core,
sim and sysid; never the CLI.
"""

from __future__ import annotations
