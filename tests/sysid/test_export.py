"""Exports of a model: linearization (against scipy.signal.freqz), .mat, python-control."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io
from scipy.signal import freqz

from sysid.export import ExportError, linearize, save_mat, to_python_control
from sysid.model import HammersteinModel


def test_linearization_is_the_local_gain_times_b_over_a(
        paper_armax_model: HammersteinModel) -> None:
    m = paper_armax_model
    for level in (35.0, 45.0, 60.0):
        lin = linearize(m, level)
        slope = float(m.input_nonlinearity_slope(level - m.operating_point.triac_pct))
        assert lin.slope == pytest.approx(slope, rel=1e-15)
        assert lin.static_gain == pytest.approx(slope * m.linear_static_gain, rel=1e-12)
        # independent reference: scipy's freqz of f'(s) B(q^-1) / A(q^-1)
        omega = np.array([1e-4, 1e-2, 0.3, 1.5])   # rad/s, below Nyquist pi/2
        _, h = freqz(slope * m.b, m.a, worN=omega * m.ts_s)
        np.testing.assert_allclose(lin.frequency_response(omega), h, rtol=1e-12)
    with pytest.raises(ExportError, match="finite TRIAC level"):
        linearize(m, float("nan"))


def test_mat_file_holds_the_model_and_each_linearization(
        paper_armax_model: HammersteinModel, tmp_path: Path) -> None:
    path = tmp_path / "m.mat"
    save_mat(paper_armax_model, path, (40.0, 50.0))
    mat = scipy.io.loadmat(path)
    np.testing.assert_array_equal(mat["A"].ravel(), paper_armax_model.a)
    np.testing.assert_array_equal(mat["B"].ravel(), paper_armax_model.b)
    np.testing.assert_array_equal(mat["input_poly"].ravel(), paper_armax_model.input_poly)
    assert float(mat["Ts"].item()) == paper_armax_model.ts_s
    assert mat["num"].shape == mat["den"].shape == (2, 3)
    for row, level in enumerate((40.0, 50.0)):
        # MATLAB: dcgain(tf(num(i,:), den(i,:), Ts)) = num(1)/den(1) summed
        gain = mat["num"][row].sum() / mat["den"][row].sum()
        assert gain == pytest.approx(linearize(paper_armax_model, level).static_gain, rel=1e-12)


def test_python_control_objects_have_the_model_gain_and_poles(
        paper_armax_model: HammersteinModel) -> None:
    control = pytest.importorskip("control")
    m = paper_armax_model
    tf = to_python_control(m, 50.0)
    assert tf.dt == m.ts_s
    assert float(np.real(control.dcgain(tf))) == pytest.approx(
        linearize(m, 50.0).static_gain, rel=1e-9)
    ss = to_python_control(m, 50.0, form="ss")
    poles = np.sort_complex(np.linalg.eigvals(ss.A))
    expected = np.sort_complex(np.roots(linearize(m, 50.0).den_z))
    np.testing.assert_allclose(poles, expected, atol=1e-9)
    with pytest.raises(ExportError, match="form must be 'tf' or 'ss'"):
        to_python_control(m, 50.0, form="zpk")  # type: ignore[arg-type]
