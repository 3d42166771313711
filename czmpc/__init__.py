"""czmpc: offset-free Hammerstein MPC of CZ heater power, solved by OSQP.

Public names load on first use (see `sysid._lazy`), so that importing `czmpc.cli`
does not import numpy before the CLI has pinned BLAS threads::

    mpc = czmpc.OffsetFreeMPC(sysid.load_model("model.json"))
    triac_pct = mpc.step(power_kw=p_measured, setpoint_kw=p_ref)

`czmpc.realization`, `kalman`, `target`, `qp` and `inversion` are importable and
documented for tests and experts but not re-exported.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from sysid._lazy import lazy_exports
from sysid._version import __version__

_EXPORTS = {
    **dict.fromkeys(["CzmpcError", "DesignError", "SettingsError"], "czmpc.errors"),
    **dict.fromkeys(["MPCSettings", "OSQPOptions"], "czmpc.settings"),
    **dict.fromkeys(["OffsetFreeMPC", "StepDiagnostics"], "czmpc.controller"),
    **dict.fromkeys(["load_settings", "settings_to_toml"], "czmpc.settings_file"),
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
# A library logs and lets the application decide where records go (the CLI: stderr).
logging.getLogger(__name__).addHandler(logging.NullHandler())
__all__ = sorted(_EXPORTS)

if TYPE_CHECKING:
    from czmpc.controller import OffsetFreeMPC, StepDiagnostics
    from czmpc.errors import CzmpcError, DesignError, SettingsError
    from czmpc.settings import MPCSettings, OSQPOptions
    from czmpc.settings_file import load_settings, settings_to_toml
