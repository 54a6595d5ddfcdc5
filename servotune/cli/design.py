"""The verbs that design and check a controller: ``tune`` (a rig or a gantry), ``plan`` (a
linkage), ``verify`` (a rig's or a gantry's tuning, or a linkage plan) and ``margins``."""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path
from typing import Any

from servotune.cli.output import (
    EXIT_FAILED,
    EXIT_OK,
    EXIT_USAGE,
    check_dirs,
    check_outputs,
    deliver_product,
    print_product,
    print_summary,
    progress_line,
    workbench_dir,
)
from servotune.cli.warmup import compile_kernels
from servotune.errors import ServotuneError

# The library is imported inside each handler, not here, so that ``servotune --help`` (and any
# verb) pays only for what it uses: numba, scipy, matplotlib and python-control stay unloaded
# until a handler needs them (tests/cli/test_help_imports.py). That is the only reason for an
# import inside a function in this module; none of them works around an import cycle.


_RIG_ONLY_TUNE = {"spec": None, "rule_base": "default", "generations": 40, "population": 32,
                  "max_overshoot_pct": None, "max_saturation_pct": None,
                  "min_phase_margin_deg": None, "min_gain_margin_db": None,
                  "max_sensitivity": None}  # fmt: skip


def _tune_gantry(args: argparse.Namespace, current: Path | None) -> int:
    from servotune.arch.gantry.load import load_gantry
    from servotune.arch.gantry.tuning import (
        gantry_tuning_to_string,
        tune_gantry,
        write_gantry_tuning,
    )
    from servotune.report.text import format_gantry_tuning

    given = [k for k, v in _RIG_ONLY_TUNE.items() if getattr(args, k) != v]
    if given:
        flag = "--" + given[0].replace("_", "-")
        raise ServotuneError(
            f"{flag} tunes a single rig; a gantry's targets are in its config "
            f"({args.rig}: [sync], [margins])"
        )
    load_gantry(args.rig)  # bad input is one line, before any progress
    progress_line(f"tune gantry {args.rig}: each drive's PI, then the sync compensator")
    compile_kernels("margins", "gantry")
    tuning = tune_gantry(args.rig)
    print_summary(args.json, tuning.design, lambda: format_gantry_tuning(tuning))
    deliver_product(
        args.output,
        lambda p: write_gantry_tuning(tuning, p),
        lambda: gantry_tuning_to_string(tuning),
        "the gantry tuning",
        current,
    )
    return EXIT_OK


def cmd_tune(args: argparse.Namespace) -> int:
    from servotune.arch.kind import config_kind
    from servotune.tuning import current_tuning_path

    check_outputs(args.output, inputs=(args.rig, args.spec))
    current = None if args.no_current else current_tuning_path()
    if current is not None:
        workbench_dir(current.parent)
    if args.json and (not args.output or args.output == "-"):
        raise ServotuneError("--json prints the summary on stdout: give -o FILE for the tuning")
    kind = config_kind(args.rig)
    if kind == "linkage":
        raise ServotuneError(
            f"{args.rig} is a linkage config: plan it with `servotune plan {args.rig}`"
        )
    if kind == "gantry":
        for flag in ("frf", "shaper"):
            if getattr(args, flag):
                raise ServotuneError(
                    f"--{flag} is for a rig file: a gantry config's tune does not take it "
                    "(a gantry's move is shaped by its [move] shaper)"
                )
        return _tune_gantry(args, current)
    from servotune.rig import load_rig

    limits = (
        "max_overshoot_pct",
        "max_saturation_pct",
        "min_phase_margin_deg",
        "min_gain_margin_db",
        "max_sensitivity",
    )
    given = {k: getattr(args, k) for k in limits if getattr(args, k) is not None}
    budget = {"generations": args.generations, "population": args.population}
    rig = load_rig(args.rig)  # a bad rig is one line, before any progress
    frf = frf_files(args.frf)
    for axis in frf:
        rig.axis(axis)
    spec = None
    if args.spec:  # a spec costs the verifier's imports: read and checked before progress too
        from servotune.tune.slave import tune_spec_from
        from servotune.verify.spec import load_spec

        spec = tune_spec_from(load_spec(args.spec), rig=rig, **budget, **given)
    progress_line(f"tune {args.rig}: loading the tuner")  # before the imports: they take a second
    compile_kernels("simulation", "margins")
    from servotune.report.text import format_tuning_summary
    from servotune.tune.slave import tune_spec_from
    from servotune.tune.workflow import tune_rig, tuning_summary
    from servotune.tuning import tuning_to_string, write_tuning

    if spec is None:
        spec = tune_spec_from(None, rig=rig, **budget, **given)
    tuning = tune_rig(
        args.rig,
        seed=args.seed,
        spec=spec,
        rule_base=args.rule_base,
        progress=progress_line,
        frf=frf,
        shaper=args.shaper,
    )
    summary = tuning_summary(tuning)
    print_summary(args.json, summary, lambda: format_tuning_summary(summary))
    deliver_product(
        args.output,
        lambda p: write_tuning(tuning, p),
        lambda: tuning_to_string(tuning),
        "the tuning",
        current,
    )
    return EXIT_OK


def _verify_linkage(args: argparse.Namespace) -> int:
    from servotune.arch.linkage import verify_plan_files
    from servotune.report.text import format_linkage_verification

    for flag, value in (
        ("--rig", args.rig),
        ("--report", args.report),
        ("--seed", args.seed),
        ("--montecarlo", args.montecarlo),
        ("--scheduler", args.scheduler),
        ("--workers", args.workers),
        ("--plants-from", args.plants_from),
    ):
        if value is not None:
            raise ServotuneError(
                f"{flag} is for a single rig's tuning; {args.tuning} is a "
                "linkage plan (its spec sets the run)"
            )
    progress_line(f"verify linkage plan {args.tuning}: every clock case of {args.spec}")
    result, record, path = verify_plan_files(
        args.tuning, args.spec, config_path=args.config, progress=progress_line
    )
    print_summary(args.json, record, lambda: format_linkage_verification(result))
    print(f"wrote the verification record to {path}", file=sys.stderr)
    return EXIT_OK if result.passed else EXIT_FAILED


def _verify_gantry(args: argparse.Namespace) -> int:
    from servotune.arch.gantry.verify import verify_gantry_files
    from servotune.report.text import format_gantry_verification

    for flag, value in (
        ("--rig", args.rig),
        ("--report", args.report),
        ("--plants-from", args.plants_from),
    ):
        if value is not None:
            raise ServotuneError(
                f"{flag} is for a single rig's tuning; {args.tuning} is a "
                "gantry tuning (its rig is named by its gantry config, "
                "--config)"
            )
    result, record, path = verify_gantry_files(
        args.tuning,
        args.spec,
        args.config,
        seed=args.seed,
        montecarlo=args.montecarlo,
        progress=progress_line,
        scheduler=args.scheduler,
        workers=args.workers,
    )
    print_summary(args.json, record, lambda: format_gantry_verification(result))
    print(f"wrote the verification record to {path}", file=sys.stderr)
    return EXIT_OK if result.passed else EXIT_FAILED


def cmd_plan(args: argparse.Namespace) -> int:
    from servotune.arch.kind import config_kind
    from servotune.arch.linkage import plan_linkage, plan_to_string, write_plan
    from servotune.report.text import format_linkage_plan

    check_outputs(args.output, inputs=(args.config,))
    if args.json and (not args.output or args.output == "-"):
        raise ServotuneError("--json prints the plan's design on stdout: give -o FILE")
    kind = config_kind(args.config)
    if kind != "linkage":
        raise ServotuneError(
            f"{args.config} is a {kind} config, not a linkage's ([[cpu]] "
            f"tables): `servotune plan` plans a multi-CPU linkage; tune a "
            f"{kind} with `servotune tune`"
        )
    progress_line(
        f"plan linkage {args.config}: the bus budget, the queues, the clock sync, the gains"
    )
    plan = plan_linkage(args.config)
    print_summary(args.json, plan.design, lambda: format_linkage_plan(plan))
    deliver_product(
        args.output, lambda p: write_plan(plan, p), lambda: plan_to_string(plan), "the linkage plan"
    )
    return EXIT_OK


def cmd_verify(args: argparse.Namespace) -> int:
    from servotune.arch.kind import document_kind
    from servotune.report.text import format_table
    from servotune.verify import record_path, verify_files

    if (args.plants_from is None) != (args.plants_axis is None):
        print(
            "servotune verify: error: --plants-from FLEET and --plants-axis AXIS go together",
            file=sys.stderr,
        )
        return EXIT_USAGE
    kind = document_kind(args.tuning)
    check_outputs(str(record_path(args.tuning)))  # the record, written beside the tuning
    if kind == "gantry":
        return _verify_gantry(args)
    if kind == "linkage":
        return _verify_linkage(args)
    if args.config is not None:
        raise ServotuneError(
            f"--config is for a gantry tuning or a linkage plan; {args.tuning} is a rig's tuning"
        )
    check_dirs(args.report)  # before the run: a report directory that cannot be made fails first
    frf = _frf_args(args.frf, args.report)  # and so does an FRF file that cannot be read
    dist = None
    if args.plants_from is not None:
        from servotune.fleet import fleet_spread

        dist = partial(fleet_spread, args.plants_from, axis=args.plants_axis)
    result, record, path = verify_files(
        args.tuning,
        args.spec,
        args.rig,
        seed=args.seed,
        montecarlo=args.montecarlo,
        progress=progress_line,
        scheduler=args.scheduler,
        workers=args.workers,
        distribution=dist,
    )
    print_summary(args.json, record, lambda: format_table(result))
    print(f"wrote the verification record to {path}", file=sys.stderr)
    if args.report:
        from servotune.report import write_report
        from servotune.tuning import read_tuning
        from servotune.verify import default_rig_path

        rig_path = args.rig or default_rig_path(read_tuning(args.tuning), args.tuning)
        Path(args.report).mkdir(parents=True, exist_ok=True)
        out = write_report(
            args.report,
            tuning_path=args.tuning,
            rig_path=rig_path,
            verification=result,
            spec_path=args.spec,
            frf=frf,
        )
        print(f"wrote the report to {out}", file=sys.stderr)
    return EXIT_OK if result.passed else EXIT_FAILED


def _frf_args(pairs: list[str] | None, report: str | None) -> dict[str, Any] | None:
    """``--frf AXIS=FILE`` options read into ``{axis: Frf}`` (None if none given)."""
    if not pairs:
        return None
    if not report:
        raise ServotuneError("--frf draws into the report: give --report DIR too")
    return frf_files(pairs)


def frf_files(pairs: list[str] | None) -> dict[str, Any]:
    """``--frf AXIS=FILE`` options read into ``{axis: Frf}`` (empty if none given)."""
    if not pairs:
        return {}  # before the import: the reader imports scipy's statistics (a second)
    from servotune.analysis.frf import read_frf

    out: dict[str, Any] = {}
    for pair in pairs:
        axis, sep, file = pair.partition("=")
        if not sep or not axis or not file:
            raise ServotuneError(f"--frf needs AXIS=FILE (e.g. master=frf.json), got {pair!r}")
        out[axis] = read_frf(file)
    return out


def cmd_margins(args: argparse.Namespace) -> int:
    from servotune.report.text import format_margins
    from servotune.verify import MarginLimits, margins_files

    limits = MarginLimits(
        min_phase_margin_deg=args.pm, min_gain_margin_db=args.gm, max_sensitivity=args.ms
    )
    m = margins_files(args.tuning, args.rig, limits=limits, frf=frf_files(args.frf))
    print_product(args.json, m.to_dict, lambda: format_margins(m))
    return EXIT_OK if m.passed else EXIT_FAILED
