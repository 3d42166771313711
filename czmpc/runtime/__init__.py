"""One controller against a live plant: wall-clock loop, OPC UA link and its security.

`czmpc.runtime.config` reads the run configuration (TOML), `czmpc.runtime.session`
opens an MPC run under the one switch-on rule, `czmpc.runtime.loop` runs the
controller against any OPC UA server (each step read, `czmpc.runtime.step`'s decide
without I/O, write, record), `czmpc.runtime.served` serves the virtual
CZ heater or a model plant as an OPC UA server; `security`, `secure_client` and `pki`
secure the link. ``asyncua`` comes with the extra ``czmpc[opcua]`` and is imported only
when a link is opened.

Layer 3 (tests/test_architecture.py): imports the core, peers, reports, sim and sysid;
never campaigns or the CLI.
"""

from __future__ import annotations
