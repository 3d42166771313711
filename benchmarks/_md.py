"""BENCHMARKS.md plumbing shared by every benchmark: the machine, one section each, the entry.

Each benchmark owns one ``## `` section of BENCHMARKS.md and rewrites only that one,
so benchmarks run at different times keep each other's numbers. Each runs as
``python -m benchmarks.<name>``; `run_main` gives them one way to report bad input.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import shlex
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from czmpc.cli._exit import BAD_INPUT_ERRORS, ExitCode
from sysid.atomic import atomic_write_text

#: BENCHMARKS.md of this repository (benchmarks/ is not installed: it lives beside it).
BENCHMARKS_MD = Path(__file__).resolve().parents[1] / "BENCHMARKS.md"

#: Libraries whose versions every benchmark records; optional ones only if installed.
CORE_LIBRARIES = ("numpy", "scipy", "osqp", "casadi", "matplotlib")
OPTIONAL_LIBRARIES = ("sippy-unipi",)


@dataclass(frozen=True, kw_only=True)
class MachineInfo:
    """The machine a benchmark ran on.

    Parameters
    ----------
    n_cpus :
        Logical cores available to this process (what ``nproc`` prints).
    cpu_model :
        ``model name`` from /proc/cpuinfo, or the platform's processor string.
    python :
        Python version.
    libraries :
        ``(name, version)`` of `CORE_LIBRARIES` and the installed `OPTIONAL_LIBRARIES`.
    load_average :
        1-minute load average when the benchmark started (other work on a shared
        machine slows the numbers), or None where the platform has none.
    """

    n_cpus: int
    cpu_model: str
    python: str
    libraries: tuple[tuple[str, str], ...]
    load_average: float | None = None

    def describe(self) -> str:
        """One line: cores, CPU, Python and library versions, load."""
        libs = ", ".join(f"{name} {version}" for name, version in self.libraries)
        load = "" if self.load_average is None else f"; load average {self.load_average:.2f} at start"
        return f"{self.n_cpus} cores ({self.cpu_model}); Python {self.python}; {libs}{load}"


def machine_info() -> MachineInfo:
    """Describe this machine (cores, CPU model, Python and library versions, load)."""
    from importlib import metadata

    cpu_model = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                cpu_model = line.split(":", 1)[1].strip()
                break
    try:
        n_cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        n_cpus = os.cpu_count() or 1
    libraries = []
    for name in CORE_LIBRARIES + OPTIONAL_LIBRARIES:
        try:
            libraries.append((name, metadata.version(name)))
        except metadata.PackageNotFoundError:
            if name not in OPTIONAL_LIBRARIES:
                libraries.append((name, "not installed"))
    try:
        load: float | None = os.getloadavg()[0]
    except (AttributeError, OSError):  # pragma: no cover - not Unix
        load = None
    return MachineInfo(n_cpus=n_cpus, cpu_model=cpu_model, python=platform.python_version(),
                       libraries=tuple(libraries), load_average=load)


def write_benchmarks_section(path: str | os.PathLike[str], body: str, *, heading: str) -> None:
    """Put ``body`` under ``heading`` in a BENCHMARKS.md, keeping every other section.

    The section runs from its heading to the next ``## `` heading (or the end of the
    file); its body is replaced. A missing file is created with a title, a missing
    section is appended. Written atomically (`sysid.atomic`).

    Parameters
    ----------
    path :
        The Markdown file.
    body :
        The section's text (without the heading).
    heading :
        The section's ``## `` heading line.
    """
    path = Path(path)
    text = path.read_text(encoding="utf-8") if path.exists() else "# Benchmarks\n"
    section = f"{heading}\n\n{body.rstrip()}\n"
    lines = text.splitlines(keepends=True)
    start = next((i for i, ln in enumerate(lines) if ln.rstrip() == heading), None)
    if start is None:
        new = text.rstrip("\n") + "\n\n" + section
    else:
        stop = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")),
                    len(lines))
        tail = "".join(lines[stop:])
        new = "".join(lines[:start]) + section + ("\n" + tail if tail else "")
    atomic_write_text(path, new)


def benchmark_parser(module: str, doc: str | None) -> argparse.ArgumentParser:
    """The parser of ``python -m benchmarks.<module>``, its module docstring as the help."""
    return argparse.ArgumentParser(prog=f"python -m benchmarks.{module}", description=doc,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def add_campaign_run_options(parser: argparse.ArgumentParser, *, out_note: str = "") -> None:
    """``--out``, ``--executor``, ``--workers``, ``--benchmarks-md``, ``--no-record``: the
    options of a benchmark that runs a shipped campaign spec and records its section."""
    parser.add_argument("--out", metavar="DIR", type=Path, default=None,
                        help="campaign directory (default: a temporary one; runs already in "
                             "it are resumed, not run again)" + out_note)
    parser.add_argument("--executor", choices=("serial", "processes"), default="serial",
                        help="where runs execute (default: serial)")
    parser.add_argument("--workers", metavar="N", type=int, default=2,
                        help="worker processes of 'processes' (default: 2)")
    parser.add_argument("--benchmarks-md", metavar="FILE", type=Path, default=BENCHMARKS_MD,
                        help="Markdown file of the section (default: BENCHMARKS.md of this "
                             "repository)")
    parser.add_argument("--no-record", action="store_true", help="only print the section")


def run_main(parser: argparse.ArgumentParser, run: Callable[[argparse.Namespace], int],
             argv: Sequence[str] | None) -> int:
    """Parse ``argv``, call ``run``; bad input prints ``<prog>: error: ...`` and returns 2.

    ``run`` finds the shell line that reruns it (``<prog> <argv>``, recorded with the
    numbers) in ``args.command_line``.

    Parameters
    ----------
    parser :
        The benchmark's parser, ``prog`` set to ``python -m benchmarks.<name>`` (usage
        errors exit 2, as argparse does).
    run :
        The benchmark; returns its exit code.
    argv :
        Arguments without the program name; None reads ``sys.argv``.
    """
    words = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(words)
    args.command_line = " ".join([parser.prog, *(shlex.quote(w) for w in words)])
    try:
        return int(run(args))
    except BAD_INPUT_ERRORS as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return int(ExitCode.BAD_INPUT)


__all__ = ["BENCHMARKS_MD", "CORE_LIBRARIES", "OPTIONAL_LIBRARIES", "MachineInfo",
           "add_campaign_run_options", "benchmark_parser", "machine_info", "run_main",
           "write_benchmarks_section"]
