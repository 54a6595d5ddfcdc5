"""Bounds every architecture's configuration checks its fields against.

A typo must not size the simulation's arrays: each field is checked with
:mod:`servotune.validate`'s ``check_number`` / ``check_integer`` against a bound. The bounds
of one architecture only (the gantry's bus cycle, the linkage's clock error) stay in its
package; the ones here are the same in each.
"""

from __future__ import annotations

__all__ = ["MAX_ACCEL_CPS2", "MAX_GAIN", "MAX_SECONDS", "MAX_SPEED_CPS"]

MAX_SECONDS = 3600.0
"""Longest time a configuration gives: a run, a dwell, a settle, a resync interval [s]."""
MAX_GAIN = 1e6
"""Largest controller gain a configuration gives (drive PI, sync compensator; any unit)."""
MAX_SPEED_CPS = 1e9
"""Largest commanded speed or feed [counts/s]."""
MAX_ACCEL_CPS2 = 1e3 * MAX_SPEED_CPS
"""Largest commanded acceleration [counts/s²] (1e12)."""
