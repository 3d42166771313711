"""czmpc regress record / check / audit through the console entry point, on a user's files."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from czmpc.campaigns.build import MUTATIONS
from czmpc.campaigns.regression import load_golden_dir
from czmpc.cli import main


def test_record_check_pass_then_a_doubled_weight_fails_naming_metric_and_divergence(
        user_suite: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    golden = tmp_path / "golden"
    assert main(["regress", "record", str(user_suite), "--out", str(golden)]) == 0
    assert "recorded 2 case(s) of suite 'puller-7'" in capsys.readouterr().out
    doc = load_golden_dir(golden).doc
    assert set(doc["cases"]) == {"tuned/model/recipe_a/s3", "tuned/perturbed g1.1 m1 d+0/recipe_a/s3"}
    assert {Path(k).name for k in doc["inputs"]} == {
        "puller7_model.json", "puller7_settings.toml", "recipe_a.toml"}
    with np.load(golden / doc["cases"]["tuned/model/recipe_a/s3"]["trajectory"]) as data:
        assert data["power_true_kw"].dtype == np.float32 and data["time_s"].shape == (300,)

    junit = tmp_path / "ci" / "junit.xml"
    assert main(["regress", "check", str(golden), "--junit", str(junit)]) == 0
    assert "puller-7: 2 of 2 case(s) hold" in capsys.readouterr().out
    root = ET.parse(junit).getroot()
    assert (root.tag, root.get("tests"), root.get("failures"), root.get("errors")) == (
        "testsuite", "2", "0", "0")

    settings = user_suite.parent / "puller7_settings.toml"
    settings.write_text(settings.read_text(encoding="utf-8").replace(
        "move_weight = 0.1", "move_weight = 0.2"), encoding="utf-8")
    report_dir = tmp_path / "report"
    assert main(["regress", "check", str(golden), "--junit", str(junit),
                 "--out", str(report_dir)]) == 1
    out = capsys.readouterr().out
    assert "FAIL" in out and "iae_kw_s" in out and "0 of 2 case(s) hold; 2 FAILED" in out
    assert "input file changed: puller7_settings.toml" in out
    assert "move_weight: 0.1 -> 0.2" in out
    # The first divergence is reported inside the 600 s run: the doubled move weight
    # changes how the loop answers the plant noise from the start, and the setpoint step
    # at 60 s at the latest.
    divergence = out.split("t = ", 1)[1].split(" s", 1)[0]
    assert 0.0 <= float(divergence) <= 60.0
    root = ET.parse(junit).getroot()
    assert root.get("failures") == "2"
    props = {p.get("name"): p.get("value") for p in root.iter("property")}
    assert props["changed_input:puller7_settings.toml"] != props.get("czmpc_version_checked")
    assert [c.get("name") for c in root.iter("testcase")] == [
        "tuned/model/recipe_a/s3", "tuned/perturbed g1.1 m1 d+0/recipe_a/s3"]
    failure = root.find("testcase/failure")
    assert failure is not None and "first divergence t = " in failure.get("message", "")
    assert "iae_kw_s" in (failure.text or "") and "likely cause" in (failure.text or "")
    md = (report_dir / "report.md").read_text(encoding="utf-8")
    assert "## Likely cause" in md and "| tuned/model/recipe_a/s3 | iae_kw_s |" in md
    assert len(list((report_dir / "figures").glob("*.png"))) == 2


def test_record_refuses_an_existing_golden_directory_without_force(
        user_suite: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    golden = tmp_path / "golden"
    golden.mkdir()
    (golden / "notes.txt").write_text("mine", encoding="utf-8")
    assert main(["regress", "record", str(user_suite), "--out", str(golden)]) == 2
    assert "already exists; pass --force" in capsys.readouterr().err
    assert main(["regress", "record", str(user_suite), "--out", str(golden), "--force"]) == 2
    assert "holds no regress.json" in capsys.readouterr().err
    (golden / "notes.txt").unlink()
    assert main(["regress", "record", str(user_suite), "--out", str(golden)]) == 0
    assert main(["regress", "record", str(user_suite), "--out", str(golden), "--force"]) == 0


def test_bad_suite_and_missing_golden_directory_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    suite = tmp_path / "s.toml"
    suite.write_text('scenarios = ["staircase"]\n[[controllers]]\nkind = "mpc"\n'
                     'settings = "nope.toml"\n[[plants]]\nkind = "model"\n', encoding="utf-8")
    assert main(["regress", "record", str(suite), "--out", str(tmp_path / "g")]) == 2
    assert "nope.toml: cannot read the settings file" in capsys.readouterr().err
    assert main(["regress", "check", str(tmp_path / "nothing")]) == 2
    assert "is not a golden directory" in capsys.readouterr().err


RATE_LIMITED = """\
name = "limited"
duration_s = 400
ts_s = 2.0
plant_noise = true
initial_setpoint_kw = 45.0
initial_triac_pct = 45.0
[limits]
max_move_pct_per_step = 0.2
[[setpoint]]
kind = "step"
at_s = 40
power_kw = 60.0
"""
FLAT = """\
name = "flat"
duration_s = 200
ts_s = 2.0
plant_noise = false
initial_setpoint_kw = 45.0
"""


def _suite(folder: Path, scenario: str) -> Path:
    folder.mkdir()
    (folder / "scenario.toml").write_text(scenario, encoding="utf-8")
    suite = folder / "suite.toml"
    suite.write_text('scenarios = ["scenario.toml"]\n[[controllers]]\nkind = "mpc"\n'
                     '[[plants]]\nkind = "model"\n', encoding="utf-8")
    return suite


def test_audit_reports_caught_mutations_and_flags_a_suite_that_catches_none(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    busy = _suite(tmp_path / "busy", RATE_LIMITED)
    assert main(["regress", "record", str(busy), "--out", str(tmp_path / "g1")]) == 0
    # A 15 kW step through a tight rate limit: the limit binds for about 55 samples (11 %
    # at 0.2 %/step), longer than the horizon (39 samples for the shipped model) and the
    # shortened one, so each of the four mutations changes the response.
    assert main(["regress", "audit", str(tmp_path / "g1")]) == 0
    out = capsys.readouterr().out
    for mutation in MUTATIONS:
        assert re.search(rf"^{re.escape(mutation)} +1 +1 case\(s\)", out, re.MULTILINE), out
    assert "the suite catches 4 of 4 mutation(s)" in out
    # At steady state without noise nothing moves: no mutation can show.
    flat = _suite(tmp_path / "flat", FLAT)
    assert main(["regress", "record", str(flat), "--out", str(tmp_path / "g2")]) == 0
    assert main(["regress", "audit", str(tmp_path / "g2"), "--mutation", "move_weight x2",
                 "--mutation", "horizon -20%"]) == 1
    assert "FLAGGED: the suite catches none of the mutations" in capsys.readouterr().out


def test_a_changed_recipe_step_is_named_with_its_old_and_new_power(
        user_suite: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    recipe = user_suite.parent / "recipe_a.toml"
    text = recipe.read_text(encoding="utf-8")
    assert text.count("power_kw = 50.0") == 1
    recipe.write_text(text.replace("power_kw = 50.0", "power_kw = 49.0"), encoding="utf-8")
    golden = tmp_path / "golden"
    assert main(["regress", "record", str(user_suite), "--out", str(golden)]) == 0
    recipe.write_text(text, encoding="utf-8")  # the recipe's step: 49 -> 50 kW
    report_dir = tmp_path / "report"
    assert main(["regress", "check", str(golden), "--out", str(report_dir)]) == 1
    out = capsys.readouterr().out
    assert "input file changed: recipe_a.toml" in out
    assert "setpoint[0].power_kw: 49.0 -> 50.0" in out
    assert "setpoint[0].power_kw: 49.0 -> 50.0" in (report_dir / "report.md").read_text(
        encoding="utf-8")


def test_a_settings_file_that_became_invalid_is_bad_input_not_a_failed_case(
        user_suite: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    golden = tmp_path / "golden"
    assert main(["regress", "record", str(user_suite), "--out", str(golden)]) == 0
    settings = user_suite.parent / "puller7_settings.toml"
    settings.write_text("move_wieght = 0.2\n", encoding="utf-8")
    assert main(["regress", "check", str(golden)]) == 2
    err = capsys.readouterr().err
    assert "czmpc: error:" in err and "move_wieght" in err and "puller7_settings.toml" in err
