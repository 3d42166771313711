"""Write the C99 step of one controller: templates filled with the controller's own data.

The C lives in ``czmpc/codegen/templates`` as C (`TEMPLATES`); this module only fills in
numbers: the model's and settings' constants and the QP's matrices, read from an
`czmpc.controller.OffsetFreeMPC` built from the same model and settings, each written as
an exact hexadecimal literal. The QP solver is OSQP's own generated code, generated from
that controller's OSQP problem with ``parameters='matrices'`` (adaptive rho kept: with
``'vectors'`` 63 % of the plans differ, issue 42). With ``solver = "daqp"`` it is DAQP's C,
from the installed daqp version's sdist (`czmpc.codegen.daqp_source`), set up at init
from the exact ``H`` and rows of the controller's `czmpc.qp_daqp.DAQPMPCQP`
(`DAQP_TEMPLATES`).
"""

from __future__ import annotations

import math
import re
import shutil
import string
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import osqp
import scipy.sparse as sp

from czmpc.codegen.daqp_source import copy_daqp, daqp_version
from czmpc.codegen.errors import CodegenError
from czmpc.controller import OffsetFreeMPC
from czmpc.qp import MPCQP
from czmpc.settings import MPCSettings
from czmpc.settings_file import load_settings, settings_to_toml
from sysid._typing import FloatArray
from sysid._version import __version__
from sysid.model import HammersteinModel
from sysid.modelfile import load_model, save_model

#: Template files and the names they are written under (``.in``: filled in).
TEMPLATES: dict[str, str] = {
    "czmpc_step.h": "czmpc_step.h",
    "czmpc_step.c": "czmpc_step.c",
    "czmpc_example.c": "czmpc_example.c",
    "czmpc_model.h.in": "czmpc_model.h",
    "Makefile.in": "Makefile",
    "CMakeLists.txt.in": "CMakeLists.txt",
}
#: Templates of a step with ``solver = "daqp"``: the step's own and DAQP's build files,
#: the problem's data and the static arena DAQP's set-up takes its workspace from.
DAQP_TEMPLATES: dict[str, str] = {
    "czmpc_step.h": "czmpc_step.h",
    "czmpc_step.c": "czmpc_step.c",
    "czmpc_example.c": "czmpc_example.c",
    "czmpc_model.h.in": "czmpc_model.h",
    "czmpc_daqp.h.in": "czmpc_daqp.h",
    "czmpc_daqp_heap.h": "czmpc_daqp_heap.h",
    "czmpc_daqp_heap.c": "czmpc_daqp_heap.c",
    "Makefile.daqp.in": "Makefile",
    "CMakeLists.daqp.txt.in": "CMakeLists.txt",
}
#: Sub-directory of the output that holds DAQP's C sources and licence.
DAQP_DIR = "daqp"
#: The model and the effective settings the step was generated from, written beside it
#: (`read_sources`): a user sees what the C holds, and ``czmpc simulate --controller
#: c:DIR`` runs the Python controller of the same model and settings beside it.
MODEL_FILE = "model.json"
SETTINGS_FILE = "settings.toml"
#: Prefix of OSQP's generated globals (``czmpc_qp_solver``) and workspace files.
OSQP_PREFIX = "czmpc_qp_"
#: Sub-directory of the output that holds OSQP's generated code.
OSQP_DIR = "osqp"
#: Files of OSQP's code generator this project builds its own way (its Makefile calls
#: gcc, its example main is not ours).
_OSQP_UNUSED = ("Makefile", "emosqp.c")

_MODES = {"off": 0, "predict": 1, "on": 2}


@dataclass(frozen=True, kw_only=True)
class GeneratedStep:
    """What `generate_step` wrote.

    Parameters
    ----------
    directory :
        The output directory.
    horizon_steps :
        ``N`` of the controller.
    n_variables, n_constraints :
        Size of the QP.
    float32 :
        True if the step and OSQP use ``float``.
    files :
        What was written at the top of the directory, the solver's folder last
        (``osqp/``: OSQP's generated code; ``daqp/``: DAQP's sources).
    """

    directory: Path
    horizon_steps: int
    n_variables: int
    n_constraints: int
    float32: bool
    files: tuple[str, ...]


def c_number(value: float) -> str:
    """``value`` as an exact C99 hexadecimal literal in parentheses.

    Raises
    ------
    CodegenError
        If ``value`` is not finite (C has no literal for it).
    """
    v = float(value)
    if not math.isfinite(v):
        raise CodegenError(f"codegen: every constant must be finite; got {v!r}")
    return f"({v.hex()})"


def c_array(values: Iterable[float] | FloatArray) -> str:
    """A C initializer list body: 1-d arrays flat, 2-d arrays as rows in braces."""
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 2:
        return "\n    " + ",\n    ".join("{" + ", ".join(c_number(v) for v in row) + "}" for row in arr)
    return ", ".join(c_number(v) for v in arr.ravel())


def check_supported(settings: MPCSettings, *, float32: bool = False) -> None:
    """Refuse settings the generated step cannot reproduce.

    Raises
    ------
    CodegenError
        With OSQP: polishing or a solver time limit (neither exists in OSQP's embedded
        code). With DAQP: ``float32`` (DAQP's single precision is not generated). A QP
        solver other than OSQP and DAQP.
    """
    solver = getattr(settings, "solver", "osqp")
    if solver == "daqp":
        if float32:
            raise CodegenError("codegen: solver = 'daqp' is generated in double precision only; "
                               "got --float32 (use solver = 'osqp' for a float step)")
        return
    if solver != "osqp":
        raise CodegenError(f"codegen: solver must be 'osqp' or 'daqp'; got {solver!r}")
    if settings.osqp.polishing:
        raise CodegenError(
            "codegen: OSQPOptions.polishing must be false (OSQP's generated code has no "
            "polishing); got true: set [osqp] polishing = false in the settings file")
    if settings.osqp.time_limit_s is not None:
        raise CodegenError(
            "codegen: OSQPOptions.time_limit_s must be unset (OSQP's generated code has no "
            f"timer, and a time limit makes results depend on machine speed); got "
            f"{settings.osqp.time_limit_s!r}")


def _flag(value: object) -> str:
    return "1" if value else "0"


def _optional(value: float | None) -> tuple[str, str]:
    """``(HAS, value)`` macros of an optional number (0 when absent)."""
    return ("0", c_number(0.0)) if value is None else ("1", c_number(value))


def template_values(mpc: OffsetFreeMPC, *, model_source: str, settings_source: str,
                    float32: bool) -> dict[str, str]:
    """The values `TEMPLATES` are filled with, read from ``mpc`` (a fresh controller).

    Parameters
    ----------
    mpc :
        The Python controller the C must equal.
    model_source, settings_source :
        Where the model and settings came from (the header says it).
    float32 :
        ``float`` instead of ``double``.
    """
    s = mpc.settings
    rel = s.reliability
    qp = mpc.qp
    im = mpc.input_map
    est = mpc._est
    ssm = mpc._ssm
    aug = mpc.augmented_model
    n_x = aug.base.n_states
    n = qp.horizon_steps
    s_nom = im.operating_triac_pct
    p_nom = mpc.model.operating_point.power_kw
    abg = np.column_stack([aug.A, aug.B, est.gains.G])
    abg_c = np.vstack([abg, aug.C @ abg])
    has_min, power_min = _optional(rel.power_min_kw)
    has_max, power_max = _optional(rel.power_max_kw)
    has_change, max_change = _optional(rel.max_change_kw_per_sample)
    has_gate, k_sigma = _optional(rel.spike_gate_k_sigma)
    has_level, level_k = _optional(rel.level_change_k_sigma)
    has_ramp = rel.setpoint_ramp_kw_per_s is not None
    shaper = mpc._shaper
    lo_ok = -1e6 if rel.power_min_kw is None else max(rel.power_min_kw, -1e6)
    hi_ok = 1e6 if rel.power_max_kw is None else min(rel.power_max_kw, 1e6)
    values: dict[str, str] = {
        "MODEL_SOURCE": model_source,
        "SETTINGS_SOURCE": settings_source,
        "CZMPC_VERSION": __version__,
        "OSQP_VERSION": osqp.__version__,
        "REAL_TYPEDEF": ("typedef float czmpc_real;\n#define CZMPC_FLOAT32 1" if float32
                         else "typedef double czmpc_real;"),
        "REAL_FLAG": "-DCZMPC_FLOAT32" if float32 else "",
        "REAL_CMAKE": ("target_compile_definitions(czmpc PUBLIC CZMPC_FLOAT32)" if float32
                       else "# double precision: czmpc_real is double"),
        "SOLVER_DAQP": _flag(getattr(s, "solver", "osqp") == "daqp"),
        "HORIZON_STEPS": str(n),
        "N_STATES": str(n_x),
        "N_COEFFICIENTS": str(len(im.coefficients)),
        "N_CRITICAL_POINTS": str(len(im.slope_critical_points_pct)),
        "N_VARIABLES": str(qp.n_variables),
        "N_CONSTRAINTS": str(qp.n_constraints),
        "HISTORY_SAMPLES": str(4 * max(rel.stuck_samples, 1) + 1),
        "N_STD": str(len(est._std_kw)),
        "HAS_RATE_LIMIT": _flag(qp.has_rate_limit),
        "HAS_SOFT_MIN": _flag(qp.has_soft_min),
        "HAS_SOFT_MAX": _flag(qp.has_soft_max),
        "DISTURBANCE_INPUT": _flag(s.disturbance_model == "input"),
        "ROW_SOFT": str(qp._row_soft),
        "TS_S": c_number(mpc.ts_s),
        "S_NOM": c_number(s_nom),
        "P_NOM": c_number(p_nom),
        "DS_INIT": c_number(mpc._ds_init),
        "DS_MIN": c_number(im.ds_min_pct),
        "DS_MAX": c_number(im.ds_max_pct),
        "W_MIN": c_number(im.w_min),
        "W_MAX": c_number(im.w_max),
        "ALLOWED_MIN": c_number(mpc.allowed_triac_range_pct[0]),
        "ALLOWED_MAX": c_number(mpc.allowed_triac_range_pct[1]),
        "STATIC_GAIN": c_number(ssm.static_gain),
        "INV_STATIC_GAIN": c_number(1.0 / ssm.static_gain),
        "W0_ABS": c_number(mpc._w0_abs),
        "D_POWER_GAIN": c_number(aug.disturbance_power_gain),
        "CM": c_number(est._cm),
        "C_D": c_number(float(aug.C[-1])),
        "INITIAL_MODE": str(_MODES[rel.initial_mode]),
        "WARMUP_SAMPLES": str(rel.warmup_samples),
        "HAS_POWER_MIN": has_min, "POWER_MIN": power_min,
        "HAS_POWER_MAX": has_max, "POWER_MAX": power_max,
        "HAS_MAX_CHANGE": has_change, "MAX_CHANGE": max_change,
        "STUCK_SAMPLES": str(rel.stuck_samples),
        "STUCK_MIN_CHANGE": c_number(rel.stuck_min_predicted_change_kw),
        "HAS_SPIKE_GATE": has_gate, "SPIKE_K_SIGMA": k_sigma,
        "SPIKE_FLOOR": c_number(rel.spike_gate_floor_kw),
        "REOPEN_AFTER": str(rel.reopen_after_samples),
        "HAS_LEVEL_CHANGE": has_level, "LEVEL_CHANGE_K_SIGMA": level_k,
        "MAX_PREDICTED": str(rel.max_predicted_samples),
        "HAS_SHED": _flag(mpc._shed_ds is not None),
        "SHED_DS": c_number(mpc._shed_ds if mpc._shed_ds is not None else 0.0),
        "MAX_BAD_SOLVES": str(rel.max_bad_solves),
        "BOUND_TOL": c_number(qp.bound_tol_kw),
        "HAS_SETPOINT_RAMP": _flag(has_ramp),
        "SETPOINT_MAX_STEP": c_number(shaper._max_step if shaper._max_step is not None else 0.0),
        "SETPOINT_ALPHA": c_number(shaper._alpha),
        "PREVIEW_LO_OK": c_number(lo_ok),
        "PREVIEW_HI_OK": c_number(hi_ok),
        "LIMIT_RAMP": c_number(mpc._limits._step),
        "MAX_MOVE": c_number(0.0 if s.max_move_pct_per_step is None else s.max_move_pct_per_step),
        "SOFT_MIN_REL": c_number(mpc._soft_min_rel or 0.0),
        "SOFT_MAX_REL": c_number(mpc._soft_max_rel or 0.0),
        "SOFT_LINEAR_WEIGHT": c_number(s.soft_limit_linear_weight),
        **osqp_values(qp),
        "COEF": c_array(im.coefficients),
        "CRIT": c_array(im.slope_critical_points_pct or (0.0,)),
        "XW": c_array(ssm.xw),
        "A_AUG": c_array(aug.A),
        "B_AUG": c_array(aug.B),
        "C_AUG": c_array(aug.C),
        "M": c_array(est.gains.M),
        "G": c_array(est.gains.G),
        "ABG_C": c_array(abg_c),
        "STD_KW": c_array(est._std_kw),
        "Q_PARAMS": c_array(qp._q_params),
        "TRAJ_COST": c_array(mpc._traj_cost),
        "REF_COST": c_array(mpc._ref_cost),
        "CPHI_MAP": c_array(qp._Cphi_map),
        "CGAM_ROWSUM": c_array(qp._Cgam_rowsum),
    }
    return values


#: OSQP's float settings the C sets exactly at init (its generator prints them as "%.20f").
OSQP_FLOAT_SETTINGS = ("rho", "sigma", "alpha", "eps_abs", "eps_rel", "eps_prim_inf",
                       "eps_dual_inf", "adaptive_rho_tolerance", "adaptive_rho_fraction")


def osqp_problem(qp: MPCQP) -> tuple[sp.csc_matrix, sp.csc_matrix]:
    """``(P, A)`` exactly as ``qp``'s OSQP object was set up with (upper triangle, CSC).

    Raises
    ------
    CodegenError
        If the OSQP object does not hold them (another osqp version).
    """
    cache = getattr(qp._solver, "_derivative_cache", None)
    if not isinstance(cache, dict) or "P" not in cache or "A" not in cache:
        raise CodegenError(f"codegen: the QP's OSQP object (osqp {osqp.__version__}) must keep the "
                           "P and A it was set up with (osqp 1.x's _derivative_cache); got none")
    return sp.csc_matrix(cache["P"]), sp.csc_matrix(cache["A"])


def osqp_values(qp: MPCQP) -> dict[str, str]:
    """The QP's exact ``P`` and ``A`` values and OSQP's float settings (template values).

    OSQP's code generator writes its workspace with ``"%.20f"``: a number below 1e-4 in
    magnitude loses digits (measured: the scaled matrices, scaling vectors and KKT
    factor of the fuzz set's QPs). The C sets the solver up again from these at init
    (``czmpc_step.c``, ``qp_setup_exact``), as ``osqp_setup`` did in Python.
    """
    P, A = osqp_problem(qp)
    st = qp._solver.settings
    values = {"QP_NNZ_P": str(P.nnz), "QP_NNZ_A": str(A.nnz),
              "QP_P_X": c_array(P.data), "QP_A_X": c_array(A.data)}
    for name in OSQP_FLOAT_SETTINGS:
        values[f"OSQP_{name.upper()}"] = c_number(getattr(st, name))
    return values


def daqp_values(qp: MPCQP) -> dict[str, str]:
    """The template values of ``czmpc_daqp.h``: ``qp``'s DAQP problem, exact.

    ``qp`` is a `czmpc.qp_daqp.DAQPMPCQP`: its Hessian and general rows are the arrays its
    ``daqp.Model`` was set up with; the arena's size is an upper bound of what DAQP's
    set-up asks for (``allocate_daqp_workspace`` and ``allocate_daqp_ldp``, 16-byte pieces).

    Raises
    ------
    CodegenError
        If ``qp`` is not a DAQP QP.
    """
    from czmpc import qp_daqp

    if not isinstance(qp, qp_daqp.DAQPMPCQP):
        raise CodegenError(f"codegen: solver = 'daqp' needs the controller's DAQPMPCQP; got "
                           f"{type(qp).__name__}")
    hessian = np.asarray(qp._daqp_hessian, dtype=float)
    rows = np.asarray(qp._daqp_rows, dtype=float)
    n, m, ms = hessian.shape[0], qp.n_constraints, qp.horizon_steps
    n_doubles = (5 * (n + 1) + (n + 1) * (n + 2) // 2 + 3 * n + n * (n + 1) // 2
                 + n * (m - ms) + 4 * m)
    n_ints = 2 * (n + 1) + m
    n_blocks = 24
    arena = 8 * n_doubles + 4 * n_ints + 16 * n_blocks + 1024   # 1 kB to spare
    status = ",\n".join(f'    {{{flag}, "{qp_daqp.daqp_status(flag)}"}}' for flag in range(-8, 6)
                        if flag != 0)
    return {
        "DAQP_VERSION": daqp_version(),
        "DAQP_N": str(n), "DAQP_M": str(m), "DAQP_MS": str(ms),
        "DAQP_ITER_LIMIT": str(qp_daqp.DAQP_ITER_LIMIT),
        "DAQP_PRIMAL_TOL": c_number(qp_daqp.DAQP_PRIMAL_TOL_KW),
        "DAQP_CHECK_BOUNDS": _flag(qp._check_bounds),
        "DAQP_ARENA_BYTES": str(arena),
        "DAQP_H": c_array(hessian.ravel()),
        "DAQP_A": c_array(np.append(rows.ravel(), 0.0)),
        "DAQP_STATUS": status,
    }


def check_osqp_structure(workspace: str, qp: MPCQP) -> None:
    """Check that OSQP's generated ``workspace`` (C source) has ``qp``'s P and A pattern.

    Raises
    ------
    CodegenError
        If the column pointers or row indices differ (the exact values would be put in
        the wrong places).
    """
    P, A = osqp_problem(qp)
    for name, mat in (("P", P), ("A", A)):
        for part, want in (("p", mat.indptr), ("i", mat.indices)):
            var = f"{OSQP_PREFIX}data_{name}_csc_{part}"
            found = re.search(rf"{var}\[\d+\] = \{{([^}}]*)\}}", workspace)
            got = None if found is None else [int(v) for v in found.group(1).replace(",", " ").split()]
            if got != [int(v) for v in want]:
                raise CodegenError(f"codegen: OSQP's generated {var} must be the pattern of the "
                                   f"QP's {name} ({mat.nnz} nonzeros); got "
                                   f"{'none' if got is None else f'{len(got)} entries that differ'}")


def generate_step(model: HammersteinModel, settings: MPCSettings | None, out_dir: Path, *,
                  float32: bool = False, model_source: str = "<memory>",
                  settings_source: str = "defaults for the model (MPCSettings.default_for)",
                  progress: Callable[[str], None] | None = None,
                  daqp_sdist: str | Path | None = None) -> GeneratedStep:
    """Write the C99 step of ``OffsetFreeMPC(model, settings)`` and its Makefile into ``out_dir``.

    Parameters
    ----------
    model :
        The identified model.
    settings :
        The controller settings; None: `MPCSettings.default_for` ``(model)``, as
        ``OffsetFreeMPC(model)``.
    out_dir :
        The output directory (created; files of the same names are replaced).
    float32 :
        Generate the step and OSQP in ``float`` (single precision).
    model_source, settings_source :
        Where model and settings came from, for the generated header.
    progress :
        Called with a line per stage.
    daqp_sdist :
        With ``solver = "daqp"``: a downloaded sdist of the installed daqp version, for
        generating offline (`czmpc.codegen.daqp_source.daqp_sources`); None: the
        environment variable ``CZMPC_DAQP_SDIST``, the cache, or a download from PyPI.

    Raises
    ------
    CodegenError
        Settings the generated step cannot reproduce (`check_supported`).
    DesignError, SettingsError
        As ``OffsetFreeMPC(model, settings)`` raises them.
    OSError
        The directory cannot be written.
    """
    say = progress if progress is not None else (lambda _msg: None)
    mpc = OffsetFreeMPC(model, settings)
    check_supported(mpc.settings, float32=float32)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if getattr(mpc.settings, "solver", "osqp") == "daqp":
        return _generate_daqp_step(mpc, model, out_dir, model_source=model_source,
                                   settings_source=settings_source, say=say, sdist=daqp_sdist)
    osqp_dir = out_dir / OSQP_DIR
    say(f"generating OSQP's solver for the QP ({mpc.qp.n_variables} variables, "
        f"{mpc.qp.n_constraints} constraints) into {osqp_dir}")
    if osqp_dir.exists():
        shutil.rmtree(osqp_dir)
    mpc.qp._solver.codegen(str(osqp_dir), parameters="matrices", extension_name=None,
                           force_rewrite=True, use_float=float32, prefix=OSQP_PREFIX,
                           include_codegen_src=True, compile=False)
    for name in _OSQP_UNUSED:
        (osqp_dir / name).unlink(missing_ok=True)
    check_osqp_structure((osqp_dir / f"{OSQP_PREFIX}workspace.c").read_text(encoding="utf-8"),
                         mpc.qp)
    sources = sorted(p.stem for p in (osqp_dir / "src").glob("*.c"))
    say(f"writing the step (horizon {mpc.qp.horizon_steps}, "
        f"{'float' if float32 else 'double'}) into {out_dir}")
    values = template_values(mpc, model_source=model_source, settings_source=settings_source,
                             float32=float32)
    values["OSQP_OBJECTS"] = " ".join(f"osqp_{name}.o" for name in sources)
    values["OSQP_SOURCES"] = " ".join(f"osqp/src/{name}.c" for name in sources)
    return _write_step(mpc, model, out_dir, TEMPLATES, values, float32=float32,
                       solver_dir=OSQP_DIR)


def _write_step(mpc: OffsetFreeMPC, model: HammersteinModel, out_dir: Path,
                templates: dict[str, str], values: dict[str, str], *, float32: bool,
                solver_dir: str) -> GeneratedStep:
    """Fill ``templates`` with ``values`` into ``out_dir``, keep the model and settings
    beside them (`read_sources`), and say what was written (the solver's folder last)."""
    folder = resources.files("czmpc.codegen") / "templates"
    for template, target in templates.items():
        text = (folder / template).read_text(encoding="utf-8")
        if template.endswith(".in"):
            text = string.Template(text).substitute(values)
        (out_dir / target).write_text(text, encoding="utf-8")
    save_model(model, out_dir / MODEL_FILE)
    (out_dir / SETTINGS_FILE).write_text(settings_to_toml(mpc.settings), encoding="utf-8")
    return GeneratedStep(directory=out_dir, horizon_steps=mpc.qp.horizon_steps,
                         n_variables=mpc.qp.n_variables, n_constraints=mpc.qp.n_constraints,
                         float32=float32,
                         files=(*templates.values(), MODEL_FILE, SETTINGS_FILE, solver_dir))


def _generate_daqp_step(mpc: OffsetFreeMPC, model: HammersteinModel, out_dir: Path, *,
                        model_source: str, settings_source: str, say: Callable[[str], None],
                        sdist: str | Path | None) -> GeneratedStep:
    """`generate_step` with ``solver = "daqp"``: DAQP's sources instead of OSQP's code."""
    say(f"copying DAQP {daqp_version()}'s C sources (its sdist) into {out_dir / DAQP_DIR}")
    sources = copy_daqp(out_dir, sdist)
    if (out_dir / OSQP_DIR).exists():
        shutil.rmtree(out_dir / OSQP_DIR)
    say(f"writing the step (horizon {mpc.qp.horizon_steps}, DAQP, double) into {out_dir}")
    values = template_values(mpc, model_source=model_source, settings_source=settings_source,
                             float32=False)
    values.update(daqp_values(mpc.qp))
    values["DAQP_OBJECTS"] = " ".join(f"daqp_{name}.o" for name in sources)
    values["DAQP_SOURCES"] = " ".join(f"daqp/src/{name}.c" for name in sources)
    return _write_step(mpc, model, out_dir, DAQP_TEMPLATES, values, float32=False,
                       solver_dir=DAQP_DIR)


def read_sources(directory: str | Path) -> tuple[HammersteinModel, MPCSettings]:
    """The model and settings a directory of `generate_step` was generated from.

    Raises
    ------
    CodegenError
        ``directory`` holds no generated step (or one written before they were kept).
    ModelFileError, SettingsError
        As `sysid.modelfile.load_model` and `czmpc.settings_file.load_settings` raise them.
    """
    folder = Path(directory)
    missing = [name for name in (MODEL_FILE, SETTINGS_FILE, "czmpc_step.c")
               if not (folder / name).is_file()]
    if missing:
        raise CodegenError(f"{folder}: not a directory written by 'czmpc codegen' (no "
                           f"{', '.join(missing)}); generate it with 'czmpc codegen MODEL.json "
                           f"--out {folder}'")
    model = load_model(folder / MODEL_FILE)
    return model, load_settings(folder / SETTINGS_FILE, model)


__all__ = ["DAQP_DIR", "DAQP_TEMPLATES", "MODEL_FILE", "OSQP_DIR", "OSQP_PREFIX", "SETTINGS_FILE",
           "TEMPLATES", "GeneratedStep",
           "c_array", "c_number", "check_supported", "daqp_values", "generate_step", "read_sources",
           "template_values"]
