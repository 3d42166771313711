"""Every public field and property of a public class says what it is, so that its page in
the API reference (one per attribute) is not empty.

A description is the property's own docstring, a ``#:`` comment on the field, or the
entry the class docstring gives it under *Attributes* or *Parameters* (what the site's
``czmpc-field`` directive, ``docs/_ext/czmpc_fields.py``, puts on the field's page).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import sys
from pathlib import Path
from types import ModuleType

import pytest
from sphinx.pycode import ModuleAnalyzer

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("czmpc", "czmpc.pid", "sysid", "sim")


@pytest.fixture(scope="module")
def fields() -> ModuleType:
    sys.path.insert(0, str(REPO / "docs" / "_ext"))
    try:
        import czmpc_fields
    finally:
        sys.path.remove(str(REPO / "docs" / "_ext"))
    return czmpc_fields


def undocumented_members(cls: type, fields: ModuleType) -> list[str]:
    """The public fields, annotations and properties of ``cls`` without a description."""
    names = set(getattr(cls, "__dataclass_fields__", {})) | set(cls.__dict__.get("__annotations__", {}))
    names |= {name for name, value in cls.__dict__.items() if isinstance(value, property)}
    try:
        comments = ModuleAnalyzer.for_module(cls.__module__).find_attr_docs()
    except Exception:           # a class defined outside a module file (a test's own)
        comments = {}
    missing = []
    for name in sorted(n for n in names if not n.startswith("_")):
        value = cls.__dict__.get(name)
        if isinstance(value, property) and (value.__doc__ or "").strip():
            continue
        if (cls.__qualname__, name) in comments or fields.field_description(cls, name):
            continue
        missing.append(name)
    return missing


def test_an_undocumented_field_is_found(fields: ModuleType) -> None:
    @dataclasses.dataclass(frozen=True)
    class Sample:
        """A sample.

        Attributes
        ----------
        power_kw :
            Power [kW].
        """

        power_kw: float
        triac_pct: float

        @property
        def energy_kj(self) -> float:
            return 0.0

    assert undocumented_members(Sample, fields) == ["energy_kj", "triac_pct"]


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_field_and_property_is_described(package: str, fields: ModuleType) -> None:
    module = importlib.import_module(package)
    missing = [f"{package}.{name}.{member}" for name in module.__all__
               if inspect.isclass(cls := getattr(module, name)) and not issubclass(cls, BaseException)
               for member in undocumented_members(cls, fields)]
    assert missing == [], f"fields and properties without a description: {missing}"
