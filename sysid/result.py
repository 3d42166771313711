"""IdentificationResult: what one identification run produced."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from sysid._arrays import readonly_array
from sysid._typing import FloatArray
from sysid.model import HammersteinModel

CriterionName = Literal["ballistic", "one_step", "least_squares"]


@dataclass(frozen=True, kw_only=True, eq=False)
class IdentificationResult:
    """Outcome of one fit (scipy.optimize-style, but typed and frozen).

    Parameters
    ----------
    model :
        The identified model, with criteria and provenance filled in.
    converged :
        True if the optimizer met its convergence test (always True for least squares).
    message :
        The optimizer's own words on why it stopped.
    n_iterations :
        Iterations used (0 for least squares).
    criterion :
        What was minimized: ``"ballistic"`` (V, eq. 9), ``"one_step"`` (W, eq. 10) or
        ``"least_squares"`` (ARX equation error, which equals W for ARX).
    parameter_names :
        Names of the estimated parameters, in the order of `parameters`.
    parameters :
        Estimated values.
    std_errors :
        Standard errors of `parameters` from the Jacobian, ``sqrt(diag(s^2 (J'J)^-1))``.
    residuals_kw :
        Residuals of the minimized criterion over the data [kW].
    raw :
        The optimizer's own result object, for experts; never needed by callers.
    """

    model: HammersteinModel
    converged: bool
    message: str
    n_iterations: int
    criterion: CriterionName
    parameter_names: tuple[str, ...]
    parameters: FloatArray
    std_errors: FloatArray
    residuals_kw: FloatArray = field(repr=False)
    raw: Any = field(default=None, repr=False)

    def __post_init__(self) -> None:
        for name in ("parameters", "std_errors", "residuals_kw"):
            object.__setattr__(self, name, readonly_array(getattr(self, name)))

    def parameter(self, name: str) -> tuple[float, float]:
        """``(value, standard error)`` of the parameter called ``name``."""
        i = self.parameter_names.index(name)
        return float(self.parameters[i]), float(self.std_errors[i])


__all__ = ["CriterionName", "IdentificationResult"]
