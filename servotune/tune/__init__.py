"""Controller synthesis: PI for the master axis (and, later, the slave's fuzzy-PID tables)."""

from servotune.tune.pi import pi_loop_shaping

__all__ = ["pi_loop_shaping"]
