"""PID tuning with a gain schedule from an identified model (layer 1.5: the core below, peers above).

From a Hammerstein model, linearised at breakpoints of the TRIAC input, this room tunes
a PI or PID per breakpoint by a published rule or an Ms-bounded optimisation, on the
sampled loop (hold and delay included), checks the schedule between breakpoints, runs
it (velocity form, bumpless, anti-windup) and writes it as the plant's own PID block
wants it.

- `czmpc.pid.plant`: the local plant at a breakpoint and its dead-time reduction.
- `czmpc.pid.rules`: SIMC, lambda/IMC, AMIGO and the sampled gain-delay rule.
- `czmpc.pid.margins`: Ms, gain and phase margins from a frequency response.
- `czmpc.pid.design`: one plant tuned by a rule, its knob or an Ms bound.
- `czmpc.pid.schedule`: the schedule over the TRIAC range, breakpoints added where needed.
- `czmpc.pid.controller`: the scheduled PID that runs in closed loop.
- `czmpc.pid.table`: ``pid_table.csv`` and the characterizer table, written and read.
- `czmpc.pid.vendor`: the tuning in the forms and units of DCS and PLC PID blocks.
- `czmpc.pid.report`: what ``czmpc tune-pid`` writes (tables, vendor forms, ``report.md``).

It imports the core (`czmpc.inversion`, `czmpc.errors`) and `sysid`; never `sim`.
"""

from czmpc.pid.controller import PIDStep, ScheduledPID, TableSchedule
from czmpc.pid.design import DesignSpec, tune_local
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.margins import LoopMargins, loop_margins, sampled_margins
from czmpc.pid.plant import LocalPlant, RulePlant, local_plant, reduce_to_rule_plant
from czmpc.pid.rules import PIDTuning, amigo, gain_delay_sampled, lambda_imc, simc
from czmpc.pid.schedule import PIDSchedule, ScheduleRow, tune_schedule

__all__ = [
    "DesignSpec",
    "PIDSchedule",
    "LocalPlant",
    "LoopMargins",
    "PIDStep",
    "PIDTuning",
    "PIDTuningError",
    "RulePlant",
    "ScheduleRow",
    "ScheduledPID",
    "TableSchedule",
    "amigo",
    "gain_delay_sampled",
    "lambda_imc",
    "local_plant",
    "loop_margins",
    "reduce_to_rule_plant",
    "sampled_margins",
    "simc",
    "tune_local",
    "tune_schedule",
]
