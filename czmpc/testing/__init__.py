"""The pytest plugin of czmpc (layer 4): users' regression suites checked inside pytest.

`czmpc.testing.plugin` (entry point ``pytest11: czmpc``) gives the fixture
``czmpc_regress``; the suites, golden directories and checks are the campaign engine's
(`czmpc.campaigns.regression`). This package imports nothing heavy on import, since
pytest loads the plugin in every session of an environment where czmpc is installed.
"""
