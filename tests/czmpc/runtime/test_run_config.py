"""The run configuration: every key checked, errors name the key."""

from __future__ import annotations

from pathlib import Path

import pytest
from plant_rig import make_config

from czmpc.runtime.config import RunConfigError, load_run_config, load_schedule


def test_a_valid_config_reads_with_defaults(tmp_path: Path) -> None:
    cfg = make_config(tmp_path, 4840, run={"setpoint_kw": 47.0})
    assert cfg.period_s == pytest.approx(2.0 / 50.0)
    assert cfg.safe_action == "hold"
    assert cfg.log_path == tmp_path / "run.csv"
    assert cfg.nodes.mode == "ns=2;s=Heater.Mode"
    assert cfg.align_to_plant is True


@pytest.mark.parametrize(("text", "key"), [
    ('[plant]\nendpoint = "opc.tcp://h:1/"\nts_s = 2.0\nspeed = 3\n', "plant.speed"),
    ('[plant]\nendpoint = "opc.tcp://h:1/"\nts_s = "2"\n', "plant.ts_s"),
    ('[plant]\nendpoint = "opc.tcp://h:1/"\nts_s = 2.0\ntime_scale = 0.5\n', "plant.time_scale"),
    ('[plant]\nendpoint = "http://h:1/"\nts_s = 2.0\n', "plant.endpoint"),
    ('[plant]\nendpoint = "opc.tcp://h:1/"\nts_s = 2.0\n[nodes]\ntriac_pct = "ns=2;i=1"\n',
     "nodes.power_kw"),
    ('[plant]\nendpoint = "opc.tcp://h:1/"\nts_s = 2.0\n[nodes]\npower_kw = "a"\n'
     'triac_pct = "b"\n[controller]\nmodel = "m.json"\n[run]\nsetpoint_kw = 45.0\n'
     '[safety]\naction = "ramp"\n',
     "safety.safe_triac_pct"),
    ('[plantt]\n', "plantt"),
    ('[plant]\nendpoint = "opc.tcp://h:1/"\nts_s = 2.0\nalign_to_plant = "yes"\n',
     "plant.align_to_plant"),
])
def test_bad_keys_are_named(tmp_path: Path, text: str, key: str) -> None:
    path = tmp_path / "run.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(RunConfigError, match=key.replace(".", r"\.")):
        load_run_config(path)


def test_schedule_gives_the_setpoint_in_force(tmp_path: Path) -> None:
    path = tmp_path / "recipe.csv"
    path.write_text("time_s,setpoint_kw\n0,45\n100,50\n300,48.5\n", encoding="utf-8")
    sched = load_schedule(path)
    assert [sched.setpoint_at(t) for t in (0.0, 99.9, 100.0, 299.0, 1e6)] == \
        [45.0, 45.0, 50.0, 50.0, 48.5]


def test_schedule_times_must_increase(tmp_path: Path) -> None:
    path = tmp_path / "recipe.csv"
    path.write_text("time_s,setpoint_kw\n0,45\n0,50\n", encoding="utf-8")
    with pytest.raises(RunConfigError, match="line 3"):
        load_schedule(path)


def test_the_shipped_example_config_reads() -> None:
    repo = Path(__file__).resolve().parents[3]
    cfg = load_run_config(repo / "examples" / "plant_link" / "run.toml")
    assert cfg.model_path.resolve() == (repo / "data" / "cz_heater_model.json").resolve()
    assert cfg.safe_action == "ramp" and cfg.safe_triac_pct == 33.0
    assert cfg.nodes.power_kw == "ns=2;s=Heater.Power"


def test_errors_name_the_file_and_key_with_a_hint_and_no_python_reprs(tmp_path: Path) -> None:
    from czmpc.runtime.config import RunConfigError, load_run_config

    path = tmp_path / "run.toml"
    base = ('[plant]\nendpoint = "opc.tcp://127.0.0.1:4840/"\nts_s = 2.0\n'
            '[nodes]\npower_kw = "ns=2;s=P"\ntriac_pct = "ns=2;s=U"\n')
    cases = [
        (base + "[run]\nsetpoint = 45.0\n",
         "run.setpoint: unknown key (did you mean 'setpoint_kw'?)"),
        (base.replace("[plant]", "[plnat]"), "plnat: unknown table (did you mean 'plant'?)"),
        (base + '[test]\npower_band_kw = [30.0, true]\n[safety]\nsafe_triac_pct = 30\n',
         "got [30, true]"),
        (base + "[plant.security]\npolicy = 'Basic256'\n", "got 'Basic256'"),
        (base.replace('triac_pct = "ns=2;s=U"', 'triac_pct = { id = "ns=2;s=U", raw = [0] }'),
         "nodes.triac_pct: give both raw = [LO, HI] and value = [LO, HI], or neither"),
    ]
    for text, expected in cases:
        path.write_text(text, encoding="utf-8")
        with pytest.raises(Exception) as info:
            load_run_config(path)
        message = str(info.value)
        assert expected in message, message
        assert "True" not in message and "PosixPath" not in message and "{'" not in message
        if isinstance(info.value, RunConfigError):
            assert message.startswith(f"{path}: ")
