"""A model for other tools: its linearization, a MATLAB ``.mat`` file, python-control objects.

The Hammerstein model ``A(q) dP = B(q) f(ds) + C(q) e`` linearized at a TRIAC level
``s`` is the transfer function from a small TRIAC deviation [input unit] to the output
[output unit]::

    G_s(z) = f'(s - s_nom) B(z^-1) / A(z^-1),   sampled every Ts

(`linearize`). As polynomials in ``z`` (descending powers, MATLAB's and python-control's
convention) numerator and denominator are ``B`` and ``A`` padded to one length, since
``B(z^-1)/A(z^-1) = (b_0 z^(n-1) + ... + b_(n-1)) / (a_0 z^(n-1) + ... + a_(n-1))``.

`save_mat` writes the model and its linearizations for MATLAB or Octave (``load``);
`to_python_control` returns a ``control.TransferFunction`` or ``control.StateSpace``
(the optional extra ``czmpc[control]``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from sysid._typing import FloatArray
from sysid.errors import SysidError
from sysid.model import HammersteinModel

__all__ = ["ExportError", "Linearization", "linearize", "save_mat", "to_python_control"]


class ExportError(SysidError, ValueError):
    """A level outside the model's range of definition, or a missing optional package."""


@dataclass(frozen=True, kw_only=True, eq=False)
class Linearization:
    """The model linearized at one TRIAC level.

    Attributes
    ----------
    triac_pct :
        The level [input unit].
    slope :
        ``f'(s - s_nom)`` [output unit per input unit of f].
    num_z, den_z :
        Numerator and denominator in descending powers of ``z`` (equal length).
    ts_s :
        Sampling time [s].
    """

    triac_pct: float
    slope: float
    num_z: FloatArray
    den_z: FloatArray
    ts_s: float

    @property
    def static_gain(self) -> float:
        """``G_s(1)`` [output unit per input unit]."""
        return float(np.sum(self.num_z) / np.sum(self.den_z))

    def frequency_response(self, omega_rad_s: FloatArray) -> np.ndarray:
        """``G_s(exp(j omega Ts))`` at the angular frequencies ``omega_rad_s`` [rad/s]."""
        z = np.exp(1j * np.asarray(omega_rad_s, dtype=float) * self.ts_s)
        out: np.ndarray = np.polyval(self.num_z, z) / np.polyval(self.den_z, z)
        return out


def linearize(model: HammersteinModel, triac_pct: float) -> Linearization:
    """``G_s(z) = f'(s - s_nom) B/A`` at the TRIAC level ``triac_pct`` (module docstring).

    Raises
    ------
    ExportError
        A level that is not finite.
    """
    s = float(triac_pct)
    if not np.isfinite(s):
        raise ExportError(f"linearize: expected a finite TRIAC level; got {triac_pct!r}")
    slope = float(model.input_nonlinearity_slope(s - model.operating_point.triac_pct))
    n = max(model.a.size, model.b.size)
    num = np.zeros(n)
    den = np.zeros(n)
    num[: model.b.size] = slope * model.b
    den[: model.a.size] = model.a
    return Linearization(triac_pct=s, slope=slope, num_z=num, den_z=den, ts_s=model.ts_s)


def save_mat(model: HammersteinModel, path: str | os.PathLike[str],
             levels_pct: tuple[float, ...] = ()) -> None:
    """Write the model and its linearizations at ``levels_pct`` as a MATLAB ``.mat`` file.

    Variables: ``A``, ``B``, ``C`` (row vectors in powers of ``q^-1``), ``input_poly``
    (``p_1 .. p_n`` of ``f(ds) = sum p_i ds^i``), ``Ts``, ``s_nom``, ``P_nom``,
    ``noise_std``, ``input_range``, ``units`` (input, output), ``parameter_names``,
    ``covariance`` (empty if the file has none), ``levels`` and, per level (one row
    each), ``num`` and ``den`` in descending powers of ``z``: in MATLAB
    ``tf(num(i,:), den(i,:), Ts)``.
    """
    import scipy.io

    units = model.effective_units
    lins = [linearize(model, s) for s in levels_pct]
    n = max(model.a.size, model.b.size)
    cov = model.covariance_matrix
    names = model.provenance.parameter_names or ()
    scipy.io.savemat(os.fspath(path), {
        "A": model.a[None, :], "B": model.b[None, :], "C": model.c[None, :],
        "input_poly": model.input_poly[None, :], "Ts": model.ts_s,
        "s_nom": model.operating_point.triac_pct, "P_nom": model.operating_point.power_kw,
        "noise_std": model.noise_std_kw, "input_range": np.array(model.input_range_pct)[None, :],
        "units": np.array([units.input, units.output], dtype=object),
        "parameter_names": np.array(list(names), dtype=object),
        "covariance": np.zeros((0, 0)) if cov is None else np.asarray(cov),
        "levels": np.array(levels_pct, dtype=float)[None, :],
        "num": np.array([lin.num_z for lin in lins]).reshape(len(lins), n),
        "den": np.array([lin.den_z for lin in lins]).reshape(len(lins), n),
    }, oned_as="row")


def to_python_control(model: HammersteinModel, triac_pct: float,
                      form: Literal["tf", "ss"] = "tf") -> Any:
    """The linearization at ``triac_pct`` as a python-control object (``dt = Ts``).

    Raises
    ------
    ExportError
        python-control is not installed (``pip install czmpc[control]``), or ``form`` is
        neither ``"tf"`` nor ``"ss"``.
    """
    if form not in ("tf", "ss"):
        raise ExportError(f"to_python_control: form must be 'tf' or 'ss'; got {form!r}")
    try:
        import control
    except ModuleNotFoundError as exc:
        raise ExportError("to_python_control needs python-control: pip install "
                          "'czmpc[control]' (or pip install control)") from exc
    lin = linearize(model, triac_pct)
    tf = control.tf(lin.num_z, lin.den_z, lin.ts_s)
    return tf if form == "tf" else control.tf2ss(tf)
