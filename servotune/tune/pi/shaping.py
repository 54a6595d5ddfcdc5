"""The closed-form loop-shaping PI rule (:func:`pi_loop_shaping`), for where no tuning exists yet
(the virtual rig's ``track`` scenario, first guesses for optimisers)."""

from __future__ import annotations

import math

from scipy.optimize import brentq

from servotune.laws.pi import PIGains
from servotune.plant import Plant

__all__ = ["pi_loop_shaping"]


def pi_loop_shaping(
    plant: Plant,
    *,
    period_s: float,
    lsb_v: float,
    compute_s: float = 0.0,
    phase_margin_deg: float = 55.0,
    zero_ratio: float = 0.2,
) -> PIGains:
    """PI gains for ``gain / (s (tau s + 1))`` by loop shaping at a target phase margin.

    The loop ``L = (Kp + Ki/s) · LSB · plant`` includes the lag ``compute_s + delay_s`` and the
    ZOH's half period. The crossover ``wc`` solves
    ``180° − 90° − atan(wc·tau) − wc·lag − atan(zero_ratio) = phase_margin_deg``; ``Ki/Kp`` is
    ``zero_ratio · wc``; ``Kp`` makes ``|L(j wc)| = 1``.

    Parameters
    ----------
    plant : Plant
        Axis model.
    period_s : float
        Tick period [s].
    lsb_v : float
        D/A step [V] (gains are in codes).
    compute_s : float
        Tick start → D/A write [s].
    phase_margin_deg : float
        Target phase margin [deg], in (0, 85).
    zero_ratio : float
        PI zero as a fraction of the crossover, in (0, 1).

    Returns
    -------
    PIGains
        ``kp`` [codes/count], ``ki`` [codes/(count·s)].

    Raises
    ------
    ValueError
        If the targets are out of range.

    Examples
    --------
    >>> g = pi_loop_shaping(Plant(gain_cps_per_v=12288, tau_s=0.025), period_s=0.004,
    ...                     lsb_v=20 / 4096)
    >>> round(g.kp, 3) > 0 and g.ki > 0
    True
    """
    if not 0 < phase_margin_deg < 85:
        raise ValueError(f"phase_margin_deg must be in (0, 85) [deg], got {phase_margin_deg!r}")
    if not 0 < zero_ratio < 1:
        raise ValueError(f"zero_ratio must be in (0, 1), got {zero_ratio!r}")
    lag = compute_s + plant.delay_s + period_s / 2
    tau = plant.tau_s
    pm = math.radians(phase_margin_deg)

    def margin(wc: float) -> float:
        return math.pi / 2 - math.atan(wc * tau) - wc * lag - math.atan(zero_ratio) - pm

    hi = math.pi / (2 * lag)
    wc = brentq(margin, 1e-9, hi)
    ki_over_kp = zero_ratio * wc
    plant_mag = plant.gain_cps_per_v * lsb_v / (wc * math.hypot(1.0, wc * tau))
    pi_mag = math.hypot(1.0, ki_over_kp / wc)
    kp = 1.0 / (plant_mag * pi_mag)
    return PIGains(kp=kp, ki=kp * ki_over_kp)
