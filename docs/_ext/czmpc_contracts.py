"""Sphinx directives that write the file-format and exit-code references from the code.

Each reference is built at documentation time from the constants the validators use
(`sysid.modelfile`, `sysid.data`, `czmpc.cli._exit`), so the documented keys cannot drift
from the accepted ones: a key the validator knows and this module does not describe (or
the other way round) stops the build, and ``tests/test_docs_contracts.py`` checks the same.
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
    lines = [f"Format tag: ``{modelfile.FORMAT}``. Keys other than these are refused.", ""]
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
    for sub in sorted(cls.__subclasses__(), key=lambda c: c.__name__):
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


def commands_rst() -> str:
    """One row per ``czmpc`` sub-command with its one-line help."""
    from czmpc.cli import build_parser

    parser = build_parser()
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    rows = [(f"``czmpc {choice.dest}``", choice.help or "") for choice in sub._choices_actions]
    return "\n".join(_table(("command", "what it does"), rows))


def _table(header: tuple[str, ...], rows: Iterable[tuple[str, ...]]) -> list[str]:
    lines = [".. list-table::", "   :header-rows: 1", ""]
    for row in (header, *rows):
        lines.append("   * - " + row[0])
        lines += [f"     - {cell}" for cell in row[1:]]
    return lines


_GENERATORS: Mapping[str, Any] = {
    "model-file": model_file_rst,
    "data-file": data_file_rst,
    "exit-codes": exit_codes_rst,
    "commands": commands_rst,
    "plant-security": plant_security_rst,
}


class ContractDirective(SphinxDirective):
    """``.. czmpc-contract:: NAME`` inserts the generated reference NAME."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        name = self.arguments[0]
        if name not in _GENERATORS:
            raise self.error(f"unknown reference {name!r}; one of {sorted(_GENERATORS)}")
        container = nodes.container()
        text = _GENERATORS[name]()
        self.state.nested_parse(StringList(text.splitlines(), source=f"<czmpc-contract {name}>"),
                                self.content_offset, container)
        return list(container.children)


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("czmpc-contract", ContractDirective)
    return {"version": "1", "parallel_read_safe": True}
