"""A user's own regression suite in tmp_path: model file, settings file, recipe scenario.

Shared by the regression engine's tests, the CLI's and the pytest plugin's.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sysid.model import HammersteinModel

#: The user's settings file (weights written out, so a test can double one).
SETTINGS = """\
horizon_steps = 30
output_weight = 1.0
move_weight = 0.1
"""
#: A recipe as a setpoint schedule: a step, then a ramp; 10 min of plant time, 300 samples.
RECIPE = """\
name = "recipe_a"
description = "step 45 -> 50 kW, then ramp to 55 kW"
duration_s = 600
ts_s = 2.0
plant_noise = true
initial_setpoint_kw = 45.0
initial_triac_pct = 45.0

[[setpoint]]
kind = "step"
at_s = 60
power_kw = 50.0

[[setpoint]]
kind = "ramp"
start_s = 300
end_s = 420
power_kw = 55.0
"""
SUITE = """\
name = "puller-7"
description = "tuned MPC of puller 7 on recipe A"
scenarios = ["recipe_a.toml"]
seeds = [3]

[[controllers]]
name = "tuned"
kind = "mpc"
model = "puller7_model.json"
settings = "puller7_settings.toml"

[[plants]]
kind = "model"
[[plants]]
kind = "perturbed"
gain_factors = [1.1]
"""


@pytest.fixture
def user_suite(tmp_path: Path) -> Path:
    """The user's folder: suite.toml beside its model, settings and scenario files."""
    folder = tmp_path / "puller7"
    folder.mkdir()
    shutil.copyfile(shipped_path(HAMMERSTEIN_MODEL_JSON), folder / "puller7_model.json")
    (folder / "puller7_settings.toml").write_text(SETTINGS, encoding="utf-8")
    (folder / "recipe_a.toml").write_text(RECIPE, encoding="utf-8")
    suite = folder / "suite.toml"
    suite.write_text(SUITE, encoding="utf-8")
    return suite


@pytest.fixture(scope="session")
def generated_step(tmp_path_factory: pytest.TempPathFactory, shipped_model: HammersteinModel) -> Path:
    """``czmpc codegen`` of the shipped model at its default settings, as ``.../step`` (not
    yet built: the first `czmpc.codegen.load_controller` builds it); skips without a C
    toolchain. Copy it before changing its files."""
    from czmpc.codegen import generate_step
    from czmpc.codegen.build import find_tools
    from czmpc.codegen.errors import BuildError

    try:
        find_tools()
    except BuildError as exc:   # pragma: no cover - CI has cc and make
        pytest.skip(str(exc))
    folder = tmp_path_factory.mktemp("c_step") / "step"
    generate_step(shipped_model, None, folder)
    return folder
