"""The generated C step as the real-time loop's controller (``czmpc run --controller c:DIR``).

`load_c_step` loads the compiled step of a directory ``czmpc codegen`` wrote
(`czmpc.codegen.load_controller`: ``libczmpc.so`` built on demand with the system's C
compiler, loaded with ctypes) as a `CStepMPC`: what the loop uses of
`czmpc.controller.OffsetFreeMPC` (``mode`` as a `czmpc.modes.Mode`, ``request_mode``,
``step``, ``last_step``, ``model``, ``settings``), with the directory's own model and
settings (``model.json``, ``settings.toml``: what the C was generated from). The loop
feeds its model-health monitor and shadow candidate from that model as it does for the
Python MPC, and reads the same step fields (status, verdict, target input, disturbance
as power, voltage and preview used) from the C step's record.
`czmpc.runtime.loop.CStepDriver`, the Python MPC's driver with the record's words read
as text, drives it in the loop.

The C carries its model and settings compiled in: a run configuration whose
``[controller] model`` or ``settings`` differ from them is refused (`load_c_step`), never
run with other numbers than the configuration names.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path

from czmpc.codegen import CController, StepRecord, load_controller
from czmpc.codegen.generate import MODEL_FILE, SETTINGS_FILE, read_sources
from czmpc.errors import SettingsError
from czmpc.modes import Mode
from czmpc.settings import MPCSettings
from sysid.atomic import file_sha256
from sysid.model import HammersteinModel
from sysid.modelfile import model_to_dict

#: The ``--controller`` prefix of a generated directory (as ``czmpc simulate`` takes it).
C_STEP_PREFIX = "c:"


class CStepMPC:
    """The compiled step of one directory with its model and settings (module notes).

    Parameters
    ----------
    controller :
        The loaded step (`czmpc.codegen.load_controller`).
    model, settings :
        What it was generated from (the directory's ``model.json`` and ``settings.toml``).
    directory :
        The directory.

    Attributes
    ----------
    ts_s :
        Sampling time [s] (the compiled one).
    float32 :
        True if the step computes in ``float``.
    """

    def __init__(self, controller: CController, *, model: HammersteinModel,
                 settings: MPCSettings, directory: Path) -> None:
        self.controller = controller
        self.model = model
        self.settings = settings
        self.directory = Path(directory)
        self.ts_s = controller.ts_s
        self.float32 = controller.float32
        self._mode = Mode(settings.reliability.initial_mode)

    @property
    def mode(self) -> Mode:
        """The step's mode now: the last step's, or the one a request set since."""
        return self._mode

    @property
    def last_step(self) -> StepRecord | None:
        """The C step's record of its latest step (strings are the Python enums' values)."""
        return self.controller.last

    def request_mode(self, mode: Mode | str) -> bool:
        """Ask for ``mode`` from the next step (`czmpc.controller.OffsetFreeMPC.request_mode`).

        Returns
        -------
        bool
            True if it is the mode now; False if refused (``ON`` before the estimator is
            warm).

        Raises
        ------
        SettingsError
            Not a mode.
        """
        try:
            wanted = Mode(mode)
        except ValueError:
            raise SettingsError(f"CStepMPC.request_mode: expected one of "
                                f"{[m.value for m in Mode]}; got {mode!r}") from None
        accepted = self.controller.request_mode(wanted.value)
        if accepted:
            self._mode = wanted
        return accepted

    def step(self, power_kw: float | None, setpoint_kw: float | None, *,
             applied_triac_pct: float | None = None,
             setpoint_preview_kw: Sequence[float] | None = None,
             grid_voltage_factor: float | None = None) -> float:
        """Return the TRIAC input [%] to apply now (`czmpc.codegen.CController.step`)."""
        triac_pct = self.controller.step(power_kw, setpoint_kw, applied_triac_pct=applied_triac_pct,
                                         setpoint_preview_kw=setpoint_preview_kw,
                                         grid_voltage_factor=grid_voltage_factor)
        record = self.controller.last
        if record is not None:
            self._mode = Mode(record.mode)
        return triac_pct

    def provenance(self) -> dict[str, object]:
        """What drives the input, for the run log's meta file: the directory, its precision
        and the SHA-256 of the generated C and of the library that ran."""
        files = {name: self.directory / name for name in (
            "czmpc_step.c", "czmpc_model.h", "libczmpc.so", MODEL_FILE, SETTINGS_FILE)}
        return {"kind": "C step run", "closed_loop": True,
                "c_step": {"directory": str(self.directory),
                           "precision": "float" if self.float32 else "double",
                           "sha256": {name: file_sha256(path) for name, path in files.items()
                                      if path.is_file()}}}


def c_step_directory(text: str) -> Path:
    """The directory of a ``--controller c:DIR`` value.

    Raises
    ------
    SettingsError
        A value without the ``c:`` prefix or without a directory.
    """
    if not text.startswith(C_STEP_PREFIX) or not text[len(C_STEP_PREFIX):]:
        raise SettingsError(f"--controller: expected c:DIR, a directory 'czmpc codegen' wrote; "
                            f"got {text!r}")
    return Path(text[len(C_STEP_PREFIX):])


def _differing(a: MPCSettings, b: MPCSettings) -> list[str]:
    """``"name: a -> b"`` for each top-level field of two settings that differs."""
    return [f"{f.name}: {getattr(a, f.name)!r} -> {getattr(b, f.name)!r}"
            for f in dataclasses.fields(a) if getattr(a, f.name) != getattr(b, f.name)]


def load_c_step(directory: str | os.PathLike[str], *, model: HammersteinModel,
                model_path: Path, settings: MPCSettings | None = None,
                settings_path: Path | None = None) -> CStepMPC:
    """Build (on demand) and load ``directory``'s step for a run configuration.

    Parameters
    ----------
    directory :
        Written by ``czmpc codegen``.
    model, model_path :
        The configuration's ``[controller] model``: it must be the model the step was
        generated from (the one ``DIR/model.json`` holds).
    settings, settings_path :
        The configuration's ``[controller] settings`` for that model, or None (then the
        compiled settings run); given, they must be the compiled ones.

    Raises
    ------
    CodegenError
        ``directory`` holds no generated step.
    SettingsError
        Another model or other settings than the compiled ones (the message says which
        fields and what to generate).
    BuildError
        No C compiler or make, a failed build, a library this czmpc cannot load.
    """
    folder = Path(directory)
    c_model, compiled = read_sources(folder)
    if model_to_dict(c_model) != model_to_dict(model):
        raise SettingsError(
            f"[controller] model {model_path} is not the model the C step in {folder} was "
            f"generated from ({folder / MODEL_FILE}); name that file as [controller] model, or "
            f"generate the step from this model: 'czmpc codegen {model_path} --out {folder}'")
    if settings is not None and settings != compiled:
        raise SettingsError(
            f"[controller] settings {settings_path} differ from the settings compiled into the "
            f"C step in {folder} ({'; '.join(_differing(compiled, settings))}); drop [controller] "
            f"settings to run the compiled ones ({folder / SETTINGS_FILE}), or generate again: "
            f"'czmpc codegen {model_path} --settings {settings_path} --out {folder}'")
    return CStepMPC(load_controller(folder), model=c_model, settings=compiled, directory=folder)


__all__ = ["C_STEP_PREFIX", "CStepMPC", "c_step_directory", "load_c_step"]
