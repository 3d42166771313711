"""Hammerstein models of heater logs: the model, its fitting routines and the paper's route.

The paper's route (secs. 7.3-7.6), each step a pure function with a frozen result:

1. `initial_input_poly`: the coefficients of ``f`` by least squares from the input
   steps' instantaneous responses and an ARX model (eqs. 14-21, Table 3, Fig. 12);
2. `reidentify_linear_block`: ``f`` fixed, the linear block re-identified with input
   ``w = f(ds)`` by ARX or OE (sec. 7.4, Fig. 13);
3. `fit_hammerstein_oe`: all parameters at once in the normalized form of eq. 25
   (``b1 = 1``) by PEM on V (the structure of eq. 26, sec. 7.5);
4. `fit_hammerstein_armax`: the noise-model extension of eqs. 29-32 by PEM on W.

Steps 1-2 and `fit_hammerstein`, which runs them all on a `Dataset`, are in
`sysid.hammerstein.route`, steps 3-4 in `sysid.hammerstein.fitting`; `HammersteinFit`, the
grey-box structures and the criteria in `sysid.hammerstein.model`.

Notation
--------
``y = dP = P - P_nom`` [kW], ``ds = s - s_nom`` [%] (deviation variables, sec. 5.1).
``f(ds) = sum_{i=1..n} p_i ds^i`` with no constant term (``input_poly = [p_1, ..., p_n]``,
the paper's ``d1, d2``). The linear block is ``A(q) y = B(q) f(ds) + C(q) e``, with
``B(q) = q^-nk (b_nk + b_{nk+1} q^-1 + ...)``: parameters are named by the lag they
multiply (``b2`` multiplies ``q^-2``), as in `sysid.linear`. In the normalized form
(eqs. 22-25) ``b_nk = 1``; the paper's ``b~2, d~1, d~2`` are ``b2, d1, d2`` here.

* OE block (eq. 27): ``C = A = F``; parameters ``b_{nk+1}.., d1..dn, f1..f_nf``.
* ARMAX block (eq. 30): parameters ``b.., d.., a1..a_na, k1..k_nc`` with
  ``c_i = a_i + k_i`` (eq. 32); ``k`` is the Kalman gain of eq. 29.
"""

from sysid.hammerstein.fitting import fit_hammerstein_armax, fit_hammerstein_oe
from sysid.hammerstein.model import (
    HammersteinBlock,
    HammersteinFit,
    RowForm,
    hammerstein_armax_structure,
    hammerstein_criteria,
    hammerstein_model,
    hammerstein_oe_structure,
    relative_parameter_difference,
)
from sysid.hammerstein.route import (
    HammersteinRoute,
    InputPolyInit,
    fit_hammerstein,
    initial_input_poly,
    reidentify_linear_block,
    run_hammerstein_route,
)

__all__ = [
    "HammersteinBlock",
    "HammersteinFit",
    "HammersteinRoute",
    "InputPolyInit",
    "RowForm",
    "fit_hammerstein",
    "fit_hammerstein_armax",
    "fit_hammerstein_oe",
    "hammerstein_armax_structure",
    "hammerstein_criteria",
    "hammerstein_model",
    "hammerstein_oe_structure",
    "initial_input_poly",
    "reidentify_linear_block",
    "relative_parameter_difference",
    "run_hammerstein_route",
]
