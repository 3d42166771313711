"""Give each dataclass field's page the description its class's docstring holds for it.

The frozen dataclasses document their fields in the class docstring's numpydoc
*Attributes* (or *Parameters*) section, with unit and meaning, as the style asks; a field
has no docstring of its own, and autodoc shows only its default. The attribute template
(``docs/_templates/autosummary/attribute.rst``) puts ``.. czmpc-field:: FULL.NAME`` in
each attribute's body; it renders that description for a dataclass field without a
``#:`` comment of its own (which autodoc shows instead) and nothing for anything else.
"""

from __future__ import annotations

import importlib
from typing import Any

from docutils import nodes
from docutils.statemachine import StringList
from numpydoc.docscrape import NumpyDocString
from sphinx.application import Sphinx
from sphinx.pycode import ModuleAnalyzer
from sphinx.util.docutils import SphinxDirective


def _import(dotted: str) -> Any:
    """The object ``dotted`` names (``czmpc.StepDiagnostics``), imported; None if none."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj: Any = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr, None)
            if obj is None:
                return None
        return obj
    return None


def field_description(owner: type, field: str) -> list[str]:
    """The lines ``owner``'s docstring gives ``field`` in Attributes, else in Parameters."""
    doc = NumpyDocString(owner.__doc__ or "")
    for section in ("Attributes", "Parameters"):
        for param in doc[section]:
            if field in (name.strip() for name in param.name.split(",")):
                return list(param.desc)
    return []


def described_field(dotted: str) -> list[str]:
    """The description of the dataclass field ``dotted`` names, or [] if it is none or
    has a ``#:`` comment of its own."""
    owner_name, _, field = dotted.rpartition(".")
    owner = _import(owner_name)
    if not isinstance(owner, type) or field not in getattr(owner, "__dataclass_fields__", {}):
        return []
    comments = ModuleAnalyzer.for_module(owner.__module__).find_attr_docs()
    if (owner.__qualname__, field) in comments:
        return []
    return field_description(owner, field)


class FieldDescription(SphinxDirective):
    """``.. czmpc-field:: czmpc.StepDiagnostics.status``: the field's class-doc description."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        lines = described_field(self.arguments[0])
        container = nodes.container()
        self.state.nested_parse(StringList(lines, source=f"<docstring of {self.arguments[0]}>"),
                                self.content_offset, container)
        return list(container.children)


def setup(app: Sphinx) -> dict[str, object]:
    app.add_directive("czmpc-field", FieldDescription)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
