"""A disk that fills up, for the tests of outputs written as a whole (docs/formats.md#outputs):
``os.write`` as servotune.io.files calls it fails with ENOSPC from its ``n``-th call on."""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator

import servotune.io.files as files


@contextlib.contextmanager
def no_space_at(monkeypatch, n: int) -> Iterator[list[int]]:
    """Within the block, the ``n``-th and every later ``os.write`` raise ENOSPC ("No space
    left on device"); yields the count of calls so far (a one-item list)."""
    calls = [0]
    real = os.write

    def write(fd: int, data) -> int:
        calls[0] += 1
        if calls[0] >= n:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fd, data)

    with monkeypatch.context() as m:
        m.setattr(files.os, "write", write)
        yield calls
