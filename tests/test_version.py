"""One version everywhere: pyproject.toml, czmpc.__version__, czmpc --version, reports, model files."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

import czmpc
from czmpc.cli import main
from sysid.modelfile import model_to_dict

REPO = Path(__file__).resolve().parents[1]
PYPROJECT_VERSION = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]["version"]


def test_package_version_is_the_pyproject_version() -> None:
    assert czmpc.__version__ == PYPROJECT_VERSION


def test_cli_version_prints_the_pyproject_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.strip() == f"czmpc {PYPROJECT_VERSION}"


def test_changelog_has_a_section_for_this_version() -> None:
    changelog = (REPO / "CHANGELOG.md").read_text(encoding="utf-8")
    assert f"\n## {PYPROJECT_VERSION} - " in changelog


def test_citation_carries_this_version() -> None:
    citation = (REPO / "CITATION.cff").read_text(encoding="utf-8")
    assert f"\nversion: {PYPROJECT_VERSION}\n" in citation


def test_a_new_model_file_names_the_software_that_wrote_it(paper_armax_model: object) -> None:
    obj = model_to_dict(paper_armax_model)  # type: ignore[arg-type]
    assert obj["provenance"]["software"] == f"czmpc {PYPROJECT_VERSION}"
    json.dumps(obj)   # still plain JSON


def test_a_loaded_model_keeps_the_version_that_made_it(paper_armax_model: object) -> None:
    from dataclasses import replace

    from sysid.model import Provenance
    from sysid.modelfile import model_from_dict

    old = replace(paper_armax_model, provenance=Provenance(extra={"software": "czmpc 0.1.0"}))  # type: ignore[type-var]
    assert model_from_dict(model_to_dict(old)).provenance.extra["software"] == "czmpc 0.1.0"
