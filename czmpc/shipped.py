"""Paths of the data shipped with the package: the paper-like experiment and its models.

The files are the package data ``czmpc.data`` (``data/`` links to them): the paths
resolve the same in a checkout, an editable install and a wheel.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def shipped_path(name: str) -> Path:
    """Path of a file shipped in ``czmpc.data``.

    Parameters
    ----------
    name :
        File name inside the data folder, e.g. ``"cz_heater_model.json"``.

    Raises
    ------
    FileNotFoundError
        The installation does not hold that file.
    """
    path = Path(str(files("czmpc.data").joinpath(name)))
    if not path.is_file():
        raise FileNotFoundError(f"czmpc.data: no shipped file {name!r} (looked at {path})")
    return path


#: The identification experiment on the virtual heater (seed 2010), 12,000 samples.
EXPERIMENT_CSV = "cz_heater_experiment.csv"
#: The Hammerstein model identified from it (eq. 30 structure).
HAMMERSTEIN_MODEL_JSON = "cz_heater_model.json"
#: The linear ARMAX(1,2,1) identified from it (the linear-MPC peer's model).
ARMAX_MODEL_JSON = "cz_heater_armax_model.json"

__all__ = ["ARMAX_MODEL_JSON", "EXPERIMENT_CSV", "HAMMERSTEIN_MODEL_JSON", "shipped_path"]
