"""Every public name of czmpc, sysid and sim has a docstring and a page in the API reference."""

from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path

import pytest
from sphinx.pycode import ModuleAnalyzer

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("czmpc", "sysid", "sim")


def _docstring(package: str, name: str) -> str:
    """The docstring Sphinx shows for ``package.name``: the object's own, or for data the
    ``#:`` comment or string literal beside its assignment in the defining module."""
    obj = getattr(importlib.import_module(package), name)
    if inspect.isclass(obj) or inspect.isroutine(obj):
        return inspect.getdoc(obj) or ""
    module = importlib.import_module(package)._EXPORTS[name]
    docs = ModuleAnalyzer.for_module(module).find_attr_docs()
    return "\n".join(docs.get(("", name), []))


def _documented(package: str) -> list[str]:
    text = (REPO / "docs" / "api" / f"{package}.rst").read_text(encoding="utf-8")
    assert f".. module:: {package}" in text
    names: list[str] = []
    for block in re.findall(r"\.\. autosummary::\n(?:   :[^\n]*\n)*\n((?:   \S[^\n]*\n)+)", text):
        names += [line.strip() for line in block.splitlines()]
    return names


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_has_a_docstring(package: str) -> None:
    missing = [name for name in importlib.import_module(package).__all__
               if len(_docstring(package, name).strip()) < 10]
    assert missing == [], f"{package}: public names without a docstring: {missing}"


@pytest.mark.parametrize("package", PACKAGES)
def test_the_api_reference_lists_exactly_the_public_names(package: str) -> None:
    documented = _documented(package)
    assert len(documented) == len(set(documented)), "a name is listed twice"
    public = set(importlib.import_module(package).__all__)
    assert sorted(public - set(documented)) == [], f"missing from docs/api/{package}.rst"
    assert sorted(set(documented) - public) == [], f"docs/api/{package}.rst lists non-public names"


def test_the_docstring_check_sees_a_missing_docstring() -> None:
    # the analyzer finds `#:` comments of data, and a name without one reads as empty
    assert "header" in _docstring("sysid", "CSV_COLUMNS")
    docs = ModuleAnalyzer.for_module("sysid.data").find_attr_docs()
    assert ("", "_readonly") not in docs
