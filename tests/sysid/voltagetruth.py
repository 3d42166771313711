"""A known Hammerstein truth driven under a wandering grid voltage (issue 40), for tests.

The paper-like model (tests/conftest.py's values): ``A = [1, -0.99]``, ``B = [0, 1,
-0.991]``, ``f(ds) = 1.35 ds - 0.0065 ds^2``, operating point 45 % / 45 kW, Ts = 2 s.
Its static gain is ``G1 = (1 - 0.991)/(1 - 0.99) = 0.9``, so ``W0 = P_nom / G1 = 50``.
The plant sees ``w_eff = v^2 f(ds) + (v^2 - 1) W0``: the controller's form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from sysid import HammersteinModel, OperatingPoint
from sysid.data import Dataset
from sysid.model import Provenance

A_TRUE = np.array([1.0, -0.99])
B_TRUE = np.array([0.0, 1.0, -0.991])
POLY_TRUE = np.array([1.35, -0.0065])
S_NOM_PCT = 45.0
P_NOM_KW = 45.0
TS_S = 2.0
#: ``B(1)/A(1)``
G1_TRUE = float(np.sum(B_TRUE) / np.sum(A_TRUE))
#: ``P_nom / G1``
W0_TRUE_KW = P_NOM_KW / G1_TRUE
#: White measurement noise [kW]: about the shipped log's one-step error.
NOISE_STD_KW = 0.05
#: AR(1) pole of the voltage's slow wander (time constant 500 samples = 1000 s) and its
#: stationary standard deviation [-]: "wanders by about 1 %".
VOLTAGE_POLE = 0.998
VOLTAGE_STD = 0.01
#: Dips of the grid voltage [-] and their starts [samples].
DIP = 0.03
DIP_STARTS = (1500, 5200, 8800, 10400)


@dataclass(frozen=True, kw_only=True, eq=False)
class VoltageRecord:
    """The synthetic log and what made it."""

    data: Dataset            # with grid_voltage_factor
    w_eff: np.ndarray        # the input the linear block saw [kW-equivalent]
    noise_kw: np.ndarray     # the measurement noise added


def multilevel_input_pct(n: int, rng: np.random.Generator) -> np.ndarray:
    """Levels uniform in 20..70 %, each held 60..400 samples; the first 200 at 45 %."""
    s = np.empty(n)
    s[:200] = S_NOM_PCT
    k = 200
    while k < n:
        hold = int(rng.integers(60, 400))
        s[k : k + hold] = rng.uniform(20.0, 70.0)
        k += hold
    return s


def grid_voltage_factor(n: int, rng: np.random.Generator) -> np.ndarray:
    """1 + a slow AR(1) wander (about 1 %) + four dips of -3 % lasting 150..400 samples;
    exactly 1 over the first 200 samples (the record starts at rest at nominal voltage)."""
    e = rng.normal(0.0, VOLTAGE_STD * np.sqrt(1.0 - VOLTAGE_POLE**2), n)
    v = 1.0 + lfilter([1.0], [1.0, -VOLTAGE_POLE], e)
    for start in DIP_STARTS:
        if start < n:
            v[start : start + int(rng.integers(150, 400))] -= DIP
    v[:200] = 1.0
    return np.asarray(v)


def truth_model() -> HammersteinModel:
    """The truth as a model file whose provenance says its input is ``w_eff`` with W0."""
    return HammersteinModel(
        kind="hammerstein", linear_block="oe", ts_s=TS_S,
        operating_point=OperatingPoint(triac_pct=S_NOM_PCT, power_kw=P_NOM_KW),
        a=A_TRUE, b=B_TRUE, c=A_TRUE, input_poly=POLY_TRUE, noise_std_kw=NOISE_STD_KW,
        input_range_pct=(20.0, 70.0),
        provenance=Provenance(extra={"grid_voltage": {
            "compensated": True, "nominal_drive_kw": W0_TRUE_KW}}))


def voltage_record(n: int = 12_000, seed: int = 40) -> VoltageRecord:
    """The truth simulated from rest by `lfilter` under the wandering voltage, plus noise."""
    rng = np.random.default_rng(seed)
    s = multilevel_input_pct(n, rng)
    v = grid_voltage_factor(n, rng)
    ds = s - S_NOM_PCT
    f = POLY_TRUE[0] * ds + POLY_TRUE[1] * ds**2
    w_eff = v**2 * f + (v**2 - 1.0) * W0_TRUE_KW
    noise = rng.normal(0.0, NOISE_STD_KW, n)
    power = P_NOM_KW + lfilter(B_TRUE, A_TRUE, w_eff) + noise
    data = Dataset(time_s=TS_S * np.arange(n), triac_pct=s, power_kw=power, ts_s=TS_S,
                   grid_voltage_factor=v)
    return VoltageRecord(data=data, w_eff=w_eff, noise_kw=noise)
