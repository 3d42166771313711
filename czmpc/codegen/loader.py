"""The compiled C step behind ctypes: a controller like `czmpc.controller.OffsetFreeMPC`.

`load_controller` builds ``libczmpc.so`` in a directory written by ``czmpc codegen``
(on demand, with the system's C compiler) and returns a `CController`: ``ts_s``,
``step(power_kw, setpoint_kw, *, applied_triac_pct, setpoint_preview_kw,
grid_voltage_factor) -> triac_pct`` and ``reset()``, so it satisfies
`sim.protocols.Controller`; `CController.last` holds the step's mode, status, fallback,
solver status and iteration count.

OSQP's generated workspace is a global of the library, so every `CController` loads a
private copy of ``libczmpc.so`` (a new file, opened and unlinked): controllers built from
one directory do not share a solver.
"""

from __future__ import annotations

import ctypes
import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np

from czmpc.codegen.build import SHARED_LIBRARY, build, build_or_use_built
from czmpc.codegen.errors import BuildError
from czmpc.errors import SettingsError
from sysid._typing import FloatArray

#: Characters of the C output's solver status text (CZMPC_STATUS_CHARS, its NUL included).
STATUS_CHARS = 64
MODES = ("off", "predict", "on")
STATUSES = ("good", "predicted", "clamped", "held", "shed")
FALLBACKS = ("none", "shifted_plan", "target")
VERDICTS = ("valid", "missing", "below_limit", "above_limit", "too_fast", "stuck", "spike")
SETPOINT_VERDICTS = ("valid", "not finite", "below power_min_kw", "beyond MAX_SETPOINT_KW",
                     "above power_max_kw")
VOLTAGE_VERDICTS = ("not measured", "valid", "implausible")
_OK, _ERR_RANGE, _ERR_NOT_READY, _ERR_UNKNOWN = 0, -1, -2, -3


_Real: TypeAlias = "type[ctypes._SimpleCData[Any]]"


def _structures(real: _Real) -> tuple[type[ctypes.Structure], type[ctypes.Structure]]:
    """ctypes mirrors of ``czmpc_inputs`` and ``czmpc_outputs`` (czmpc_step.h) for ``real``."""
    c_int, c_long = ctypes.c_int, ctypes.c_long

    class Inputs(ctypes.Structure):
        _fields_ = [("power_kw", real), ("setpoint_kw", real), ("applied_triac_pct", real),
                    ("grid_voltage_factor", real), ("setpoint_preview_kw", ctypes.POINTER(real)),
                    ("n_preview", c_int)]

    int_fields = ("mode", "status", "fallback", "measurement_used", "verdict",
                  "level_change_accepted", "setpoint_verdict", "voltage_verdict",
                  "solver_status_val", "n_iterations", "setpoint_reachable",
                  "samples_without_measurement", "bad_solves_in_row", "rolled_back_samples",
                  "preview_samples")
    real_fields = ("solver_outside_bounds_kw", "setpoint_kw", "setpoint_used_kw", "innovation_kw",
                   "innovation_std_kw", "disturbance_estimate", "disturbance_power_kw",
                   "target_w", "target_triac_pct", "target_power_kw", "slack_kw",
                   "advised_triac_pct", "applied_triac_pct", "triac_min_pct", "triac_max_pct",
                   "voltage_factor_used")

    fields: list[tuple[str, Any]] = [("k", c_long), ("triac_pct", real)]
    fields += [(n, c_int) for n in int_fields]
    fields += [("solver_status", ctypes.c_char * STATUS_CHARS)] + [(n, real) for n in real_fields]

    class Outputs(ctypes.Structure):
        _fields_ = fields

    return Inputs, Outputs


@dataclass(frozen=True, kw_only=True)
class StepRecord:
    """What one C step did (the fields of `czmpc.diagnostics.StepDiagnostics` the C has).

    Strings use the Python controller's values (`czmpc.modes.Mode`, `Status`, ...).
    """

    k: int
    triac_pct: float
    mode: str
    status: str
    fallback: str
    measurement_used: bool
    verdict: str
    level_change_accepted: bool
    setpoint_verdict: str
    voltage_verdict: str
    solver_status: str
    solver_status_val: int
    n_iterations: int
    setpoint_reachable: bool
    samples_without_measurement: int
    bad_solves_in_row: int
    rolled_back_samples: int
    preview_samples: int
    setpoint_used_kw: float
    innovation_kw: float
    innovation_std_kw: float
    disturbance_estimate: float
    disturbance_power_kw: float
    target_w: float
    target_triac_pct: float
    target_power_kw: float
    soft_limit_slack_kw: float
    advised_triac_pct: float
    applied_triac_pct: float
    triac_limits_pct: tuple[float, float]
    voltage_factor_used: float


class CController:
    """The generated step of one directory, loaded with ctypes (module notes).

    Parameters
    ----------
    library :
        Path of a built ``libczmpc.so``.
    initial_triac_pct :
        The input the plant holds now [%] (bumpless start); None: the settings'.

    Attributes
    ----------
    ts_s :
        Sampling time [s].
    horizon_steps :
        ``N``.
    float32 :
        True if the step computes in ``float``.
    last :
        The latest step's `StepRecord` (None before the first).

    Raises
    ------
    BuildError
        The library cannot be loaded or does not match this loader.
    SettingsError
        ``initial_triac_pct`` outside the allowed range.
    """

    def __init__(self, library: Path, *, initial_triac_pct: float | None = None) -> None:
        library = Path(library)
        fd, private = tempfile.mkstemp(prefix="czmpc_step_", suffix=".so")
        os.close(fd)
        try:
            shutil.copyfile(library, private)
            lib = ctypes.CDLL(private)
        except OSError as exc:
            raise BuildError(f"{library}: the generated step could not be loaded: {exc}") from exc
        finally:
            os.unlink(private)   # the mapping stays; nothing is left behind
        self._lib = lib
        lib.czmpc_sizeof_real.restype = ctypes.c_ulong
        size = lib.czmpc_sizeof_real()
        real: _Real = ctypes.c_double if size == 8 else ctypes.c_float
        self.float32 = size == 4
        self._real = real
        inputs_t, outputs_t = _structures(real)
        for name, struct in (("inputs", inputs_t), ("outputs", outputs_t)):
            fn = getattr(lib, f"czmpc_sizeof_{name}")
            fn.restype = ctypes.c_ulong
            if fn() != ctypes.sizeof(struct):
                raise BuildError(f"{library}: czmpc_{name} has {fn()} bytes, this loader expects "
                                 f"{ctypes.sizeof(struct)}: regenerate the directory with this czmpc")
        lib.czmpc_sizeof_state.restype = ctypes.c_ulong
        self._state = ctypes.create_string_buffer(int(lib.czmpc_sizeof_state()))
        lib.czmpc_sampling_time_s.restype = ctypes.c_double
        self.ts_s = float(lib.czmpc_sampling_time_s())
        self.horizon_steps = int(lib.czmpc_horizon_steps())
        self._inputs = inputs_t()
        self._outputs = outputs_t()
        self._preview = (real * self.horizon_steps)()
        step = lib.czmpc_step
        step.restype = real
        step.argtypes = [ctypes.c_void_p, ctypes.POINTER(inputs_t), ctypes.POINTER(outputs_t)]
        self._step = step
        lib.czmpc_init_at.argtypes = [ctypes.c_void_p, real]
        lib.czmpc_set_triac_limits.argtypes = [ctypes.c_void_p, real, real]
        lib.czmpc_planned_w.restype = ctypes.POINTER(real)
        for name in ("n_fallbacks", "n_inaccurate", "n_rejected_measurements", "n_shed_steps"):
            getattr(lib, f"czmpc_{name}").restype = ctypes.c_long
        code = (lib.czmpc_init(self._state) if initial_triac_pct is None
                else lib.czmpc_init_at(self._state, float(initial_triac_pct)))
        if code == _ERR_RANGE:
            raise SettingsError(f"CController: initial_triac_pct must lie in the allowed range of "
                                f"{library.parent}; got {initial_triac_pct!r}")
        if code != _OK:
            raise BuildError(f"{library}: the generated QP solver could not be set up (czmpc_init "
                             f"returned {code}: its KKT matrix was not factored)")
        self.last: StepRecord | None = None

    def reset(self) -> None:
        """Forget all state, as if newly loaded (the solver's step size is kept, as in Python)."""
        self._lib.czmpc_reset(self._state)
        self.last = None

    def step(self, power_kw: float | None, setpoint_kw: float | None, *,
             applied_triac_pct: float | None = None, setpoint_preview_kw: object = None,
             grid_voltage_factor: float | None = None) -> float:
        """Return the TRIAC input [%] to apply now (`czmpc.controller.OffsetFreeMPC.step`).

        Parameters
        ----------
        power_kw :
            Measured heater power [kW]; None or NaN: missing.
        setpoint_kw :
            Power setpoint [kW]; None or non-finite: the last valid one is held.
        applied_triac_pct :
            The input applied over the last sample [%] if it differs; None: as returned.
        setpoint_preview_kw :
            Setpoints of samples ``k+1, ...`` [kW] (any 1-d sequence), or None.
        grid_voltage_factor :
            Grid voltage / nominal [-] measured over the last sample; None: not measured.
        """
        nan = math.nan
        inp = self._inputs
        inp.power_kw = nan if power_kw is None else float(power_kw)
        inp.setpoint_kw = nan if setpoint_kw is None else float(setpoint_kw)
        inp.applied_triac_pct = nan if applied_triac_pct is None else float(applied_triac_pct)
        inp.grid_voltage_factor = _voltage(grid_voltage_factor)
        inp.n_preview = 0
        inp.setpoint_preview_kw = None
        if setpoint_preview_kw is not None:
            try:
                raw = np.asarray(setpoint_preview_kw, dtype=float).ravel()[: self.horizon_steps]
            except (TypeError, ValueError):
                raw = np.empty(0)
            if raw.size:
                buf = self._preview
                for i, v in enumerate(raw.tolist()):
                    buf[i] = v
                inp.n_preview = raw.size
                inp.setpoint_preview_kw = ctypes.cast(buf, ctypes.POINTER(self._real))
        out = self._outputs
        triac = float(self._step(self._state, ctypes.byref(inp), ctypes.byref(out)))
        self.last = _record(out)
        return triac

    def request_mode(self, mode: str) -> bool:
        """Ask for mode ``"off"``, ``"predict"`` or ``"on"`` (from the next step); True if
        it is the mode now, False if refused (``"on"`` before the estimator is warm).

        Raises
        ------
        SettingsError
            Not a mode.
        """
        if mode not in MODES:
            raise SettingsError(f"CController.request_mode: expected one of {list(MODES)}; got {mode!r}")
        return int(self._lib.czmpc_request_mode(self._state, MODES.index(mode))) == _OK

    def set_triac_limits(self, triac_min_pct: float, triac_max_pct: float) -> None:
        """Change the TRIAC limits at run time [%] (`OffsetFreeMPC.set_triac_limits`).

        Raises
        ------
        SettingsError
            Non-finite or inverted limits, or none of the allowed range left.
        """
        if self._lib.czmpc_set_triac_limits(self._state, float(triac_min_pct),
                                            float(triac_max_pct)) != _OK:
            raise SettingsError(f"CController.set_triac_limits: expected finite min < max [%] "
                                f"overlapping the allowed range; got ({triac_min_pct!r}, "
                                f"{triac_max_pct!r})")

    @property
    def planned_w(self) -> FloatArray:
        """(N,) the last step's plan [kW-equivalent] (a copy; NaN when unusable or skipped)."""
        ptr = self._lib.czmpc_planned_w(self._state)
        return np.array([ptr[i] for i in range(self.horizon_steps)], dtype=float)

    @property
    def n_fallbacks(self) -> int:
        """Steps since init/reset whose QP result was not used."""
        return int(self._lib.czmpc_n_fallbacks(self._state))

    @property
    def n_inaccurate(self) -> int:
        """Steps whose QP ended "solved inaccurate"."""
        return int(self._lib.czmpc_n_inaccurate(self._state))

    @property
    def n_rejected_measurements(self) -> int:
        """Samples (in PREDICT/ON) not fed to the estimator since init/reset."""
        return int(self._lib.czmpc_n_rejected_measurements(self._state))

    @property
    def n_shed_steps(self) -> int:
        """Steps reported SHED since init/reset."""
        return int(self._lib.czmpc_n_shed_steps(self._state))

    @property
    def last_step(self) -> StepRecord | None:
        """`last` under the Python controller's name, so that `sim.loop.run_closed_loop`
        records each step's mode, status and fallback as it does the MPC's."""
        return self.last


def _voltage(value: float | None) -> float:
    """The C input for a voltage reading: NaN for none; a value that is no number: inf
    (implausible, as `czmpc.voltage.voltage_verdict` says)."""
    if value is None:
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.inf


def _record(out: ctypes.Structure) -> StepRecord:
    status = out.solver_status.decode("ascii")
    if out.solver_outside_bounds_kw > 0.0:
        status = f"{status}; outside bounds by {out.solver_outside_bounds_kw:.3g} kW"
    return StepRecord(
        k=out.k, triac_pct=out.triac_pct, mode=MODES[out.mode], status=STATUSES[out.status],
        fallback=FALLBACKS[out.fallback], measurement_used=bool(out.measurement_used),
        verdict=VERDICTS[out.verdict], level_change_accepted=bool(out.level_change_accepted),
        setpoint_verdict=SETPOINT_VERDICTS[out.setpoint_verdict],
        voltage_verdict=VOLTAGE_VERDICTS[out.voltage_verdict], solver_status=status,
        solver_status_val=out.solver_status_val, n_iterations=out.n_iterations,
        setpoint_reachable=bool(out.setpoint_reachable),
        samples_without_measurement=out.samples_without_measurement,
        bad_solves_in_row=out.bad_solves_in_row, rolled_back_samples=out.rolled_back_samples,
        preview_samples=out.preview_samples, setpoint_used_kw=out.setpoint_used_kw,
        innovation_kw=out.innovation_kw, innovation_std_kw=out.innovation_std_kw,
        disturbance_estimate=out.disturbance_estimate,
        disturbance_power_kw=out.disturbance_power_kw, target_w=out.target_w,
        target_triac_pct=out.target_triac_pct, target_power_kw=out.target_power_kw,
        soft_limit_slack_kw=out.slack_kw, advised_triac_pct=out.advised_triac_pct,
        applied_triac_pct=out.applied_triac_pct,
        triac_limits_pct=(out.triac_min_pct, out.triac_max_pct),
        voltage_factor_used=out.voltage_factor_used)


def load_controller(directory: str | os.PathLike[str], *, initial_triac_pct: float | None = None,
                    cflags: str | None = None, ldflags: str | None = None) -> CController:
    """Build ``directory``'s ``libczmpc.so`` if needed (make) and load it.

    Without flags, on a machine without ``make`` or a C compiler (a plant's controller
    host), a library built in the directory elsewhere is used as it is, if it is current
    (`czmpc.codegen.build.build_or_use_built`).

    Parameters
    ----------
    directory :
        Written by ``czmpc codegen``.
    initial_triac_pct :
        The input the plant holds now [%]; None: the settings'.
    cflags, ldflags :
        ``CFLAGS`` / ``LDFLAGS`` for the build (None: the Makefile's).

    Raises
    ------
    BuildError
        No compiler or make and no current library, a failed build, or a library this
        loader cannot use.
    SettingsError
        ``initial_triac_pct`` outside the allowed range.
    """
    path = Path(directory)
    if cflags is None and ldflags is None:
        build_or_use_built(path, SHARED_LIBRARY)
    else:
        build(path, (SHARED_LIBRARY,), cflags=cflags, ldflags=ldflags)
    return CController(path / SHARED_LIBRARY, initial_triac_pct=initial_triac_pct)


__all__ = ["FALLBACKS", "MODES", "STATUSES", "VERDICTS", "CController", "StepRecord", "load_controller"]
