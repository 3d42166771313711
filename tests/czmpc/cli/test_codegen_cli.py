"""``czmpc codegen`` as a user runs it: generate, build with make, try the example."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from czmpc.cli import main
from czmpc.codegen.build import find_tools
from czmpc.codegen.errors import BuildError
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

MODEL = shipped_path(HAMMERSTEIN_MODEL_JSON)


def test_generate_build_and_try_the_example(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    try:
        find_tools()
    except BuildError as exc:   # pragma: no cover - CI has cc and make
        pytest.skip(str(exc))
    out = tmp_path / "step"
    assert main(["codegen", str(MODEL), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"{out / 'czmpc_step.c'}" in printed and f"{out / 'osqp'}" in printed
    assert f"make -C {out}" in printed
    subprocess.run(["make", "-s", "-C", str(out)], check=True, capture_output=True)
    lines = ["45.0,46.0", "45.1,46.0", "nan,46.0", "45.6,46.0,0.97"]
    done = subprocess.run([str(out / "example")], input="\n".join(lines) + "\n",
                          capture_output=True, text=True, check=True)
    rows = [row.split(",") for row in done.stdout.splitlines()]
    assert len(rows) == 4
    triac = [float(row[0]) for row in rows]
    # The setpoint is 1 kW above the power: the input rises; a missing sample is a
    # predicted step; a measured 3 % sag raises the input further at once.
    assert 45.0 < triac[0] < triac[1] < triac[3] <= 100.0
    assert [row[1:3] for row in rows] == [["on", "good"], ["on", "good"], ["on", "predicted"],
                                          ["on", "good"]]


def test_settings_the_c_cannot_reproduce_are_refused_with_what_to_change(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    settings = tmp_path / "s.toml"
    settings.write_text("[osqp]\npolishing = true\n", encoding="utf-8")
    rc = main(["codegen", str(MODEL), "--settings", str(settings), "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "set [osqp] polishing = false in the settings file" in capsys.readouterr().err


def test_help_names_the_files_and_the_offline_source_of_daqp(
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["codegen", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for word in ("czmpc_step.h", "example", "--daqp-sdist", "--float32", "osqp/", "daqp/"):
        assert word in text, word
