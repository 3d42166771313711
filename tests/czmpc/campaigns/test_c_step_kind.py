"""The generated C step as a campaign and regression controller (``kind = "c_step"``).

The C replays the Python MPC of the model and settings it was generated from (issue 42:
within 1e-6 % of the input in double precision, bit-equal where the solver allows), so a
``c_step`` case must land within the tolerance rule of an ``mpc`` case of that model and
those settings, on the same plant, scenario and seed.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
from pathlib import Path

import pytest

from czmpc.campaigns.build import TIGHT_OSQP, build_controller, build_plant
from czmpc.campaigns.campaign import CampaignError, execute_run, load_spec, spec_from_dict
from czmpc.campaigns.regression import (
    RegressError,
    RegressRunError,
    check_golden,
    record_suite,
    suite_from_dict,
)
from czmpc.campaigns.runner import run_campaign
from czmpc.cli import main
from czmpc.codegen import generate_step
from czmpc.codegen.errors import BuildError
from czmpc.controller import OffsetFreeMPC
from czmpc.errors import SettingsError
from czmpc.settings import MPCSettings
from sim.scenario import load_scenario
from sysid.model import HammersteinModel

#: A c_step (the C) and an mpc (Python) of the same model and settings, on the model plant
#: and the heater; the staircase at a tenth of its length (390 samples, two steps).
SUITE = """
scenarios = ["staircase"]
time_scale = 0.1
seeds = [7]
[[controllers]]
kind = "c_step"
directory = "step"
[[controllers]]
kind = "mpc"
model = "step/model.json"
settings = "step/settings.toml"
[[plants]]
kind = "model"
[[plants]]
kind = "heater"
"""
#: The tolerance rule makes a c_step case's tolerance the mpc case's: both tight re-runs
#: are the same Python run, and the nominal runs agree to the solver's rounding (1e-14 %
#: of the input measured), so the tolerances agree to far better than this.
SAME_TOLERANCE_RTOL = 1e-6


def _suite_dir(tmp_path: Path, generated_step: Path, text: str = SUITE) -> Path:
    """``tmp_path`` with ``suite.toml`` and a copy of the generated step as ``step/``."""
    shutil.copytree(generated_step, tmp_path / "step")
    (tmp_path / "suite.toml").write_text(text, encoding="utf-8")
    return tmp_path


def test_a_suite_with_a_c_step_records_within_the_tolerances_of_the_mpc_it_came_from(
        tmp_path: Path, generated_step: Path) -> None:
    root = _suite_dir(tmp_path, generated_step)
    doc = json.loads(record_suite(root / "suite.toml", root / "golden").read_text())
    cases = doc["cases"]
    assert sorted(cases) == ["c_step/heater/staircase/s7", "c_step/model/staircase/s7",
                             "mpc/heater/staircase/s7", "mpc/model/staircase/s7"]
    for plant in ("model", "heater"):
        c, py = cases[f"c_step/{plant}/staircase/s7"], cases[f"mpc/{plant}/staircase/s7"]
        assert c["kind"] == "c_step"
        assert c["inputs"] == {"model": "step/model.json", "settings": "step/settings.toml",
                               "c_step": "step/czmpc_step.c", "c_constants": "step/czmpc_model.h"}
        for name, golden in py["metrics"].items():
            got = c["metrics"][name]
            assert abs(got["value"] - golden["value"]) <= golden["tol"], (plant, name)
            assert got["tol"] == pytest.approx(golden["tol"], rel=SAME_TOLERANCE_RTOL, abs=0.0)
        assert c["metrics"]["iae_kw_s"]["value"] > 50.0         # two 5 kW steps were run
        assert c["metrics"]["n_solver_failures"]["value"] == 0
        assert c["metrics"]["iae_kw_s"]["tol"] > 1e-6 * c["metrics"]["iae_kw_s"]["value"]
    report = check_golden(root / "golden")
    assert report.passed and len(report.cases) == 4
    assert all(c.divergence is None for c in report.cases)


def test_regenerated_c_with_other_settings_fails_the_check_and_is_named(
        tmp_path: Path, generated_step: Path, shipped_model: HammersteinModel) -> None:
    text = SUITE.replace('[[plants]]\nkind = "heater"\n', "")
    root = _suite_dir(tmp_path, generated_step, text)
    record_suite(root / "suite.toml", root / "golden")
    slower = MPCSettings.default_for(shipped_model)
    slower = slower.with_updates(move_weight=4.0 * slower.move_weight)
    generate_step(shipped_model, slower, root / "step")       # the same directory, new C
    report = check_golden(root / "golden")
    by_id = {c.case_id: c for c in report.cases}
    c_case = by_id["c_step/model/staircase/s7"]
    assert not c_case.passed
    assert {f.metric for f in c_case.failures} >= {"iae_kw_s", "input_total_variation_pct"}
    assert set(c_case.changed_inputs) >= {"step/settings.toml", "step/czmpc_model.h"}
    changed = {c.name: c for c in report.input_changes}
    assert any(d.startswith("move_weight:") for d in changed["step/settings.toml"].details)


def test_a_campaign_spec_with_a_c_step_runs_on_parallel_workers_from_an_unbuilt_directory(
        tmp_path: Path, generated_step: Path) -> None:
    # Two spawned workers load the same unbuilt directory: the build lock makes one build
    # it and the other load it after (make run twice at once in one directory garbles it).
    root = _suite_dir(tmp_path, generated_step, SUITE.replace("seeds = [7]", "seeds = 2"))
    assert not (root / "step" / "libczmpc.so").exists()
    spec = load_spec(root / "suite.toml")
    outcome = run_campaign(spec, root / "campaign", executor="processes", workers=2)
    rows = {r["run_id"]: r for r in outcome.rows}
    assert outcome.n_errors == 0 and len(rows) == 8
    for plant in ("model", "heater"):
        for k in (0, 1):
            c, py = rows[f"c_step|{plant}|staircase|{k}"], rows[f"mpc|{plant}|staircase|{k}"]
            assert c["kind"] == "c_step" and c["seed"] == py["seed"]
            assert c["iae_kw_s"] == pytest.approx(py["iae_kw_s"], rel=1e-9, abs=0.0)
            assert c["input_total_variation_pct"] == pytest.approx(
                py["input_total_variation_pct"], rel=1e-9, abs=0.0)
            assert c["offset_free"] == py["offset_free"]
            assert c["n_allowed_range_violations"] == 0
    assert (root / "step" / "libczmpc.so").is_file()


def test_the_campaign_command_runs_a_c_step(tmp_path: Path, generated_step: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    root = _suite_dir(tmp_path, generated_step, SUITE.replace('[[plants]]\nkind = "heater"\n', ""))
    rc = main(["campaign", "run", str(root / "suite.toml"), "--out", str(root / "out")])
    assert rc == 0, capsys.readouterr().err
    assert "2 runs (2 run now, 0 resumed), 0 crashed" in capsys.readouterr().out


def test_a_c_step_table_is_checked_when_the_spec_is_read(tmp_path: Path, generated_step: Path) -> None:
    root = _suite_dir(tmp_path, generated_step)
    base = {"scenarios": ["staircase"], "plants": [{"kind": "model"}]}

    def refused(table: dict[str, object]) -> str:
        with pytest.raises(CampaignError) as info:
            spec_from_dict({**base, "controllers": [table]}, source="s.toml", base_dir=root)
        return str(info.value)

    assert "directory = 'nowhere': no such directory" in refused(
        {"kind": "c_step", "directory": "nowhere"})
    assert "czmpc codegen MODEL.json --out" in refused({"kind": "c_step", "directory": "nowhere"})
    (root / "empty").mkdir()
    assert "not a directory written by 'czmpc codegen'" in refused(
        {"kind": "c_step", "directory": "empty"})
    assert "expected 'directory' the directory 'czmpc codegen' wrote" in refused({"kind": "c_step"})
    assert "drop 'model'" in refused({"kind": "c_step", "directory": "step",
                                      "model": "step/model.json"})
    assert "'directory' is for kind 'c_step' only" in refused({"kind": "mpc", "directory": "step"})
    spec = spec_from_dict({**base, "controllers": [{"kind": "c_step", "directory": "step"}]},
                          base_dir=root)
    (c,) = spec.controllers
    assert (c.name, c.directory) == ("c_step", str((root / "step").resolve()))
    assert c.model_path == str((root / "step" / "model.json").resolve())
    assert set(spec.input_files()) == {str((root / "step" / n).resolve()) for n in (
        "model.json", "settings.toml", "czmpc_step.c", "czmpc_model.h")}
    with pytest.raises(RegressError, match="no such directory"):
        suite_from_dict({**base, "controllers": [{"kind": "c_step", "directory": "gone"}]},
                        source="s.toml", base_dir=root)


def _no_compiler(monkeypatch: pytest.MonkeyPatch) -> None:
    """The tool lookup as on a machine without the compiler ``CC`` names."""
    module = sys.modules["czmpc.codegen.build"]   # the package re-exports a function `build`
    real = module.find_tools
    monkeypatch.setattr(module, "find_tools",
                        lambda env=None: real({"CC": "czmpc-no-such-compiler"}))


def test_without_a_c_compiler_a_suite_or_campaign_says_what_to_install(
        tmp_path: Path, generated_step: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    root = _suite_dir(tmp_path, generated_step)
    _no_compiler(monkeypatch)
    with pytest.raises(BuildError, match=r"a C compiler \('czmpc-no-such-compiler'\).*build-essential"):
        record_suite(root / "suite.toml", root / "golden")
    assert not (root / "golden").exists()
    rc = main(["campaign", "run", str(root / "suite.toml"), "--out", str(root / "out")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "czmpc: error: building the generated C step needs a C compiler" in err
    run = next(r for r in load_spec(root / "suite.toml").expand() if r.controller.kind == "c_step")
    row = execute_run(run)                    # the engine without the CLI: the run's error
    assert row["status"] == "error" and row["error"].startswith("BuildError: building the")


def test_a_scenario_that_changes_the_compiled_limits_is_refused_with_what_to_generate(
        tmp_path: Path, generated_step: Path) -> None:
    text = SUITE.replace('scenarios = ["staircase"]', 'scenarios = ["narrow.toml"]')
    root = _suite_dir(tmp_path, generated_step, text)
    (root / "narrow.toml").write_text(
        'name = "narrow"\nduration_s = 400\nts_s = 2.0\ninitial_setpoint_kw = 45.0\n'
        "[limits]\ntriac_min_pct = 20.0\ntriac_max_pct = 70.0\n", encoding="utf-8")
    with pytest.raises(RegressRunError,
                       match=r"c_step/model/narrow/s7: SettingsError: .*scenario 'narrow-short' changes "
                             r"settings compiled into the C step \(triac_min_pct 0\.0 -> 20\.0; "
                             r"triac_max_pct 100\.0 -> 70\.0\).*--settings FILE"):
        record_suite(root / "suite.toml", root / "golden")


def test_the_tight_reference_of_a_c_step_is_the_python_mpc_at_tight_tolerances(
        tmp_path: Path, generated_step: Path, shipped_model: HammersteinModel) -> None:
    folder = tmp_path / "step"
    shutil.copytree(generated_step, folder)
    scenario = load_scenario("meltdown_ramp").shortened(0.02)
    plant, s0, _ = build_plant("heater", shipped_model, scenario, noise=True)
    tight = build_controller("c_step", shipped_model, scenario, initial_triac_pct=s0, tight=True,
                             c_step_directory=str(folder))
    assert isinstance(tight, OffsetFreeMPC)
    assert tight.settings.osqp == TIGHT_OSQP
    c = build_controller("c_step", shipped_model, scenario, initial_triac_pct=s0,
                         c_step_directory=str(folder))
    assert type(c).__name__ == "CController"
    # starts at the plant's input (20 kW on the heater: below the model's range, so at its
    # low end), inside the shared allowed range [28, 70] % as every other kind does
    s = c.step(scenario.initial_setpoint_kw, scenario.initial_setpoint_kw)
    assert 28.0 - 1e-9 <= s <= 70.0 + 1e-9
    other = dataclasses.replace(shipped_model, noise_std_kw=2 * shipped_model.noise_std_kw)
    with pytest.raises(SettingsError, match="another model than the one given"):
        build_controller("c_step", other, scenario, initial_triac_pct=s0,
                         c_step_directory=str(folder))


def test_the_codegen_guides_suite_passes_the_validator(tmp_path: Path, generated_step: Path) -> None:
    import textwrap
    import tomllib

    guide = Path(__file__).resolve().parents[3] / "docs" / "guides" / "codegen.rst"
    section = guide.read_text(encoding="utf-8").split("6. In a regression suite", 1)[1]
    block = section.split("::\n\n", 1)[1]
    lines = []
    for line in block.splitlines():
        if line and not line.startswith("    "):
            break
        lines.append(line)
    doc = tomllib.loads(textwrap.dedent("\n".join(lines)))
    shutil.copytree(generated_step, tmp_path / "step")
    suite = suite_from_dict(doc, source=str(tmp_path / "suite.toml"), base_dir=tmp_path)
    assert [(c.kind, c.model_path) for c in suite.controllers] == [
        ("c_step", str((tmp_path / "step" / "model.json").resolve())),
        ("mpc", str((tmp_path / "step" / "model.json").resolve()))]
    assert len(suite.expand()) == 2 * 2      # 2 controllers x 2 scenarios on the heater
