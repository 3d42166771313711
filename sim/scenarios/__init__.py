"""Scenario TOML files shipped with the package (read by `sim.scenario`)."""
