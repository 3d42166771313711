"""Build a generated step directory with the system's C compiler and ``make``.

The directory's own Makefile does the work (`czmpc.codegen.generate`); this module finds
the tools, runs it, and turns a failure into a `BuildError` that says what to install or
what the compiler said.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Mapping, Sequence
from pathlib import Path

from czmpc.codegen.errors import BuildError

#: Targets of the generated Makefile.
SHARED_LIBRARY = "libczmpc.so"
STATIC_LIBRARY = "libczmpc.a"
EXAMPLE = "example"
#: Lines of compiler output a `BuildError` quotes at most.
MAX_ERROR_LINES = 30


def find_tools(env: Mapping[str, str] | None = None) -> tuple[str, str]:
    """``(make, cc)`` as found on ``PATH`` (``CC`` from the environment if set).

    Raises
    ------
    BuildError
        If ``make`` or the C compiler is missing, with what to install.
    """
    env = os.environ if env is None else env
    make = shutil.which("make")
    cc_name = env.get("CC", "cc")
    cc = shutil.which(cc_name.split()[0]) if cc_name.strip() else None
    missing = [what for what, found in (("make", make), (f"a C compiler ({cc_name!r})", cc))
               if found is None]
    if missing or make is None or cc is None:
        raise BuildError(
            f"building the generated C step needs {' and '.join(missing)} on PATH; none found. "
            "Install a C99 compiler and make (Debian/Ubuntu: apt-get install build-essential; "
            "Fedora: dnf install gcc make), or set CC to your compiler")
    return make, cc


def build(directory: Path, targets: Sequence[str] = (SHARED_LIBRARY,), *,
          cflags: str | None = None, ldflags: str | None = None,
          warnings: str | None = None, jobs: int = 2) -> None:
    """Run ``make -C directory TARGETS``.

    Parameters
    ----------
    directory :
        A directory written by `czmpc.codegen.generate.generate_step`.
    targets :
        Makefile targets (`SHARED_LIBRARY`, `STATIC_LIBRARY`, `EXAMPLE`, ``all``).
    cflags, ldflags :
        ``CFLAGS`` and ``LDFLAGS`` for make (None: the Makefile's, ``-O2``).
    warnings :
        ``WARNINGS`` for the step's own files (e.g. ``-Wall -Wextra -Werror``).
    jobs :
        Parallel jobs.

    Raises
    ------
    BuildError
        Missing tools, a directory without a Makefile, or a failed build (with the
        compiler's messages).
    """
    directory = Path(directory)
    if not (directory / "Makefile").is_file():
        raise BuildError(f"{directory}: expected a directory written by 'czmpc codegen' "
                         f"(with a Makefile); got none")
    make, _ = find_tools()
    cmd = [make, "-C", str(directory), f"-j{jobs}", *targets]
    for name, value in (("CFLAGS", cflags), ("LDFLAGS", ldflags), ("WARNINGS", warnings)):
        if value is not None:
            cmd.append(f"{name}={value}")
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        lines = (done.stderr or done.stdout).strip().splitlines()[-MAX_ERROR_LINES:]
        raise BuildError(f"{directory}: 'make {' '.join(targets)}' failed (exit "
                         f"{done.returncode}):\n" + "\n".join(lines))


def build_or_use_built(directory: Path, target: str) -> None:
    """`build` ``target`` in ``directory``, or, without the tools, use it as built.

    A plant's controller host may have no compiler: the directory is then built where
    one is (``make -C DIR TARGET``) and copied there whole. Without ``make`` or the
    compiler, a ``target`` that exists and is newer than every C source, header and
    Makefile under ``directory`` (make's own rule) is used as it is.

    Raises
    ------
    BuildError
        As `build`; without the tools, when ``target`` is missing or older than a source
        (the file named), with where to build it.
    """
    directory = Path(directory)
    try:
        find_tools()
    except BuildError as missing:
        built = directory / target
        if not built.is_file():
            raise BuildError(f"{missing}; or build {built} where they are ('make -C {directory} "
                             f"{target}') and copy the directory here") from None
        newer = _newer_sources(built)
        if newer:
            more = f" and {len(newer) - 1} more file(s)" if len(newer) > 1 else ""
            raise BuildError(f"{built} is older than {newer[0]}{more}, and this machine cannot "
                             f"rebuild it: {missing}; or rebuild it where they are ('make -C "
                             f"{directory} {target}') and copy the directory here") from None
        return
    build(directory, (target,))


def _newer_sources(built: Path) -> list[Path]:
    """The C sources, headers and Makefile under ``built``'s folder modified after it."""
    when = built.stat().st_mtime
    return [p for p in sorted(built.parent.rglob("*"))
            if (p.suffix in (".c", ".h") or p.name == "Makefile") and p.stat().st_mtime > when]


__all__ = ["EXAMPLE", "SHARED_LIBRARY", "STATIC_LIBRARY", "build", "build_or_use_built",
           "find_tools"]
