"""The generated C step in closed loop beside the Python MPC it was generated from.

`compare_generated` runs, through the same scenario, plant and seed, the compiled step
of a directory written by ``czmpc codegen`` (`czmpc.codegen.CController`, built on demand
with the system's C compiler) and the Python `czmpc.controller.OffsetFreeMPC` of the
model and settings that directory was generated from (its ``model.json`` and
``settings.toml``). Both get what `czmpc.campaigns.simulation.run_simulation` gives the
MPC: the plant's start input, the scenario's recipe preview and voltage reading.

It reports each run's metrics and how far the two controllers' inputs are apart, step by
step: in double precision the C replays the Python controller to the solver's rounding
(issue 42: within 1e-6 % where neither side's OSQP iteration count flips), so a larger
difference is a fault of the generated code or of its build. The C carries its settings
(limits, rate limit) compiled in: a scenario whose limits would change them is refused,
with what to generate instead.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from czmpc.campaigns.build import check_compiled_settings
from czmpc.campaigns.simulation import PlantKind, SimulationOutcome, run_simulation
from czmpc.codegen import load_controller
from czmpc.codegen.generate import MODEL_FILE, read_sources
from czmpc.errors import SettingsError
from czmpc.settings import MPCSettings
from sim.loop import ProgressCallback
from sim.protocols import Controller
from sim.scenario import Scenario
from sysid.model import HammersteinModel
from sysid.modelfile import model_to_dict

#: Names of the two runs, in report order (also their sub-directories of the output).
COMPARED = ("c_step", "mpc")


@dataclass(frozen=True, eq=False, kw_only=True)
class GeneratedComparison:
    """The C step's run and the Python MPC's on one scenario, and their differences.

    Parameters
    ----------
    c_step, mpc :
        The two runs.
    directory :
        The generated directory.
    float32 :
        Whether the C computes in single precision.
    max_triac_difference_pct :
        Largest ``|u_C - u_Python|`` over the run [%].
    first_difference_k :
        First sample whose inputs differ by more than 1e-6 % (None: none does).
    bit_equal_steps :
        Samples whose inputs are equal to the last bit.
    status_differences :
        Samples whose mode, status or fallback differ.
    """

    c_step: SimulationOutcome
    mpc: SimulationOutcome
    directory: Path
    float32: bool
    max_triac_difference_pct: float
    first_difference_k: int | None
    bit_equal_steps: int
    status_differences: int

    @property
    def n_steps(self) -> int:
        """Samples of each run."""
        return int(self.mpc.result.triac_pct.size)

    def table(self) -> str:
        """The two runs' headline metrics and their differences, as printed by ``czmpc simulate``."""
        lines = [f"{'controller':<10} {'IAE [kW s]':>12} {'max overshoot [kW]':>19} "
                 f"{'input travel [%]':>17} {'fallbacks':>9}"]
        for name, outcome in zip(COMPARED, (self.c_step, self.mpc), strict=True):
            m = outcome.metrics
            overshoot = max((c.overshoot_kw for c in m.changes), default=0.0)
            lines.append(f"{name:<10} {m.iae_kw_s:>12.3f} {overshoot:>19.4f} "
                         f"{m.input_total_variation_pct:>17.3f} {m.n_solver_failures or 0:>9d}")
        first = ("none beyond 1e-6 %" if self.first_difference_k is None
                 else f"first beyond 1e-6 % at sample {self.first_difference_k}")
        lines.append(
            f"C step ({'float' if self.float32 else 'double'}) against the Python MPC over "
            f"{self.n_steps} samples: max |TRIAC difference| {self.max_triac_difference_pct:.3g} % "
            f"({first}); {self.bit_equal_steps} bit-equal; mode, status or fallback differ at "
            f"{self.status_differences} samples")
        return "\n".join(lines)


def _statuses(outcome: SimulationOutcome) -> list[tuple[str, str, str]]:
    """Each step's (mode, status, fallback) as the CSV writes them."""
    diags = outcome.result.diagnostics or ()
    return [tuple(str(getattr(getattr(d, name), "value", getattr(d, name)))   # type: ignore[misc]
                  for name in ("mode", "status", "fallback")) for d in diags]


def compare_generated(model: HammersteinModel, directory: str | Path, scenario: Scenario, *,
                      plant: PlantKind, seed: int, noise: bool,
                      progress: ProgressCallback | None = None) -> GeneratedComparison:
    """Run ``directory``'s C step and the Python MPC it was generated from (module notes).

    Parameters
    ----------
    model :
        The plant's model (for ``plant="model"``) and the one the directory was
        generated from.
    directory :
        Written by ``czmpc codegen``.
    scenario, plant, seed, noise :
        As `run_simulation`.
    progress :
        As `run_simulation`'s, for each run in turn.

    Raises
    ------
    CodegenError
        ``directory`` holds no generated step.
    BuildError
        No C compiler or make, or a failed build.
    SettingsError
        ``model`` is not the one the directory was generated from, or the scenario's
        limits differ from the compiled ones.
    """
    folder = Path(directory)
    c_model, settings = read_sources(folder)
    if model_to_dict(c_model) != model_to_dict(model):
        raise SettingsError(f"{folder}: the C step was generated from another model than the "
                            f"one given; simulate with {folder / MODEL_FILE}")
    float32 = False

    def build(used: MPCSettings, _allowed: tuple[float, float]) -> Controller:
        nonlocal float32
        check_compiled_settings(folder, settings, used, what=f"scenario '{scenario.name}'")
        controller = load_controller(folder, initial_triac_pct=used.initial_triac_pct)
        float32 = controller.float32
        return controller

    c_run = run_simulation(model, scenario, plant=plant, seed=seed, settings=settings,
                           noise=noise, progress=progress, controller_factory=("c_step", build))
    py_run = run_simulation(model, scenario, plant=plant, seed=seed, settings=settings,
                            noise=noise, progress=progress)
    u_c, u_py = c_run.result.triac_pct, py_run.result.triac_pct
    diff = np.abs(u_c - u_py)
    beyond = np.flatnonzero(diff > 1e-6)
    return GeneratedComparison(
        c_step=c_run, mpc=py_run, directory=folder, float32=float32,
        max_triac_difference_pct=float(diff.max()) if diff.size else 0.0,
        first_difference_k=int(beyond[0]) if beyond.size else None,
        bit_equal_steps=int(np.count_nonzero(u_c == u_py)),
        status_differences=sum(a != b for a, b in zip(_statuses(c_run), _statuses(py_run),
                                                       strict=True)),
    )


__all__ = ["COMPARED", "GeneratedComparison", "compare_generated"]
