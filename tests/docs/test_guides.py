"""The guides' commands and run configs are what this version accepts.

Every ``czmpc ...`` line of a shell block in docs/guides parses with the current command
line (an option renamed or removed fails here), every TOML block that is a run config or
a campaign spec passes its validator, and the commissioning guide's playback script runs.
"""

from __future__ import annotations

import re
import shlex
import shutil
import tomllib
from pathlib import Path
from typing import Any

import pytest

from czmpc.cli import build_parser
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

REPO = Path(__file__).resolve().parents[2]
GUIDES = sorted((REPO / "docs" / "guides").glob("*.rst"))


def _blocks(text: str, language: str) -> list[str]:
    found = re.findall(rf"\.\. code-block:: {language}\n\n((?:   [^\n]*\n|\n)+)", text)
    return ["\n".join(line[3:] for line in block.splitlines()) for block in found]


def _czmpc_commands(text: str) -> list[list[str]]:
    commands = []
    for block in _blocks(text, "sh"):
        joined = block.replace("\\\n", " ")
        for line in joined.splitlines():
            line = line.split("#", 1)[0].strip()
            if line.startswith("czmpc "):
                args = shlex.split(line)[1:]
                for i, arg in enumerate(args):          # the shell's redirections and pipes
                    if arg in (">", ">>", "|", "2>"):
                        args = args[:i]
                        break
                commands.append(args)
    return commands


def test_the_guides_are_found() -> None:
    names = {p.stem for p in GUIDES}
    assert {"identify", "tune", "plant_link", "campaigns", "commission", "regress"} <= names
    assert sum(len(_czmpc_commands(p.read_text(encoding="utf-8"))) for p in GUIDES) >= 15


@pytest.mark.parametrize("guide", GUIDES, ids=lambda p: p.stem)
def test_every_czmpc_command_of_a_guide_parses(guide: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parser = build_parser()
    for args in _czmpc_commands(guide.read_text(encoding="utf-8")):
        try:
            parser.parse_args(args)
        except SystemExit as exc:
            pytest.fail(f"{guide.name}: 'czmpc {shlex.join(args)}' does not parse "
                        f"(exit {exc.code}): {capsys.readouterr().err}")


def _toml_blocks() -> list[tuple[str, dict[str, Any]]]:
    out = []
    for guide in GUIDES:
        for block in _blocks(guide.read_text(encoding="utf-8"), "toml"):
            out.append((guide.stem, tomllib.loads(block)))
    return out


def test_the_guides_run_configs_pass_the_validator(tmp_path: Path) -> None:
    from czmpc.errors import SettingsError
    from czmpc.runtime.config import run_config_from_dict

    configs = [doc for _, doc in _toml_blocks() if "nodes" in doc]
    assert len(configs) == 2
    config = run_config_from_dict(configs[0], base_dir=tmp_path)
    assert config.time_scale == 20.0 and config.duration_s == 900.0
    # the PLC's nodes (plant_link.rst, "A PLC's own OPC UA server"): Siemens-style ids and
    # a raw Int16 command scaled 0..27648 = 0..100 %
    plc = run_config_from_dict({**configs[0], "nodes": configs[1]["nodes"],
                                "run": {**configs[0]["run"], "setpoint_kw": 45.0}},
                               base_dir=tmp_path)
    assert plc.nodes.triac_pct == 'ns=3;s="DB_Heater"."TriacRaw"'
    assert plc.nodes.scales["triac_pct"].to_raw(100.0) == 27648.0
    # the secured example: everything but the files it names (which the reader must make)
    secured = [doc for _, doc in _toml_blocks() if "security" in doc.get("plant", {})]
    assert len(secured) == 1
    doc = {**configs[0], "plant": secured[0]["plant"]}
    with pytest.raises(SettingsError, match="no such file"):
        run_config_from_dict(doc, base_dir=tmp_path)


def test_the_guides_campaign_spec_passes_the_validator(tmp_path: Path) -> None:
    from czmpc.campaigns.campaign import spec_from_dict

    (doc,) = [doc for _, doc in _toml_blocks() if "controllers" in doc and "model" in doc]
    shutil.copy(shipped_path(HAMMERSTEIN_MODEL_JSON), tmp_path / doc["model"])
    spec = spec_from_dict(doc, source=str(tmp_path / "mine.toml"), base_dir=tmp_path)
    assert len(spec.expand()) == 620          # as the guide counts them


def test_the_guides_regression_suite_passes_the_validator(tmp_path: Path) -> None:
    from czmpc.campaigns.regression import suite_from_dict

    (doc,) = [doc for _, doc in _toml_blocks() if "controllers" in doc and "model" not in doc]
    for entry in doc["controllers"]:       # the reader's own files, made here
        shutil.copy(shipped_path(HAMMERSTEIN_MODEL_JSON), tmp_path / entry["model"])
        (tmp_path / entry["settings"]).write_text("horizon_steps = 60\n", encoding="utf-8")
    suite = suite_from_dict(doc, source=str(tmp_path / "suite.toml"), base_dir=tmp_path)
    assert suite.name == "puller-7"
    assert len(suite.expand()) == 2 * 3      # 2 scenarios x (model + 2 perturbed plants)


@pytest.mark.slow
def test_the_commissioning_playback_script_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    from czmpc.cli import main

    page = (REPO / "docs" / "guides" / "commission.rst").read_text(encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    (design,) = [c for c in _czmpc_commands(page) if c[0] == "design-test"]
    design = [a if a != "model.json" else "prior.json" for a in design]
    from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
    (tmp_path / "prior.json").write_bytes(shipped_path(HAMMERSTEIN_MODEL_JSON).read_bytes())
    assert main(design) == 0
    (script,) = _blocks(page, "python")
    exec(compile(script, "commission.rst", "exec"), {})
    printed = capsys.readouterr().out
    assert "wrote test-log.csv: 8501 samples, power 31.2 .. 62.7 kW" in printed   # as in the guide


def test_the_tune_guides_settings_file_passes_the_reader() -> None:
    from czmpc.settings import MPCSettings
    from czmpc.settings_file import settings_from_dict
    from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
    from sysid.modelfile import load_model

    (doc,) = [doc for stem, doc in _toml_blocks() if stem == "tune"]
    model = load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))
    settings = settings_from_dict(doc, model, source="tune.rst")
    assert settings.max_move_pct_per_step == 1.0 and settings.soft_power_max_kw == 60.0
    assert settings.move_weight == MPCSettings.preset("smooth", model).move_weight
