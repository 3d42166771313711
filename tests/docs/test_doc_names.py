"""Every object of czmpc, sysid or sim that a page of the documentation names exists.

The guides, the theory page and the references name functions and classes in prose
(````czmpc.qp.MoveBounds````, ```sysid.load_log```). Sphinx checks only the names it can
cross-reference, and a literal is not checked at all, so a renamed function would leave a
page pointing at nothing. This test imports each named object.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
#: Generated or executed output, not text someone wrote.
SKIP = ("_build", "_templates", "auto_examples", "generated")
#: A dotted name of the three packages inside a literal or a role; file names end it.
NAME = re.compile(r"`{1,2}~?((?:czmpc|sysid|sim)(?:\.[A-Za-z_]\w*)+)(?![\w/-]|\.\w)")
FILE_SUFFIXES = {"der", "pem", "toml", "json", "csv", "md", "py", "html", "txt", "png", "sqlite"}


def pages() -> list[Path]:
    return sorted(p for p in DOCS.rglob("*.rst") if not any(part in SKIP for part in p.parts))


def named_objects(text: str) -> set[str]:
    """The dotted names of czmpc, sysid and sim objects in ``text`` (file names excluded)."""
    return {name for name in NAME.findall(text) if name.rsplit(".", 1)[-1] not in FILE_SUFFIXES}


def resolves(dotted: str) -> bool:
    """Whether ``dotted`` is a module, or an attribute path from the longest importable one."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj: object = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                # a dataclass field without a default is not a class attribute
                fields = getattr(obj, "__dataclass_fields__", {})
                if attr not in fields:
                    return False
                return True
            obj = getattr(obj, attr)
        return True
    return False


def test_the_scan_finds_names_and_skips_files() -> None:
    text = ("``czmpc.qp.MPCQP`` and `sysid.load_log`, :doc:`x`, ``pki/own/czmpc.der``, "
            "``sysid.ballistic_mse(model, data)``, ``czmpc.nowhere.Nothing``")
    assert named_objects(text) == {"czmpc.qp.MPCQP", "sysid.load_log", "sysid.ballistic_mse",
                                   "czmpc.nowhere.Nothing"}
    assert resolves("czmpc.qp.MPCQP") and resolves("sysid.load_log")
    assert not resolves("czmpc.nowhere.Nothing") and not resolves("czmpc.qp.no_such_function")


@pytest.mark.parametrize("page", pages(), ids=lambda p: p.relative_to(DOCS).as_posix())
def test_every_named_object_exists(page: Path) -> None:
    missing = sorted(name for name in named_objects(page.read_text(encoding="utf-8"))
                     if not resolves(name))
    assert missing == [], f"{page.relative_to(REPO)} names objects that do not exist: {missing}"
