"""Sphinx directive that writes the command-line reference from the console script's parser.

``.. czmpc-cli::`` calls `czmpc.cli.build_parser` at build time and renders what
``czmpc --help`` prints, then a section per group of commands (`czmpc.cli.command_groups`,
as ``czmpc --help`` groups them) and in it one per command (and per sub-command, such as
``czmpc plant serve``): its one-line help, usage, description and every option with its
help text. Nothing is written by hand, so a command added, removed or regrouped in
``czmpc/cli`` shows on the next build; ``tests/docs/test_cli_reference.py`` checks that
every command and every option of the parser appears.

Descriptions are module docstrings written as plain text for a terminal; they are shown as
paragraphs (indented lines as literal blocks) with ````code```` and ```name``` as inline
literals, never parsed as reStructuredText, so a docstring cannot break the build.
"""

from __future__ import annotations

import argparse
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager

from docutils import nodes
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

#: Width of the rendered ``--help`` texts (a terminal's, and what fits a page).
HELP_COLUMNS = 88

_INLINE = re.compile(r"``(.+?)``|`([^`\n]+)`")


@contextmanager
def _columns(width: int) -> Iterator[None]:
    """argparse wraps help at ``$COLUMNS``; fix it for the build."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)
    try:
        yield
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


def _inline(text: str) -> list[nodes.Node]:
    """Text with ````x```` and ```x``` as inline literals, everything else as plain text."""
    out: list[nodes.Node] = []
    pos = 0
    for match in _INLINE.finditer(text):
        if match.start() > pos:
            out.append(nodes.Text(text[pos:match.start()]))
        code = match.group(1) or match.group(2)
        out.append(nodes.literal(code, code))
        pos = match.end()
    if pos < len(text):
        out.append(nodes.Text(text[pos:]))
    return out


def _paragraph(text: str) -> nodes.paragraph:
    # terminal text: ``--show`` stays two hyphens and 'x' keeps straight quotes
    para = nodes.paragraph(support_smartquotes=False)
    para.extend(_inline(text))
    return para


def description_nodes(text: str) -> list[nodes.Node]:
    """A docstring-like description as paragraphs; blocks with indented lines stay literal."""
    out: list[nodes.Node] = []
    for block in re.split(r"\n\s*\n", text.strip("\n")):
        lines = block.splitlines()
        if not lines:
            continue
        indent = min(len(line) - len(line.lstrip()) for line in lines if line.strip())
        lines = [line[indent:] for line in lines]
        indented = [i for i, line in enumerate(lines) if line.startswith((" ", "\t"))]
        if indented:
            # the prose before the first indented line stays prose; the rest keeps its layout
            first = indented[0] - 1 if lines[indented[0] - 1].lstrip().startswith("- ") else indented[0]
            if first > 0:
                out.append(_paragraph(" ".join(line.strip() for line in lines[:first])))
            body = "\n".join(lines[first:])
            out.append(nodes.literal_block(body, body))
        else:
            out.append(_paragraph(" ".join(line.strip() for line in lines)))
    return out


def _invocation(action: argparse.Action, formatter: argparse.HelpFormatter) -> str:
    # the same text argparse prints left of an option's help (``-o FILE, --out FILE``)
    return formatter._format_action_invocation(action)


def _option_list(parser: argparse.ArgumentParser) -> list[nodes.Node]:
    """One rubric per argument group, each option as a term with its expanded help."""
    formatter = parser._get_formatter()
    out: list[nodes.Node] = []
    for group in parser._action_groups:
        actions = [a for a in group._group_actions
                   if a.help is not argparse.SUPPRESS
                   and not isinstance(a, argparse._SubParsersAction)]
        if not actions:
            continue
        out.append(nodes.rubric(text=group.title or "arguments"))
        items = nodes.definition_list()
        for action in actions:
            term = nodes.term()
            term.append(nodes.literal(text=_invocation(action, formatter)))
            definition = nodes.definition()
            help_text = formatter._expand_help(action) if action.help else ""
            if help_text:
                definition.append(_paragraph(help_text))
            items.append(nodes.definition_list_item("", term, definition))
        out.append(items)
    return out


def subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """``(name, one-line help, parser)`` of each sub-command of ``parser``, in help order."""
    found: list[tuple[str, str, argparse.ArgumentParser]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help or "" for choice in action._choices_actions}
            for name, sub in action.choices.items():
                if name in helps:            # aliases have no help entry of their own
                    found.append((name, helps[name], sub))
    return found


class CliReference(SphinxDirective):
    """``.. czmpc-cli::``: the whole command-line reference, from `czmpc.cli.build_parser`."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        from czmpc.cli import build_parser, command_groups

        # the text comes from czmpc/cli, which Sphinx does not watch: re-read every build
        self.env.note_reread()
        with _columns(HELP_COLUMNS):
            parser = build_parser()
            top = parser.format_help()
            out: list[nodes.Node] = [
                _paragraph("``czmpc --help`` prints:"),
                nodes.literal_block(top, top),
            ]
            commands = {name: (help_line, sub) for name, help_line, sub in subcommands(parser)}
            for title, names in command_groups(list(commands)).items():
                group = nodes.section(ids=[nodes.make_id(f"cli group {title}")])
                group.append(nodes.title(text=title[0].upper() + title[1:]))
                for name in names:
                    group.append(self._section(f"czmpc {name}", *commands[name]))
                out.append(group)
        return out

    def _section(self, title: str, help_line: str, parser: argparse.ArgumentParser) -> nodes.section:
        section = nodes.section(ids=[nodes.make_id(f"cli {title}")])
        section.append(nodes.title(text=title))
        if help_line:
            section.append(_paragraph(help_line[0].upper() + help_line[1:] + "."))
        usage = parser.format_usage().strip()
        section.append(nodes.literal_block(usage, usage))
        if parser.description:
            section.extend(description_nodes(parser.description))
        section.extend(_option_list(parser))
        if parser.epilog:
            section.extend(description_nodes(parser.epilog))
        for name, sub_help, sub in subcommands(parser):
            section.append(self._section(f"{title} {name}", sub_help, sub))
        return section


def setup(app: Sphinx) -> dict[str, object]:
    app.add_directive("czmpc-cli", CliReference)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
