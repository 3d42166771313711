"""sim: plants and closed loops (the virtual CZ heater, model plants, scenarios, runner)."""

from sim.errors import PlantError, ScenarioError, SimError

__all__ = ["PlantError", "ScenarioError", "SimError"]
