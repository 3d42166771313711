"""Console script ``czmpc``: wires sysid, sim and czmpc together; maps errors to exit codes.

Exit codes: 0 success, 1 a run that failed (for example an identification that did
not converge), 2 bad input (files, options). Errors print ``czmpc: error: <message>``
without a traceback unless ``--debug`` is given.
"""

from __future__ import annotations

import os

# The numerics here are small (12,000-sample filters, 100x100 QPs): BLAS threads only
# contend on a busy machine (fits ran 5-10x slower with them). A user's own setting wins.
# This must run before numpy is first imported.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import importlib
import pkgutil
import shutil
import signal
import sys
import textwrap
import threading
from collections.abc import Generator, Sequence
from types import FrameType, ModuleType

from czmpc.cli._exit import BAD_INPUT_ERRORS, ExitCode
from sysid._version import __version__


class _Parser(argparse.ArgumentParser):
    """argparse parser whose usage errors exit with code 2 and one clear line."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(2, f"czmpc: error: {message}\n")


class _GroupedHelpFormatter(argparse.RawDescriptionHelpFormatter):
    """``czmpc --help``: no flat list of commands under COMMAND; the epilog groups them."""

    def _iter_indented_subactions(
            self, action: argparse.Action) -> Generator[argparse.Action, None, None]:
        yield from ()


#: The commands by task, in the order ``czmpc --help`` lists them. Every command module
#: of `czmpc.cli` belongs to exactly one group (a test holds them equal).
COMMAND_GROUPS: dict[str, tuple[str, ...]] = {
    "start here": ("demo",),
    "identify: from a logged data set to a checked model": (
        "inspect", "design-test", "experiment", "identify", "show-model", "check-model"),
    "control: tune, simulate and test the controller": (
        "simulate", "settings", "tune-pid", "regress", "campaign", "codegen"),
    "plant: commission and run the MPC on a live plant": (
        "commission", "run", "run-report", "plant", "pki"),
}
#: Heading of the commands no group names (none, when the map is complete).
UNGROUPED = "other"


def _command_modules() -> dict[str, ModuleType]:
    """Every command module of `czmpc.cli` by command name (helpers start with ``_``)."""
    names = sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))
    modules = (importlib.import_module(f"czmpc.cli.{name}") for name in names)
    return {m.NAME: m for m in modules}


def command_groups(commands: Sequence[str]) -> dict[str, tuple[str, ...]]:
    """``commands`` by group, in `COMMAND_GROUPS` order; those no group names under `UNGROUPED`."""
    grouped = {title: tuple(c for c in names if c in commands)
               for title, names in COMMAND_GROUPS.items()}
    listed = {c for names in COMMAND_GROUPS.values() for c in names}
    rest = tuple(sorted(c for c in commands if c not in listed))
    return {title: names for title, names in {**grouped, UNGROUPED: rest}.items() if names}


def _grouped_listing(helps: dict[str, str]) -> str:
    """The commands of ``czmpc --help``: a block per group, one line (wrapped) per command."""
    width = max(shutil.get_terminal_size().columns - 2, 60)
    name_width = max(map(len, helps)) + 2
    lines = ["commands, by task:"]
    for title, names in command_groups(list(helps)).items():
        lines.append(f"  {title}")
        for name in names:
            lines.append(textwrap.fill(helps[name], width, initial_indent=f"    {name:<{name_width}}",
                                       subsequent_indent=" " * (4 + name_width)))
    return "\n".join(lines)


def _accept_debug(parser: argparse.ArgumentParser) -> None:
    """Let ``--debug`` follow a command and its actions (``czmpc plant history ... --debug``).

    Its default is SUPPRESS: absent after the command, it leaves the value given before it.
    """
    parser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show tracebacks on errors")
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):   # aliases share a parser
                _accept_debug(sub)


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser, one sub-parser per module in `czmpc.cli`.

    ``czmpc --help`` lists the commands by task (`COMMAND_GROUPS`); ``--debug`` is
    accepted before and after the command.
    """
    parser = _Parser(
        prog="czmpc",
        description=(
            "Identify a Hammerstein model of a CZ puller's heater power from logged data\n"
            "and control that power with an offset-free MPC."
        ),
        formatter_class=_GroupedHelpFormatter,
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}",
                        help="print the version of czmpc and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser,
                                help="one of the commands below")
    modules = _command_modules()
    order = [c for names in command_groups(list(modules)).values() for c in names]
    for name in order:
        module = modules[name]
        p = sub.add_parser(name, help=module.HELP, description=module.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.register(p)
        _accept_debug(p)
        p.set_defaults(_run=module.run)
    parser.epilog = (_grouped_listing({name: modules[name].HELP for name in order})
                     + "\n\nRun 'czmpc COMMAND --help' for the options of one command.")
    return parser


class Terminated(SystemExit):
    """Raised in the main thread by the console script's SIGTERM handler.

    Python's default SIGTERM action kills the process at once, so no ``finally`` or
    ``except BaseException`` runs and `sysid.atomic` would leave its hidden temporary
    file. Raising an exception instead unwinds the stack through the same cleanup
    paths as Ctrl-C (``KeyboardInterrupt``). It derives from ``SystemExit`` (not from
    ``Exception``), so no ``except Exception`` in the library swallows it.
    """


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    raise Terminated(ExitCode.TERMINATED)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the console script; return the process exit code.

    While it runs, SIGTERM raises `Terminated` (when called from the main thread), so
    partial outputs are cleaned up as on Ctrl-C; the exit code is then 143.
    """
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_terminated) if in_main_thread else None
    try:
        return _main(argv)
    finally:
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous)


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return ExitCode.BAD_INPUT
    try:
        return int(args._run(args))
    except BAD_INPUT_ERRORS as exc:
        if args.debug:
            raise
        print(f"czmpc: error: {exc}", file=sys.stderr)
        return ExitCode.BAD_INPUT
    except KeyboardInterrupt:
        print("czmpc: interrupted", file=sys.stderr)
        return ExitCode.INTERRUPTED
    except Terminated:
        print("czmpc: terminated (SIGTERM)", file=sys.stderr)
        return ExitCode.TERMINATED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
