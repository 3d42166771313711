"""Opens an MPC run: the sampling-time and candidate checks and the one switch-on rule.

`czmpc run` and the commissioning journey both open their runs here (`open_run`), so a
model reaches a plant's TRIAC by one rule (`switch_on_rule`) on its check-model verdict in
``MODEL.check.json`` (`czmpc.commissioning.check.write_check`; `read_check` compares the
model file's SHA-256, so a model changed since its check counts as unchecked):

=========================  ==========================  ==========================
verdict                    attended (``czmpc run``)    unattended (the journey)
=========================  ==========================  ==========================
``ready``                  ON                          ON
``ready with conditions``  ON                          PREDICT only
never checked or changed   ON, with a warning          PREDICT only
``not ready``              PREDICT only (``--force``:  PREDICT only
                           ON, said and logged)
=========================  ==========================  ==========================

PREDICT only: the MPC starts in PREDICT and refuses the plant's requests for ON; nothing
is written (a shadow run).

The MPC is the Python `czmpc.controller.OffsetFreeMPC`, or the step ``czmpc codegen``
wrote as C (``czmpc run --controller c:DIR``: `czmpc.runtime.c_step`), which must hold
the configuration's model (and settings, if it names any); the rule is the same.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from czmpc.controller import OffsetFreeMPC
from czmpc.errors import SettingsError
from czmpc.modes import Mode
from czmpc.runtime.c_step import CStepMPC, load_c_step
from czmpc.runtime.config import RunConfig, RunConfigError
from czmpc.runtime.loop import ControlLoop
from czmpc.runtime.step import LoopController
from czmpc.settings import MPCSettings
from czmpc.settings_file import load_settings
from sysid.atomic import file_sha256
from sysid.model import HammersteinModel
from sysid.modelfile import load_model

Verdict = Literal["ready", "ready with conditions", "not ready"]

#: Format tag of the check file written beside a model.
CHECK_FORMAT = "czmpc-model-check/1"


def check_path(model_path: str | Path) -> Path:
    """``MODEL.check.json`` beside ``MODEL.json``."""
    p = Path(model_path)
    return p.with_name(p.name.removesuffix(".json") + ".check.json")


def read_check(model_path: str | Path) -> tuple[Verdict | None, str]:
    """The stored verdict of a model file, and a sentence about it.

    Returns
    -------
    verdict, note
        ``(None, why)`` when the model was never checked, changed since, or the check
        file is unreadable; else the verdict and its reasons.
    """
    target = check_path(model_path)
    if not target.is_file():
        return None, f"{Path(model_path).name} was never checked (no {target.name})"
    try:
        doc = json.loads(target.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        return None, f"{target.name} cannot be read ({exc}); treating the model as unchecked"
    if not isinstance(doc, dict) or doc.get("format") != CHECK_FORMAT:
        return None, f"{target.name}: expected format {CHECK_FORMAT!r}; treating as unchecked"
    if doc.get("model_sha256") != file_sha256(model_path):
        return None, (f"{Path(model_path).name} changed since {target.name} was written; "
                      "check it again")
    verdict = doc.get("verdict")
    if verdict not in ("ready", "ready with conditions", "not ready"):
        return None, f"{target.name}: unknown verdict {verdict!r}; treating as unchecked"
    reasons = doc.get("reasons") or []
    note = f"check-model verdict: {verdict}" + (
        "" if not reasons else " (" + "; ".join(str(r) for r in reasons) + ")")
    return verdict, note


@dataclass(frozen=True, slots=True, kw_only=True)
class SwitchOn:
    """What the switch-on rule allows (module docstring).

    Attributes
    ----------
    allowed :
        True: the controller may switch ON and write; False: PREDICT only.
    forced :
        True when ``force`` let a ``not ready`` model switch ON.
    notes :
        What to say at the start: (logging level, text) pairs.
    """

    allowed: bool
    forced: bool
    notes: tuple[tuple[int, str], ...]


def switch_on_rule(verdict: Verdict | None, note: str, *, force: bool = False,
                   unattended: bool = False) -> SwitchOn:
    """May a model with this check-model verdict drive the plant? (module docstring's table).

    Parameters
    ----------
    verdict, note :
        As `read_check` returns them.
    force :
        An operator's override of ``not ready`` (``czmpc run --force``); attended only.
    unattended :
        No operator decides (the commissioning journey): only ``ready`` switches ON.
    """
    said = (logging.INFO, note)
    if verdict == "ready" or (verdict == "ready with conditions" and not unattended):
        return SwitchOn(allowed=True, forced=False, notes=(said,))
    if unattended:
        return SwitchOn(allowed=False, forced=False, notes=(
            (logging.WARNING, f"{note}: not 'ready', so the MPC is not switched on "
                              "unattended"),))
    if verdict is None:
        return SwitchOn(allowed=True, forced=False, notes=(
            (logging.WARNING, f"{note}; run 'czmpc check-model' before switching on"),))
    if force:
        return SwitchOn(allowed=True, forced=True, notes=(
            said, (logging.WARNING, "--force: switching ON with a model judged not ready")))
    return SwitchOn(allowed=False, forced=False, notes=(
        said, (logging.WARNING, "the model is not ready: running in PREDICT only (nothing is "
                                "written); --force overrides")))


def _same_ts(model: HammersteinModel, config: RunConfig, where: str, path: Path) -> None:
    if abs(model.ts_s - config.ts_s) > 1e-9 * config.ts_s:
        raise SettingsError(f"{where}: expected the sampling time {config.ts_s:g} s of "
                            f"plant.ts_s; {path} has {model.ts_s:g} s")


@dataclass(frozen=True, kw_only=True, eq=False)
class OpenedRun:
    """A run opened by `open_run`: the MPC built under the switch-on rule.

    Attributes
    ----------
    config :
        The run configuration.
    mpc :
        The controller of ``[controller] model`` (the Python MPC, or the generated C
        step of ``open_run``'s ``c_step``); it starts in PREDICT when
        ``switch_on.allowed`` is False.
    switch_on :
        The rule's answer.
    """

    config: RunConfig
    mpc: OffsetFreeMPC | CStepMPC
    switch_on: SwitchOn

    def loop(self, controller: LoopController | None = None, *,
             provenance: Mapping[str, object] | None = None,
             status: Callable[[str], None] | None = None) -> ControlLoop:
        """The loop that drives ``controller`` (default: the MPC) under the rule.

        Parameters
        ----------
        controller :
            A `LoopController` wrapping `mpc` (a dithered MPC), or None for the MPC.
        provenance :
            What drives the input, for the run log's meta file (a C step adds its
            directory and the SHA-256 of its C and library, `CStepMPC.provenance`).
        status :
            The live status line (`czmpc.runtime.loop.ControlLoop`).
        """
        if controller is None and isinstance(self.mpc, CStepMPC):
            provenance = {**(provenance or {}), **self.mpc.provenance()}
        loop = ControlLoop(self.config, self.mpc if controller is None else controller,
                           status=status, provenance=provenance)
        loop.allow_on = self.switch_on.allowed
        return loop


def open_run(config: RunConfig, *, force: bool = False, unattended: bool = False,
             log: logging.Logger | None = None, c_step: Path | None = None) -> OpenedRun:
    """Load the model, check it fits the config, apply the switch-on rule, build the MPC.

    Parameters
    ----------
    config :
        The run configuration (``[controller] model`` required; its settings file, or
        `MPCSettings.default_for` the model).
    force, unattended :
        As `switch_on_rule`.
    log :
        Where the rule's notes and the candidate's are said (None: this module's logger).
    c_step :
        A directory ``czmpc codegen`` wrote: its compiled step is the MPC
        (`czmpc.runtime.c_step.load_c_step`, built on demand); None: the Python MPC.

    Raises
    ------
    RunConfigError
        No ``[controller] model``.
    SettingsError
        The model's or the candidate's sampling time is not the config's; a ``c_step``
        generated from another model or with other settings than the config names.
    DesignError
        The controller refuses the model (`OffsetFreeMPC`).
    CodegenError, BuildError
        ``c_step`` is no generated directory, or cannot be built (no C compiler).
    """
    say = log or logging.getLogger(__name__)
    if config.model_path is None:
        raise RunConfigError("controller.model: missing; the MPC needs a model "
                             "(only an open-loop test, --test TEST.csv, runs without one)")
    model = load_model(config.model_path)
    _same_ts(model, config, "plant.ts_s", config.model_path)
    rule = switch_on_rule(*read_check(config.model_path), force=force, unattended=unattended)
    for level, text in rule.notes:
        say.log(level, "%s", text)
    if config.candidate_path is not None:   # checked before anything runs
        _same_ts(load_model(config.candidate_path), config, "controller.candidate",
                 config.candidate_path)
        say.info("candidate model %s in shadow (logged, compared, never driving)",
                 config.candidate_path)
    if c_step is not None:
        compiled = load_c_step(
            c_step, model=model, model_path=config.model_path, settings_path=config.settings_path,
            settings=None if config.settings_path is None else load_settings(config.settings_path,
                                                                             model))
        say.info("the MPC is the C step in %s (%s, settings %s)", c_step,
                 "float" if compiled.float32 else "double", c_step / "settings.toml")
        if not rule.allowed and compiled.mode is not Mode.PREDICT:
            compiled.request_mode(Mode.PREDICT)   # as the Python MPC's initial_mode below
        return OpenedRun(config=config, mpc=compiled, switch_on=rule)
    settings = (MPCSettings.default_for(model) if config.settings_path is None
                else load_settings(config.settings_path, model))
    if not rule.allowed:
        settings = dataclasses.replace(settings, reliability=dataclasses.replace(
            settings.reliability, initial_mode="predict"))
    return OpenedRun(config=config, mpc=OffsetFreeMPC(model, settings), switch_on=rule)


__all__ = ["CHECK_FORMAT", "OpenedRun", "SwitchOn", "Verdict", "check_path", "open_run",
           "read_check", "switch_on_rule"]
