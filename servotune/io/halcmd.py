"""What a running HAL session has: its pins and threads, read with ``halcmd``
(docs/autotune.md#checking-the-session).

:func:`parse_pins` and :func:`parse_threads` read ``halcmd show pin`` and ``halcmd show thread``
output (LinuxCNC 2.9's layout: a header line, then one line per pin ``owner type dir value name``
with ``<==``/``==>``/``<=>`` and a signal where it is linked; per thread ``period FP name
(time, max-time)`` then its functions). :func:`read_session` runs ``halcmd -s`` where a
session's ``rtapi_app`` runs, and returns None where there is no ``halcmd`` or no session.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

__all__ = ["HalPin", "HalSession", "parse_pins", "parse_threads", "read_session"]

PIN_TYPES = ("bit", "float", "s32", "u32", "s64", "u64", "port")
PIN_DIRS = ("IN", "OUT", "I/O")


@dataclass(frozen=True, slots=True)
class HalPin:
    """One pin: its type (``bit``, ``float``, ``s32``, …), direction (``IN``, ``OUT``, ``I/O``)
    and the signal it is linked to (None if none)."""

    type: str
    dir: str
    signal: str | None = None


@dataclass(frozen=True, slots=True)
class HalSession:
    """A session's pins by name and threads' periods [ns] by name."""

    pins: dict[str, HalPin]
    threads: dict[str, int]


def parse_pins(text: str) -> dict[str, HalPin]:
    """The pins of ``halcmd show pin`` output, by name."""
    pins = {}
    for line in text.splitlines():
        f = line.split()
        if len(f) >= 5 and f[0].isdigit() and f[1] in PIN_TYPES and f[2] in PIN_DIRS:
            signal = f[6] if len(f) >= 7 and f[5] in ("<==", "==>", "<=>") else None
            pins[f[4]] = HalPin(type=f[1], dir=f[2], signal=signal)
    return pins


def parse_threads(text: str) -> dict[str, int]:
    """The threads of ``halcmd show thread`` output: name → period [ns]."""
    threads = {}
    for line in text.splitlines():
        f = line.split()
        if len(f) >= 3 and f[0].isdigit() and f[1] in ("YES", "NO"):
            threads[f[2]] = int(f[0])
    return threads


def _rtapi_running() -> bool:
    """Whether an ``rtapi_app`` process (a user-space HAL session's) runs on this machine."""
    for stat in Path("/proc").glob("[0-9]*/comm"):
        try:
            if stat.read_text().strip() == "rtapi_app":
                return True
        except OSError:  # the process ended while we looked
            continue
    return False


def read_session(timeout: float = 10.0) -> HalSession | None:
    """The running session's pins and threads (``halcmd -s show pin``, ``show thread``), or
    None where ``halcmd`` is not installed or no session runs (no ``rtapi_app`` process, or a
    HAL without a pin or a thread: ``halcmd`` alone would make an empty one)."""
    exe = shutil.which("halcmd")
    if exe is None or not _rtapi_running():
        return None
    out = []
    for what in ("pin", "thread"):
        try:
            res = subprocess.run(
                [exe, "-s", "show", what], capture_output=True, text=True, timeout=timeout
            )
        except (OSError, subprocess.TimeoutExpired):
            return None
        if res.returncode != 0:
            return None
        out.append(res.stdout)
    session = HalSession(pins=parse_pins(out[0]), threads=parse_threads(out[1]))
    return session if session.pins or session.threads else None
