"""Generated C of the whole controller step, proven equal to the Python controller (issue 42).

Layer 2, beside `czmpc.peers`: it reads the composed controller's stages and data; no
core module imports it.

Generate, build, use::

    czmpc codegen model.json --settings settings.toml --out step/   # C99 + OSQP's solver
    make -C step/                     # *.o, libczmpc.a and step/example
    cmake -S step/ -B step/build && cmake --build step/build   # the same, with CMake
    printf '45.0,46.0\\nnan,46.0\\n' | step/example   # triac_pct,mode,status,... per line

From Python (builds ``libczmpc.so`` on demand with the system's C compiler)::

    from czmpc.codegen import load_controller
    c = load_controller("step/")
    triac_pct = c.step(power_kw=45.0, setpoint_kw=46.0)
    c.last.status, c.last.n_iterations

- `czmpc.codegen.generate`: the templates (``templates/*.c, *.h, *.in``, C as C) filled
  with the controller's numbers, and OSQP's generated solver from the controller's own
  OSQP problem (``parameters='matrices'``);
- `czmpc.codegen.build`: ``make`` with the system compiler (``-ffp-contract=off``);
- `czmpc.codegen.loader`: the compiled step behind ctypes, a `sim.protocols.Controller`.
- `czmpc.codegen.daqp_source`: DAQP's C sources for ``solver = "daqp"`` (sdist, cache).

What is in the C: every stage of `czmpc.controller.OffsetFreeMPC.step` (setpoint shaper
with preview, limit ramp, measured voltage, measurement checks, estimator with roll-back
and level change, target, reference cost, QP vectors, OSQP, fallbacks, guard, inversion,
modes, statuses), `reset`, `request_mode` and `set_triac_limits`. Not in C: the mismatch
monitor (`czmpc.mismatch`, diagnostics only: it changes no output) and the log of mode
transitions. OSQP polishing and solver time limits are refused (OSQP's embedded code
has neither). With ``solver = "daqp"`` the QP is solved by DAQP's C instead
(`czmpc.codegen.daqp_source`: the installed version's sdist, cached; set up at init in a
static arena, ``templates/czmpc_daqp_heap.c``), in double precision only.

Equal, measured (tests/codegen). In double precision, with OSQP, the C step is bit-equal
to the Python controller: every step of the golden suite's 28 MPC cases (7,440 steps, and 7,440
more with a 60 s preview and a measured voltage), of the fault classes and of the fuzz
set (20,000 steps in CI; 1e6 with ``python -m tests.codegen.fuzz``). Two things make it
so: the C sets OSQP up again at init from the exact problem (OSQP's generator prints its
workspace as ``"%.20f"``, which drops digits below 1e-4: ``generate.osqp_values``), and
the Python controller sums its matrix-vector products in the C's order
(`czmpc.ordered`; BLAS's order depends on the CPU). Before both, 5 of 8 fuzzed
controllers drifted from their C step within 25 to 376 samples.

``--float32`` (float step and float OSQP against the double Python controller), measured
on the same 2 x 7,440 golden steps: TRIAC within 0.0034 % (0.0025 % with preview and
voltage); mode, fallback, solver status and measurement checks equal at every step;
iteration counts differ on 886 (626) steps; the status differs on 23 (91) steps, always
GOOD against CLAMPED and only where the plan's first move lies within 1.5e-4
kW-equivalent of its bound: the CLAMPED test's tolerance (`czmpc.controller.CLAMP_TOL`,
1e-6) is finer than float's resolution there (an ulp of 40 is 3.8e-6) and than OSQP's.

With DAQP (tests/codegen/test_codegen_daqp.py): the same modes, statuses, fallbacks and
iteration counts at every step of the golden suite's 7,440 MPC steps, of 2,000
fault-stream steps and of 20,000 fuzzed steps (8 random controllers), the TRIAC input
within 1.2e-13 % (golden) and 2.5e-11 % (fuzz); bit-equal on 20 to 45 % of the steps
only, because the ``daqp`` wheel's C is compiled with ``-O3 -fassociative-math``
(reordered sums), the step's with ``-ffp-contract=off`` and no reassociation.
"""

from __future__ import annotations

from czmpc.codegen.build import build
from czmpc.codegen.errors import BuildError, CodegenError
from czmpc.codegen.generate import GeneratedStep, generate_step
from czmpc.codegen.loader import CController, StepRecord, load_controller

__all__ = ["BuildError", "CController", "CodegenError", "GeneratedStep", "StepRecord", "build",
           "generate_step", "load_controller"]
