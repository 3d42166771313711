"""The getting-started page's code runs as printed."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PAGE = REPO / "docs" / "getting_started.rst"


def _python_blocks(text: str) -> list[str]:
    blocks = re.findall(r"\.\. code-block:: python\n\n((?:   [^\n]*\n|\n)+)", text)
    return ["\n".join(line[3:] for line in block.splitlines()) for block in blocks]


def test_the_two_readme_commands_open_the_page() -> None:
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    page = PAGE.read_text(encoding="utf-8")
    for command in ("make demo", "make test"):
        assert command in readme and f"   {command}" in page


@pytest.mark.slow
def test_the_library_in_ten_lines_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    (code,) = _python_blocks(PAGE.read_text(encoding="utf-8"))
    assert len([line for line in code.splitlines() if line.strip()]) <= 11   # imports + ten
    monkeypatch.chdir(tmp_path)
    exec(compile(code, str(PAGE), "exec"), {})
    assert (tmp_path / "model.json").is_file()
    # the printed steady-state error of the closed loop on the virtual heater [kW]
    printed = float(capsys.readouterr().out.strip().splitlines()[-1])
    assert abs(printed) < 0.05
