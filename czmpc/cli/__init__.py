"""Console script ``czmpc``: wires sysid, sim and czmpc together; maps errors to exit codes.

Exit codes: 0 success, 1 a run that failed (for example an identification that did
not converge, or a benchmark goal missed when asked to be strict), 2 bad input (files,
options). Errors print ``czmpc: error: <message>`` without a traceback unless
``--debug`` is given.
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
import sys
from collections.abc import Sequence
from types import ModuleType

from czmpc.cli._exit import BAD_INPUT_ERRORS, ExitCode
from sysid._version import __version__


class _Parser(argparse.ArgumentParser):
    """argparse parser whose usage errors exit with code 2 and one clear line."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(2, f"czmpc: error: {message}\n")


def _command_modules() -> list[ModuleType]:
    names = sorted(m.name for m in pkgutil.iter_modules(__path__)
                   if not m.name.startswith("_"))   # _argtypes etc. are helpers
    modules = [importlib.import_module(f"czmpc.cli.{name}") for name in names]
    return sorted(modules, key=lambda m: (getattr(m, "ORDER", 50), m.NAME))


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser, one sub-parser per module in `czmpc.cli`."""
    parser = _Parser(
        prog="czmpc",
        description=(
            "Identify a Hammerstein model of a CZ puller's heater power from logged data "
            "and control that power with an offset-free MPC."
        ),
        epilog="Run 'czmpc COMMAND --help' for the options of one command.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}",
                        help="print the version of czmpc and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for module in _command_modules():
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.__doc__)
        module.register(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the console script; return the process exit code."""
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
