"""PID tuning with a gain schedule from an identified model (layer 1.5: the core below, peers above).

From a Hammerstein model, linearised at breakpoints of the TRIAC input, this room tunes
a PI or PID per breakpoint by a published rule or an Ms-bounded optimisation, on the
sampled loop (hold and delay included) in each difference equation a block may run it
with (forward, backward or trapezoidal integration), checks the schedule between
breakpoints, runs it (velocity form, bumpless, anti-windup) and writes it as the plant's
own PID block wants it.

The modules, in that order: ``plant``, ``rules``, ``discretization``, ``margins``,
``design``, ``schedule``, ``controller``, ``table``, ``vendor``, ``report`` (each
docstring's first line says its job). It imports the core (`czmpc.inversion`,
`czmpc.errors`) and `sysid`; never `sim`.
"""

from czmpc.pid.controller import PIDStep, ScheduledPID, TableSchedule
from czmpc.pid.design import DesignSpec, tune_local
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.margins import LoopMargins, loop_margins, sampled_margins
from czmpc.pid.plant import LocalPlant, RulePlant, local_plant, reduce_to_rule_plant
from czmpc.pid.rules import PIDTuning, amigo, gain_delay_sampled, lambda_imc, simc
from czmpc.pid.schedule import PIDSchedule, ScheduleRow, tune_schedule

__all__ = ["DesignSpec", "PIDSchedule", "LocalPlant", "LoopMargins", "PIDStep", "PIDTuning",
           "PIDTuningError", "RulePlant", "ScheduleRow", "ScheduledPID", "TableSchedule", "amigo",
           "gain_delay_sampled", "lambda_imc", "local_plant", "loop_margins", "reduce_to_rule_plant",
           "sampled_margins", "simc", "tune_local", "tune_schedule"]
