"""Opening a run (`czmpc.runtime.session`): the switch-on rule, its check file, the ts checks."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import pytest
from plant_rig import make_config

from czmpc.commissioning.check import ModelCheck, write_check
from czmpc.errors import SettingsError
from czmpc.modes import Mode
from czmpc.runtime.config import RunConfig, RunConfigError
from czmpc.runtime.session import Verdict, open_run, read_check, switch_on_rule
from czmpc.shipped import shipped_path
from sysid.atomic import file_sha256
from sysid.modelfile import load_model, save_model

SHIPPED = shipped_path("cz_heater_model.json")


@pytest.mark.parametrize(("verdict", "force", "unattended", "allowed", "forced"), [
    ("ready", False, False, True, False),
    ("ready", False, True, True, False),
    ("ready with conditions", False, False, True, False),
    ("ready with conditions", False, True, False, False),
    (None, False, False, True, False),
    (None, False, True, False, False),
    ("not ready", False, False, False, False),
    ("not ready", True, False, True, True),
    ("not ready", True, True, False, False),
], ids=["ready", "ready-unattended", "conditions", "conditions-unattended", "unchecked",
        "unchecked-unattended", "not-ready", "not-ready-forced", "not-ready-forced-unattended"])
def test_the_switch_on_rule_follows_its_table(verdict: Verdict | None, force: bool,
                                              unattended: bool, allowed: bool,
                                              forced: bool) -> None:
    rule = switch_on_rule(verdict, "check-model verdict", force=force, unattended=unattended)
    assert (rule.allowed, rule.forced) == (allowed, forced)
    assert rule.notes and all(text for _, text in rule.notes)


def _config(tmp_path: Path, model_path: Path, **changes: object) -> RunConfig:
    config = make_config(tmp_path, 4840)
    return dataclasses.replace(config, model_path=model_path, **changes)  # type: ignore[arg-type]


def _checked(model_path: Path, verdict: Verdict) -> None:
    write_check(ModelCheck(verdict=verdict, reasons=("a reason",), items=(),
                           model_sha256=file_sha256(model_path)), model_path)


def test_a_not_ready_model_opens_in_predict_only_unless_forced(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="czmpc.runtime.session")
    model_path = tmp_path / "model.json"
    model_path.write_bytes(SHIPPED.read_bytes())
    assert switch_on_rule(*read_check(model_path)).allowed     # never checked: ON, warned
    _checked(model_path, "not ready")
    assert read_check(model_path) == ("not ready", "check-model verdict: not ready (a reason)")
    shadow = open_run(_config(tmp_path, model_path))
    assert not shadow.switch_on.allowed and shadow.mpc.mode is Mode.PREDICT
    assert shadow.loop().allow_on is False
    assert "running in PREDICT only (nothing is written); --force overrides" in caplog.text
    caplog.clear()
    forced = open_run(_config(tmp_path, model_path), force=True)
    assert forced.switch_on.forced and forced.mpc.mode is Mode.ON
    assert forced.loop().allow_on is True
    assert "--force: switching ON with a model judged not ready" in caplog.text
    _checked(model_path, "ready with conditions")
    assert open_run(_config(tmp_path, model_path)).loop().allow_on is True
    assert open_run(_config(tmp_path, model_path), unattended=True).loop().allow_on is False
    model_path.write_bytes(model_path.read_bytes() + b"\n")    # changed since its check
    verdict, note = read_check(model_path)
    assert verdict is None and "changed since" in note


def test_a_model_or_candidate_of_another_sampling_time_is_refused(tmp_path: Path) -> None:
    other = tmp_path / "other.json"
    save_model(load_model(SHIPPED).with_updates(ts_s=1.0), other)
    with pytest.raises(SettingsError, match=r"plant\.ts_s: expected the sampling time 2 s.*has 1 s"):
        open_run(_config(tmp_path, other))
    with pytest.raises(SettingsError, match=r"controller\.candidate: .* has 1 s"):
        open_run(_config(tmp_path, SHIPPED, candidate_path=other))
    with pytest.raises(RunConfigError, match="controller.model: missing"):
        open_run(dataclasses.replace(make_config(tmp_path, 4840), model_path=None))
