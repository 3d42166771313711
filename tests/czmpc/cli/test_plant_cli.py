"""``czmpc plant serve`` with a varied plant: the options reach the served plant; bad ones exit 2."""

from __future__ import annotations

import socket

import pytest

from czmpc.cli import main

pytest.importorskip("asyncua")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_plant_serve_rejects_a_bad_drift(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["plant", "serve", "--drift", "gain=0.75"])
    assert code == 2
    assert "czmpc: error: drift: expected QUANTITY=VALUE@TIME_S" in capsys.readouterr().err


@pytest.mark.parametrize("plant", ["heater", "model"])
def test_plant_serve_runs_a_varied_plant_and_says_so(
    plant: str, capsys: pytest.CaptureFixture[str],
) -> None:
    code = main(["plant", "serve", "--plant", plant, "--endpoint",
                 f"opc.tcp://127.0.0.1:{_free_port()}/czmpc/", "--time-scale", "100",
                 "--duration-s", "6", "--gain-factor", "0.8", "--tau-s", "600",
                 "--extra-delay-samples", "2", "--drift", "gain=0.75@2"])
    assert code == 0
    err = capsys.readouterr().err
    assert "gain x0.8, tau 600 s, +2 samples delay, gain->x0.75 @ 2 s" in err
    assert "stopped after 6 s of plant time" in err
