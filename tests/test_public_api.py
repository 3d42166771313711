"""Every name a package's ``__all__`` lists resolves, and resolves to the defining object."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest


@pytest.mark.parametrize("package", ["sysid", "sim", "czmpc"])
def test_every_public_name_resolves(package: str) -> None:
    mod = importlib.import_module(package)
    for name in mod.__all__:
        value = getattr(mod, name)
        assert value is not None, name
    assert set(mod.__all__) <= set(dir(mod))


def test_a_public_name_wins_over_the_submodule_of_the_same_name() -> None:
    # sysid.simulate is a function; sysid.criteria imports the module sysid.simulate first
    code = ("import sys, sysid; sysid.ballistic_mse; import sysid.simulate; "
            "print(sysid.simulate is sys.modules['sysid.simulate'].simulate)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"


def test_unknown_name_raises_attribute_error() -> None:
    import sysid

    with pytest.raises(AttributeError, match="has no attribute 'nope'"):
        sysid.nope  # noqa: B018


def test_cli_import_does_not_import_numpy_before_pinning_blas_threads() -> None:
    code = (
        "import sys, os; os.environ.pop('OPENBLAS_NUM_THREADS', None); import czmpc.cli; "
        "print(os.environ['OPENBLAS_NUM_THREADS'], 'numpy' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    pinned, numpy_loaded = out.stdout.split()
    assert pinned == "1"
    assert numpy_loaded == "False"  # else OpenBLAS would have started its threads already
