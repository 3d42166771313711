"""The command-line reference is written from the parser, and each class page lists its methods.

Both build a one-page Sphinx project in a temporary folder with the site's own extension
and templates (``docs/_ext``, ``docs/_templates``): seconds, where ``make docs`` takes
minutes.
"""

from __future__ import annotations

import argparse
import html
import re
import sys
from pathlib import Path

import pytest
from sphinx.application import Sphinx

from czmpc.cli import build_parser

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"


def _build(tmp_path: Path, conf: str, index: str) -> Path:
    """Build ``index`` with ``conf`` into HTML; warnings are errors. Return the output folder."""
    src = tmp_path / "src"
    src.mkdir()
    (src / "conf.py").write_text(conf, encoding="utf-8")
    (src / "index.rst").write_text(index, encoding="utf-8")
    out = tmp_path / "html"
    app = Sphinx(str(src), str(src), str(out), str(tmp_path / "doctrees"), "html",
                 status=None, warning=sys.stderr, warningiserror=True, freshenv=True)
    app.build()
    return out


def _text(page: Path) -> str:
    """The page's visible text, tags removed, entities decoded."""
    return html.unescape(re.sub(r"<[^>]+>", "", page.read_text(encoding="utf-8")))


def _commands(parser: argparse.ArgumentParser, prefix: str) -> list[tuple[str, argparse.ArgumentParser]]:
    found: list[tuple[str, argparse.ArgumentParser]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.append((f"{prefix} {name}", sub))
                found += _commands(sub, f"{prefix} {name}")
    return found


@pytest.fixture(scope="module")
def cli_page(tmp_path_factory: pytest.TempPathFactory) -> str:
    conf = f"import sys\nsys.path.insert(0, {str(DOCS / '_ext')!r})\nextensions = ['czmpc_cli']\n"
    out = _build(tmp_path_factory.mktemp("cli"), conf, "CLI\n===\n\n.. czmpc-cli::\n")
    return _text(out / "index.html")


def test_every_command_and_sub_command_has_a_section(cli_page: str) -> None:
    commands = _commands(build_parser(), "czmpc")
    assert len(commands) >= 10
    missing = [name for name, _ in commands if f"{name}¶" not in cli_page
               and f"{name}#" not in cli_page and f"\n{name}\n" not in cli_page]
    assert missing == [], f"commands without a section: {missing}"


def test_every_option_of_every_command_is_listed_with_its_help(cli_page: str) -> None:
    missing: list[str] = []
    for name, parser in _commands(build_parser(), "czmpc"):
        for action in parser._actions:
            if action.help == argparse.SUPPRESS or isinstance(action, argparse._SubParsersAction):
                continue
            for option in action.option_strings:
                if option not in cli_page:
                    missing.append(f"{name} {option}")
            first_words = " ".join((action.help or "").split()[:4]).replace("%%", "%")
            if "%(" not in first_words and first_words.replace("``", "") not in cli_page:
                missing.append(f"{name} {action.dest}: help {first_words!r}")
    assert missing == [], f"options missing from the reference: {missing}"


def test_terminal_text_keeps_its_hyphens_and_quotes(cli_page: str) -> None:
    # smart quotes would print '--show' as an en dash and mangle 'czmpc identify'
    assert "\u2013show" not in cli_page and "czmpc settings --show" in cli_page
    assert "\u2018" not in cli_page and "\u2019" not in cli_page


def test_the_top_level_help_is_shown_as_the_console_script_prints_it(cli_page: str) -> None:
    assert "usage: czmpc [-h]" in cli_page
    for action in build_parser()._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                assert choice.dest in cli_page


def test_a_class_page_links_each_method_and_field_to_a_page_of_its_own(tmp_path: Path) -> None:
    conf = (f"import sys\nsys.path.insert(0, {str(DOCS / '_ext')!r})\n"
            f"templates_path = [{str(DOCS / '_templates')!r}]\n"
            "extensions = ['sphinx.ext.autodoc', 'sphinx.ext.autosummary', 'numpydoc', "
            "'czmpc_fields']\n"
            "autosummary_generate = True\nautodoc_typehints = 'none'\n"
            "numpydoc_show_class_members = False\nnumpydoc_class_members_toctree = False\n"
            "default_role = 'py:obj'\n")
    index = ("API\n===\n\n.. currentmodule:: czmpc\n\n.. autosummary::\n   :toctree: generated\n\n"
             "   OffsetFreeMPC\n   CzmpcError\n   StepDiagnostics\n")
    out = _build(tmp_path, conf, index)
    step = out / "generated" / "czmpc.OffsetFreeMPC.step.html"
    assert step.is_file()
    text = _text(step)
    for expected in ("power_kw", "setpoint_kw", "applied_triac_pct", "[kW]", "Returns", "finite"):
        assert expected in text, f"{expected!r} not on the step page"
    assert "czmpc.OffsetFreeMPC.step.html" in (out / "generated" / "czmpc.OffsetFreeMPC.html").read_text(
        encoding="utf-8")
    # an exception's inherited methods (with_traceback, add_note) stay on BaseException
    assert not list((out / "generated").glob("czmpc.CzmpcError.*.html"))
    # a dataclass field's page carries the description the class docstring gives it
    from numpydoc.docscrape import NumpyDocString

    from czmpc import StepDiagnostics

    doc = NumpyDocString(StepDiagnostics.__doc__ or "")
    (entry,) = [p for p in [*doc["Attributes"], *doc["Parameters"]] if p.name == "triac_pct"]
    described = " ".join(" ".join(entry.desc).replace("`", "").split()[:4])
    field = " ".join(_text(out / "generated" / "czmpc.StepDiagnostics.triac_pct.html").split())
    assert described and described in field and "[%]" in field


def test_the_commands_stand_under_their_groups_in_the_help_order(cli_page: str) -> None:
    from czmpc.cli import COMMAND_GROUPS

    body = cli_page.split("options:", 1)[-1]          # past the literal `czmpc --help` text
    position = 0
    for title, names in COMMAND_GROUPS.items():
        heading = title[0].upper() + title[1:]
        assert heading in body, f"no section for the group {title!r}"
        start = body.index(heading)
        assert start >= position, f"group {title!r} out of the help's order"
        for name in names:
            assert body.index(f"czmpc {name}¶" if f"czmpc {name}¶" in body else f"czmpc {name}#",
                              start) >= start
        position = start


def test_getting_started_lists_every_command_with_its_task() -> None:
    from czmpc.cli import COMMAND_GROUPS

    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        import czmpc_contracts
    finally:
        sys.path.remove(str(DOCS / "_ext"))
    cells = re.findall(r"   \* - (.*)\n     - ``(czmpc [\w-]+)``", czmpc_contracts.commands_rst())
    expected = [(title.split(":")[0], f"czmpc {name}")
                for title, names in COMMAND_GROUPS.items() for name in names]
    assert cells == expected


def test_a_description_keeps_prose_as_prose_and_indented_lines_as_they_are() -> None:
    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        import czmpc_cli
    finally:
        sys.path.remove(str(DOCS / "_ext"))
    text = ("Run it.\n\nWith --policy, the server\nadmits only:\n  - trusted clients;\n"
            "  - known users.\n\nExample:\n  czmpc run x.toml\n")
    found = [(type(node).__name__, node.astext()) for node in czmpc_cli.description_nodes(text)]
    assert found == [
        ("paragraph", "Run it."),
        ("paragraph", "With --policy, the server admits only:"),
        ("literal_block", "  - trusted clients;\n  - known users."),
        ("paragraph", "Example:"),
        ("literal_block", "  czmpc run x.toml"),
    ]
