"""Regression suites for the user's own controller (layer 4).

A suite (`czmpc.testing.suite`) names models, settings files, scenarios, plants, seeds
and the metrics to hold; `czmpc.testing.regress` records its golden results, checks a
controller against them and audits whether the suite would catch a changed controller;
`czmpc.testing.report` writes the terminal table, Markdown, figures and JUnit XML;
`czmpc.testing.plugin` is the pytest plugin (fixture ``czmpc_regress``).

This package imports nothing heavy on import, since pytest loads the plugin in every
session of an environment where czmpc is installed.
"""
