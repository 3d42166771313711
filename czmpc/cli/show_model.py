"""Print a model file as an engineer reads it: equation, parameters, gains, time constants.

Checks the file against the czmpc-model/1 contract on the way (a bad file exits with
code 2 and says what is wrong).
"""

from __future__ import annotations

import argparse
import math

NAME = "show-model"
HELP = "print a czmpc-model/1 file: equation, gains, time constants, validity range"
ORDER = 30


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument("model", metavar="MODEL.json", help="model file to show")


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

    f_terms = " ".join(f"{p:+.6g} ds^{i + 1}" for i, p in enumerate(model.input_poly))
    lines = [
        f"kind: {model.kind} ({model.linear_block} linear block), Ts = {model.ts_s:g} s, "
        f"delay = {model.delay_steps} sample(s)",
        f"operating point: s_nom = {op.triac_pct:g} %, P_nom = {op.power_kw:g} kW",
        "A(q) dP = B(q) f(ds) + C(q) e   with dP = P - P_nom [kW], ds = s - s_nom [%]",
        "  " + poly("A", model.a),
        "  " + poly("B", model.b),
        "  " + poly("C", model.c),
        f"  f(ds) = {f_terms}   [kW]",
        f"  noise std(e) = {model.noise_std_kw:.4g} kW",
        f"linear-block static gain B(1)/A(1) = {model.linear_static_gain:.4g}",
    ]
    poles = roots_z(model.a)
    for z in poles:
        if abs(z.imag) < 1e-12 and 0 < z.real < 1:
            lines.append(f"  pole z = {z.real:.5f}: time constant {-model.ts_s / math.log(z.real):.1f} s")
        else:
            lines.append(f"  pole z = {complex(z):.5f}")
    lo, hi = model.input_range_pct
    grid = np.linspace(lo, hi, 5)
    slopes = model.input_nonlinearity_slope(grid - op.triac_pct)
    steady = model.steady_state_power_kw(grid)
    lines.append(f"identified input range: {lo:g} .. {hi:g} %")
    lines.append("      s [%]   f'(ds) [kW/%]   steady P [kW]")
    for s, g, p in zip(grid, slopes, steady, strict=True):
        lines.append(f"  {s:9.2f}   {g:13.4f}   {p:13.3f}")
    crit = model.criteria
    if crit.ballistic_mse_kw2 is not None or crit.one_step_mse_kw2 is not None:
        lines.append(
            f"criteria: V = {crit.ballistic_mse_kw2!s} kW^2 (eq. 9), "
            f"W = {crit.one_step_mse_kw2!s} kW^2 (eq. 10)"
        )
    prov = model.provenance
    if prov.data_file or prov.method:
        lines.append(f"provenance: data {prov.data_file}, method {prov.method}")
    for step in prov.preprocessing:
        lines.append(f"  preprocessing: {dict(step)}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Load and print the model."""
    from sysid.modelfile import load_model

    print(describe_model(load_model(args.model)))
    return 0
