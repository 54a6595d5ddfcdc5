"""A time and memory guard for tests that feed hostile inputs to the readers (the corpus and
the fuzz tests): a file asking for a 2**(10**12) integer must not take the test run down."""

from __future__ import annotations

import contextlib
import resource
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any


class GuardTimeout(BaseException):
    """Raised when a guarded block runs too long (not an Exception: ``main()`` must not catch
    it)."""


@contextlib.contextmanager
def guarded(seconds: int, memory: int) -> Iterator[None]:
    """Raise :class:`GuardTimeout` after ``seconds``, MemoryError beyond ``memory`` more bytes
    of address space than the process holds now."""

    def on_alarm(signum: int, frame: Any) -> None:
        raise GuardTimeout(f"still running after {seconds} s")

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    vm = next(
        int(ln.split()[1]) * 1024
        for ln in Path("/proc/self/status").read_text().splitlines()
        if ln.startswith("VmSize:")
    )
    limit = vm + memory if hard == resource.RLIM_INFINITY else min(vm + memory, hard)
    old = signal.signal(signal.SIGALRM, on_alarm)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
        signal.signal(signal.SIGALRM, old)
