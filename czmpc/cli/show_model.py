"""Print a model file as an engineer reads it: equation, parameters, gains, time constants.

Checks the file against the czmpc-model/1 contract on the way (a bad file exits with
code 2 and says what is wrong). With --plot DIR it also draws, linearized at --levels-pct
(default: the ends and the middle of the identified input range): the response to a
1-unit input step, the Bode plot up to the Nyquist frequency and the poles and zeros,
each with a 95 % band from models drawn from the parameter covariance (--draws, seeded).
--export-mat FILE writes the model and those linearizations for MATLAB or Octave
(tf(num(i,:), den(i,:), Ts)); in Python, sysid.export.to_python_control gives
python-control objects (pip install 'czmpc[control]').
"""

from __future__ import annotations

import argparse
import math

NAME = "show-model"
HELP = "print a czmpc-model/1 file: equation, gains, time constants, validity range"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    from pathlib import Path

    from czmpc.cli import _argtypes

    parser.add_argument("model", metavar="MODEL.json", help="model file to show")
    parser.add_argument("--plot", metavar="DIR", type=Path, default=None,
                        help="also draw step.png, bode.png and poles_zeros.png into DIR")
    parser.add_argument("--levels-pct", metavar="PCT", type=_argtypes.number(unit="%"),
                        nargs="+", default=None,
                        help="input levels to linearize at (default: the ends and the middle "
                             "of the identified input range)")
    parser.add_argument("--draws", metavar="N", type=_argtypes.non_negative_int, default=200,
                        help="models drawn from the parameter covariance for the bands "
                             "(default: 200; 0: no bands)")
    parser.add_argument("--export-mat", metavar="FILE.mat", type=Path, default=None,
                        help="write the model and its linearizations at the levels as a "
                             "MATLAB .mat file")


def describe_model(model: object) -> str:
    """Multi-line description of a `sysid.HammersteinModel`."""
    import numpy as np

    from sysid.model import HammersteinModel
    from sysid.polynomials import roots_z

    if not isinstance(model, HammersteinModel):
        raise TypeError(f"expected a HammersteinModel; got {type(model).__name__}")
    op = model.operating_point

    def poly(name: str, coefs: np.ndarray) -> str:
        terms = [f"{c:+.6g} q^-{i}" if i else f"{c:.6g}" for i, c in enumerate(coefs) if c != 0]
        return f"{name}(q) = " + " ".join(terms)

    units = model.effective_units
    u_in, u_out = units.input, units.output
    # a CZ puller's log (TRIAC s in %, power P in kW) keeps the paper's symbols; any
    # other rig reads as input u and output y
    s_, p_ = ("s", "P") if (u_in, u_out) == ("%", "kW") else ("u", "y")
    ds, dp = f"d{s_}", f"d{p_}"
    f_terms = " ".join(f"{p:+.6g} {ds}^{i + 1}" for i, p in enumerate(model.input_poly))
    names = _column_names(model)
    lines = [
        f"kind: {model.kind} ({model.linear_block} linear block), Ts = {model.ts_s:g} s, "
        f"delay = {model.delay_steps} sample(s)",
        f"units: input {u_in}, output {u_out}"
        + ("" if model.units is not None else " (the file has no units: % and kW assumed)"),
    ]
    if names is not None:
        lines.append(f"signals: input {s_} = column '{names[0]}' [{u_in}], output {p_} = "
                     f"column '{names[1]}' [{u_out}]")
    lines += [
        f"operating point: {s_}_nom = {op.triac_pct:g} {u_in}, {p_}_nom = {op.power_kw:g} {u_out}",
        f"A(q) {dp} = B(q) f({ds}) + C(q) e   with {dp} = {p_} - {p_}_nom [{u_out}], "
        f"{ds} = {s_} - {s_}_nom [{u_in}]",
        "  " + poly("A", model.a),
        "  " + poly("B", model.b),
        "  " + poly("C", model.c),
        f"  f({ds}) = {f_terms}   [{u_out}]",
        f"  noise std(e) = {model.noise_std_kw:.4g} {u_out}",
        f"linear-block static gain B(1)/A(1) = {model.linear_static_gain:.4g}",
    ]
    for z in roots_z(model.a):
        if abs(z.imag) < 1e-12 and 0 < z.real < 1:
            lines.append(f"  pole z = {z.real:.5f}: time constant {-model.ts_s / math.log(z.real):.1f} s")
        else:
            lines.append(f"  pole z = {complex(z):.5f}")
    lo, hi = model.input_range_pct
    grid = np.linspace(lo, hi, 5)
    slopes = model.input_nonlinearity_slope(grid - op.triac_pct)
    steady = model.steady_state_power_kw(grid)
    lines.append(f"identified input range: {lo:g} .. {hi:g} {u_in}")
    lines.append(f"      {s_} [{u_in}]   f'({ds}) [{u_out}/{u_in}]   steady {p_} [{u_out}]")
    for s, g, p in zip(grid, slopes, steady, strict=True):
        lines.append(f"  {s:9.2f}   {g:13.4f}   {p:13.3f}")
    crit = model.criteria
    if crit.ballistic_mse_kw2 is not None or crit.one_step_mse_kw2 is not None:
        lines.append(
            f"criteria: V = {crit.ballistic_mse_kw2!s} {u_out}^2 (eq. 9), "
            f"W = {crit.one_step_mse_kw2!s} {u_out}^2 (eq. 10)"
        )
    prov = model.provenance
    if prov.data_file or prov.method:
        lines.append(f"provenance: data {prov.data_file}, method {prov.method}")
    for step in prov.preprocessing:
        if step.get("what") == "load_log":
            lines.append(
                f"  loaded: {step.get('format')}, time {step.get('time_format')}, --gaps "
                f"{step.get('gaps')} ({step.get('n_filled')} filled, {step.get('n_dropped')} "
                f"dropped, {step.get('n_segments')} segment(s)), --resample "
                f"{step.get('resample')} ({step.get('n_snapped')} snapped)")
        else:
            lines.append(f"  preprocessing: {dict(step)}")
    lines.extend(f"WARNING: {w}" for w in model_warnings(model))
    return "\n".join(lines)


def _column_names(model: object) -> tuple[str, str] | None:
    """The log's input and output column names, if the model's provenance records them."""
    prov = getattr(model, "provenance", None)
    for step in getattr(prov, "preprocessing", ()):
        columns = step.get("columns") if step.get("what") == "load_log" else None
        if isinstance(columns, dict) and "triac_pct" in columns and "power_kw" in columns:
            return str(columns["triac_pct"]), str(columns["power_kw"])
    return None


#: A pole this close to |z| = 1 (time constant over 1e5 samples) acts as an integrator
#: over any record a user can log.
UNIT_CIRCLE_MARGIN = 1e-5
#: A zero of B closer to a pole p of A than this fraction of |1 - p| nearly cancels it:
#: the mode then carries under 1 % of the static response (the paper's slow drift mode,
#: |z - p| about 0.1 |1 - p|, is a real mode and is not flagged).
CANCELLATION_RTOL = 1e-2
#: B normalized to its first coefficient with a later one this many times larger: the
#: normalization divides by a coefficient near zero, so f's scale is ill-determined.
NORMALIZATION_RATIO_LIMIT = 20.0


def model_warnings(model: object) -> tuple[str, ...]:
    """What an engineer must know before trusting ``model`` (a `sysid.HammersteinModel`).

    Poles on or near the unit circle, near pole-zero cancellations between ``A`` and
    ``B``, an ill-conditioned normalization of ``B`` (a later coefficient much larger
    than the first, which is 1), and an instantaneous gain ``f'(0)`` of zero or of
    the wrong sign.
    """
    import numpy as np

    from sysid.model import HammersteinModel
    from sysid.polynomials import roots_z

    if not isinstance(model, HammersteinModel):
        raise TypeError(f"expected a HammersteinModel; got {type(model).__name__}")
    out: list[str] = []
    poles = roots_z(model.a)
    for z in poles:
        if abs(z) >= 1.0 - UNIT_CIRCLE_MARGIN:
            out.append(
                f"pole z = {complex(z):.6f} (|z| = {abs(z):.6f}) is on or within "
                f"{UNIT_CIRCLE_MARGIN:g} of the unit circle: the model is (nearly) an integrator")
    b_tail = np.trim_zeros(model.b, "f")
    zeros = roots_z(b_tail) if b_tail.size > 1 else np.array([], dtype=complex)
    for z in zeros:
        if abs(z) >= 1.0:
            out.append(f"zero z = {complex(z):.5f} of B(q) lies on or outside the unit circle "
                       "(non-minimum phase: an inverse-response)")
        for p in poles:
            if abs(z - p) <= CANCELLATION_RTOL * abs(1.0 - p):
                out.append(
                    f"zero z = {complex(z):.5f} of B(q) nearly cancels pole z = {complex(p):.5f} "
                    "of A(q): the order is higher than the data support; try lower orders")
    ratio = float(np.max(np.abs(b_tail))) if b_tail.size else 0.0
    if ratio > NORMALIZATION_RATIO_LIMIT:
        out.append(
            f"B(q) normalized to its first non-zero coefficient has a coefficient {ratio:.4g} "
            f"times larger: the first coefficient is near zero (delay too short?), so f's "
            "scale is ill-conditioned; try a longer delay")
    slope = float(model.input_nonlinearity_slope(0.0))
    gain = slope * model.linear_static_gain
    if not gain > 0:
        units = model.effective_units
        out.append(
            f"static gain at the operating point is {gain:.4g} {units.output}/{units.input} "
            "(not positive): a heater controller refuses it; for other processes check the sign")
    return tuple(out)


def run(args: argparse.Namespace) -> int:
    """Load and print the model; draw and export it when asked."""
    from sysid.modelfile import load_model

    model = load_model(args.model)
    print(describe_model(model))
    if args.plot is None and args.export_mat is None:
        return 0
    lo, hi = model.input_range_pct
    levels = tuple(args.levels_pct) if args.levels_pct else (lo, 0.5 * (lo + hi), hi)
    if args.export_mat is not None:
        from sysid.export import save_mat

        args.export_mat.parent.mkdir(parents=True, exist_ok=True)
        save_mat(model, args.export_mat, levels)
        print(f"wrote {args.export_mat} (linearized at {', '.join(f'{v:g}' for v in levels)} "
              f"{model.effective_units.input})")
    if args.plot is not None:
        from czmpc.reports.model_figures import bode_figure, draw_models, pole_zero_figure, step_figure

        args.plot.mkdir(parents=True, exist_ok=True)
        draws = draw_models(model, args.draws)
        paths = (step_figure(args.plot / "step.png", model, levels, draws),
                 bode_figure(args.plot / "bode.png", model, levels, draws),
                 pole_zero_figure(args.plot / "poles_zeros.png", model, draws))
        print(f"{draws.note}; wrote {', '.join(str(p) for p in paths)}")
    return 0
