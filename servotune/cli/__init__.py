"""Command line: ``servotune <verb>``. Each handler is a few lines calling the library.

stdout carries only the product (JSON, CSV); diagnostics go to stderr. Exit codes: 0 ok,
1 a verification or tuning failed its spec, or the inputs are not the verified ones (a digest
differs), 2 usage error, 3 bad input data, 130 interrupted (SIGINT, Ctrl-C), 143 terminated
(SIGTERM). Errors are one line on stderr; the traceback only with ``--debug``. An interrupted
or terminated run leaves no partial or temporary file: every output is written to a temporary
file and renamed into place, and the temporary file is removed when the run stops.

The package, its imports running down: :mod:`~servotune.cli.output` (exit codes, signals,
progress, error lines, the product) ← the verbs' handlers, by concept
(:mod:`~servotune.cli.measure`: init, rig, simulate, excite, fit; :mod:`~servotune.cli.design`:
tune, plan, verify, margins; :mod:`~servotune.cli.tables`: export-table, check-table;
:mod:`~servotune.cli.studies`: demo, compare, sync, linkage; :mod:`~servotune.cli.warmup`:
warmup, and the compile step the others take first) ← :mod:`~servotune.cli.parser`
(the verbs and their options) ← this module (:func:`main`, the ``servotune`` script).
"""

from __future__ import annotations

import argparse
import signal
import sys
import warnings
from collections.abc import Callable, Sequence
from contextlib import nullcontext

from servotune.budget import set_memory_budget
from servotune.cli.output import SIGNALLED, SINK, Terminated, on_sigterm, outcome, progress_line
from servotune.cli.parser import build_parser
from servotune.errors import ServotuneError
from servotune.kernels import compile_notices

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (module docstring)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    previous = signal.signal(signal.SIGTERM, on_sigterm)
    SIGNALLED.clear()
    format_warning = warnings.formatwarning

    def one_line(message: Warning | str, *_: object, **__: object) -> str:
        return f"servotune {args.verb}: warning: {message}\n"

    if not args.debug:  # a warning is one line naming the verb (the source line only on --debug)
        warnings.formatwarning = one_line
    try:
        if args.max_memory is not None:
            set_memory_budget(args.max_memory)
        if getattr(args, "workers", None) is not None:  # no cluster of 10,000 processes
            from servotune.executor import check_workers

            check_workers(args.workers, args.scheduler)  # one line, exit 3, before any work
        if args.quiet or sys.stderr.isatty():  # tqdm only where it draws bars (--help stays lean)
            from servotune.progress import StderrProgress

            SINK.append(StderrProgress(quiet=args.quiet))
        # the verbs' warm-up steps say when kernels compile; on a terminal, so does any other
        # compiling (a small kernel, a specialisation no step covers). Not in a log or a pipe:
        # there a failed run's stderr stays its one error line, whatever the cache holds
        with compile_notices(progress_line) if sys.stderr.isatty() else nullcontext():
            return func(args)
    except (ServotuneError, OSError, KeyboardInterrupt, Terminated) as exc:
        if args.debug:
            raise
        message, code = outcome(exc)
        print(f"servotune {args.verb}: {message}", file=sys.stderr)
        return code
    finally:
        signal.signal(signal.SIGTERM, previous)
        warnings.formatwarning = format_warning
        set_memory_budget(None)
        while SINK:
            close = getattr(SINK.pop(), "close", None)
            if close is not None:
                close()
