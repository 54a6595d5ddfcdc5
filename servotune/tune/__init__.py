"""Controller synthesis: PI for the master axis, the slave's fuzzy-PID + feedforward tuning."""

from servotune.tune.pi import PITuning, pi_loop_shaping, tune_pi, tune_pi_axis

__all__ = ["PITuning", "pi_loop_shaping", "tune_pi", "tune_pi_axis"]
