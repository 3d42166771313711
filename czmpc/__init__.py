"""czmpc: offset-free Hammerstein MPC of CZ heater power, solved by OSQP."""

from czmpc.errors import CzmpcError, DesignError, SettingsError

__all__ = ["CzmpcError", "DesignError", "SettingsError"]
