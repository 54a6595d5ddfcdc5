"""What every verb shares: exit codes, signals, progress, error lines and the product.

stdout carries only the product (:func:`print_product`, :func:`deliver_product`); progress,
summaries and diagnostics go to stderr. :func:`check_outputs`, :func:`check_dirs` and
:func:`workbench_dir` check where outputs go before any work, so a run that cannot write fails
first.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

from servotune.errors import AutotuneStopped, InfeasibleError, ServotuneError, TrustError

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_BAD_INPUT = 0, 1, 2, 3
EXIT_INTERRUPTED, EXIT_TERMINATED = 128 + signal.SIGINT, 128 + signal.SIGTERM


class Terminated(BaseException):
    """Raised in the main thread by the SIGTERM handler, so cleanup (``finally``) runs."""


SIGNALLED: list[int] = []  # the signal that asked this run to end, once one has


def on_sigterm(signum: int, frame: object) -> None:
    SIGNALLED.append(signum)
    raise Terminated


SINK: list[Callable[[str], None]] = []  # this run's progress sink (main sets it)


def progress_line(message: str) -> None:
    """Progress on stderr (:class:`servotune.progress.StderrProgress`: bars on a terminal, lines
    elsewhere, nothing with ``--quiet``); long runs report often, so this is also where a run
    whose SIGTERM exception was swallowed (raised inside a destructor or a C callback, where
    Python ignores exceptions) ends after all."""
    if SIGNALLED:
        raise Terminated
    if SINK:
        SINK[-1](message)
    else:
        print(message, file=sys.stderr)


_MAX_MESSAGE = 600  # characters of an error line


def outcome(exc: BaseException) -> tuple[str, int]:
    """The one line (after ``servotune VERB:``) and the exit code for a run that raised."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted", EXIT_INTERRUPTED
    if isinstance(exc, Terminated):
        return "terminated", EXIT_TERMINATED
    if isinstance(exc, TrustError):
        return f"refused: {_line(exc)}", EXIT_FAILED
    if isinstance(exc, AutotuneStopped):
        return f"stopped: {_line(exc)}", EXIT_FAILED
    if isinstance(exc, InfeasibleError):
        return f"failed: {_line(exc)}", EXIT_FAILED
    if isinstance(exc, OSError) and not isinstance(exc, ServotuneError):
        where = f" {_line(repr(exc.filename))}:" if getattr(exc, "filename", None) else ""
        return f"error:{where} {_line(exc.strerror or exc)}", EXIT_BAD_INPUT
    return f"error: {_line(exc)}", EXIT_BAD_INPUT


def _line(exc: object) -> str:
    """An error as one line of at most :data:`_MAX_MESSAGE` characters."""
    text = " ".join(str(exc).split())
    return text if len(text) <= _MAX_MESSAGE else text[: _MAX_MESSAGE - 1] + "…"


def print_product(as_json: bool, doc: Callable[[], object], text: Callable[[], str]) -> None:
    """The product on stdout: ``doc()`` as indented, key-sorted JSON, or else ``text()``."""
    if as_json:
        print(json.dumps(doc(), indent=2, sort_keys=True))
    else:
        print(text())


def print_summary(as_json: bool, doc: object, text: Callable[[], str]) -> None:
    """A verb's summary (docs/decisions.md#10-output-streams): with ``--json`` ``doc`` as JSON on
    stdout, else ``text()`` on stderr."""
    if as_json:
        print(json.dumps(doc, indent=2, sort_keys=True))
    else:
        print(text(), file=sys.stderr)


def deliver_product(
    output: str | None,
    write: Callable[[str | Path], None],
    text: Callable[[], str],
    what: str,
    current: Path | None = None,
) -> None:
    """A file product: written to ``output`` (saying so on stderr), else its ``text()`` on
    stdout; and recorded as the workbench's ``current`` tuning when given."""
    if output and output != "-":
        write(output)
        print(f"wrote {what} to {output}", file=sys.stderr)
    else:
        sys.stdout.write(text())
    if current is not None:
        write(current)
        print(f"recorded it as the current tuning ({current})", file=sys.stderr)


def check_outputs(*paths: str | None, inputs: Sequence[str | Path | None] = ()) -> None:
    """Fail before any work when an output file's directory is missing, the output names a
    directory, or it is one of the command's ``inputs`` (writing it would replace what was
    read): nothing gets written."""
    for p in paths:
        if not p or p == "-":
            continue
        if Path(p).is_dir():
            raise IsADirectoryError(
                errno.EISDIR, "is a directory: give the name of the file to write", p
            )
        for i in inputs:
            if i and Path(p).exists() and Path(i).exists() and os.path.samefile(p, i):
                named = f" ({str(i)!r})" if str(i) != str(p) else ""
                raise ServotuneError(
                    f"{str(p)!r} is also an input of this command{named}: writing it would "
                    "replace it; give another output file"
                )
        parent = Path(p).resolve().parent
        if not parent.is_dir():
            raise FileNotFoundError(
                2, f"the directory of {p!r} does not exist (create it first)", p
            )
        _probe(parent, f"cannot write {p!r}")


def _probe(directory: Path, what: str) -> None:
    """Create and remove a file of a unique name in ``directory``, as every output is written
    (a temporary file there, renamed into place): a directory where no file can be created
    (read-only, ``/proc``, full) fails before any work instead of after it. ``what`` begins
    the error line. The file is removed whatever happens."""
    try:
        fd, name = tempfile.mkstemp(prefix=".servotune-probe-", dir=directory)
    except OSError as exc:
        raise ServotuneError(
            f"{what}: cannot create a file in {str(directory)!r} ({exc.strerror or exc})"
        ) from None
    try:
        os.close(fd)
    finally:
        os.unlink(name)


def check_dirs(*dirs: str | None) -> None:
    """Fail before any work when an output directory (``--out``, ``--report``, ``--plot``, the C
    export's ``-o``) names an existing file, or cannot be created under its nearest existing
    parent (a file in the way, or no file can be created there: :func:`_probe`, in the
    directory if it exists, else in that parent). No directory is created here: a command
    that then fails on its inputs leaves no empty directory behind."""
    for d in dirs:
        if not d:
            continue
        p = Path(d)
        if p.exists() and not p.is_dir():
            raise ServotuneError(
                f"{d!r} is a file, not a directory: give a directory to write into "
                "(it is created if missing)"
            )
        if p.is_dir():
            _probe(p, f"the directory {d!r} is not writable")
            continue
        parent = p.absolute().parent
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        if not parent.is_dir():
            raise ServotuneError(f"cannot create the directory {d!r}: {str(parent)!r} is a file")
        _probe(parent, f"cannot create the directory {d!r}")


def workbench_dir(d: Path) -> None:
    """Create the workbench directory and check it is writable, before any work or output."""
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ServotuneError(
            f"cannot create the workbench directory {str(d)!r}: {exc.strerror or exc} "
            "(set SERVOTUNE_WORKBENCH, or pass --no-current)"
        ) from None
    _probe(
        d,
        f"the workbench directory {str(d)!r} is not writable (set SERVOTUNE_WORKBENCH, "
        "or pass --no-current)",
    )
