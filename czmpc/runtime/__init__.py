"""The plant link: a soft real-time MPC loop over OPC UA and a served virtual plant.

`czmpc.runtime.config` reads the run configuration (TOML), `czmpc.runtime.loop` runs
the controller against any OPC UA server, `czmpc.runtime.served` serves the virtual
CZ heater or a model plant as an OPC UA server. ``asyncua`` comes with the extra
``czmpc[opcua]`` and is imported only when a link is opened.
"""

from __future__ import annotations
