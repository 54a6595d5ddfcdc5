"""The checks the master makes before motion, the bus figures and the resync rule."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune.arch.linkage.config import LinkageAxis, LinkageConfig
from servotune.arch.linkage.path import Interpolation, interpolate
from servotune.errors import ConfigError
from servotune.hw import counter as hw_counter

__all__ = [
    "BusFigures",
    "Check",
    "LinkageCheckError",
    "bus_figures",
    "check_linkage",
    "recommended_resync_interval_s",
]


class LinkageCheckError(ConfigError):
    """A check made before motion failed (bus overload, prefill or queue too short, speed).

    The configuration is well formed but the machine cannot run it; ``checks`` holds the failed
    :class:`Check` entries, and the message states every reason with its numbers.
    """

    def __init__(self, checks: tuple[Check, ...]) -> None:
        self.checks = tuple(checks)
        super().__init__("; ".join(c.detail for c in self.checks))


@dataclass(frozen=True, slots=True, kw_only=True)
class Check:
    """One check of the linkage.

    Parameters
    ----------
    name : str
        ``bus``, ``prefill``, ``queue:<cpu>``, ``speed:<axis>`` (before motion);
        ``underrun:<cpu>``, ``overrun:<cpu>``, ``fault:<axis>`` (during motion).
    passed : bool
    detail : str
        What was checked, with the numbers; for a failure the reason and what to change.
    """

    name: str
    passed: bool
    detail: str

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {"detail": self.detail, "name": self.name, "passed": self.passed}


@dataclass(frozen=True, slots=True, kw_only=True)
class BusFigures:
    """The bus and queue figures of a linkage at nominal clocks (:func:`bus_figures`).

    Attributes
    ----------
    frame_bytes : int
        Bytes of one block frame [bytes].
    frame_s : float
        Time one block frame takes on the line [s].
    broadcast_period_s : float
        Time between two blocks, ``B·T`` [s].
    utilisation : float
        ``frame_s / broadcast_period_s`` [-].
    lead_s : float
        How long before its first command is needed a block arrives, ``P·B·T − frame_s`` [s].
    nominal_min_level : int
        Queue level before the pop just ahead of each arrival, ``P·B − floor(frame_s/T)``
        [setpoints].
    required_queue_depth : int
        Queue capacity the prefill plus the block in flight need, ``(P + 1)·B`` [setpoints].
    """

    frame_bytes: int
    frame_s: float
    broadcast_period_s: float
    utilisation: float
    lead_s: float
    nominal_min_level: int
    required_queue_depth: int

    def to_dict(self) -> dict[str, int | float]:
        """Plain dict of the fields, sorted by name."""
        return {k: getattr(self, k) for k in sorted(self.__slots__)}  # type: ignore[attr-defined]


def bus_figures(config: LinkageConfig) -> BusFigures:
    """The bus and queue figures the checks use (nominal clocks).

    Parameters
    ----------
    config : LinkageConfig

    Returns
    -------
    BusFigures

    Examples
    --------
    >>> from servotune.arch.linkage import load_linkage
    >>> from servotune.rig import EXAMPLE_RIG_PATH
    >>> f = bus_figures(load_linkage(EXAMPLE_RIG_PATH.parent / "linkage-6axis.toml"))
    >>> f.frame_bytes, round(f.utilisation, 3)
    (128, 0.278)
    """
    bus, period = config.bus, config.period_s
    n = config.n_axes
    frame_s = bus.frame_s(n)
    bp = bus.block_size * period
    return BusFigures(
        frame_bytes=bus.frame_bytes(n),
        frame_s=frame_s,
        broadcast_period_s=bp,
        utilisation=frame_s / bp,
        lead_s=bus.prefill_blocks * bp - frame_s,
        nominal_min_level=bus.prefill_blocks * bus.block_size - math.floor(frame_s / period),
        required_queue_depth=(bus.prefill_blocks + 1) * bus.block_size,
    )


def _speed_limits(config: LinkageConfig, a: LinkageAxis) -> tuple[float, str]:
    """Largest speed an axis may be commanded to [counts/s] and what limits it."""
    rig = config.rig
    cpr = rig.counts_per_rev
    drive = a.plant.max_speed_cps(cpr)
    lo, hi = rig.dac.range_v
    reach_v = min(-lo, hi) - abs(a.plant.offset_v) - a.plant.coulomb_v
    dac = a.plant.gain_cps_per_v * reach_v
    unwrap = hw_counter.max_counts_per_tick(rig.counter.bits) / config.period_s
    options = [
        (drive, f"the drive's limit ({a.plant.max_speed_rpm} r/min × {cpr:g} counts/rev)"),
        (dac, f"what the D/A reaches ({reach_v:.3f} V × {a.plant.gain_cps_per_v:g} counts/s/V)"),
        (unwrap, f"the counter's high-byte unwrap limit ({rig.counter.bits}-bit, per tick)"),
    ]
    return min(options, key=lambda o: o[0])


def check_linkage(
    config: LinkageConfig, interpolation: Interpolation | None = None
) -> tuple[Check, ...]:
    """The checks the master makes before motion (nominal clocks).

    - ``bus``: utilisation = frame time / broadcast period <= ``max_utilisation``.
    - ``prefill``: the first block broadcast during motion arrives before its first command is
      needed: ``lead_s = P·B·T − frame_s > 0`` (then every later block does too).
    - ``queue:<cpu>``: the queue holds the prefill plus one block: ``queue_depth >= (P+1)·B``.
    - ``speed:<axis>``: the path's speed on each axis (from the interpolation) stays within the
      drive's speed limit, what the D/A can command and the counter's unwrap limit.

    Parameters
    ----------
    config : LinkageConfig
    interpolation : Interpolation, optional
        The master's path (computed if not given).

    Returns
    -------
    tuple of Check
        Every check, passed or not.
    """
    ip = interpolate(config) if interpolation is None else interpolation
    f = bus_figures(config)
    return (
        _bus_check(config, f),
        _prefill_check(config, f),
        *_queue_checks(config, f),
        *_speed_checks(config, ip),
    )


def _bus_check(config: LinkageConfig, f: BusFigures) -> Check:
    """``bus``: a block frame fits the broadcast period at ``max_utilisation`` (else the baud
    or block size that would make it fit)."""
    bus, period = config.bus, config.period_s
    u = f.utilisation
    bits = bus.bits_per_byte
    if u <= bus.max_utilisation:
        return Check(
            name="bus",
            passed=True,
            detail=(
                f"a block frame ({f.frame_bytes} bytes) takes {f.frame_s * 1e3:.2f} ms of the "
                f"{f.broadcast_period_s * 1e3:.2f} ms broadcast period (utilisation "
                f"{u * 100:.1f} % <= {bus.max_utilisation * 100:.0f} %)"
            ),
        )
    m = bus.max_utilisation
    baud_min = f.frame_bytes * bits / (m * f.broadcast_period_s)
    n = config.n_axes
    per_block = bus.bytes_per_setpoint * n * bits / bus.baud  # line time per setpoint row
    room = m * period - per_block
    hint = f"raise baud to >= {math.ceil(baud_min)}"
    if room > 0:
        b_min = math.ceil(bus.frame_overhead_bytes * bits / bus.baud / room)
        hint += f" or block_size to >= {b_min}"
    return Check(
        name="bus",
        passed=False,
        detail=(
            f"bus overload: a block frame ({f.frame_bytes} bytes × {bits} bits at "
            f"{bus.baud:g} baud) takes {f.frame_s * 1e3:.2f} ms but the broadcast period "
            f"is "
            f"{f.broadcast_period_s * 1e3:.2f} ms (utilisation {u * 100:.0f} % > "
            f"{m * 100:.0f} %) — {hint}"
        ),
    )


def _prefill_check(config: LinkageConfig, f: BusFigures) -> Check:
    """``prefill``: the first block broadcast during motion arrives before it is needed."""
    bus = config.bus
    p_blocks, p_min = bus.prefill_blocks, math.floor(f.frame_s / f.broadcast_period_s) + 1
    early = f.lead_s > 0
    return Check(
        name="prefill",
        passed=early,
        detail=(
            f"each block arrives {f.lead_s * 1e3:.2f} ms before its first command is "
            f"needed (prefill {p_blocks} blocks; worst queue level before a pop "
            f"{f.nominal_min_level} setpoints)"
            if early
            else f"prefill too short: the first block broadcast during motion arrives "
            f"{f.frame_s * 1e3:.2f} ms after the start but its first command is needed at "
            f"{p_blocks * f.broadcast_period_s * 1e3:.2f} ms (prefill {p_blocks} blocks of "
            f"{bus.block_size}) — raise prefill_blocks to >= {p_min}"
        ),
    )


def _queue_checks(config: LinkageConfig, f: BusFigures) -> list[Check]:
    """``queue:<cpu>``: each CPU's queue holds the prefill plus the block in flight."""
    bus = config.bus
    p_blocks = bus.prefill_blocks
    need = f.required_queue_depth
    checks: list[Check] = []
    for c in config.cpus:
        deep = c.queue_depth >= need
        checks.append(
            Check(
                name=f"queue:{c.name}",
                passed=deep,
                detail=(
                    f"cpu {c.name}: queue_depth {c.queue_depth} >= the prefill plus one block "
                    f"({need} setpoints per axis)"
                    if deep
                    else f"queue too short on cpu {c.name}: queue_depth {c.queue_depth} setpoints "
                    f"per "
                    f"axis, but the prefill ({p_blocks} blocks × {bus.block_size}) plus the block "
                    f"in flight need {need} — raise queue_depth to >= {need} or lower "
                    f"prefill_blocks / block_size"
                ),
            )
        )
    return checks


def _speed_checks(config: LinkageConfig, ip: Interpolation) -> list[Check]:
    """``speed:<axis>``: the path's top speed on each axis within its limit
    (:func:`_speed_limits`); a failure names the move and time of the top speed."""
    period = config.period_s
    checks: list[Check] = []
    speed = np.abs(np.diff(ip.positions, axis=0)) / period
    for i, a in enumerate(config.axes):
        limit, what = _speed_limits(config, a)
        k = int(np.argmax(speed[:, i])) if speed.shape[0] else 0
        top = float(speed[k, i]) if speed.shape[0] else 0.0
        if top <= limit:
            checks.append(
                Check(
                    name=f"speed:{a.name}",
                    passed=True,
                    detail=(
                        f"axis {a.name}: the path's top speed {top:,.0f} counts/s is within "
                        f"{what}: {limit:,.0f} counts/s"
                    ),
                )
            )
        else:
            mv = int(ip.move_of_tick[k + 1])
            checks.append(
                Check(
                    name=f"speed:{a.name}",
                    passed=False,
                    detail=(
                        f"axis {a.name}: the path commands {top:,.0f} counts/s (move {mv}, "
                        f"t = {(k + 1) * period:.3f} s) but {what} is {limit:,.0f} counts/s — "
                        f"lower "
                        f"the feed of move {mv} or max_feed_cps"
                    ),
                )
            )
    return checks


def recommended_resync_interval_s(config: LinkageConfig) -> float:
    """The longest resync interval that keeps every slave's drift well within its margins.

    Rule: between two syncs a slave's tick phase drifts by ``|ε|·interval`` against the master
    (``ε = clock_ppm·1e-6``). That drift must stay within half of the smallest of

    - one period ``T`` (so no command is ever skipped or executed twice at a sync, and two
      slaves never differ by more than one tick),
    - the underrun lead ``P·B·T − frame_s`` (how much earlier a fast slave's tick may come
      before a block arrives too late),
    - the overrun slack ``(queue_depth − (P+1)·B + 1)·T + frame_s`` (how much later a slow
      slave's ticks may come before an arriving block no longer fits),

    at the worst ``|clock_ppm|``; the result is rounded down to whole master ticks.

    Parameters
    ----------
    config : LinkageConfig

    Returns
    -------
    float
        Interval [s]; 0.0 if every clock is exact (the start sync suffices).

    Raises
    ------
    LinkageCheckError
        If the lead or a slack is not positive (the prefill or queue checks fail).

    Examples
    --------
    >>> from servotune.arch.linkage import load_linkage
    >>> from servotune.rig import EXAMPLE_RIG_PATH
    >>> recommended_resync_interval_s(load_linkage(EXAMPLE_RIG_PATH.parent / "linkage-6axis.toml"))
    12.5
    """
    f = bus_figures(config)
    period, bus = config.period_s, config.bus
    eps = max(abs(c.clock_ppm) for c in config.cpus) * 1e-6
    if eps == 0.0:
        return 0.0
    slack = min(
        (c.queue_depth - (bus.prefill_blocks + 1) * bus.block_size + 1) * period + f.frame_s
        for c in config.cpus
    )
    if f.lead_s <= 0.0 or slack <= 0.0:
        failed = tuple(c for c in check_linkage(config) if not c.passed)
        raise LinkageCheckError(
            failed
            or (
                Check(
                    name="prefill",
                    passed=False,
                    detail=("no resync interval works: the queue has no margin for drift"),
                ),
            )
        )
    budget = 0.5 * min(period, f.lead_s, slack)
    ticks = max(1, math.floor(budget / eps / period + 1e-9))
    return ticks * period
