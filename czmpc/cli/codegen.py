"""Generate the controller step as self-contained C99 for a PLC or a real-time task.

Writes into DIR the whole step of the offset-free MPC that 'czmpc simulate' runs for
this model and these settings (setpoint shaping and preview, limit ramp, measured
voltage, measurement checks, Kalman estimator, target, QP, fallbacks, rate-limit guard,
inversion, modes and statuses), with the QP solved by OSQP's own generated code:

  czmpc_step.h     the API: one state struct, czmpc_init, czmpc_step (units and
                   statuses documented), czmpc_reset, czmpc_request_mode,
                   czmpc_set_triac_limits
  czmpc_step.c     the step (no heap, libm only, bounded loops)
  czmpc_model.h    this controller's constants and matrices (exact hexadecimal numbers)
  czmpc_example.c  a program to try the step: reads 'power_kw,setpoint_kw' lines on
                   stdin ('nan' for a missing sample), writes one line per step whose
                   first field is the TRIAC input [%]
  Makefile         'make -C DIR' builds the objects (*.o, in DIR), libczmpc.a and
                   DIR/example; 'make -C DIR libczmpc.so' a shared library
  osqp/            OSQP's generated solver of this controller's QP, or with
  daqp/            solver = "daqp" in the settings: DAQP's C sources and licence, from
                   the installed daqp version's source distribution (fetched from PyPI
                   once and cached; --daqp-sdist for a machine without PyPI)

Try it:

  czmpc codegen data/cz_heater_model.json --out step
  make -C step
  printf '45.0,46.0\\n45.2,46.0\\nnan,46.0\\n' | step/example

The C equals the Python controller step by step (TRIAC input within 1e-6 %, the same
mode, status, fallback and solver iterations; tests/codegen). Without --settings the
controller's defaults for the model, as OffsetFreeMPC(model). --float32 computes in
single precision (smaller, not equal to Python: check the deviation on your cases).

Exit codes: 0 written; 2 bad input (model or settings file, settings the generated code
cannot reproduce: OSQP polishing or a solver time limit).
"""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "codegen"
HELP = "write the MPC step as C99 (with OSQP's generated solver) and a Makefile, for a PLC"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    from czmpc.cli import _argtypes

    parser.add_argument("model", metavar="MODEL.json", type=Path,
                        help="identified model file (format czmpc-model/1)")
    _argtypes.add_settings_options(parser)
    parser.add_argument("--out", metavar="DIR", type=Path, required=True,
                        help="output directory (created; the generated files in it are replaced)")
    parser.add_argument("--daqp-sdist", metavar="daqp-VERSION.tar.gz", type=Path, default=None,
                        help="with solver = \"daqp\" in the settings: DAQP's source distribution "
                             "for the installed daqp version, for a machine without PyPI "
                             "(default: the cache, else downloaded from PyPI; get it elsewhere "
                             "with 'pip download daqp==VERSION --no-binary :all: --no-deps')")
    parser.add_argument("--float32", action="store_true",
                        help="compute in float instead of double (the step and OSQP); results "
                             "then differ from the Python controller's")


def run(args: argparse.Namespace) -> int:
    """Generate the step; print where it went and how to build it."""
    from czmpc.cli import _argtypes
    from czmpc.cli._progress import Progress, print_written
    from czmpc.codegen.generate import generate_step
    from sysid.modelfile import load_model

    progress = Progress()
    progress(f"reading {args.model}")
    model = load_model(args.model)
    settings = _argtypes.settings_for(args, model)
    source = (str(args.settings) if args.settings is not None
              else f"preset '{args.preset}' for the model")
    step = generate_step(model, settings, args.out, float32=args.float32,
                         model_source=str(args.model), settings_source=source,
                         progress=progress, daqp_sdist=args.daqp_sdist)
    print_written([step.directory / name for name in step.files])
    print(f"build: make -C {step.directory}   (then: printf '45,46\\n' | {step.directory}/example)")
    return 0
