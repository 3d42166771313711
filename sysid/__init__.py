"""sysid: logged heater data -> identified Hammerstein model (paper secs. 5-7).

Public names load on first use (see `sysid._lazy`)::

    data = sysid.read_csv("heater.csv")
    result = sysid.fit_hammerstein(data, operating_point=sysid.OperatingPoint(triac_pct=45.0, power_kw=45.0))
    sysid.save_model(result.model, "model.json")
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sysid._lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(["CSV_COLUMNS", "Dataset", "read_csv", "write_csv"], "sysid.data"),
    **dict.fromkeys(["LoadPolicy", "LoadReport", "load_log"], "sysid.historian"),
    **dict.fromkeys(
        ["DataFileError", "IdentificationError", "IdentificationWarning", "ModelFileError",
         "SamplingTimeError", "SysidError", "UnstableModelError"], "sysid.errors"),
    **dict.fromkeys(
        ["Criteria", "HammersteinModel", "OperatingPoint", "Provenance", "Units"], "sysid.model"
    ),
    **dict.fromkeys(["load_model", "save_model"], "sysid.modelfile"),
    "IdentificationResult": "sysid.result",
    **dict.fromkeys(["simulate", "predict_one_step"], "sysid.simulate"),
    **dict.fromkeys(["ballistic_mse", "one_step_mse", "fit_percent"], "sysid.criteria"),
    **dict.fromkeys(["fit_arx", "fit_oe", "fit_armax"], "sysid.linear"),
    "fit_hammerstein": "sysid.hammerstein",
    **dict.fromkeys(["GreyBoxStructure", "fit_greybox"], "sysid.greybox"),
    **dict.fromkeys(
        ["to_deviation", "find_operating_point", "find_outlier_candidates", "interpolate_spike",
         "correct_level_shift"], "sysid.preprocess"),
    **dict.fromkeys(["autocorrelation", "cross_correlation"], "sysid.residuals"),
    **dict.fromkeys(["InputStep", "detect_steps"], "sysid.steps"),
    **dict.fromkeys(["PipelineResult", "run_paper_pipeline"], "sysid.pipeline"),
    **dict.fromkeys(["ExportError", "Linearization", "linearize", "save_mat",
                     "to_python_control"], "sysid.export"),
    **dict.fromkeys(["ParameterDistribution", "ParameterError", "draw_parameters",
                     "model_with_parameters", "parameter_distribution"], "sysid.uncertainty"),
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
__all__ = sorted(_EXPORTS)

if TYPE_CHECKING:
    from sysid.criteria import ballistic_mse, fit_percent, one_step_mse
    from sysid.data import CSV_COLUMNS, Dataset, read_csv, write_csv
    from sysid.errors import (
        DataFileError,
        IdentificationError,
        IdentificationWarning,
        ModelFileError,
        SamplingTimeError,
        SysidError,
        UnstableModelError,
    )
    from sysid.export import ExportError, Linearization, linearize, save_mat, to_python_control
    from sysid.greybox import GreyBoxStructure, fit_greybox
    from sysid.hammerstein import fit_hammerstein
    from sysid.historian import LoadPolicy, LoadReport, load_log
    from sysid.linear import fit_armax, fit_arx, fit_oe
    from sysid.model import Criteria, HammersteinModel, OperatingPoint, Provenance, Units
    from sysid.modelfile import load_model, save_model
    from sysid.pipeline import PipelineResult, run_paper_pipeline
    from sysid.preprocess import (
        correct_level_shift,
        find_operating_point,
        find_outlier_candidates,
        interpolate_spike,
        to_deviation,
    )
    from sysid.residuals import autocorrelation, cross_correlation
    from sysid.result import IdentificationResult
    from sysid.simulate import predict_one_step, simulate
    from sysid.steps import InputStep, detect_steps
    from sysid.uncertainty import (
        ParameterDistribution,
        ParameterError,
        draw_parameters,
        model_with_parameters,
        parameter_distribution,
    )
