"""Docstrings and comments of the three packages point only to pages in this repository.

The design notes the project started from (``DESIGN.md``, ``STYLE.md``) are not shipped:
a reader of the wheel or of the documentation site cannot open them. What they say lives
in ``docs/`` (the controller in ``docs/theory.rst`` C1-C7, the model file in
``docs/reference/model_file.rst``), so source text points there instead.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("czmpc", "sysid", "sim")

#: Names of files outside the repository that source text must not send a reader to.
OUTSIDE = re.compile(r"\b(DESIGN\.md|STYLE\.md)|\.\./shared/")


def outside_pointers(root: Path) -> list[str]:
    """``path:line: text`` of every line under ``root`` that names an outside file."""
    found: list[str] = []
    for path in sorted(root.rglob("*")):
        if not path.is_file() or "__pycache__" in path.parts:
            continue
        if path.suffix not in (".py", ".toml", ".md", ".rst", ".txt", ".json", ".csv"):
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        for number, line in enumerate(text.splitlines(), start=1):
            if OUTSIDE.search(line):
                found.append(f"{path.relative_to(REPO)}:{number}: {line.strip()}")
    return found


def test_the_pattern_catches_each_outside_name(tmp_path: Path) -> None:
    # the check itself must see what it is there to see
    lines = ["x = 1  # see DESIGN.md item 4", '"""Style (STYLE.md B.9)."""',
             "# ../shared/notes", "# docs/theory.rst, C4"]
    assert [bool(OUTSIDE.search(line)) for line in lines] == [True, True, True, False]


@pytest.mark.parametrize("package", PACKAGES)
def test_no_docstring_or_comment_points_outside_the_repository(package: str) -> None:
    found = outside_pointers(REPO / package)
    assert found == [], (
        f"{len(found)} lines in {package}/ name a file that is not in the repository; "
        "point to a page under docs/ instead (docs/theory.rst C1-C7, "
        "docs/reference/model_file.rst, ...):\n" + "\n".join(found))
