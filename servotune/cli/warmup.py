"""The compiled kernels: ``warmup`` (compile every kernel now), and :func:`compile_kernels`, the
step the other verbs take before the work that needs their kernels.

A cold cache (a fresh install, edited sources) is compiled in that step, with its lines on
stderr (:func:`servotune.kernels.warm_up`); a warm one costs a look at numba's index files and
prints nothing.
"""

from __future__ import annotations

import argparse
import sys

from servotune.cli.output import EXIT_OK, print_product, progress_line


def compile_kernels(*groups: str) -> None:
    """Compile the kernel groups a verb is about to use if the cache lacks them, saying so."""
    from servotune.kernels import warm_up

    warm_up(groups, progress=progress_line)


def cmd_warmup(args: argparse.Namespace) -> int:
    from servotune.kernels import GROUPS, warm_up

    result = warm_up(args.groups or None, progress=progress_line)
    names = result.compiled + result.cached
    asked = "every kernel group" if len(names) == len(GROUPS) else ", ".join(names)
    where = f" in {result.cache_dir}" if result.cache_dir is not None else ""
    if result.compiled:
        print(
            f"compiled the {', '.join(result.compiled)} kernels in {result.seconds:.0f} s, "
            f"cached{where}: later runs load them",
            file=sys.stderr,
        )
    else:
        print(f"nothing to compile: {asked} already compiled (cached{where})", file=sys.stderr)
    for name in result.still_cold:
        print(
            f"servotune warmup: warning: the {name} kernels compiled but could not be cached "
            f"(is the cache directory writable?): every run compiles them again",
            file=sys.stderr,
        )
    if args.json:
        print_product(True, result.to_dict, str)
    return EXIT_OK
