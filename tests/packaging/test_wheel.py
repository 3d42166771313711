"""The wheel works on its own: built by ``python -m build``, installed into a fresh virtual
environment outside the source tree, and run from there without reading the source tree.

The fresh environment gets the already installed dependencies (numpy, scipy, osqp, ...)
through a ``.pth`` line naming this interpreter's site-packages, so no network is needed;
a plain path line does not run that folder's own ``.pth`` hooks, so the editable install of
the source tree stays out. czmpc itself comes only from the wheel (``pip install --no-deps``:
its dependencies are already there).
"""

from __future__ import annotations

import csv
import json
import os
import re
import socket
import subprocess
import sys
import sysconfig
import time
import tomllib
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
VERSION = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]["version"]

# Runs a command of the installed czmpc (or pytest, for the plugin) with an audit hook that
# records every file opened inside the source tree (its .venv, which holds the
# dependencies, excepted), then prints them on stderr after a marker so that the test can
# fail on any.
_GUARD_OF = """
import os, sys
repo, venv = os.path.realpath(sys.argv[1]), os.path.realpath(os.path.join(sys.argv[1], ".venv"))
seen = []
def hook(event, args):
    if event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
        path = os.path.realpath(os.fsdecode(args[0]))
        if path.startswith(repo + os.sep) and not path.startswith(venv + os.sep):
            seen.append(path)
sys.addaudithook(hook)
from {module} import main
try:
    code = main(sys.argv[2:])
finally:
    print("SOURCE-TREE-READS:" + repr(sorted(set(seen))), file=sys.stderr)
sys.exit(code)
"""
#: The guard around the czmpc command line.
_GUARD = _GUARD_OF.format(module="czmpc.cli")


def _run(args: list[str], cwd: Path, timeout_s: float = 300,
         warnings: str = "") -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PYTHONWARNINGS"] = warnings
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout_s,
                          check=False)


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``python -m build`` of the repository: the sdist, then the wheel built from it."""
    out = tmp_path_factory.mktemp("dist")
    proc = _run([sys.executable, "-m", "build", "--outdir", str(out), str(REPO)], cwd=out, timeout_s=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    log = proc.stdout + proc.stderr
    # setuptools announces removals (licence tables, classifiers) as deprecation warnings
    assert "Deprecat" not in log and "deprecat" not in log, log[-3000:]
    return out


@pytest.fixture(scope="module")
def venv(dist: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh virtual environment outside the source tree with the wheel installed."""
    root = tmp_path_factory.mktemp("wheel-venv")
    env_dir = root / "venv"
    assert _run([sys.executable, "-m", "venv", str(env_dir)], cwd=root).returncode == 0
    python = env_dir / "bin" / "python"
    purelib = _run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                   cwd=root).stdout.strip()
    deps = {sysconfig.get_path("purelib"), sysconfig.get_path("platlib")}
    (Path(purelib) / "_czmpc_test_deps.pth").write_text("\n".join(sorted(deps)) + "\n", encoding="utf-8")
    (wheel,) = dist.glob("czmpc-*.whl")
    proc = _run([str(python), "-m", "pip", "install", "--quiet", "--no-deps", "--no-index", str(wheel)],
                cwd=root)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return env_dir


@pytest.mark.slow
def test_sdist_and_wheel_carry_the_version_licence_and_package_data(dist: Path) -> None:
    (sdist,) = dist.glob("czmpc-*.tar.gz")
    (wheel,) = dist.glob("czmpc-*.whl")
    assert sdist.name == f"czmpc-{VERSION}.tar.gz"
    assert wheel.name == f"czmpc-{VERSION}-py3-none-any.whl"
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        metadata = zf.read(f"czmpc-{VERSION}.dist-info/METADATA").decode()
    assert f"czmpc-{VERSION}.dist-info/licenses/LICENSE" in names
    assert "License-Expression: BSD-3-Clause" in metadata
    for name in ("czmpc/data/cz_heater_experiment.csv", "czmpc/data/cz_heater_model.json",
                 "czmpc/py.typed", "sysid/py.typed", "sim/py.typed", "sim/scenarios/staircase.toml"):
        assert name in names, name
    assert not any(n.startswith(("tests/", "docs/")) for n in names)
    assert _benchmark_modules(names) == []


def _benchmark_modules(names: set[str] | list[str]) -> list[str]:
    """The benchmark modules among file names: benchmarks/ or a module named bench*."""
    return sorted(n for n in names if n.endswith(".py")
                  and (n.startswith("benchmarks/") or Path(n).name.startswith("bench")))


def test_the_packages_setuptools_finds_hold_no_benchmark_module() -> None:
    """What the wheel would contain (pyproject's package find), without building it.

    The benchmarks (benchmarks/ at the repository root) are the project's own: they
    rewrite BENCHMARKS.md and hold goal constants, so they never ship.
    """
    from setuptools import find_packages

    config = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    packages = find_packages(str(REPO), **config["tool"]["setuptools"]["packages"]["find"])
    assert "czmpc.cli" in packages and "sysid" in packages and "sim" in packages
    assert not [p for p in packages if p.split(".")[0] in ("benchmarks", "tests", "docs")]
    files = [str(f.relative_to(REPO)) for p in packages
             for f in (REPO / p.replace(".", "/")).glob("*.py")]
    assert _benchmark_modules(files) == []
    assert _benchmark_modules(["benchmarks/_md.py", "czmpc/cli/bench.py", "czmpc/x.py"]) == [
        "benchmarks/_md.py", "czmpc/cli/bench.py"]


def _czmpc(venv: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return _run([str(venv / "bin" / "python"), "-c", _GUARD, str(REPO),
                 *args], cwd=cwd, warnings="error::DeprecationWarning")


def _pytest(venv: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """pytest in the wheel's environment: plugins come from entry points, czmpc's from the wheel."""
    return _run([str(venv / "bin" / "python"), "-c", _GUARD_OF.format(module="pytest"), str(REPO),
                 "-p", "no:cacheprovider", *args], cwd=cwd)


def _source_tree_reads(proc: subprocess.CompletedProcess[str]) -> str:
    return proc.stderr.rsplit("SOURCE-TREE-READS:", 1)[1].strip()


@pytest.mark.slow
def test_installed_packages_come_from_the_venv_not_the_source_tree(venv: Path, tmp_path: Path) -> None:
    code = ("import czmpc, sysid, sim, czmpc.shipped as s; "
            "print(czmpc.__file__); print(sysid.__file__); print(sim.__file__); "
            "print(s.shipped_path(s.EXPERIMENT_CSV)); print(czmpc.__version__)")
    proc = _run([str(venv / "bin" / "python"), "-c", code], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    *paths, version = proc.stdout.split()
    for path in paths:
        assert Path(path).resolve().is_relative_to(venv.resolve()), path
    assert version == VERSION
    console = _run([str(venv / "bin" / "czmpc"), "--version"], cwd=tmp_path)
    assert console.stdout.strip() == f"czmpc {VERSION}"


@pytest.mark.slow
def test_demo_runs_from_the_wheel(venv: Path, tmp_path: Path) -> None:
    proc = _czmpc(venv, tmp_path, "demo", "--out", "demo")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert _source_tree_reads(proc) == "[]"
    assert "identical to the shipped cz_heater_experiment.csv" in proc.stdout
    assert (tmp_path / "demo" / "identify" / "model.json").is_file()
    assert (tmp_path / "demo" / "simulate-heater" / "metrics.json").is_file()


@pytest.mark.slow
def test_identify_on_the_shipped_log_runs_from_the_wheel(venv: Path, tmp_path: Path) -> None:
    where = _run([str(venv / "bin" / "python"), "-c",
                  "import czmpc.shipped as s; print(s.shipped_path(s.EXPERIMENT_CSV))"], cwd=tmp_path)
    log = Path(where.stdout.strip())
    assert log.resolve().is_relative_to(venv.resolve())
    proc = _czmpc(venv, tmp_path, "identify", str(log), "--out", "id")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert _source_tree_reads(proc) == "[]"
    model = (tmp_path / "id" / "model.json").read_text(encoding="utf-8")
    assert f'"software": "czmpc {VERSION}"' in model
    report = (tmp_path / "id" / "report.md").read_text(encoding="utf-8")
    assert f"Produced by czmpc {VERSION}" in report


@pytest.mark.slow
def test_a_shipped_campaign_spec_runs_from_the_wheel(venv: Path, tmp_path: Path) -> None:
    # campaign_smoke.toml is package data: named without a path, found in the venv.
    proc = _czmpc(venv, tmp_path, "campaign", "run", "campaign_smoke.toml", "--out", "smoke")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert _source_tree_reads(proc) == "[]"
    assert "24 runs (24 run now, 0 resumed), 0 crashed" in proc.stdout
    assert (tmp_path / "smoke" / "results.parquet").is_file()
    spec = json.loads((tmp_path / "smoke" / "campaign.json").read_text(encoding="utf-8"))
    assert Path(spec["source"]).resolve().is_relative_to(venv.resolve()), spec["source"]
    report = _czmpc(venv, tmp_path, "campaign", "report", "smoke")
    assert report.returncode == 0, report.stderr[-3000:]
    assert _source_tree_reads(report) == "[]"
    assert (tmp_path / "smoke" / "iae_distribution.png").stat().st_size > 10_000


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


#: Plant time [s] the MPC runs against the served plant, and the time scale of both:
#: 60 s of plant time = 30 samples in 3 s of wall time.
RUN_PLANT_S, TIME_SCALE = 60.0, 20.0


@pytest.mark.slow
def test_the_shipped_run_config_runs_against_a_served_plant_from_the_wheel(
        venv: Path, tmp_path: Path) -> None:
    """examples/plant_link/run.toml (with its settings.toml), pointed at a plant served on
    127.0.0.1 and at the wheel's shipped model, runs the MPC in real time (scaled) with
    nothing read from the tree."""
    where = _run([str(venv / "bin" / "python"), "-c",
                  "import czmpc.shipped as s; print(s.shipped_path(s.HAMMERSTEIN_MODEL_JSON))"],
                 cwd=tmp_path)
    model = Path(where.stdout.strip())
    assert model.resolve().is_relative_to(venv.resolve()), where.stderr
    endpoint = f"opc.tcp://127.0.0.1:{_free_port()}/czmpc/"
    text = (REPO / "examples" / "plant_link" / "run.toml").read_text(encoding="utf-8")
    for pattern, value in ((r'endpoint = "[^"]*"', f'endpoint = "{endpoint}"'),
                           (r"time_scale = [0-9.]+", f"time_scale = {TIME_SCALE}"),
                           (r'model = "[^"]*"', f'model = "{model.as_posix()}"'),
                           (r"duration_s = [0-9.]+", f"duration_s = {RUN_PLANT_S}")):
        text, n = re.subn(pattern, value, text)
        assert n == 1, pattern                      # the example still has each key once
    (tmp_path / "run.toml").write_text(text, encoding="utf-8")
    assert 'settings = "settings.toml"' in text          # the example's settings file, beside it
    (tmp_path / "settings.toml").write_bytes(
        (REPO / "examples" / "plant_link" / "settings.toml").read_bytes())
    server_log = (tmp_path / "serve.out").open("w", encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    # The server stops by itself after 30 s of wall time (600 s of plant time) at the latest.
    server = subprocess.Popen(
        [str(venv / "bin" / "python"), "-c", _GUARD, str(REPO), "plant", "serve",
         "--endpoint", endpoint, "--time-scale", str(TIME_SCALE), "--duration-s", "600",
         "--scenario", "staircase", "--no-noise"],
        cwd=tmp_path, env=env, stdout=server_log, stderr=subprocess.STDOUT, text=True)
    try:
        # start the loop once the server listens (a cold start of the fresh venv is slow)
        deadline = time.monotonic() + 60.0
        while "serving the heater plant" not in (tmp_path / "serve.out").read_text(encoding="utf-8"):
            assert server.poll() is None and time.monotonic() < deadline, "the plant did not start"
            time.sleep(0.2)
        proc = _czmpc(venv, tmp_path, "run", "run.toml")
    finally:
        server.terminate()
        server.wait(timeout=30)
        server_log.close()
    served = (tmp_path / "serve.out").read_text(encoding="utf-8")
    assert proc.returncode == 0, proc.stderr[-3000:] + served[-2000:]
    assert _source_tree_reads(proc) == "[]"
    assert "SOURCE-TREE-READS:[]" in served, served[-2000:]
    assert f"serving the heater plant on {endpoint}" in served
    assert "stopped by duration" in proc.stdout
    with open(tmp_path / "run.csv", newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh) if r["k"] != ""]     # the safe ramp has no k
    assert len(rows) == int(RUN_PLANT_S / 2.0)                      # Ts = 2 s
    good = [r for r in rows if r["quality"] == "good"]
    assert len(good) >= len(rows) - 2, rows                         # a noise-free, healthy plant
    # the staircase starts at 45 kW in steady state: the MPC holds it
    assert all(abs(float(r["power_kw"]) - float(r["setpoint_kw"])) < 1.0 for r in good)


@pytest.mark.slow
def test_a_users_regression_suite_records_and_checks_from_the_wheel(
        venv: Path, tmp_path: Path) -> None:
    """Issue 16: outside the source tree, a suite of the user's own model, settings and
    scenario files is recorded, holds unchanged, and fails (exit 1, naming the metric and
    the first divergence) after one weight of the settings file is doubled; through the
    command and through the pytest plugin of the installed wheel."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "_regress_user_files", REPO / "tests" / "czmpc" / "conftest.py")
    assert spec is not None and spec.loader is not None
    files = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(files)
    RECIPE, SETTINGS, SUITE = files.RECIPE, files.SETTINGS, files.SUITE  # noqa: N806
    folder = tmp_path / "puller7"
    folder.mkdir()
    shipped = venv.glob("lib/python*/site-packages/czmpc/data/cz_heater_model.json")
    (folder / "puller7_model.json").write_bytes(next(shipped).read_bytes())
    (folder / "puller7_settings.toml").write_text(SETTINGS, encoding="utf-8")
    (folder / "recipe_a.toml").write_text(RECIPE, encoding="utf-8")
    (folder / "suite.toml").write_text(SUITE, encoding="utf-8")

    record = _czmpc(venv, tmp_path, "regress", "record", "puller7/suite.toml", "--out", "golden")
    assert record.returncode == 0, record.stderr[-3000:]
    assert _source_tree_reads(record) == "[]"
    check = _czmpc(venv, tmp_path, "regress", "check", "golden", "--junit", "junit.xml")
    assert check.returncode == 0, check.stderr[-3000:]
    assert "puller-7: 2 of 2 case(s) hold" in check.stdout
    assert _source_tree_reads(check) == "[]"
    # the same check from the user's own pytest suite, through the plugin's fixture
    (tmp_path / "test_puller7.py").write_text(_USER_PLUGIN_TEST, encoding="utf-8")
    plugin = _pytest(venv, tmp_path, "-q", "-s", "test_puller7.py")
    assert plugin.returncode == 0, plugin.stdout[-3000:] + plugin.stderr[-3000:]
    assert "1 passed" in plugin.stdout
    (plugin_file,) = re.findall(r"PLUGIN-FROM:(\S+)", plugin.stdout)
    assert Path(plugin_file).resolve().is_relative_to(venv.resolve()), plugin_file
    assert _source_tree_reads(plugin) == "[]"

    settings = folder / "puller7_settings.toml"
    settings.write_text(SETTINGS.replace("move_weight = 0.1", "move_weight = 0.2"),
                        encoding="utf-8")
    failed = _czmpc(venv, tmp_path, "regress", "check", "golden")
    assert failed.returncode == 1, failed.stderr[-3000:]
    assert "iae_kw_s" in failed.stdout and "first divergence" in failed.stdout
    assert "move_weight: 0.1 -> 0.2" in failed.stdout
    assert _source_tree_reads(failed) == "[]"
    plugin = _pytest(venv, tmp_path, "-q", "test_puller7.py")
    assert plugin.returncode == 1, plugin.stdout[-3000:] + plugin.stderr[-3000:]
    assert "1 failed" in plugin.stdout
    assert "iae_kw_s" in plugin.stdout and "move_weight: 0.1 -> 0.2" in plugin.stdout
    assert _source_tree_reads(plugin) == "[]"


#: A user's test of their suite through the pytest plugin (fixture ``czmpc_regress``).
_USER_PLUGIN_TEST = """
import czmpc.testing

def test_puller7_did_not_change(czmpc_regress):
    print("PLUGIN-FROM:" + czmpc.testing.__file__)
    report = czmpc_regress.check("golden")
    assert len(report.cases) == 2
"""
