"""Progress on stderr for long runs: what the CLI passes as ``progress`` to the library.

The library reports progress as short lines (``"tune composite: generation 3/12, best ITAE
…"``): a stage name before the colon, and, for a step of a known count, ``k/N``. On a terminal
each stage with a count is one `tqdm <https://tqdm.github.io>`_ bar with its rate and ETA, and a
line without a count is printed above the bars; elsewhere (a log, CI) the lines go out as they
come, one per line. ``quiet`` silences it all. Diagnostics and summaries are not progress: they
never go through here.
"""

from __future__ import annotations

import re
import sys
from typing import Any, TextIO

from tqdm import tqdm

__all__ = ["StderrProgress"]

_STEP = re.compile(r"^(?P<stage>[^:]{1,80}):.*?(?<![\d.])(?P<k>\d+)/(?P<n>\d+)(?![\d.])")


class StderrProgress:
    """A callable progress sink (see the module docstring).

    Parameters
    ----------
    stream : file, optional
        Where to write (default ``sys.stderr``, looked up at each call so that a redirected
        stderr is honoured).
    quiet : bool
        Write nothing.
    tty : bool, optional
        Draw bars (default: whether the stream is a terminal).
    """

    def __init__(
        self, stream: TextIO | None = None, *, quiet: bool = False, tty: bool | None = None
    ) -> None:
        self._stream = stream
        self.quiet = quiet
        self._tty = tty
        self._bar: Any = None
        self._stage = ""

    @property
    def stream(self) -> TextIO:
        """The stream written to."""
        return self._stream if self._stream is not None else sys.stderr

    def _is_tty(self) -> bool:
        if self._tty is not None:
            return self._tty
        isatty = getattr(self.stream, "isatty", None)
        return bool(isatty and isatty())

    def __call__(self, message: str) -> None:
        """Report one progress line."""
        if self.quiet:
            return
        m = _STEP.match(message) if self._is_tty() else None
        if m is None:
            if self._bar is not None:
                self._bar.write(message, file=self.stream)
            else:
                print(message, file=self.stream, flush=True)
            return
        stage, k, n = m["stage"], int(m["k"]), int(m["n"])
        if self._bar is None or stage != self._stage or self._bar.total != n:
            self.close()
            self._bar = tqdm(total=n, desc=stage, file=self.stream, leave=True, dynamic_ncols=True)
            self._stage = stage
        if k > self._bar.n:
            self._bar.update(k - self._bar.n)
        else:  # the same step again (a heartbeat while it lasts): redraw, so its clock runs on
            self._bar.refresh()
        if k >= n:
            self.close()

    def close(self) -> None:
        """End the current bar (if any)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
            self._stage = ""
