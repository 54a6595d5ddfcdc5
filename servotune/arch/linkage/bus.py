"""The serial bus the master broadcasts on, the clock sync, the slave CPUs
(docs/systems.md#multi-cpu-linkage).

Their fields are checked against :mod:`servotune.arch.bounds` (re-exported here) and
:data:`MAX_CLOCK_PPM`; a typo must not size the simulation's arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

from servotune.arch.bounds import MAX_GAIN, MAX_SECONDS
from servotune.arch.bounds import MAX_SPEED_CPS as MAX_FEED_CPS
from servotune.errors import ConfigError
from servotune.validate import check_integer, check_number, show_value

__all__ = [
    "MAX_CLOCK_PPM",
    "MAX_FEED_CPS",
    "MAX_GAIN",
    "MAX_SECONDS",
    "Bus",
    "Clock",
    "SlaveCpu",
]

MAX_CLOCK_PPM = 10_000.0
"""Largest clock error accepted [ppm] (1 %, beyond a ceramic resonator's tolerance)."""
# MAX_SECONDS (dwell, settle, resync interval), MAX_GAIN (PI gains) and MAX_FEED_CPS (the feed:
# MAX_SPEED_CPS; accelerations up to MAX_ACCEL_CPS2) are every architecture's (arch.bounds).


# --- bus, clock, slave CPUs ----------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Bus:
    """The serial bus (SCI) the master broadcasts the command blocks on.

    Parameters
    ----------
    baud : float
        Line rate [bits/s].
    block_size : int
        Commands per axis in one block [setpoints]; one block is broadcast every
        ``block_size · period_s`` (the broadcast period).
    bytes_per_setpoint : int
        Bytes of one axis's command in a block [bytes] (4: an int32 position).
    frame_overhead_bytes : int
        Bytes of a block frame besides the commands (header, block index, CRC) [bytes].
    bits_per_byte : int
        Bits on the line per byte [bits] (10 for 8N1: start, 8 data, stop).
    max_utilisation : float
        Largest accepted frame time / broadcast period [-], in (0, 1].
    prefill_blocks : int
        Blocks the master sends before motion starts [blocks].
    """

    baud: float
    block_size: int
    bytes_per_setpoint: int = 4
    frame_overhead_bytes: int = 8
    bits_per_byte: int = 10
    max_utilisation: float = 1.0
    prefill_blocks: int = 1

    def __post_init__(self) -> None:
        check_number("baud", self.baud, "bits/s", strict=True, hi=1e9, error=ConfigError)
        check_integer(
            "block_size", self.block_size, "setpoints", lo=1, hi=10_000, error=ConfigError
        )
        check_integer(
            "bytes_per_setpoint", self.bytes_per_setpoint, "bytes", lo=1, hi=64, error=ConfigError
        )
        check_integer(
            "frame_overhead_bytes", self.frame_overhead_bytes, "bytes", hi=65_536, error=ConfigError
        )
        check_integer("bits_per_byte", self.bits_per_byte, "bits", lo=8, hi=16, error=ConfigError)
        # <= 1: a frame cannot outlast its period
        check_number(
            "max_utilisation", self.max_utilisation, "-", strict=True, hi=1.0, error=ConfigError
        )
        check_integer("prefill_blocks", self.prefill_blocks, "blocks", hi=10_000, error=ConfigError)

    def frame_bytes(self, n_axes: int) -> int:
        """Bytes of one block frame for ``n_axes`` axes [bytes]."""
        return self.frame_overhead_bytes + self.bytes_per_setpoint * n_axes * self.block_size

    def frame_s(self, n_axes: int) -> float:
        """Time one block frame takes on the line [s]."""
        return self.frame_bytes(n_axes) * self.bits_per_byte / self.baud


@dataclass(frozen=True, slots=True, kw_only=True)
class Clock:
    """Clock synchronisation.

    Parameters
    ----------
    resync_interval_s : float
        Time between sync broadcasts during motion [s], rounded to whole master ticks;
        0: only the sync at motion start.
    """

    resync_interval_s: float = 0.0

    def __post_init__(self) -> None:
        check_number(
            "resync_interval_s", self.resync_interval_s, "s", hi=MAX_SECONDS, error=ConfigError
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class SlaveCpu:
    """One slave CPU.

    Parameters
    ----------
    name : str
        Its name, unique among the config's CPUs.
    axes : tuple of str
        The 2–4 axes it drives.
    queue_depth : int
        Local queue capacity per axis [setpoints].
    clock_ppm : float
        Its clock's error relative to the master's [ppm] (> 0: runs fast).
    """

    name: str
    axes: tuple[str, ...]
    queue_depth: int
    clock_ppm: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError(f"name must be a non-empty string, got {show_value(self.name)}")
        if isinstance(self.axes, list):
            object.__setattr__(self, "axes", tuple(self.axes))
        if not isinstance(self.axes, tuple) or not all(isinstance(a, str) for a in self.axes):
            raise ConfigError(f"axes must be a list of axis names, got {show_value(self.axes)}")
        if not 2 <= len(self.axes) <= 4:
            raise ConfigError(
                f"axes must name 2 to 4 axes (a slave CPU drives 2–4 motors), got "
                f"{show_value(list(self.axes))}"
            )
        if len(set(self.axes)) != len(self.axes):
            raise ConfigError(f"axes must not repeat an axis, got {show_value(list(self.axes))}")
        check_integer(
            "queue_depth", self.queue_depth, "setpoints", lo=1, hi=1_000_000, error=ConfigError
        )
        check_number(
            "clock_ppm",
            self.clock_ppm,
            "ppm",
            lo=-MAX_CLOCK_PPM,
            hi=MAX_CLOCK_PPM,
            error=ConfigError,
        )
