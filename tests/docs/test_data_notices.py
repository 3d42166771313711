"""Every third-party data file in data/real keeps its notice (README and docs page)."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
REAL = REPO / "data" / "real"


def _data_files() -> list[str]:
    return sorted(p.name for p in REAL.iterdir() if p.is_file() and p.name != "README.md")


def test_every_real_data_file_has_a_notice_row_with_source_licence_and_original() -> None:
    readme = (REAL / "README.md").read_text(encoding="utf-8")
    notices = readme.split("## Third-party notices", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in notices.splitlines() if line.startswith("| `")]
    assert len(_data_files()) == 5
    for name in _data_files():
        (row,) = [r for r in rows if f"`{name}`" in r]
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert len(cells) == 5, row
        assert re.search(r"https://github\.com/\S+ `[0-9a-f]{40}`", cells[1]), cells[1]
        licence_files = re.findall(r"\(licenses/([^)]+)\)", cells[2])
        assert licence_files and all((REAL / "licenses" / f).is_file() for f in licence_files)
        assert cells[3] and cells[4]                     # original source, its licence (or "not confirmed")


def test_the_licence_texts_are_the_named_licences() -> None:
    texts = {p.name: p.read_text(encoding="utf-8") for p in (REAL / "licenses").iterdir()}
    assert len(texts) == 4
    for name, text in texts.items():
        if ".MIT." in name:
            assert text.startswith(("MIT License", "The MIT License")) and "Copyright (c)" in text
        else:
            assert "Apache License" in text and "Version 2.0, January 2004" in text


def test_the_docs_page_names_every_real_data_file() -> None:
    page = (REPO / "docs" / "reference" / "data_sources.rst").read_text(encoding="utf-8")
    for name in _data_files():
        if not name.endswith("_description.txt"):
            assert f"``{name}``" in page, name
