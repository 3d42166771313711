"""Issue 40 without a server: the recipe ahead and the grid voltage from the config and the
read to the controller's keyword arguments (a fake controller records them)."""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path
from typing import Any

import pytest
from plant_rig import make_config, served_nodes

from czmpc.modes import Mode
from czmpc.runtime.config import RunConfigError, load_schedule
from czmpc.runtime.link import check_node
from czmpc.runtime.loop import ControlLoop, context_args_taken
from czmpc.runtime.node_types import LinearScale, NodeSpec
from czmpc.runtime.step import decide, judge, preview_of

ua = pytest.importorskip("asyncua").ua

MAX_AGE_S = 1.0
SPECS = {k: NodeSpec(node_id=f"ns=2;s={k}")
         for k in ("power_kw", "setpoint_preview_kw", "grid_voltage_factor")}
RECIPE = "time_s,setpoint_kw\n0,45\n20,47\n30,46\n"


def _dv(value: object, *, age_s: float = 0.0, status: int = 0,
        vtype: Any = None) -> Any:
    variant = ua.Variant(value, vtype or ua.VariantType.Double)
    source = dt.datetime.now(dt.UTC) - dt.timedelta(seconds=age_s)
    return ua.DataValue(variant, StatusCode=ua.StatusCode(status), SourceTimestamp=source)


class _Recorder:
    """A `LoopController` that records what each step was told (the MPC's keyword API)."""

    mode = Mode.ON
    rate_limit_pct_per_step = None

    def __init__(self) -> None:
        self.calls: list[dict[str, Any]] = []

    def request_mode(self, mode: Mode) -> None:
        self.mode = mode

    def step(self, power_kw: float, setpoint_kw: float, *,
             applied_triac_pct: float | None = None,
             setpoint_preview_kw: Any = None, grid_voltage_factor: float | None = None) -> float:
        self.calls.append({"setpoint_kw": setpoint_kw, "setpoint_preview_kw": setpoint_preview_kw,
                           "grid_voltage_factor": grid_voltage_factor})
        return 45.0

    def status_words(self) -> tuple[str, str]:
        return "GOOD", "OK"

    def skipped(self, n_periods: int) -> None:
        pass

    def finished(self) -> None:
        return None

    def abort_reason(self) -> None:
        return None


class _OldStyle(_Recorder):
    """A controller that takes neither (an open-loop test schedule)."""

    def step(self, power_kw: float, setpoint_kw: float, *,  # type: ignore[override]
             applied_triac_pct: float | None = None) -> float:
        self.calls.append({"setpoint_kw": setpoint_kw})
        return 45.0


# -- the config ------------------------------------------------------------------------

def _recipe(tmp_path: Path) -> None:
    (tmp_path / "recipe.csv").write_text(RECIPE, encoding="utf-8")


def test_the_schedule_gives_the_setpoints_of_the_coming_samples(tmp_path: Path) -> None:
    _recipe(tmp_path)
    sched = load_schedule(tmp_path / "recipe.csv")
    # sample k = 8 is t = 16 s: the next samples are t = 18, 20, 22, 24 s
    assert sched.setpoints_after(16.0, 2.0, 4) == (45.0, 47.0, 47.0, 47.0)
    assert sched.setpoints_after(26.0, 2.0, 3) == (47.0, 46.0, 46.0)
    assert sched.setpoints_after(0.0, 2.0, 0) == ()


def test_setpoint_preview_s_reads_with_a_schedule_or_an_array_node(tmp_path: Path) -> None:
    _recipe(tmp_path)
    cfg = make_config(tmp_path, 4840, run={"schedule": "recipe.csv", "setpoint_preview_s": 7.0})
    assert cfg.setpoint_preview_s == 7.0 and cfg.preview_samples == 4   # round(3.5) -> 4
    nodes = served_nodes() | {"setpoint_preview_kw": "ns=2;s=Heater.SetpointPreview",
                              "grid_voltage_factor": "ns=2;s=Heater.GridVoltage"}
    cfg = make_config(tmp_path, 4840, nodes=nodes, run={"setpoint_preview_s": 20.0})
    assert cfg.preview_samples == 10
    assert cfg.nodes.grid_voltage_factor == "ns=2;s=Heater.GridVoltage"
    assert make_config(tmp_path, 4840, run={"setpoint_kw": 45.0}).preview_samples == 0


@pytest.mark.parametrize(("run", "nodes", "match"), [
    ({"setpoint_kw": 45.0, "setpoint_preview_s": -2.0}, {}, r"run\.setpoint_preview_s.*>= 0"),
    ({"setpoint_kw": 45.0, "setpoint_preview_s": 20.0}, {}, r"run\.setpoint_preview_s.*needs"),
    ({"setpoint_preview_s": 20.0}, {"setpoint_kw": "ns=2;s=Heater.PowerSetpoint"},
     r"run\.setpoint_preview_s.*needs"),
    ({"schedule": "recipe.csv", "setpoint_preview_s": 0.5}, {},
     r"run\.setpoint_preview_s.*half a sample"),
    ({"schedule": "recipe.csv", "setpoint_preview_s": "20"}, {}, r"run\.setpoint_preview_s"),
    ({"schedule": "recipe.csv"}, {"setpoint_preview_kw": "ns=2;s=Heater.SetpointPreview"},
     r"nodes\.setpoint_preview_kw.*not both"),
])
def test_preview_config_errors_name_the_key(tmp_path: Path, run: dict[str, object],
                                            nodes: dict[str, str], match: str) -> None:
    _recipe(tmp_path)
    base = {k: v for k, v in served_nodes().items() if k != "setpoint_kw"}
    with pytest.raises(RunConfigError, match=match):
        make_config(tmp_path, 4840, run=run, nodes=base | nodes)


# -- the read --------------------------------------------------------------------------

def test_judge_reads_the_voltage_as_it_reads_the_power() -> None:
    def read(voltage_dv: Any) -> float | None:
        values = {"power_kw": _dv(44.0), "grid_voltage_factor": voltage_dv}
        return judge(values, SPECS, max_age_s=MAX_AGE_S, previous_time=None).grid_voltage_factor

    assert read(_dv(0.93)) == 0.93
    bad, stale = read(_dv(0.93, status=0x80000000)), read(_dv(0.93, age_s=5.0))
    uncertain, text = read(_dv(0.93, status=0x40000000)), read(_dv("x", vtype=ua.VariantType.String))
    assert all(v is not None and math.isnan(v) for v in (bad, stale, uncertain, text))
    # no node configured: None (not measured); configured but no link: NaN (missing)
    without = {k: v for k, v in SPECS.items() if k != "grid_voltage_factor"}
    assert judge({"power_kw": _dv(44.0)}, without, max_age_s=MAX_AGE_S,
                 previous_time=None).grid_voltage_factor is None
    gone = judge(None, SPECS, max_age_s=MAX_AGE_S, previous_time=None)
    assert gone.grid_voltage_factor is not None and math.isnan(gone.grid_voltage_factor)
    assert gone.preview_quality == "disconnected" and gone.setpoint_preview_kw is None


def test_the_array_node_is_judged_whole_and_scaled() -> None:
    spec = SPECS["setpoint_preview_kw"]
    assert preview_of(_dv([46.0, 47.0, math.nan]), MAX_AGE_S, spec)[0][:2] == (46.0, 47.0)
    assert preview_of(_dv([46.0, 47.0]), MAX_AGE_S, spec) == ((46.0, 47.0), "good")
    assert preview_of(_dv([]), MAX_AGE_S, spec) == ((), "good")
    assert preview_of(_dv([46.0], age_s=5.0), MAX_AGE_S, spec) == (None, "stale")
    assert preview_of(_dv([46.0], status=0x80000000), MAX_AGE_S, spec) == (None, "bad")
    assert preview_of(_dv(46.0), MAX_AGE_S, spec) == (None, "not an array of numbers")
    raw = NodeSpec("ns=2;s=raw", LinearScale(0.0, 1000.0, 0.0, 100.0))
    assert preview_of(_dv([455.0, 470.0]), MAX_AGE_S, raw) == ((45.5, 47.0), "good")


def test_decide_passes_preview_and_voltage_only_when_given() -> None:
    sample = judge({"power_kw": _dv(44.0)}, SPECS, max_age_s=MAX_AGE_S, previous_time=None)
    ctrl = _Recorder()
    decide(ctrl, sample, setpoint_kw=45.0, last_command_pct=45.0, allow_on=True)
    decide(ctrl, sample, setpoint_kw=45.0, last_command_pct=45.0, allow_on=True,
           setpoint_preview_kw=(46.0, 47.0), grid_voltage_factor=math.nan)
    assert ctrl.calls[0]["setpoint_preview_kw"] is None and ctrl.calls[0]["grid_voltage_factor"] is None
    assert ctrl.calls[1]["setpoint_preview_kw"] == (46.0, 47.0)
    assert math.isnan(ctrl.calls[1]["grid_voltage_factor"])
    # a controller without the keywords is never given them
    old = _OldStyle()
    assert context_args_taken(old) == frozenset()
    assert context_args_taken(ctrl) == {"setpoint_preview_kw", "grid_voltage_factor"}


# -- the loop's step, without I/O --------------------------------------------------------

def _loop_steps(tmp_path: Path, ctrl: Any, reads: list[dict[str, Any] | None], **kw: Any,
                ) -> tuple[ControlLoop, list[dict[str, Any]]]:
    cfg = make_config(tmp_path, 4840, **kw)
    loop = ControlLoop(cfg, ctrl)
    rows = []
    for k, values in enumerate(reads):
        sample, decision, _ = loop._decide(k, values)
        rows.append({"sample": sample, "events": loop._take_events()})
    return loop, rows


def test_the_loop_passes_the_recipe_ahead_on_its_own_clock(tmp_path: Path) -> None:
    _recipe(tmp_path)
    ctrl = _Recorder()
    nodes = {k: v for k, v in served_nodes().items() if k != "setpoint_kw"}
    reads = [{"power_kw": _dv(45.0)} for _ in range(12)]
    _loop_steps(tmp_path, ctrl, reads, nodes=nodes,
                run={"schedule": "recipe.csv", "setpoint_preview_s": 6.0})
    previews = [c["setpoint_preview_kw"] for c in ctrl.calls]
    setpoints = [c["setpoint_kw"] for c in ctrl.calls]
    # the step to 47 kW is at t = 20 s, sample 10: it appears 3 samples ahead at k = 7
    assert setpoints[9:11] == [45.0, 47.0]
    assert previews[6] == (45.0, 45.0, 45.0) and previews[7] == (45.0, 45.0, 47.0)
    assert previews[9] == (47.0, 47.0, 47.0)
    # element 0 of step k's preview is step k+1's setpoint
    assert all(p[0] == s for p, s in zip(previews, setpoints[1:], strict=False))
    # without the key: no preview at all
    ctrl = _Recorder()
    _loop_steps(tmp_path, ctrl, reads[:3], nodes=nodes, run={"schedule": "recipe.csv"})
    assert [c["setpoint_preview_kw"] for c in ctrl.calls] == [None, None, None]


def test_the_loop_passes_the_array_node_cut_and_says_when_it_is_unusable(tmp_path: Path) -> None:
    nodes = served_nodes() | {"setpoint_preview_kw": "ns=2;s=Heater.SetpointPreview",
                              "grid_voltage_factor": "ns=2;s=Heater.GridVoltage"}
    ahead = [46.0, 47.0, 48.0, 49.0, 50.0]

    def read(preview: Any, voltage: Any) -> dict[str, Any]:
        return {"power_kw": _dv(45.0), "setpoint_preview_kw": preview,
                "grid_voltage_factor": voltage}

    reads: list[dict[str, Any] | None] = [
        read(_dv(ahead), _dv(0.95)), read(_dv(ahead, age_s=5.0), _dv(0.95, status=0x80000000)),
        read(_dv(ahead, age_s=5.0), _dv(0.95, status=0x80000000)), None,
        read(_dv(ahead), _dv(0.97))]
    ctrl = _Recorder()
    loop, rows = _loop_steps(tmp_path, ctrl, reads, nodes=nodes,
                             run={"setpoint_kw": 45.0, "setpoint_preview_s": 6.0})
    assert loop.link.specs.keys() >= {"setpoint_preview_kw", "grid_voltage_factor"}
    previews = [c["setpoint_preview_kw"] for c in ctrl.calls]
    assert previews == [(46.0, 47.0, 48.0), None, None, None, (46.0, 47.0, 48.0)]
    volts = [c["grid_voltage_factor"] for c in ctrl.calls]
    assert volts[0] == 0.95 and volts[4] == 0.97 and all(math.isnan(v) for v in volts[1:4])
    events = [r["events"] for r in rows]
    # said once when it turns unusable, once when it is back; nothing in between
    assert "setpoint preview not usable at t=2s ([nodes] setpoint_preview_kw stale)" in events[1]
    assert "grid voltage not usable at t=2s" in events[1]
    assert events[2] == "" and "setpoint preview not usable at t=6s" in events[3]
    assert "usable again" in events[4] and events[4].count("usable again") == 2
    # setpoint_preview_s = 0 with the node: all of it
    ctrl = _Recorder()
    _loop_steps(tmp_path, ctrl, reads[:1], nodes=nodes, run={"setpoint_kw": 45.0})
    assert ctrl.calls[0]["setpoint_preview_kw"] == tuple(ahead)


def test_a_controller_without_the_keywords_runs_on_and_is_warned_of(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    nodes = served_nodes() | {"grid_voltage_factor": "ns=2;s=Heater.GridVoltage"}
    ctrl = _OldStyle()
    _loop_steps(tmp_path, ctrl, [{"power_kw": _dv(45.0), "grid_voltage_factor": _dv(0.9)}],
                nodes=nodes, run={"setpoint_kw": 45.0})
    assert ctrl.calls == [{"setpoint_kw": 45.0}]
    assert "grid_voltage_factor is configured but this controller does not take it" in caplog.text


# -- the node check ------------------------------------------------------------------------

def _attrs(value: Any, rank: int, vtype: Any = None) -> dict[str, Any]:
    vt = vtype or ua.VariantType.Double
    return {"Value": _dv(value, vtype=vt),
            "DataType": ua.DataValue(ua.Variant(ua.NodeId(vt.value, 0))),
            "ValueRank": ua.DataValue(ua.Variant(rank, ua.VariantType.Int32)),
            "AccessLevel": ua.DataValue(ua.Variant(1, ua.VariantType.Byte)),
            "UserAccessLevel": ua.DataValue(ua.Variant(1, ua.VariantType.Byte))}


def test_the_check_wants_an_array_for_the_preview_and_a_scalar_for_the_voltage() -> None:
    spec = SPECS["setpoint_preview_kw"]
    ok, _ = check_node("setpoint_preview_kw", spec, _attrs([46.0, 47.0], 1), user=None)
    assert ok.problem is None
    scalar, _ = check_node("setpoint_preview_kw", spec, _attrs(46.0, -1), user=None)
    assert scalar.code == "BadTypeMismatch" and "one-dimensional array" in (scalar.problem or "")
    text, _ = check_node("setpoint_preview_kw", spec, _attrs(["a"], 1, ua.VariantType.String),
                         user=None)
    assert text.code == "BadTypeMismatch"
    volt, _ = check_node("grid_voltage_factor", SPECS["grid_voltage_factor"], _attrs(0.97, -1),
                         user=None)
    assert volt.problem is None
    volt_array, _ = check_node("grid_voltage_factor", SPECS["grid_voltage_factor"],
                               _attrs([0.97], 1), user=None)
    assert volt_array.code == "BadTypeMismatch"


def test_the_guides_preview_config_passes_the_validator(tmp_path: Path) -> None:
    """docs/guides/plant_link.rst section 9's addition to section 2's run config."""
    import re
    import tomllib

    guide = (Path(__file__).parents[3] / "docs" / "guides" / "plant_link.rst").read_text(
        encoding="utf-8")
    blocks = re.findall(r"\.\. code-block:: toml\n(   :caption: [^\n]*\n)?\n((?:   [^\n]*\n|\n)+)",
                        guide)
    docs = [(caption, tomllib.loads("\n".join(line[3:] for line in body.splitlines())))
            for caption, body in blocks]
    base = next(doc for caption, doc in docs if not caption and "nodes" in doc)
    (added,) = [doc for caption, doc in docs if "section 2" in caption]
    from czmpc.runtime.config import run_config_from_dict

    doc = {**base, "nodes": base["nodes"] | added["nodes"], "run": base["run"] | added["run"]}
    cfg = run_config_from_dict(doc, base_dir=tmp_path)
    assert cfg.preview_samples == 30 and cfg.nodes.grid_voltage_factor is not None
