"""The CMakeLists.txt beside the generated Makefile builds the same step.

Both builds' example programs read one fault stream (400 closed-loop samples of
`tests.codegen.replay.fault_replay`) and must print the same lines, byte for byte.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from czmpc.codegen import CController, build, generate_step
from czmpc.codegen.build import EXAMPLE, SHARED_LIBRARY
from czmpc.controller import OffsetFreeMPC
from czmpc.settings import MPCSettings
from sysid.model import HammersteinModel
from tests.codegen.replay import example_lines, fault_replay


def _run(cmd: list[str], stdin: str | None = None) -> str:
    done = subprocess.run(cmd, input=stdin, capture_output=True, text=True, check=False,
                          timeout=600)
    assert done.returncode == 0, f"{' '.join(cmd)}:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
    return done.stdout


@pytest.mark.slow
def test_cmake_build_prints_what_the_makefile_build_prints(
        tmp_path: Path, paper_armax_model: HammersteinModel) -> None:
    cmake = shutil.which("cmake")
    if cmake is None:
        pytest.skip("cmake is not installed (the Makefile builds are tested without it)")
    settings = MPCSettings.default_for(paper_armax_model).with_updates(
        soft_power_max_kw=paper_armax_model.operating_point.power_kw + 12.0)
    directory = tmp_path / "step"
    generate_step(paper_armax_model, settings, directory)
    assert (directory / "CMakeLists.txt").is_file()
    build(directory, (SHARED_LIBRARY, EXAMPLE))
    _, samples = fault_replay(OffsetFreeMPC(paper_armax_model, settings),
                              CController(directory / SHARED_LIBRARY), n_steps=400,
                              rng=np.random.default_rng(11), modes=False)
    stdin = example_lines(samples)
    by_make = _run([str(directory / EXAMPLE)], stdin)

    out = tmp_path / "cmake-build"
    _run([cmake, "-S", str(directory), "-B", str(out), "-DCMAKE_BUILD_TYPE=Release"])
    _run([cmake, "--build", str(out), "-j", "2"])
    assert (out / "libczmpc.a").is_file()
    by_cmake = _run([str(out / EXAMPLE)], stdin)
    assert len(by_cmake.splitlines()) == len(samples)
    assert by_cmake == by_make
