"""Import-direction contract (DESIGN.md "Layout", STYLE.md B.2), per subpackage.

Layers, lowest first; a module imports only from lower layers and from its own room::

    6  benchmarks            (the project's own studies: not installed; may use anything)
    5  czmpc.cli
    4  czmpc.commissioning   czmpc.testing
    3  czmpc.runtime         czmpc.campaigns
    2  czmpc.peers           czmpc.reports
  1.5  czmpc.pid             (tuning from a model: uses the core, the peers use it)
    1  czmpc (the core)      sim
    0  sysid

On top of the layers: neither the core, `czmpc.pid` nor `czmpc.peers` imports `sim` (they
talk to plants only through the structural `sim.protocols.Controller`). Every import counts,
also those inside functions and under ``TYPE_CHECKING``: a lazy import is still a
dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: Layer of each room. A room is ``sysid``, ``sim``, ``czmpc`` (the core: the modules at
#: the top of czmpc/), ``czmpc.<subpackage>`` or ``benchmarks`` (above the product, which
#: ships without it and so never imports it).
LAYERS: dict[str, float] = {
    "sysid": 0,
    "sim": 1,
    "czmpc": 1,
    "czmpc.pid": 1.5,
    "czmpc.peers": 2,
    "czmpc.reports": 2,
    "czmpc.codegen": 2,
    "czmpc.campaigns": 3,
    "czmpc.runtime": 3,
    "czmpc.commissioning": 4,
    "czmpc.testing": 4,
    "czmpc.cli": 5,
    "benchmarks": 6,
}
#: Imports forbidden although the layers would allow them.
FORBIDDEN = {("czmpc", "sim"), ("czmpc.pid", "sim"), ("czmpc.peers", "sim")}


def room_of_module(module: str) -> str | None:
    """The room a dotted module name belongs to, or None for a third-party module."""
    parts = module.split(".")
    if parts[0] not in {"sysid", "sim", "czmpc", "benchmarks"}:
        return None
    if parts[0] == "czmpc" and len(parts) > 1 and f"czmpc.{parts[1]}" in LAYERS:
        return f"czmpc.{parts[1]}"
    return parts[0]


#: Modules that are entry points of the command line, whatever folder they sit in: they
#: belong to the CLI's room (``python -m czmpc`` runs ``czmpc/__main__.py``).
ENTRY_POINTS = {"czmpc.__main__": "czmpc.cli"}


def room_of_path(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    module = ".".join(p for p in rel.parts if p != "__init__")
    if module in ENTRY_POINTS:
        return ENTRY_POINTS[module]
    room = room_of_module(module)
    if room is None:  # pragma: no cover - only our packages are walked
        raise AssertionError(path)
    return room


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def _sources() -> list[Path]:
    return sorted(p for pkg in ("sysid", "sim", "czmpc", "benchmarks")
                  for p in (REPO / pkg).rglob("*.py"))


def violations(own: str, modules: set[str]) -> list[str]:
    """Every import of ``modules`` by room ``own`` that breaks the contract, as readable lines."""
    bad = []
    for module in sorted(modules):
        room = room_of_module(module)
        if room is None or room == own:
            continue
        if (own, room) in FORBIDDEN or LAYERS[room] >= LAYERS[own]:
            bad.append(f"{own} (layer {LAYERS[own]}) imports {module} ({room}, layer {LAYERS[room]})")
    return bad


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(REPO)))
def test_module_imports_only_downward(path: Path) -> None:
    assert violations(room_of_path(path), imported_modules(path)) == []


def test_every_czmpc_subpackage_has_a_layer() -> None:
    subpackages = {f"czmpc.{p.parent.name}" for p in (REPO / "czmpc").glob("*/__init__.py")}
    subpackages.discard("czmpc.data")   # package data, no code
    assert subpackages <= set(LAYERS), subpackages - set(LAYERS)


def test_contract_catches_upward_and_forbidden_imports() -> None:
    assert violations("czmpc", {"czmpc.cli.identify"}) == [
        "czmpc (layer 1) imports czmpc.cli.identify (czmpc.cli, layer 5)"]
    assert violations("czmpc.peers", {"sim.loop"})
    assert violations("czmpc.pid", {"sim.loop"})
    assert violations("czmpc.pid", {"czmpc.peers.pi"})
    assert violations("czmpc.peers", {"czmpc.pid.rules", "czmpc.inversion"}) == []
    assert violations("czmpc.reports", {"czmpc.campaigns.bench"})
    assert violations("sim", {"czmpc.settings"})
    assert violations("sysid", {"sim"})
    assert violations("czmpc.cli", {"czmpc.campaigns.bench", "sim.loop", "sysid.data", "numpy"}) == []
    assert violations("czmpc.campaigns", {"czmpc.campaigns.golden", "czmpc.peers.pi", "sim"}) == []
    assert violations("czmpc.cli", {"benchmarks._md"})       # the wheel has no benchmarks/
    assert violations("benchmarks", {"czmpc.cli._argtypes", "czmpc.runtime.loop", "sim"}) == []


def test_test_module_names_are_unique() -> None:
    """pytest imports the test modules by basename (no __init__.py): a second
    ``test_controller.py`` in another folder breaks the collection of a run that takes
    both (the realtime run takes every folder)."""
    names: dict[str, Path] = {}
    clashes = []
    for path in sorted((REPO / "tests").rglob("test_*.py")):
        if "node_modules" in path.parts:
            continue
        if path.name in names:
            clashes.append(f"{names[path.name].relative_to(REPO)} and {path.relative_to(REPO)}")
        names.setdefault(path.name, path)
    assert clashes == []
