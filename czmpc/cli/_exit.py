"""Exit codes of the ``czmpc`` command and which errors mean bad input.

The documentation's exit-code reference is generated from this module, so what is
documented is what `czmpc.cli.main` returns.
"""

from __future__ import annotations

from enum import IntEnum

from czmpc.errors import CzmpcError
from sim.errors import SimError
from sysid.errors import SysidError


class ExitCode(IntEnum):
    """Process exit codes of ``czmpc``."""

    OK = 0
    RUN_FAILED = 1
    BAD_INPUT = 2
    INTERRUPTED = 130
    #: 128 + SIGTERM (15): what a shell reports for a process the signal killed.
    TERMINATED = 143


#: What each exit code means, for ``--help`` texts and the documentation.
MEANING: dict[ExitCode, str] = {
    ExitCode.OK: "success: every output was written",
    ExitCode.RUN_FAILED: (
        "a run that failed: an identification that did not converge (the files are still "
        "written; ``--allow-unconverged`` accepts it), a log that cannot support a model "
        "(``czmpc identify`` writes nothing; ``--accept-unidentifiable`` overrides), a "
        "constraint violated in a campaign"
    ),
    ExitCode.BAD_INPUT: (
        "bad input: a file that cannot be read or breaks its contract, an invalid option, "
        "a model or settings the controller refuses; the message names the file, line and "
        "column or the option"
    ),
    ExitCode.INTERRUPTED: "interrupted by the user (Ctrl-C)",
    ExitCode.TERMINATED: (
        "terminated by SIGTERM; partial outputs removed as on Ctrl-C"
    ),
}

#: Errors that `czmpc.cli.main` reports as ``czmpc: error: <message>`` with
#: `ExitCode.BAD_INPUT` (a traceback only with ``--debug``); their subclasses too.
BAD_INPUT_ERRORS: tuple[type[Exception], ...] = (SysidError, SimError, CzmpcError, OSError)

__all__ = ["BAD_INPUT_ERRORS", "MEANING", "ExitCode"]
