"""Import direction contract (DESIGN.md, "Layout"): sysid <- sim; sysid <- czmpc core."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: czmpc modules allowed to import sim: the CLI and the benchmarks sit on top of all three.
CZMPC_MODULES_ALLOWED_SIM = {
    "cli.py", "commands", "bench.py", "bench_mpc.py", "bench_identify.py", "golden.py",
    "figures_sim.py", "robustness.py", "simulation.py",
}


def _imported_roots(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    roots: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            roots.add(node.module.split(".")[0])
    return roots


def _sources(package: str) -> list[Path]:
    return sorted((REPO / package).rglob("*.py"))


@pytest.mark.parametrize("path", _sources("sysid"), ids=lambda p: p.name)
def test_sysid_imports_neither_sim_nor_czmpc(path: Path) -> None:
    assert not (_imported_roots(path) & {"sim", "czmpc"})


@pytest.mark.parametrize("path", _sources("sim"), ids=lambda p: p.name)
def test_sim_never_imports_czmpc(path: Path) -> None:
    assert "czmpc" not in _imported_roots(path)


def _czmpc_core_sources() -> list[Path]:
    return [
        p for p in _sources("czmpc")
        if p.relative_to(REPO / "czmpc").parts[0] not in CZMPC_MODULES_ALLOWED_SIM
    ]


@pytest.mark.parametrize("path", _czmpc_core_sources(), ids=lambda p: p.name)
def test_czmpc_core_does_not_import_sim(path: Path) -> None:
    assert "sim" not in _imported_roots(path)
