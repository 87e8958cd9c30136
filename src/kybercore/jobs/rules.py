"""The queue's rules, pure: what to dispatch where, why a job waits, what can never print.

No asyncio, no database, no I/O, no clock (the caller passes ``now``): the dispatcher feeds
these functions plain data and acts on what they return, and tests call them the same way.

- :func:`plan`: one dispatch round, :func:`placeable`: a job it may place
  (:mod:`kybercore.jobs.planner`).
- :func:`why`, :func:`never_printable`: explanations (:mod:`kybercore.jobs.why`).
- :func:`is_heating`, :func:`power_group`: the heating budget's inputs
  (:mod:`kybercore.jobs.heating`).
- Eligibility of one printer for one job: :mod:`kybercore.jobs.eligibility`; the lines'
  codes and messages: :mod:`kybercore.jobs.reasons`.
"""

from __future__ import annotations

from kybercore.jobs.eligibility import IDLE_STATES, Memo, PrinterSnapshot
from kybercore.jobs.heating import HEATING_MARGIN, is_heating, power_group
from kybercore.jobs.planner import Assignment, Plan, placeable, plan
from kybercore.jobs.reasons import WhyLine
from kybercore.jobs.why import never_printable, why

__all__ = [
    "HEATING_MARGIN",
    "IDLE_STATES",
    "Assignment",
    "Memo",
    "Plan",
    "PrinterSnapshot",
    "WhyLine",
    "is_heating",
    "never_printable",
    "placeable",
    "plan",
    "power_group",
    "why",
]
