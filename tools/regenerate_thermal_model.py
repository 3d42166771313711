"""Regenerate tests/data/models/thermal_model.json: the furnace zone identified by czmpc.

The plant of another kind (`sim.thermal_plant.ThermalPlant`: two lags of 20 s and 140 s,
a quantised temperature sensor) goes through what a user would do with it::

    czmpc design-test --ts-s 2 --range-pct 30 70 --tau-s 140 --duration-s 6000 \
        --kind multilevel --seed 0 --out test.csv
    (play test.csv on the plant, seed 1, and log time_s,triac_pct,power_kw)
    czmpc identify log.csv --output-unit degC --out identify/

and the identified model.json is copied to the fixture with ``provenance["test_run"]``
saying how its log was made. Run it after a change to the plant, to design-test or to
identify that moves the model (``tests/sim/test_thermal_plant.py`` compares the
fixture with a fresh run)::

    python tools/regenerate_thermal_model.py [OUT.json]
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from sim.thermal_plant import ThermalParams, ThermalPlant
from sysid.data import Dataset, write_csv

FIXTURE = Path(__file__).resolve().parents[1] / "tests" / "data" / "models" / "thermal_model.json"
#: The design-test options (the plant's slow lag as the prior time constant).
DESIGN_ARGS = ("--ts-s", "2", "--range-pct", "30", "70", "--tau-s", "140", "--duration-s", "6000",
               "--kind", "multilevel", "--seed", "0")
#: Seed of the plant's sensor noise during the test.
PLANT_SEED = 1


def play_schedule(schedule_csv: Path, params: ThermalParams, *, seed: int) -> Dataset:
    """Apply a design-test schedule to the plant (zero-order hold) and return the log.

    Row ``k`` holds the input applied from ``t_k`` and the temperature measured at ``t_k``.
    """
    table = np.loadtxt(schedule_csv, delimiter=",", skiprows=1, ndmin=2)
    time_s, triac_pct = table[:, 0], table[:, 1]
    plant = ThermalPlant(params, rng=seed)
    measured = np.empty_like(triac_pct)
    measured[0] = plant.reset(seed)
    for k in range(1, triac_pct.size):
        measured[k] = plant.step(float(triac_pct[k - 1]))
    return Dataset(time_s=time_s, triac_pct=triac_pct, power_kw=measured, ts_s=params.ts_s,
                   output_unit="degC")


def regenerate(out: Path) -> dict[str, object]:
    """Run design-test, the plant and identify; write the model to ``out``; return its JSON."""
    params = ThermalParams(initial_triac_pct=50.0)
    czmpc = [sys.executable, "-m", "czmpc"]
    with tempfile.TemporaryDirectory(prefix="czmpc-thermal-") as tmp:
        work = Path(tmp)
        design = [*czmpc, "design-test", *DESIGN_ARGS, "--out", str(work / "test.csv")]
        subprocess.run(design, check=True, stdout=subprocess.DEVNULL)
        write_csv(play_schedule(work / "test.csv", params, seed=PLANT_SEED), work / "log.csv")
        identify = [*czmpc, "identify", str(work / "log.csv"), "--output-unit", "degC",
                    "--out", str(work / "identify")]
        subprocess.run(identify, check=True, stdout=subprocess.DEVNULL)
        doc = json.loads((work / "identify" / "model.json").read_text())
    doc["provenance"]["test_run"] = {
        "plant": f"sim.thermal_plant.ThermalPlant({params!r})",
        "plant_seed": PLANT_SEED,
        "design_test": "czmpc design-test " + " ".join(DESIGN_ARGS),
        "identify": "czmpc identify log.csv --output-unit degC --out identify/",
        "script": "tools/regenerate_thermal_model.py",
    }
    out.write_text(json.dumps(doc, indent=2) + "\n")
    return doc


def main(argv: list[str]) -> None:
    out = Path(argv[0]) if argv else FIXTURE
    doc = regenerate(out)
    print(f"wrote {out}: A = {doc['A']}, B = {doc['B']}, input_poly = {doc['input_poly']}")


if __name__ == "__main__":
    main(sys.argv[1:])
