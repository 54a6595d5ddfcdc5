"""Control laws as tick step functions in the runtime arithmetic
(docs/runtime.md).

Each law is written once here (numba-compiled, integer arithmetic) and mirrored line by line in
the C runtime. ``axis`` holds the runtime's per-axis tick: counter read and unwrap, mode
switching (lock / task / open), faults, and the dispatch to the task law.
"""

from servotune.laws.axis import AxisController, axis_control, axis_read
from servotune.laws.lock import lock_holding_band, lock_step
from servotune.laws.pi import PIConstants, PIGains, pi_ideal_step, pi_step

__all__ = [
    "AxisController",
    "PIConstants",
    "PIGains",
    "axis_control",
    "axis_read",
    "lock_holding_band",
    "lock_step",
    "pi_ideal_step",
    "pi_step",
]
