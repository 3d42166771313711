"""sysid: logged heater data -> identified Hammerstein model (paper secs. 5-7)."""

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
from sysid.model import Criteria, HammersteinModel, OperatingPoint, Provenance
from sysid.modelfile import load_model, save_model

__all__ = [
    "CSV_COLUMNS",
    "Criteria",
    "DataFileError",
    "Dataset",
    "HammersteinModel",
    "IdentificationError",
    "IdentificationWarning",
    "ModelFileError",
    "OperatingPoint",
    "Provenance",
    "SamplingTimeError",
    "SysidError",
    "UnstableModelError",
    "load_model",
    "read_csv",
    "save_model",
    "write_csv",
]
