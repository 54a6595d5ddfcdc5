"""The whole-job and architecture studies: ``demo``, ``compare`` (Figure 4), ``sync`` (gantry
topologies) and ``linkage`` (a multi-CPU linkage run)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from servotune.cli.output import EXIT_FAILED, EXIT_OK, check_dirs, print_product, progress_line
from servotune.cli.warmup import compile_kernels
from servotune.errors import ServotuneError

# The library is imported inside each handler, not here, so that ``servotune --help`` (and any
# verb) pays only for what it uses: numba, scipy, matplotlib and python-control stay unloaded
# until a handler needs them (tests/cli/test_help_imports.py). That is the only reason for an
# import inside a function in this module; none of them works around an import cycle.


def cmd_compare(args: argparse.Namespace) -> int:
    from servotune.pipeline import DemoPreset, comparison_statement, run_comparison
    from servotune.rig import load_rig
    from servotune.verify.spec import load_spec

    try:
        ms = tuple(float(x) for x in args.pareto.split(",") if x.strip())
    except ValueError:
        raise ServotuneError(
            f"--pareto takes numbers separated by commas, got {args.pareto!r}"
        ) from None
    if args.seeds < 1:
        raise ServotuneError(f"--seeds must be >= 1, got {args.seeds}")
    check_dirs(args.out)
    rig, spec = load_rig(args.rig), load_spec(args.spec)
    compile_kernels("simulation", "margins", "verification")
    preset = DemoPreset(
        generations=args.generations,
        population=args.population,
        seeds=tuple(range(args.seeds)),
        heldout_count=args.heldout_count,
        pareto_ms=ms,
    )
    cmp = run_comparison(rig, spec, args.out, preset=preset, seed=args.seed, progress=progress_line)
    print("\n".join(comparison_statement(cmp)), file=sys.stderr)
    if args.json:
        sys.stdout.write((Path(args.out) / "figure4.json").read_text())
    print(
        f"wrote figure4.png, figure4.json{', pareto.png' if ms else ''} to {args.out}",
        file=sys.stderr,
    )
    return EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    from servotune.pipeline import comparison_table_text, run_demo
    from servotune.rig import load_rig

    check_dirs(args.out)
    load_rig(args.rig)  # a bad rig fails before the output directory is made
    Path(args.out).mkdir(parents=True, exist_ok=True)
    compile_kernels("simulation", "margins", "verification", "identification", "gantry", "linkage")
    summary = run_demo(
        args.rig,
        args.out,
        seed=args.seed,
        preset="full" if args.full else "quick",
        progress=progress_line,
    )
    for name, h in summary["lock_hold"].items():
        print(
            f"lock hold {name}: observed {h['observed_counts']} "
            f"predicted {h['predicted_counts']} counts",
            file=sys.stderr,
        )
    for name, f in summary["identification"].items():
        err = f["relative_error"]
        print(
            f"fit {name}: {'+'.join(f['structure'])}; gain {err['gain_cps_per_v']:+.2%}, "
            f"tau {err['tau_s']:+.2%} vs the virtual rig's truth",
            file=sys.stderr,
        )
    print(
        "Figure 4 (slave tracking, each structure tuned with the same budget):\n"
        + comparison_table_text(summary["comparison"]),
        file=sys.stderr,
    )
    print("\n".join(summary["figure4_statement"]), file=sys.stderr)
    v = summary["verification"]
    print(
        "verify: " + ("PASSED" if v["passed"] else "FAILED: " + "; ".join(v["failures"])),
        file=sys.stderr,
    )
    for name, a in summary["architectures"].items():
        print(f"{name}: {'checks passed' if a['passed'] else 'a check FAILED'}", file=sys.stderr)
    print(
        f"wrote demo_summary.json, report.html, lock_hold.png, track.png, fit_*.png, "
        f"fitted-rig.toml, tuning.json, figure4.png, sync.json, sync_*.png, linkage.json, "
        f"linkage_*.png, "
        f"{', '.join(summary['exported']) or 'no exports'} and logs to {args.out}",
        file=sys.stderr,
    )
    return EXIT_OK


def cmd_sync(args: argparse.Namespace) -> int:
    from servotune.arch.gantry import compare_topologies
    from servotune.arch.gantry.load import load_gantry
    from servotune.arch.gantry.synthesis import resolve_gains
    from servotune.report.text import format_comparison

    check_dirs(args.plot)
    cfg = resolve_gains(
        load_gantry(args.config)
    )  # a bad config is one line, before the gantry's compiling
    compile_kernels("gantry")
    cmp = compare_topologies(cfg, seed=args.seed, montecarlo=args.montecarlo)
    print_product(args.json, cmp.to_dict, lambda: format_comparison(cmp))
    if args.plot:
        from servotune.arch.gantry import CASES
        from servotune.io.files import staged_directory
        from servotune.plot import plot_sync_errors, save_figure

        with staged_directory(args.plot) as stage:
            for case in CASES:
                save_figure(plot_sync_errors(cmp.traces, case), stage / f"sync_{case}.png")
        print(f"wrote sync_{{{','.join(CASES)}}}.png to {args.plot}", file=sys.stderr)
    for reason in cmp.failed:
        print(f"servotune sync: check failed: {reason}", file=sys.stderr)
    return EXIT_OK if cmp.passed else EXIT_FAILED


def cmd_linkage(args: argparse.Namespace) -> int:
    from servotune.arch.linkage import LinkageCheckError, load_linkage, resolve_gains, run_linkage
    from servotune.report.text import format_linkage_summary

    check_dirs(args.plot)
    config = resolve_gains(load_linkage(args.config))  # the gains the file leaves out, tuned
    compile_kernels("linkage")
    try:
        result = run_linkage(config, seconds=args.seconds, seed=args.seed)
    except LinkageCheckError as exc:
        for check in exc.checks:
            print(f"servotune linkage: check failed: {check.detail}", file=sys.stderr)
        return EXIT_FAILED
    print_product(args.json, result.to_dict, lambda: format_linkage_summary(result))
    if args.plot:
        from servotune.io.files import staged_directory
        from servotune.plot import plot_queue_levels, plot_radial_deviation, save_figure

        with staged_directory(args.plot) as stage:
            save_figure(plot_queue_levels(result), stage / "linkage_queues.png")
            save_figure(plot_radial_deviation(result), stage / "linkage_circle.png")
        print(f"wrote linkage_queues.png, linkage_circle.png to {args.plot}", file=sys.stderr)
    for check in result.failed_checks:
        print(f"servotune linkage: check failed: {check.detail}", file=sys.stderr)
    return EXIT_OK if result.passed else EXIT_FAILED
