"""What a running HAL session has: its pins and threads, read with ``halcmd``
(docs/autotune.md#checking-the-session).

:func:`parse_pins` and :func:`parse_threads` read ``halcmd show pin`` and ``halcmd show thread``
output (LinuxCNC 2.9's layout: a header line, then one line per pin ``owner type dir value name``,
the owner a number, or its component's name with ``-s``, with ``<==``/``==>``/``<=>`` and a signal
where it is linked; per thread ``period FP name (time, max-time)`` then its functions).
:func:`read_session` runs ``halcmd -s`` where a session's ``rtapi_app`` runs, and returns None
where there is no ``halcmd`` or no session.

:class:`Halcmd` changes a running session, one ``halcmd -s`` call per command (``getp``, ``setp``,
``net``, ``unlinkp``, ``loadrt``, ``addf``, …), and runs ``halstreamer`` and ``halsampler`` against
it; a command HAL refuses is a :class:`~servotune.errors.HalError` naming the command and HAL's own
message.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from servotune.errors import HalError

__all__ = [
    "HalPin",
    "HalSession",
    "Halcmd",
    "parse_pins",
    "parse_thread_functions",
    "parse_threads",
    "read_session",
]

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
        # the owner is a number (show pin) or the component's name (halcmd -s show pin)
        if len(f) >= 5 and f[1] in PIN_TYPES and f[2] in PIN_DIRS:
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


def parse_thread_functions(text: str) -> dict[str, list[str]]:
    """The functions of each thread of ``halcmd show thread`` output, in the order the thread
    runs them: name → function names. Both of its forms: ``halcmd -s`` prints a thread on one
    line (period, FP, name, time, max time, the functions), plain ``halcmd`` the functions on
    numbered lines below the thread's (whose times are in parentheses)."""
    threads: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in text.splitlines():
        f = line.split()
        if len(f) >= 3 and f[0].isdigit() and f[1] in ("YES", "NO"):
            current = threads.setdefault(f[2], [])
            if len(f) >= 5 and f[3] != "(":  # the one-line form
                current.extend(f[5:])
                current = None
        elif current is not None and len(f) == 2 and f[0].isdigit():
            current.append(f[1])
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


class Halcmd:
    """Commands to a running HAL session (module docstring); ``timeout`` [s] per command.

    ``user``: run every HAL program as that user (``runuser -m -u USER``, the environment
    kept: ``HOME`` or ``RTAPI_FIFO_PATH`` must lead to the session's ``.rtapi_fifo``), for a
    servotune running as root beside a session another user started (``halrun`` refuses
    root, and a component loads only into its owner's session).
    """

    def __init__(self, timeout: float = 30.0, user: str | None = None) -> None:
        exe = shutil.which("halcmd")
        if exe is None:
            raise HalError("halcmd is not installed (LinuxCNC's HAL): no HAL session to work in")
        self.exe = exe
        self.timeout = timeout
        self.prefix = [] if user is None else ["runuser", "-m", "-u", user, "--"]

    def __call__(self, *args: str) -> str:
        """Run ``halcmd -s ARGS``; its standard output."""
        return self._run([self.exe, "-s", *args], f"halcmd {' '.join(args)}")

    def _run(
        self, argv: list[str], what: str, stdin: bytes | None = None, timeout: float | None = None
    ) -> str:
        limit = self.timeout if timeout is None else timeout
        try:
            res = subprocess.run(
                [*self.prefix, *argv], input=stdin, capture_output=True, timeout=limit
            )
        except subprocess.TimeoutExpired:
            raise HalError(f"{what}: no answer in {limit:g} s") from None
        except OSError as exc:
            raise HalError(f"{what}: {exc.strerror}") from None
        if res.returncode != 0:
            msg = " ".join((res.stderr or res.stdout).decode(errors="replace").split())
            raise HalError(f"{what} failed: {msg or f'exit {res.returncode}'}")
        return res.stdout.decode(errors="replace")

    def getp(self, name: str) -> str:
        """A pin's or parameter's value as HAL prints it."""
        return self("getp", name).strip()

    def get_float(self, name: str) -> float:
        return float(self.getp(name))

    def get_bit(self, name: str) -> bool:
        return self.getp(name).upper() in ("TRUE", "1")

    def setp(self, name: str, value: str | float | int | bool) -> None:
        if isinstance(value, bool):
            value = "1" if value else "0"
        self("setp", name, value if isinstance(value, str) else repr(float(value)))

    def session(self) -> HalSession:
        """The session's pins and threads now."""
        return HalSession(
            pins=parse_pins(self("show", "pin")), threads=parse_threads(self("show", "thread"))
        )

    def stream(self, rows: str, *, instance: int = 0, timeout: float) -> None:
        """Feed ``rows`` (one line of values per period) to ``streamer.<instance>`` with
        ``halstreamer``; returns once every row is in the FIFO."""
        exe = shutil.which("halstreamer")
        if exe is None:
            raise HalError("halstreamer is not installed (LinuxCNC's HAL)")
        self._run([exe, "-c", str(instance)], "halstreamer", rows.encode(), timeout)

    def sample(self, n: int, *, instance: int = 0) -> str:
        """``n`` records of ``sampler.<instance>`` read with ``halsampler -t`` (the sample
        number first)."""
        exe = shutil.which("halsampler")
        if exe is None:
            raise HalError("halsampler is not installed (LinuxCNC's HAL)")
        return self._run([exe, "-c", str(instance), "-t", "-n", str(n)], "halsampler")
