"""The browser check's reading of an API page (``tools/check_site_in_browser.py``).

The check itself needs a built site and a Chromium, so it runs by hand after ``make docs``;
what it reads from a page is tested here on the HTML Sphinx writes for a numpydoc method.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parents[2]

PAGE = """<dl class="field-list simple">
<dt class="field-odd">Parameters<span class="colon">:</span></dt>
<dd class="field-odd"><dl class="simple">
<dt><strong>power_kw</strong></dt><dd><p>Measured heater power [kW]; NaN: missing.</p>
</dd>
<dt><strong>applied_triac_pct</strong></dt><dd><p>The applied input {unit}, or None.</p>
</dd>
</dl>
</dd>
<dt class="field-even">Returns<span class="colon">:</span></dt>
<dd class="field-even"><dl class="simple"><dt><strong>float</strong></dt><dd><p>TRIAC input [%].</p>
</dd></dl></dd></dl>"""


@pytest.fixture(scope="module")
def tool() -> ModuleType:
    spec = importlib.util.spec_from_file_location("check_site_in_browser",
                                                  REPO / "tools" / "check_site_in_browser.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_parameters_section_is_read_to_its_last_entry(tool: ModuleType) -> None:
    params = tool.rendered_parameters(PAGE.format(unit="[%]"))
    assert sorted(params) == ["applied_triac_pct", "power_kw"]
    assert "[kW]" in params["power_kw"] and "[%]" in params["applied_triac_pct"]
    assert "float" not in params            # the Returns field is not a parameter


def test_a_page_without_a_parameters_section_gives_nothing(tool: ModuleType) -> None:
    assert tool.rendered_parameters(PAGE.split('<dt class="field-even">')[1]) == {}


def test_the_checked_page_is_the_controller_step_with_its_parameters(tool: ModuleType) -> None:
    import inspect

    from czmpc import OffsetFreeMPC

    assert tool.API_PAGE == "api/generated/czmpc.OffsetFreeMPC.step.html"
    signature = inspect.signature(OffsetFreeMPC.step)
    assert set(tool.API_PARAMETERS) == set(signature.parameters) - {"self"}
    full = {"power_kw": "power [kW]", "setpoint_kw": "setpoint [kW]", "applied_triac_pct": "input [%]",
            "setpoint_preview_kw": "setpoints [kW]", "grid_voltage_factor": "voltage [-]"}
    assert tool.parameters_without_unit(full) == []
    # a parameter left out, or described without its unit, is reported
    assert tool.parameters_without_unit({**full, "applied_triac_pct": "input"}) == ["applied_triac_pct"]
    del full["setpoint_kw"]
    assert tool.parameters_without_unit(full) == ["setpoint_kw"]
