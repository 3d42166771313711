"""Fixtures of the plant-link tests (the rig itself is in opcua_rig.py)."""

from __future__ import annotations

import pytest
from opcua_rig import Pki, make_pki


@pytest.fixture(scope="session")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return make_pki(tmp_path_factory.mktemp("pki"))
