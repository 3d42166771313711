"""Sphinx directives that write the file-format and exit-code references from the code.

Each reference is built at documentation time from the constants the validators use
(`sysid.modelfile`, `sysid.data`, `czmpc.cli._exit`, `czmpc.runtime.config`,
`czmpc.runtime.security`, `czmpc.campaigns.campaign`), so the documented keys cannot drift
from the accepted ones: a key the validator knows and this module does not describe (or
the other way round) stops the build, and ``tests/docs/test_contract_references.py`` and
``tests/docs/test_config_references.py`` check the same. Pages with a generated reference
are re-read on every build, so an incremental ``make docs`` never shows an outdated one.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from typing import Any

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.application import Sphinx
from sphinx.errors import ExtensionError
from sphinx.util.docutils import SphinxDirective

# What each key of a czmpc-model/1 file means. The set of keys must equal the validator's.
MODEL_KEYS: dict[str, str] = {
    "format": 'Always ``"czmpc-model/1"``; other formats are refused.',
    "kind": '``"hammerstein"`` (polynomial ``f``) or ``"linear"`` (``input_poly`` has one coefficient).',
    "linear_block": '``"armax"``, ``"oe"`` (stored with ``C = A``) or ``"arx"``.',
    "ts_s": "Sampling time [s].",
    "operating_point": 'Object ``{"triac_pct": s_nom, "power_kw": P_nom}``: deviations are from it.',
    "A": "``A(q)`` in ascending powers of q^-1, ``A[0] = 1``; roots inside the unit circle.",
    "B": "``B(q)``; its leading zeros are the delay; its first non-zero coefficient is 1.",
    "C": "``C(q)``, ``C[0] = 1``; roots inside the unit circle.",
    "input_poly": "``[p_1, ..., p_n]``: ``f(ds) = sum_i p_i ds^i`` [kW per %^i], no constant term.",
    "noise_std_kw": "Standard deviation of the innovation ``e`` [kW].",
    "input_range_pct": "``[s_min, s_max]``: the input range seen in the identification data [%].",
    "criteria": 'Object ``{"V": ..., "W": ...}``: ballistic and one-step mean squared errors [kW^2].',
    "units": 'Object ``{"input": "%", "output": "kW"}``: what the input and output measure '
             "(absent: % and kW); the key names keep their roles on other rigs.",
    "covariance": "Full parameter covariance (square, symmetric), in the order of "
                  "``provenance.parameter_names``; used to sample plants for Monte Carlo studies.",
    "provenance": "Object: where the model came from (keys below); unknown keys are kept.",
}

# What each provenance entry means. The writer's keys must equal these.
PROVENANCE_KEYS: dict[str, str] = {
    "software": "Name and version of the software that wrote the file (``czmpc X.Y.Z``).",
    "data_file": "Name of the identification data file.",
    "data_sha256": "SHA-256 of that file's bytes.",
    "preprocessing": "Every change made to the data before fitting, in order (objects with ``what``).",
    "method": "How the model was fitted (for example ``pem-one-step``).",
    "created_utc": "ISO-8601 creation time.",
}

# What each column of the data file holds. The set must equal `sysid.data.CSV_COLUMNS`.
DATA_COLUMNS: dict[str, str] = {
    "time_s": "Time of the sample [s], increasing, uniformly sampled.",
    "triac_pct": "The input: TRIAC signal [%] (another unit with ``input_unit``).",
    "power_kw": "The output: measured heater power [kW] (another unit with ``output_unit``).",
}

# What each key of a run config's [plant.security] table means. Must equal SECURITY_KEYS.
PLANT_SECURITY_KEYS: dict[str, str] = {
    "policy": 'OPC UA security policy: one of the secure policies below, or ``"None"`` (loopback only).',
    "mode": 'Message security mode: ``"SignAndEncrypt"`` (default) or ``"Sign"``.',
    "certificate": "czmpc's application instance certificate (DER file; ``czmpc pki create`` makes one).",
    "private_key": "Its private key (PEM file), readable by its owner only (mode 600).",
    "server_certificate": "The plant server's certificate (DER), pinned: any other server is refused.",
    "username": "OPC UA user name; absent for an anonymous session.",
    "password_env": "Name of the environment variable holding the password (never the password itself).",
}

# Every key of a run config (`czmpc run CONFIG.toml`), as ``table.key``: (type, default,
# unit, meaning). A default of "required" means the validator refuses a file without it.
# The set of keys must equal the validator's (`czmpc.runtime.config._TABLES`).
RUN_CONFIG_KEYS: dict[str, tuple[str, str, str, str]] = {
    "plant.endpoint": ("string", "required", "-",
                       "OPC UA endpoint of the plant's server, ``opc.tcp://HOST:PORT/PATH``."),
    "plant.ts_s": ("number > 0", "required", "s",
                   "Sampling time of the loop; must equal the model's ``ts_s``."),
    "plant.time_scale": ("number in [1, 1000]", "1", "-",
                         "Plant samples per ``ts_s`` of wall time; > 1 only for simulated plants "
                         "(``czmpc plant serve --time-scale``). The loop period is "
                         "``ts_s / time_scale``."),
    "plant.max_sample_age_s": ("number > 0", "2 ts_s", "s",
                               "A power sample whose source timestamp (or, from a server that "
                               "sends none, server timestamp) is older than this is a missing "
                               "sample."),
    "plant.connect_timeout_s": ("number > 0", "2", "s",
                                "Deadline of each OPC UA call, disconnect included: a call that "
                                "misses it is abandoned and its socket closed, so no step lasts "
                                "longer than one period plus this."),
    "plant.align_to_plant": ("true or false", "true", "-",
                             "Keep the reads just after the plant publishes its sample (from "
                             "the power's source timestamps, on a clock synchronised with "
                             "the controller's), so that each write lands before the plant's "
                             "next step and the input delay does not jitter by a sample "
                             "(``czmpc.runtime.alignment``)."),
    "plant.reject_repeated_samples": ("true or false", "true", "-",
                                      "A power sample whose source timestamp is not later "
                                      "than the previous read's (the plant's step was late, "
                                      "so the previous sample was read again) is a missing "
                                      "sample. Set false for a server that refreshes the "
                                      "source timestamp only when the value changes."),
    "plant.max_refused_writes": ("whole number >= 1", "5", "samples",
                                 "Command writes refused in a row (a Bad code that may clear, "
                                 "e.g. ``BadResourceUnavailable``) that stop the run through "
                                 "the safe action, exit 1. A code that cannot clear by itself "
                                 "(``BadTypeMismatch``, ``BadNotWritable``, "
                                 "``BadUserAccessDenied``, ...) stops it at once, exit 2."),
    "plant.security": ("table", "none (loopback only)", "-",
                       "Channel security: see :doc:`plant_security`."),
    "nodes.power_kw": ("node", "required", "kW", "Node id of the measured heater power (read; "
                       "any numeric type)."),
    "nodes.triac_pct": ("node", "required", "%",
                        "Node id of the TRIAC command (written as the node's own type: Float, "
                        "Double or an integer, rounded and range-checked). A table "
                        "``{ id = '...', raw = [0, 27648], value = [0.0, 100.0] }`` scales a "
                        "raw integer tag both ways; so may every numeric node."),
    "nodes.applied_triac_pct": ("node", "none", "%",
                                "Node id of the input the plant applies (read; the bumpless start "
                                "begins from it)."),
    "nodes.setpoint_kw": ("node", "none", "kW",
                          "Node id of a setpoint set at the plant (read every step)."),
    "nodes.heartbeat": ("string", "none", "-",
                        "Node id of a counter written every step (the plant's watchdog): it "
                        "goes on from the value the node holds and wraps to 0 past its "
                        "integer type's top; a Boolean heartbeat toggles."),
    "nodes.mode": ("string", "none", "-",
                   "Node id of the plant's mode (read): text ``OFF``/``PREDICT``/``ON``, an "
                   "integer 0/1/2, or a Boolean (true: ON)."),
    "nodes.model_health": ("node", "none", "-",
                           "Node id to which the model-health score (`czmpc.health`) is "
                           "written every step."),
    "logging.syslog": ("string", "none", "-",
                       "Also send the run's log lines to syslog: a socket path (``/dev/log``) "
                       "or ``HOST:PORT`` (UDP)."),
    "logging.facility": ("string", "daemon", "-",
                         "Syslog facility: ``user``, ``daemon`` or ``local0`` .. ``local7``."),
    "nodes.owner": ("string", "none", "-",
                    "Node id of a String tag where czmpc writes its identity every step (a "
                    "lease) and reads it back: a run refuses to start (exit 2) while another "
                    "controller's lease is fresh, and stops writing (exit 1) when another "
                    "writer overwrites it."),
    "nodes.status": ("string", "none", "-",
                     "Node id where the controller status is written every step, for the "
                     "HMI: text ``GOOD``/``PREDICTED``/``CLAMPED``/``HELD``/``SHED`` (and "
                     "``LEAD_IN``/``TEST`` in a test), or on an INT tag 0..4 (5, 6 in a test)."),
    "nodes.mode_in_effect": ("string", "none", "-",
                             "Node id where the mode in effect is written every step: text "
                             "``OFF``/``PREDICT``/``ON``, or 0/1/2 on an INT tag."),
    "nodes.stale_alarm": ("string", "none", "-",
                          "Node id where the stale-model alarm is written every step (BOOL, "
                          "or 0/1 on an INT tag); an HMI alarm can trigger on it."),
    "nodes.predicted_power_kw": ("node", "none", "kW",
                                 "Node id where the model's prediction of the next sample's "
                                 "power is written every step (trend it beside the measured)."),
    "nodes.target_triac_pct": ("node", "none", "%",
                               "Node id where the MPC's steady-state target input is written "
                               "every step."),
    "nodes.watchdog": ("string", "none", "-",
                       "Node id of czmpc's own counter, written every step like the heartbeat "
                       "(goes on from the node's value, wraps within its type), for an HMI "
                       "that shows whether the controller is alive."),
    "nodes.setpoint_preview_kw": ("node", "none", "kW",
                                  "Node id of a one-dimensional numeric array (OPC UA Double[] "
                                  "or Float[]) that the DCS rewrites every sample with the "
                                  "setpoints of the coming samples, element 0 the next sample. "
                                  "Read every step and given to the MPC (cut to "
                                  "``run.setpoint_preview_s`` when that is set, else all of "
                                  "it); Bad, Uncertain or older than "
                                  "``plant.max_sample_age_s``: no preview that step, said in "
                                  "the event column. The form for a recipe the DCS owns; not "
                                  "with ``run.schedule``."),
    "nodes.grid_voltage_factor": ("node", "none", "-",
                                  "Node id of the measured grid voltage relative to nominal "
                                  "over the last sample (e.g. 0.95 for a 5 % sag), refreshed "
                                  "every sample. Judged as the power is (Bad, Uncertain or "
                                  "stale: not usable); the MPC then takes the nominal voltage "
                                  "and logs ``voltage_verdict`` ``missing``."),
    "controller.model": ("string (file)", "required", "-",
                         "Model file (:doc:`model_file`) the controller is built from. An "
                         "open-loop test (``czmpc run --test``) may leave out the whole "
                         "``[controller]`` table."),
    "controller.settings": ("string (file)", "none (defaults from the model)", "-",
                            "MPC settings file (:doc:`settings_file`)."),
    "controller.candidate": ("string (file)", "none", "-",
                             "a candidate model file run in shadow beside the active model: "
                             "its one-step prediction and model-health figure are logged "
                             "(``candidate_predicted_kw``, ``candidate_health``, "
                             "``candidate_stale_alarm``) and its RMS one-step error is "
                             "compared with the active model's at the end; it never drives "
                             "the TRIAC."),
    "run.duration_s": ("number > 0", "none (until stopped)", "s",
                       "Plant time to run (``--duration-s`` overrides it)."),
    "run.setpoint_kw": ("number", "none", "kW",
                        "A fixed setpoint. One of ``run.setpoint_kw``, ``run.schedule`` or "
                        "``nodes.setpoint_kw`` is required; not both run keys."),
    "run.schedule": ("string (file)", "none", "-",
                     "Recipe CSV with header ``time_s,setpoint_kw`` [s, kW], increasing times: "
                     "the setpoint from each time of the run on."),
    "run.setpoint_preview_s": ("number >= 0", "0", "s",
                               "How far ahead the MPC is told the setpoint: each step passes "
                               "the setpoints of the next ``round(setpoint_preview_s / "
                               "ts_s)`` samples, from ``run.schedule`` on the run's clock "
                               "or from ``nodes.setpoint_preview_kw``, so the input starts "
                               "moving before a recipe step. 0: no preview from a schedule, "
                               "the whole array from the node. A value > 0 needs one of "
                               "them; 0 < value < ts_s / 2 is refused (it would round to no "
                               "preview). The scenario key of the same name means the same."),
    "run.log": ("string (file or directory/)", "run.csv", "-",
                "Step log, one CSV row per step, flushed per row (``--log`` overrides it). A "
                "start never overwrites an earlier run's log: it refuses unless ``--append`` "
                "or ``--replace-log``. A directory (``\"logs/\"``) gets one timestamped file "
                "per run, which a service that restarts needs."),
    "run.rotate": ("string", "none", "-",
                   "``daily``: a new part of the log at midnight UTC, each part with its meta "
                   "file; readers take the parts as one log."),
    "run.rotate_mb": ("number > 0", "none", "MB",
                      "A new part of the log when the current one reaches this size."),
    "safety.action": ('``"hold"`` or ``"ramp"``', "hold", "-",
                      "On SIGINT/SIGTERM: hold the last command, or ramp to "
                      "``safety.safe_triac_pct`` at the rate limit."),
    "safety.safe_triac_pct": ("number in [0, 100]", "none (required for ramp and for a test)",
                              "%", "TRIAC input of the ramp, and where an aborted test moves to."),
    "test.power_band_kw": ("[low, high] numbers, low < high", "required in [test]", "kW",
                           "Band the measured power must stay in during ``czmpc run --test`` "
                           "or ``--dither-pct``; leaving it aborts the test (exit 1)."),
    "test.max_bad_quality_s": ("number > 0", "10", "s",
                               "Longest stretch of plant time without a usable sample (Bad, "
                               "Uncertain, stale, disconnected) a test tolerates."),
}

# The keys of a campaign spec (`czmpc campaign run SPEC.toml`): (type, default, meaning).
# Each set must equal the one the validator accepts (`czmpc.campaigns.campaign`).
CAMPAIGN_KEYS: dict[str, tuple[str, str, str]] = {
    "name": ("string", "the file's stem", "Name of the campaign."),
    "description": ("string", "empty", "What the campaign or suite is for."),
    "model": ("string (file)", "cz_heater_model.json",
              "Model of every controller that names none (and of its plants): a file next "
              "to the spec or the name of a shipped model."),
    "seeds": ("integer >= 1, or list of integers >= 0", "1",
              "Seed indices ``0..seeds-1`` per (controller, plant, scenario), keyed by the "
              "run; or a list of seeds used as they are (``[7]``: one seed for every run)."),
    "base_seed": ("integer >= 0", "0",
                  "Entropy of every run's `numpy.random.SeedSequence`; a run's seed depends "
                  "on it and on the run's identity only."),
    "noise": ("boolean", "true", "Plant noise on or off."),
    "time_scale": ("number in (0, 1]", "1", "Shortens every scenario to this fraction of its "
                   "length (``Scenario.shortened``)."),
    "linear_model": ("string (file)", "cz_heater_armax_model.json",
                     "Model of the ``linear-mpc`` preset (a linear ARMAX model: the linear "
                     "MPC of the tracking benchmark)."),
    "metrics": ("list of strings", "none (a suite: the default metrics)",
                "A regression suite's held metrics (``czmpc regress``): row columns such as "
                "``iae_kw_s``."),
    "tolerances": ("table", "none (derived)",
                   "A regression suite's tolerances: metric = absolute value or ``\"2%\"``."),
    "scenarios": ("list of strings", "required",
                  "Scenarios: shipped names (``staircase``, ``voltage_sag``, ...) or TOML files."),
    "controllers": ("array of tables", "required", "``[[controllers]]``: keys below."),
    "plants": ("array of tables", "required", "``[[plants]]``: keys below."),
}
CAMPAIGN_CONTROLLER_KEYS: dict[str, tuple[str, str, str]] = {
    "name": ("string without ``|`` or ``/``", "the preset",
             "Name of the controller in the rows; unique."),
    "preset": ("string", "``mpc``",
               "``mpc``, ``pi``, ``pi-scheduled``, ``pi-table``, ``linear-mpc``, ``nmpc``, "
               "``open-loop`` (or ``pi_gs``, ``pi_table``, ``linear_mpc``, ``open_loop``) or "
               "``c_step`` (the MPC step as C, from the key directory), each built by the one "
               "controller builder of the campaign engine."),
    "kind": ("string", "``mpc``", "The same as ``preset`` (the word regression suites use)."),
    "model": ("string (file)", "the spec's ``model``", "This controller's model (and its plants')."),
    "linear_model": ("string (file)", "the spec's ``linear_model``", "``linear-mpc`` only."),
    "settings": ("string (file)", "none (defaults from the model)",
                 "MPC settings file (:doc:`settings_file`) for ``mpc``, ``linear-mpc`` and "
                 "``nmpc``; its SHA-256 is part of the spec's identity."),
    "directory": ("string (directory)", "required for ``c_step``",
                  "``c_step`` only: a directory ``czmpc codegen`` wrote, built on demand with "
                  "the system's C compiler. Its ``model.json`` and ``settings.toml`` are the "
                  "controller's model (and its plants') and settings, so ``model`` and "
                  "``settings`` are refused; a scenario whose limits would change the "
                  "compiled settings is refused too (generate with those settings)."),
}
CAMPAIGN_PLANT_KEYS: dict[str, tuple[str, str, str]] = {
    "kind": ("string", "required",
             "``model`` (the model's own equation), ``heater`` (the virtual heater), "
             "``thermal`` (the furnace zone `sim.thermal_plant`, for a model identified "
             "from it), "
             "``sampled`` (plants drawn from the model's parameter covariance; its keys "
             "in the next table) or ``perturbed`` (the model perturbed; the three factor "
             "keys below, only for this kind)."),
    "gain_factors": ("list of numbers > 0", "[1.0]", "Static gain factors."),
    "time_constant_factors": ("list of numbers > 0", "[1.0]", "Slow time-constant factors."),
    "extra_delays_steps": ("list of whole numbers >= 0", "[0]",
                           "Extra input delays [samples]. One plant per element of the "
                           "product of the three lists."),
}
#: Keys of a ``kind = "sampled"`` plant table (`czmpc.campaigns.sampling`).
CAMPAIGN_SAMPLED_KEYS: dict[str, tuple[str, str, str]] = {
    "kind": ("string", "required", "``sampled``."),
    "n": ("integer >= 1", "required",
          "Number of plants drawn from N(theta, covariance) of the model file (its standard "
          "errors, with a warning, when it has no covariance); unstable or sign-changed "
          "draws are rejected and counted."),
    "first": ("integer >= 0", "0", "Number of the first plant: plants ``first .. first+n-1`` "
              "(to extend a study later with the same draws)."),
}


def _check_same(documented: Iterable[str], accepted: Iterable[str], what: str) -> None:
    documented, accepted = set(documented), set(accepted)
    if documented != accepted:
        raise ExtensionError(
            f"{what}: documented {sorted(documented)} but the code accepts {sorted(accepted)}; "
            f"update docs/_ext/czmpc_contracts.py"
        )


def model_file_rst() -> str:
    """The model-file reference: the keys, whether each is required, and a real example."""
    from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
    from sysid import modelfile

    _check_same(MODEL_KEYS, modelfile._TOP_KEYS, "model-file keys")
    example = modelfile.model_to_dict(modelfile.load_model(shipped_path(HAMMERSTEIN_MODEL_JSON)))
    _check_same(PROVENANCE_KEYS, [k for k in example["provenance"] if k in PROVENANCE_KEYS
                                  or k in modelfile._PROVENANCE_KEYS or k == "software"],
                "model-file provenance keys")
    rows = [(f"``{key}``", "yes" if key in modelfile._REQUIRED else "no", text)
            for key, text in sorted(MODEL_KEYS.items(), key=lambda kv: list(MODEL_KEYS).index(kv[0]))]
    prov = [(f"``{key}``", text) for key, text in PROVENANCE_KEYS.items()]
    example["provenance"]["preprocessing"] = example["provenance"]["preprocessing"][:1] + (
        ["..."] if len(example["provenance"]["preprocessing"]) > 1 else [])
    lines = [f"Format tag: ``{modelfile.FORMAT}``. Keys other than these are ignored: optional "
             "fields may be added to this format; a field that changes the meaning of an "
             "existing one needs a new format.", ""]
    lines += _table(("key", "required", "meaning"), rows)
    lines += ["", "Provenance entries:", ""]
    lines += _table(("entry", "meaning"), prov)
    lines += ["", "The shipped Hammerstein model (``czmpc.data/cz_heater_model.json``) as written "
              "by this version (long lists shortened):", "", ".. code-block:: json", ""]
    lines += ["   " + line for line in json.dumps(example, indent=2).splitlines()]
    return "\n".join(lines)


def data_file_rst() -> str:
    """The data-file reference: the columns and the reader's limits."""
    from sysid import data

    _check_same(DATA_COLUMNS, data.CSV_COLUMNS, "data-file columns")
    lines = [f"Header, in this order: ``{','.join(data.CSV_COLUMNS)}``; one row per sample.", ""]
    lines += _table(("column", "meaning"), [(f"``{c}``", DATA_COLUMNS[c]) for c in data.CSV_COLUMNS])
    lines += ["",
              f"- At least {data.MIN_SAMPLES} samples.",
              f"- Uniform sampling: every interval within {data.DEFAULT_SAMPLING_RTOL:.0%} of the "
              "nominal one by default (``sampling_rtol``, ``--sampling-rtol``).",
              "- Other column names are read through an explicit mapping (``columns=``, "
              "``--columns``) that must name each of the columns above exactly once.",
              "- A file that breaks the contract raises `sysid.DataFileError` naming the file, "
              "line and column (``czmpc``: exit code 2)."]
    return "\n".join(lines)


def exit_codes_rst() -> str:
    """Exit codes and which errors map to them."""
    from czmpc.cli._exit import BAD_INPUT_ERRORS, MEANING, ExitCode

    _check_same([c.name for c in MEANING], [c.name for c in ExitCode], "exit codes")
    rows = [(str(int(c)), f"``{c.name}``", MEANING[c]) for c in ExitCode]
    lines = _table(("code", "name", "meaning"), rows)
    lines += ["", "Errors reported as ``czmpc: error: <message>`` on stderr with exit code "
              f"{int(ExitCode.BAD_INPUT)}, without a traceback unless ``--debug`` is given "
              "(each with its subclasses):", ""]
    for base in BAD_INPUT_ERRORS:
        lines += _class_tree(base, 0)
    return "\n".join(lines)


def _class_tree(cls: type, depth: int) -> list[str]:
    name = cls.__name__ if cls.__module__ == "builtins" else f"{_public_module(cls)}.{cls.__name__}"
    doc = (cls.__doc__ or "").strip().splitlines()[0] if cls.__module__ != "builtins" else (
        "operating-system errors: a missing file, no permission, a full disk")
    out = ["", "  " * depth + f"- `{name}`: {doc}"]
    if cls.__module__ == "builtins":
        return out
    subclasses: list[type] = sorted(cls.__subclasses__(), key=lambda c: c.__name__)
    for sub in subclasses:
        if sub.__module__.split(".")[0] in ("sysid", "sim", "czmpc"):
            out += _class_tree(sub, depth + 1)
    return out


def _public_module(cls: type) -> str:
    package = cls.__module__.split(".")[0]
    module = __import__(package)
    return package if cls.__name__ in getattr(module, "__all__", ()) else cls.__module__


def plant_security_rst() -> str:
    """The ``[plant.security]`` table of a run config, from the validator's constants."""
    from czmpc.runtime.security import MODES, SECURE_POLICIES, SECURITY_KEYS

    _check_same(PLANT_SECURITY_KEYS, SECURITY_KEYS, "[plant.security] keys")
    lines = _table(("key", "meaning"), [(f"``{k}``", PLANT_SECURITY_KEYS[k]) for k in SECURITY_KEYS])
    lines += ["",
              "- Secure policies: " + ", ".join(f"``{p}``" for p in SECURE_POLICIES) + ".",
              "- Modes: " + ", ".join(f"``{m}``" for m in MODES) + ".",
              "- Without the table only a loopback endpoint is accepted; a ``password`` key, an "
              "unknown key, a missing file or a private key that others can read are refused "
              "before any connection (`czmpc.SettingsError`, exit code 2).",
              "- Relative file names are taken from the run config's directory."]
    return "\n".join(lines)


def run_config_rst() -> str:
    """The run-config reference: every table and key, from the validator's key table."""
    from czmpc.runtime import config

    accepted = [f"{table}.{key}" for table, keys in config._TABLES.items() for key in keys]
    _check_same(RUN_CONFIG_KEYS, accepted, "run-config keys")
    lines = [f"Tables: {', '.join(f'``[{t}]``' for t in config._TABLES)}. Each key below; an "
             "unknown table or key, a wrong type or a value out of range is refused with "
             "`czmpc.runtime.config.RunConfigError` naming it (``czmpc run``: exit code 2).", ""]
    for table in config._TABLES:
        lines += ["", f"``[{table}]``", "", *_table(
            ("key", "type", "default", "unit", "meaning"),
            [(f"``{key}``", *RUN_CONFIG_KEYS[f"{table}.{key}"]) for key in config._TABLES[table]]),
            ""]
    return "\n".join(lines)


def accepted_campaign_keys() -> dict[str, list[str]]:
    """The keys the campaign validator accepts, top level and per table, read from its errors.

    `czmpc.campaigns.campaign.spec_from_dict` names every accepted key when it refuses an
    unknown one; this asks it with one unknown key at each level.
    """
    import ast

    from czmpc.campaigns.campaign import CampaignError, spec_from_dict

    probe = "zz_undocumented"
    base: dict[str, Any] = {"scenarios": ["staircase"], "controllers": [{"preset": "mpc"}],
                            "plants": [{"kind": "model"}]}
    docs = {
        "top": {**base, probe: 1},
        "controllers": {**base, "controllers": [{"preset": "mpc", probe: 1}]},
        "plants": {**base, "plants": [{"kind": "perturbed", probe: 1}]},
        "plants-other": {**base, "plants": [{"kind": "heater", probe: 1}]},
        "plants-sampled": {**base, "plants": [{"kind": "sampled", "n": 1, probe: 1}]},
    }
    out: dict[str, list[str]] = {}
    for level, doc in docs.items():
        try:
            spec_from_dict(doc)
        except CampaignError as exc:
            text = str(exc)
            if probe not in text or "expected some of " not in text:
                raise ExtensionError(f"campaign spec: cannot read the accepted keys of {level} "
                                     f"from {text!r}; update docs/_ext/czmpc_contracts.py") from exc
            out[level] = ast.literal_eval(text.rsplit("expected some of ", 1)[1].strip())
        else:
            raise ExtensionError(f"campaign spec: an unknown key in {level} was accepted")
    return out


def campaign_spec_rst() -> str:
    """The campaign-spec reference: top-level keys, controllers and plants."""
    from czmpc.campaigns.campaign import PLANT_KINDS, PRESETS

    accepted = accepted_campaign_keys()
    _check_same(CAMPAIGN_KEYS, accepted["top"], "campaign-spec keys")
    _check_same(CAMPAIGN_CONTROLLER_KEYS, accepted["controllers"], "[[controllers]] keys")
    _check_same(CAMPAIGN_PLANT_KEYS, accepted["plants"], "[[plants]] keys")
    _check_same(["kind"], accepted["plants-other"], "[[plants]] keys of model/heater plants")
    _check_same(CAMPAIGN_SAMPLED_KEYS, accepted["plants-sampled"], "[[plants]] keys of sampled plants")
    _check_same([p for p in CAMPAIGN_CONTROLLER_KEYS["preset"][2].split("``")[1::2]], PRESETS,
                "controller presets")
    _check_same([k for k in CAMPAIGN_PLANT_KEYS["kind"][2].split("``")[1::2]
                 if k in PLANT_KINDS or k.isalpha()], PLANT_KINDS, "plant kinds")
    header = ("key", "type", "default", "meaning")
    lines = ["Top-level keys:", ""]
    lines += _table(header, [(f"``{k}``", *v) for k, v in CAMPAIGN_KEYS.items()])
    lines += ["", "``[[controllers]]`` (one table per controller):", ""]
    lines += _table(header, [(f"``{k}``", *v) for k, v in CAMPAIGN_CONTROLLER_KEYS.items()])
    lines += ["", "``[[plants]]`` (one table per plant or grid of plants):", ""]
    lines += _table(header, [(f"``{k}``", *v) for k, v in CAMPAIGN_PLANT_KEYS.items()])
    lines += ["", '``[[plants]]`` with ``kind = "sampled"``:', ""]
    lines += _table(header, [(f"``{k}``", *v) for k, v in CAMPAIGN_SAMPLED_KEYS.items()])
    lines += ["",
              "- The runs are controllers x plants x scenarios x seed indices.",
              "- Unknown or invalid keys are refused with "
              "`czmpc.campaigns.campaign.CampaignError` naming the key and the value "
              "(``czmpc campaign``: exit code 2).",
              "- Relative file names are taken from the spec's directory."]
    return "\n".join(lines)

def accepted_settings_keys() -> dict[str, list[str]]:
    """The keys the settings-file reader accepts, top level and per table, from its errors.

    `czmpc.settings_file.settings_from_dict` lists the valid keys when it refuses an
    unknown one; this asks it with one unknown key at each level.
    """
    from czmpc.errors import SettingsError
    from czmpc.settings_file import PRESET_KEY, TABLES, settings_from_dict
    from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
    from sysid.modelfile import load_model

    model = load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))
    probe = "zz_undocumented"
    out: dict[str, list[str]] = {}
    for level in ("", *TABLES):
        doc: dict[str, Any] = {probe: 1} if not level else {level: {probe: 1}}
        try:
            settings_from_dict(doc, model)
        except SettingsError as exc:
            text = str(exc)
            if probe not in text or "valid keys: " not in text:
                raise ExtensionError(f"settings file: cannot read the accepted keys of "
                                     f"[{level}] from {text!r}; update docs/_ext/czmpc_contracts.py"
                                     ) from exc
            keys = text.rsplit("valid keys: ", 1)[1].split(", ")
            out[level] = [PRESET_KEY, *keys, *TABLES] if not level else keys
        else:
            raise ExtensionError(f"settings file: an unknown key in [{level}] was accepted")
    return out


def settings_keys() -> dict[str, list[tuple[str, str, str, str, str]]]:
    """Per table ("" = top level): (key, type, default, unit, meaning) of every setting.

    Types and meanings come from the settings dataclasses and their numpy docstrings
    (`czmpc.settings_file.field_docs`); defaults are those of the ``default`` preset for
    the shipped model. Raises ExtensionError when a key has no documented meaning or the
    keys differ from those the reader accepts.
    """
    import dataclasses
    import re
    from typing import get_args

    from czmpc import settings_file as sf
    from czmpc.settings import MPCSettings, PresetName
    from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
    from sysid.modelfile import load_model

    model = load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))
    defaults, plain = MPCSettings.default_for(model), MPCSettings()
    out: dict[str, list[tuple[str, str, str, str, str]]] = {"": [(
        f"``{sf.PRESET_KEY}``", "one of " + ", ".join(f"``{p}``" for p in get_args(PresetName)),
        "default", "-", "The preset the file starts from: every key left out takes its value.")]}
    for level, cls in (("", MPCSettings), *sf.TABLES.items()):
        obj, ref = ((defaults, plain) if not level
                    else (getattr(defaults, level), getattr(plain, level)))
        docs = sf.field_docs(cls)
        rows = out.setdefault(level, [])
        for field in dataclasses.fields(cls):
            if field.name in sf.TABLES:
                continue
            meaning = docs.get(field.name, "").replace("None", f'``"{sf.OFF}"``')
            if not meaning:
                raise ExtensionError(f"settings file: {cls.__name__}.{field.name} has no "
                                     "description in its numpy docstring")
            base, optional, choices = sf._field_kind(cls, field.name)
            kind = ("one of " + ", ".join(f"``{c}``" for c in choices) if choices
                    else {bool: "boolean", int: "integer", float: "number"}.get(base, base.__name__))
            if optional:
                kind += f' or ``"{sf.OFF}"``'
            value = sf._toml_value(getattr(obj, field.name))
            if getattr(obj, field.name) != getattr(ref, field.name):
                value += " (from the model)"
            unit = re.search(r"\[([^\]]+)\]", meaning)
            rows.append((f"``{field.name}``", kind, value.replace('"', ""),
                         unit.group(1) if unit else "-", meaning + "."))
    accepted = accepted_settings_keys()
    for level, rows in out.items():
        documented = [r[0].strip("`") for r in rows]
        if not level:
            documented += list(sf.TABLES)
        _check_same(documented, accepted[level], f"settings-file keys of [{level or 'top'}]")
    return out


def settings_file_rst() -> str:
    """The settings-file reference: every key of every table, from the settings classes."""
    from czmpc.settings_file import TABLES

    keys = settings_keys()
    lines = ["Top-level keys (`czmpc.MPCSettings`):", ""]
    lines += _table(("key", "type", "default", "unit", "meaning"), keys[""])
    for name, cls in TABLES.items():
        lines += ["", f"``[{name}]`` (`czmpc.settings.{cls.__name__}`):", ""]
        lines += _table(("key", "type", "default", "unit", "meaning"), keys[name])
    return "\n".join(lines)

def commands_rst() -> str:
    """One row per ``czmpc`` sub-command with its task and one-line help, as ``czmpc --help``
    groups them (`czmpc.cli.command_groups`)."""
    from czmpc.cli import build_parser, command_groups

    parser = build_parser()
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    choices: list[Any] = getattr(sub, "_choices_actions")  # noqa: B009 - argparse keeps no public list
    helps = {choice.dest: choice.help or "" for choice in choices}
    rows = [(title.split(":")[0], f"``czmpc {name}``", helps[name])
            for title, names in command_groups(list(helps)).items() for name in names]
    return "\n".join(_table(("task", "command", "what it does"), rows))


def _table(header: tuple[str, ...], rows: Iterable[tuple[str, ...]]) -> list[str]:
    lines = [".. list-table::", "   :header-rows: 1", ""]
    for row in (header, *rows):
        cells = [r"\-" if cell == "-" else cell for cell in row]   # a lone "-" is a list
        lines.append("   * - " + cells[0])
        lines += [f"     - {cell}" for cell in cells[1:]]
    return lines


_GENERATORS: Mapping[str, Any] = {
    "model-file": model_file_rst,
    "data-file": data_file_rst,
    "exit-codes": exit_codes_rst,
    "commands": commands_rst,
    "plant-security": plant_security_rst,
    "run-config": run_config_rst,
    "campaign-spec": campaign_spec_rst,
    "settings-file": settings_file_rst,
}


class ContractDirective(SphinxDirective):
    """``.. czmpc-contract:: NAME`` inserts the generated reference NAME."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        name = self.arguments[0]
        if name not in _GENERATORS:
            raise self.error(f"unknown reference {name!r}; one of {sorted(_GENERATORS)}")
        docs: set[str] = getattr(self.env, "czmpc_contract_docs", set())
        docs.add(self.env.docname)
        self.env.czmpc_contract_docs = docs  # type: ignore[attr-defined]
        container = nodes.container()
        text = _GENERATORS[name]()
        self.state.nested_parse(StringList(text.splitlines(), source=f"<czmpc-contract {name}>"),
                                self.content_offset, container)
        return list(container.children)


def _always_reread(app: Sphinx, env: Any, added: set[str], changed: set[str],
                   removed: set[str]) -> list[str]:
    """Re-read the pages with a generated reference on every build: their text comes
    from the code, which Sphinx does not watch, so an incremental build would keep an
    outdated reference."""
    return sorted(getattr(env, "czmpc_contract_docs", set()) - removed)


def _merge(app: Sphinx, env: Any, docnames: set[str], other: Any) -> None:
    env.czmpc_contract_docs = (getattr(env, "czmpc_contract_docs", set())
                               | getattr(other, "czmpc_contract_docs", set()))


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("czmpc-contract", ContractDirective)
    app.connect("env-get-outdated", _always_reread)
    app.connect("env-merge-info", _merge)
    return {"version": "1", "parallel_read_safe": True}
