"""Rewrite the shipped models from the shipped experiment with the paper pipeline.

Run after a change to the pipeline that moves the identified models (the test
``tests/sysid/test_shipped_model.py`` fails until then)::

    python tools/regenerate_shipped_models.py

Writes ``czmpc/data/cz_heater_model.json`` (the pipeline's final model, the
noise-model Hammerstein) and ``czmpc/data/cz_heater_armax_model.json`` (its linear
ARMAX of Table 2, the linear-MPC peer's model).
"""

from __future__ import annotations

import warnings

from czmpc.shipped import ARMAX_MODEL_JSON, EXPERIMENT_CSV, HAMMERSTEIN_MODEL_JSON, shipped_path
from sysid.data import read_csv
from sysid.modelfile import save_model
from sysid.pipeline import run_paper_pipeline


def main() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = run_paper_pipeline(read_csv(shipped_path(EXPERIMENT_CSV)))
    assert result.final is not None, result.skipped
    armax = next(m for m in result.linear if m.name == "armax_1_2_1")
    save_model(result.final.model, shipped_path(HAMMERSTEIN_MODEL_JSON))
    save_model(armax.model, shipped_path(ARMAX_MODEL_JSON))
    print(f"wrote {HAMMERSTEIN_MODEL_JSON} ({result.final.name}) and {ARMAX_MODEL_JSON}; "
          f"operating point {result.final.model.operating_point}")


if __name__ == "__main__":
    main()
