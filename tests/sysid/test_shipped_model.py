"""data/cz_heater_model.json is what `czmpc identify` makes of the shipped experiment."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from sysid.data import read_csv
from sysid.modelfile import load_model
from sysid.pipeline import run_paper_pipeline

REPO = Path(__file__).resolve().parents[2]

#: The pipeline is deterministic; the only differences come from floating-point
#: summation order across BLAS builds, far below 1e-8 relative on these parameters.
REIDENTIFY_RTOL = 1e-8


def test_shipped_model_is_the_pipelines_model_of_the_shipped_experiment() -> None:
    shipped = load_model(REPO / "data" / "cz_heater_model.json")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = run_paper_pipeline(read_csv(REPO / "data" / "cz_heater_experiment.csv"))
    model = result.final.model
    for name in ("a", "b", "c", "input_poly"):
        np.testing.assert_allclose(getattr(shipped, name), getattr(model, name),
                                   rtol=REIDENTIFY_RTOL, atol=1e-12)
    assert shipped.operating_point == model.operating_point
    assert shipped.input_range_pct == model.input_range_pct
    assert shipped.provenance.data_sha256 == model.provenance.data_sha256
