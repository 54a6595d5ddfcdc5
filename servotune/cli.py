"""Command line: ``servotune <verb>``. Each handler is a few lines calling the library.

stdout carries only the product (JSON, CSV); diagnostics go to stderr. Exit codes: 0 ok,
1 a verification or tuning failed its spec, or the inputs are not the verified ones (a digest
differs), 2 usage error, 3 bad input data, 130 interrupted (SIGINT, Ctrl-C), 143 terminated
(SIGTERM). Errors are one line on stderr; the traceback only with ``--debug``. An interrupted
or terminated run leaves no partial or temporary file: every output is written to a temporary
file and renamed into place, and the temporary file is removed when the run stops.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import warnings
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path

from servotune._version import __version__
from servotune.budget import set_memory_budget
from servotune.errors import InfeasibleError, ServotuneError, TrustError

# The library is imported inside each handler, not here, so that ``servotune --help`` (and any
# verb) pays only for what it uses: numba, scipy, matplotlib and python-control stay unloaded
# until a handler needs them (tests/cli/test_help_imports.py). That is the only reason for an
# import inside a function in this module; none of them works around an import cycle.

__all__ = ["main"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_BAD_INPUT = 0, 1, 2, 3
EXIT_INTERRUPTED, EXIT_TERMINATED = 128 + signal.SIGINT, 128 + signal.SIGTERM


class _Terminated(BaseException):
    """Raised in the main thread by the SIGTERM handler, so cleanup (``finally``) runs."""


_SIGNALLED: list[int] = []  # the signal that asked this run to end, once one has


def _on_sigterm(signum: int, frame: object) -> None:
    _SIGNALLED.append(signum)
    raise _Terminated


_SINK: list[Callable[[str], None]] = []  # this run's progress sink (main sets it)


def _progress(message: str) -> None:
    """Progress on stderr (:class:`servotune.progress.StderrProgress`: bars on a terminal, lines
    elsewhere, nothing with ``--quiet``); long runs report often, so this is also where a run
    whose SIGTERM exception was swallowed (raised inside a destructor or a C callback, where
    Python ignores exceptions) ends after all."""
    if _SIGNALLED:
        raise _Terminated
    if _SINK:
        _SINK[-1](message)
    else:
        print(message, file=sys.stderr)


_MAX_MESSAGE = 600  # characters of an error line


def _outcome(exc: BaseException) -> tuple[str, int]:
    """The one line (after ``servotune VERB:``) and the exit code for a run that raised."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted", EXIT_INTERRUPTED
    if isinstance(exc, _Terminated):
        return "terminated", EXIT_TERMINATED
    if isinstance(exc, TrustError):
        return f"refused: {_line(exc)}", EXIT_FAILED
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


def _print_product(as_json: bool, doc: Callable[[], object], text: Callable[[], str]) -> None:
    """The product on stdout: ``doc()`` as indented, key-sorted JSON, or else ``text()``."""
    if as_json:
        print(json.dumps(doc(), indent=2, sort_keys=True))
    else:
        print(text())


def _summary(as_json: bool, doc: object, text: Callable[[], str]) -> None:
    """A verb's summary (DECISIONS 10): with ``--json`` ``doc`` as JSON on stdout, else
    ``text()`` on stderr."""
    if as_json:
        print(json.dumps(doc, indent=2, sort_keys=True))
    else:
        print(text(), file=sys.stderr)


def _deliver(
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


def _cmd_rig(args: argparse.Namespace) -> int:
    from servotune.report.text import format_rig_facts
    from servotune.rig import describe_rig, load_rig

    facts = describe_rig(load_rig(args.rig))
    if args.json:
        from servotune.io.files import json_safe

        print(json.dumps(json_safe(facts), indent=2, sort_keys=True, allow_nan=False))
    else:
        print(format_rig_facts(facts))
    return EXIT_OK


def _cmd_simulate(args: argparse.Namespace) -> int:
    from servotune.logs import format_log, write_log
    from servotune.pipeline import log_metadata, run_scenario, trace_log_columns
    from servotune.rig import load_rig
    from servotune.scenarios import Scenario, build_scenario

    _check_dirs(args.output)
    rig = load_rig(args.rig)
    if (args.scenario is None) == (args.input is None):
        raise ServotuneError("give exactly one of --scenario NAME or --input EXCITATION.csv")
    if args.input:
        from servotune.excite import excitation_inputs, read_excitation

        axis, codes = read_excitation(args.input, rig)
        inputs = excitation_inputs(rig, axis, codes, closed_loop=args.closed_loop)
        scen = Scenario(name="input", axis=axis, inputs=inputs)
    else:
        axis = args.axis or next(a.name for a in rig.axes if a.role == "master")
        scen = build_scenario(
            rig, args.scenario, axis=axis, seconds=args.seconds, closed_loop=args.closed_loop
        )
    trace = run_scenario(rig, scen, seed=args.seed, noise=not args.no_noise)
    meta = log_metadata(
        rig, scenario=scen.name, axis=scen.axis, closed_loop=str(args.closed_loop).lower(),
        seed=args.seed,
    )  # fmt: skip
    cols = trace_log_columns(trace, scen.inputs.dac_add_codes)  # with exc_code (DECISIONS 5)
    kwargs = {"period_s": rig.period_s, "columns": cols, "metadata": meta}
    if args.output == "-":
        sys.stdout.write(format_log(**kwargs))
    else:
        write_log(args.output, **kwargs)
        print(f"wrote {trace.n_ticks} ticks to {args.output}", file=sys.stderr)
    return EXIT_OK


def _cmd_fit(args: argparse.Namespace) -> int:
    if (problem := _fleet_usage(args)) is not None:
        print(f"servotune fit: error: {problem}", file=sys.stderr)
        return EXIT_USAGE
    if args.fleet:
        return _cmd_fit_fleet(args)
    args.log = args.log[0]  # one log (the positional takes several for --fleet)
    from servotune.identify import fit_log
    from servotune.identify.result import FIT_SCHEMA
    from servotune.io.hal import hal_settings
    from servotune.rig import load_rig, write_plant
    from servotune.tuning import file_sha256

    _check_dirs(args.output, args.plot)
    rig = load_rig(args.rig) if args.rig else None
    dac_range = _range(args.dac_range_v) if args.dac_range_v else None
    hal = hal_settings(args.map, format=args.hal_format, columns=args.hal_columns,
                       position_scale=args.position_scale, output_scale=args.output_scale,
                       sample_number=args.sample_number, capture=args.log)  # fmt: skip
    result, log, axis = fit_log(
        args.log, axis=args.axis, rig=rig, structure=args.structure,
        counter_bits=args.counter_bits, dac_bits=args.dac_bits, dac_range_v=dac_range,
        period_s=args.period_s, compute_s=args.compute_s, method=args.method,
        friction=args.friction, invert_encoder=args.invert_encoder,
        need_axis_name=bool(args.output), strict=args.strict, hal=hal,
    )  # fmt: skip
    print(f"axis {axis or '(unprefixed)'}: " + result.summary(), file=sys.stderr)
    if args.plot:
        from servotune.identify import simulate_fit, validation_split
        from servotune.plot import plot_fit, save_figure

        ax = log.axis(None if list(log.axes) == [""] else axis)
        pos = -ax.pos_counts if result.inverted_encoder else ax.pos_counts
        sim = simulate_fit(result, ax.cmd_v, pos)
        save_figure(plot_fit(pos, sim, log.period_s, validation_split(sim.size),
                             f"fit of {axis or 'axis'}"), args.plot)  # fmt: skip
    if args.output:
        prov = result.provenance(Path(args.log).name, file_sha256(args.log),
                                 log.metadata.get("date", ""))  # fmt: skip
        new = not Path(args.output).exists()
        name = args.name or Path(args.output).stem
        write_plant(args.output, axis, result.plant, provenance=prov, fit=result.plant_fit,
                    new_name=name if new else None,
                    new_header=f"Rig {name}: made by `servotune fit -o` ({prov}).\nUnits are "
                    "in the key names; gains are D/A codes per count.")  # fmt: skip
        if new:
            print(f"wrote a new rig {name!r} with [axis.{axis}.plant] to {args.output} (its "
                  "hardware facts are the example rig's: check them)", file=sys.stderr)  # fmt: skip
        else:
            print(f"wrote [axis.{axis}.plant] to {args.output}", file=sys.stderr)
    if args.json:
        out = {"axis": axis, "schema": FIT_SCHEMA, "version": __version__}
        out.update(result.to_dict())
        print(json.dumps(out, indent=2, sort_keys=True))
    return EXIT_OK


def _fleet_usage(args: argparse.Namespace) -> str | None:
    """What is wrong with ``fit``'s options for one log or a fleet, if anything."""
    if args.fleet is None:
        if len(args.log) > 1:
            return (f"several logs need --fleet TABLE.parquet|.csv ({len(args.log)} given); "
                    "without it fit takes one log")  # fmt: skip
        for flag, v in (("--baseline", args.baseline), ("--fleet-report", args.fleet_report),
                        ("--scheduler", args.scheduler), ("--workers", args.workers)):  # fmt: skip
            if v is not None:
                return f"{flag} needs --fleet TABLE.parquet|.csv"
        return None
    for flag, v in (("-o", args.output), ("--plot", args.plot), ("--name", args.name)):
        if v is not None:
            return (f"{flag} is for one log, not with --fleet (the fleet's outputs are --fleet "
                    "and --fleet-report)")  # fmt: skip
    return None


def _cmd_fit_fleet(args: argparse.Namespace) -> int:
    from servotune.executor import open_executor
    from servotune.fleet import (
        FLEET_CLUSTER_MIN_LOGS,
        FleetFitOptions,
        fit_fleet,
        read_fleet_table,
        write_fleet_table,
    )
    from servotune.io.fleet_table import table_format
    from servotune.io.hal import hal_settings
    from servotune.rig import load_rig

    table_format(args.fleet)  # a wrong suffix fails before any work
    _check_dirs(args.fleet, args.fleet_report)
    baseline = read_fleet_table(args.baseline) if args.baseline else ()
    hal = hal_settings(args.map, format=args.hal_format, columns=args.hal_columns,
                       position_scale=args.position_scale, output_scale=args.output_scale,
                       sample_number=args.sample_number)  # fmt: skip
    options = FleetFitOptions(
        axis=args.axis, rig=load_rig(args.rig) if args.rig else None, structure=args.structure,
        counter_bits=args.counter_bits, dac_bits=args.dac_bits,
        dac_range_v=_range(args.dac_range_v) if args.dac_range_v else None,
        period_s=args.period_s, compute_s=args.compute_s, method=args.method,
        friction=args.friction, invert_encoder=args.invert_encoder, strict=args.strict, hal=hal,
    )  # fmt: skip
    with open_executor(len(args.log), scheduler=args.scheduler, workers=args.workers,
                       min_items=FLEET_CLUSTER_MIN_LOGS) as ex:  # fmt: skip
        result = fit_fleet(args.log, options=options, executor=ex, baseline=baseline,
                           progress=_progress)  # fmt: skip
    write_fleet_table(result, args.fleet)
    _summary(args.json, result.to_dict(), result.summary.text)
    print(f"wrote the fleet table ({len(result.rows)} rows) to {args.fleet}", file=sys.stderr)
    if args.fleet_report:
        from servotune.report.fleet import write_fleet_report

        write_fleet_report(result, args.fleet_report, title=Path(args.fleet).name)
        print(f"wrote the fleet report to {args.fleet_report}", file=sys.stderr)
    return EXIT_OK if result.summary.n_failed < result.summary.n_rows else EXIT_BAD_INPUT


def _check_dirs(*paths: str | None) -> None:
    """Fail before any work when an output's directory is missing (nothing gets written)."""
    for p in paths:
        if p and p != "-" and not Path(p).resolve().parent.is_dir():
            raise FileNotFoundError(
                2, f"the directory of {p!r} does not exist (create it first)", p
            )


def _workbench_dir(d: Path) -> None:
    """Create the workbench directory and check it is writable, before any work or output."""
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ServotuneError(
            f"cannot create the workbench directory {str(d)!r}: {exc.strerror or exc} "
            "(set SERVOTUNE_WORKBENCH, or pass --no-current)"
        ) from None
    if not os.access(d, os.W_OK | os.X_OK):
        raise ServotuneError(
            f"the workbench directory {str(d)!r} is not writable (set SERVOTUNE_WORKBENCH, or "
            "pass --no-current)"
        )


def _range(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise ServotuneError(f"--dac-range-v must be LOW,HIGH in volts, got {text!r}") from None
    return lo, hi


def _cmd_excite(args: argparse.Namespace) -> int:
    from servotune.excite import design_excitation, write_excitation
    from servotune.rig import load_rig

    _check_dirs(args.output)
    rig = load_rig(args.rig)
    axis = args.axis or next(a.name for a in rig.axes if a.role == "master")
    exc = design_excitation(rig, axis, args.kind, args.seconds, seed=args.seed,
                            amplitude_codes=args.amplitude_codes)  # fmt: skip
    write_excitation(args.output, exc, rig)
    lo, hi = exc.predicted_travel_counts
    print(f"wrote {exc.n_ticks} ticks of {args.kind} on {axis} to {args.output}: amplitude "
          f"{exc.amplitude_codes} codes (limited by {exc.limited_by}), predicted max speed "
          f"{exc.predicted_max_speed_rpm:.0f} r/min, travel {lo:.0f} … {hi:.0f} counts",
          file=sys.stderr)  # fmt: skip
    return EXIT_OK


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
        raise ServotuneError(f"{flag} tunes a single rig; a gantry's targets are in its config "
                             f"({args.rig}: [sync], [margins])")  # fmt: skip
    load_gantry(args.rig, resolve=False)  # bad input is one line, before any progress
    _progress(f"tune gantry {args.rig}: each drive's PI, then the sync compensator")
    tuning = tune_gantry(args.rig)
    _summary(args.json, tuning.design, lambda: format_gantry_tuning(tuning))
    _deliver(args.output, lambda p: write_gantry_tuning(tuning, p),
             lambda: gantry_tuning_to_string(tuning), "the gantry tuning", current)  # fmt: skip
    return EXIT_OK


def _cmd_tune(args: argparse.Namespace) -> int:
    from servotune.arch.kind import config_kind
    from servotune.tuning import current_tuning_path

    _check_dirs(args.output)
    current = None if args.no_current else current_tuning_path()
    if current is not None:
        _workbench_dir(current.parent)
    if args.json and (not args.output or args.output == "-"):
        raise ServotuneError("--json prints the summary on stdout: give -o FILE for the tuning")
    kind = config_kind(args.rig)
    if kind == "linkage":
        raise ServotuneError(f"{args.rig} is a linkage config: plan it with `servotune plan "
                             f"{args.rig}`")  # fmt: skip
    if kind == "gantry":
        return _tune_gantry(args, current)
    from servotune.rig import load_rig

    limits = ("max_overshoot_pct", "max_saturation_pct", "min_phase_margin_deg",
              "min_gain_margin_db", "max_sensitivity")  # fmt: skip
    given = {k: getattr(args, k) for k in limits if getattr(args, k) is not None}
    budget = {"generations": args.generations, "population": args.population}
    rig = load_rig(args.rig)  # a bad rig is one line, before any progress
    spec = None
    if args.spec:  # a spec costs the verifier's imports: read and checked before progress too
        from servotune.tune.slave import tune_spec_from
        from servotune.verify.spec import load_spec

        spec = tune_spec_from(load_spec(args.spec), rig=rig, **budget, **given)
    _progress(f"tune {args.rig}: loading the tuner")  # before the imports: they take a second
    from servotune.report.text import format_tuning_summary
    from servotune.tune.slave import tune_spec_from
    from servotune.tune.workflow import tune_rig, tuning_summary
    from servotune.tuning import tuning_to_string, write_tuning

    if spec is None:
        spec = tune_spec_from(None, rig=rig, **budget, **given)
    tuning = tune_rig(args.rig, seed=args.seed, spec=spec, rule_base=args.rule_base,
                      progress=_progress)  # fmt: skip
    summary = tuning_summary(tuning)
    _summary(args.json, summary, lambda: format_tuning_summary(summary))
    _deliver(args.output, lambda p: write_tuning(tuning, p), lambda: tuning_to_string(tuning),
             "the tuning", current)  # fmt: skip
    return EXIT_OK


def _verify_linkage(args: argparse.Namespace) -> int:
    from servotune.arch.linkage import verify_plan_files
    from servotune.report.text import format_linkage_verification

    for flag, value in (("--rig", args.rig), ("--report", args.report), ("--seed", args.seed),
                        ("--montecarlo", args.montecarlo), ("--scheduler", args.scheduler),
                        ("--workers", args.workers),
                        ("--plants-from", args.plants_from)):  # fmt: skip
        if value is not None:
            raise ServotuneError(f"{flag} is for a single rig's tuning; {args.tuning} is a "
                                 "linkage plan (its spec sets the run)")  # fmt: skip
    _progress(f"verify linkage plan {args.tuning}: every clock case of {args.spec}")
    result, record, path = verify_plan_files(args.tuning, args.spec, config_path=args.config)
    _summary(args.json, record, lambda: format_linkage_verification(result))
    print(f"wrote the verification record to {path}", file=sys.stderr)
    return EXIT_OK if result.passed else EXIT_FAILED


def _verify_gantry(args: argparse.Namespace) -> int:
    from servotune.arch.gantry.verify import verify_gantry_files
    from servotune.report.text import format_gantry_verification

    for flag, value in (("--rig", args.rig), ("--report", args.report),
                        ("--plants-from", args.plants_from)):  # fmt: skip
        if value is not None:
            raise ServotuneError(f"{flag} is for a single rig's tuning; {args.tuning} is a "
                                 "gantry tuning (its rig is named by its gantry config, "
                                 "--config)")  # fmt: skip
    result, record, path = verify_gantry_files(args.tuning, args.spec, args.config,
                                               seed=args.seed, montecarlo=args.montecarlo,
                                               progress=_progress, scheduler=args.scheduler,
                                               workers=args.workers)  # fmt: skip
    _summary(args.json, record, lambda: format_gantry_verification(result))
    print(f"wrote the verification record to {path}", file=sys.stderr)
    return EXIT_OK if result.passed else EXIT_FAILED


def _cmd_plan(args: argparse.Namespace) -> int:
    from servotune.arch.kind import config_kind
    from servotune.arch.linkage import plan_linkage, plan_to_string, write_plan
    from servotune.report.text import format_linkage_plan

    _check_dirs(args.output)
    if args.json and (not args.output or args.output == "-"):
        raise ServotuneError("--json prints the plan's design on stdout: give -o FILE")
    kind = config_kind(args.config)
    if kind != "linkage":
        raise ServotuneError(f"{args.config} is a {kind} config, not a linkage's ([[cpu]] "
                             f"tables): `servotune plan` plans a multi-CPU linkage; tune a "
                             f"{kind} with `servotune tune`")  # fmt: skip
    _progress(f"plan linkage {args.config}: the bus budget, the queues, the clock sync, the gains")
    plan = plan_linkage(args.config)
    _summary(args.json, plan.design, lambda: format_linkage_plan(plan))
    _deliver(args.output, lambda p: write_plan(plan, p), lambda: plan_to_string(plan),
             "the linkage plan")  # fmt: skip
    return EXIT_OK


def _cmd_verify(args: argparse.Namespace) -> int:
    from servotune.arch.kind import document_kind
    from servotune.report.text import format_table
    from servotune.verify import verify_files

    if (args.plants_from is None) != (args.plants_axis is None):
        print("servotune verify: error: --plants-from FLEET and --plants-axis AXIS go together",
              file=sys.stderr)  # fmt: skip
        return EXIT_USAGE
    kind = document_kind(args.tuning)
    if kind == "gantry":
        return _verify_gantry(args)
    if kind == "linkage":
        return _verify_linkage(args)
    if args.config is not None:
        raise ServotuneError(f"--config is for a gantry tuning or a linkage plan; {args.tuning} "
                             "is a rig's tuning")  # fmt: skip
    if args.report:  # before the run: a report directory that cannot be made fails first
        Path(args.report).mkdir(parents=True, exist_ok=True)
    dist = None
    if args.plants_from is not None:
        from servotune.fleet import fleet_spread

        dist = partial(fleet_spread, args.plants_from, axis=args.plants_axis)
    result, record, path = verify_files(args.tuning, args.spec, args.rig, seed=args.seed,
                                        montecarlo=args.montecarlo, progress=_progress,
                                        scheduler=args.scheduler, workers=args.workers,
                                        distribution=dist)  # fmt: skip
    _summary(args.json, record, lambda: format_table(result))
    print(f"wrote the verification record to {path}", file=sys.stderr)
    if args.report:
        from servotune.report import write_report
        from servotune.tuning import read_tuning
        from servotune.verify import default_rig_path

        rig_path = args.rig or default_rig_path(read_tuning(args.tuning), args.tuning)
        out = write_report(args.report, tuning_path=args.tuning, rig_path=rig_path,
                           verification=result, spec_path=args.spec)  # fmt: skip
        print(f"wrote the report to {out}", file=sys.stderr)
    return EXIT_OK if result.passed else EXIT_FAILED


def _cmd_margins(args: argparse.Namespace) -> int:
    from servotune.report.text import format_margins
    from servotune.verify import MarginLimits, margins_files

    limits = MarginLimits(min_phase_margin_deg=args.pm, min_gain_margin_db=args.gm,
                          max_sensitivity=args.ms)  # fmt: skip
    m = margins_files(args.tuning, args.rig, limits=limits)
    _print_product(args.json, m.to_dict, lambda: format_margins(m))
    return EXIT_OK if m.passed else EXIT_FAILED


def _export_gantry(args: argparse.Namespace, path: Path) -> int:
    from servotune.arch.gantry.verify import load_gantry_for_export
    from servotune.export.gantry import (
        gantry_document,
        gantry_tables_to_string,
        write_gantry_c,
        write_gantry_tables,
    )

    if args.rig is not None:
        raise ServotuneError(f"--rig is for a single rig's tuning; {path} is a gantry tuning "
                             "(give its gantry config with --config)")  # fmt: skip
    v = load_gantry_for_export(path, args.config, args.spec, unverified=args.unverified)
    doc = gantry_document(v.tuning, v.config.rig, record=v.record, unverified=args.unverified)
    if args.format == "c":
        Path(args.output).mkdir(parents=True, exist_ok=True)
        written = write_gantry_c(doc, args.output)
        print(f"wrote {', '.join(p.name for p in written)} to {args.output}", file=sys.stderr)
    elif args.output and args.output != "-":
        write_gantry_tables(doc, args.output)
        print(f"wrote the gantry tables to {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(gantry_tables_to_string(doc))
    return EXIT_OK


def _export_linkage(args: argparse.Namespace, path: Path) -> int:
    from servotune.arch.linkage import load_plan_for_export
    from servotune.export.linkage import linkage_plan_json, write_linkage_c

    for flag, value in (("--rig", args.rig), ("--config", args.config)):
        if value is not None:
            raise ServotuneError(f"{flag} does not apply to a linkage plan ({path}): the plan "
                                 "binds its config and rig by their hashes")  # fmt: skip
    plan, record = load_plan_for_export(path, args.spec, unverified=args.unverified)
    if args.format == "c":
        Path(args.output).mkdir(parents=True, exist_ok=True)
        written = write_linkage_c(plan, args.output, record=record, unverified=args.unverified)
        print(f"wrote {', '.join(p.name for p in written)} to {args.output}", file=sys.stderr)
        return EXIT_OK
    text = linkage_plan_json(plan, record, unverified=args.unverified)
    if args.output and args.output != "-":
        from servotune.io.files import atomic_write_text

        atomic_write_text(args.output, text)
        print(f"wrote the linkage export to {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return EXIT_OK


def _cmd_export_table(args: argparse.Namespace) -> int:
    from servotune.arch.kind import document_kind
    from servotune.export import tables_to_string, write_c, write_tables
    from servotune.io.files import atomic_write_text
    from servotune.tuning import current_tuning_path
    from servotune.verify import load_for_export

    path = Path(args.tuning) if args.tuning else current_tuning_path()
    if args.format == "c" and not args.output:
        raise ServotuneError("--format c needs -o DIR (the directory to write the C files into)")
    _check_dirs(args.output if args.format != "c" else None)
    kind = document_kind(path)
    if args.format.startswith("linuxcnc-") and kind in ("gantry", "linkage"):
        raise ServotuneError(
            f"--format {args.format} exports a rig's tuning (one runtime, its master and slave "
            f"axes); {path} is a {kind} {'plan' if kind == 'linkage' else 'tuning'}: export it "
            "with --format json or c"
        )
    if kind == "gantry":
        return _export_gantry(args, path)
    if kind == "linkage":
        return _export_linkage(args, path)
    if args.config is not None:
        raise ServotuneError(f"--config is for a gantry tuning; {path} is a rig's tuning")
    v = load_for_export(path, args.rig, args.spec, unverified=args.unverified)
    kw = {"rig": v.rig, "verification": v.record, "unverified": v.record is None}
    if args.format.startswith("linuxcnc-"):
        text = _linuxcnc_text(args, v.tuning, kw)
        what = "HAL file" if args.format == "linuxcnc-hal" else "HAL component"
        _deliver(args.output, lambda p: atomic_write_text(p, text), lambda: text, f"the {what}")
    elif args.format == "c":
        Path(args.output).mkdir(parents=True, exist_ok=True)
        written = write_c(v.tuning, args.output, **kw)
        print(f"wrote {', '.join(p.name for p in written)} to {args.output}", file=sys.stderr)
    elif args.output and args.output != "-":
        write_tables(v.tuning, args.output, **kw)
        print(f"wrote the tables to {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(tables_to_string(v.tuning, **kw))
    return EXIT_OK


def _linuxcnc_text(args: argparse.Namespace, tuning: object, kw: dict) -> str:
    """The text of a LinuxCNC export of ``tuning`` (``--format linuxcnc-*``)."""
    if args.format == "linuxcnc-comp":
        from servotune.export.hal_component import component_source

        return component_source(tuning, name=args.name, **kw)
    from servotune.export.linuxcnc import pid_hal_text

    if args.position_scale is None:
        raise ServotuneError(
            "--format linuxcnc-hal needs --position-scale (encoder counts per machine unit, "
            "the encoder's position-scale parameter)"
        )
    return pid_hal_text(tuning, position_scale=args.position_scale,
                        output_scale=args.output_scale, pid_name=args.pid,
                        velocity_feedforward=not args.no_feedforward, **kw)  # fmt: skip


def _check_gantry_table(args: argparse.Namespace) -> int:
    from servotune.errors import ExportError
    from servotune.export.gantry import check_gantry_tables
    from servotune.io.files import read_bytes

    raw = read_bytes(args.file, ExportError, "gantry tables export")
    doc = check_gantry_tables(raw.decode("utf-8", errors="replace"), args.file)
    data = doc["data"]
    if args.json:
        print(json.dumps({"c_layout_sha256": data["c_layout_sha256"], "file": args.file,
                          "gantry": data["gantry_name"], "ok": True, "schema": doc["schema"],
                          "sha256": doc["sha256"], "verified": doc["verified"]},
                         indent=2, sort_keys=True))  # fmt: skip
    verified = "verified" if doc["verified"] else "NOT verified (exported --unverified)"
    print(f"{args.file}: ok: {doc['schema']}, gantry {data['gantry_name']} "
          f"({data['topology']}), {verified}; both digests match (sha256 "
          f"{doc['sha256'][:12]}…)", file=sys.stderr)  # fmt: skip
    return EXIT_OK


def _cmd_check_table(args: argparse.Namespace) -> int:
    from servotune.arch.kind import document_kind
    from servotune.export.json import load_tables

    if document_kind(args.file) == "gantry":
        return _check_gantry_table(args)
    doc = load_tables(args.file)
    data = doc["data"]
    summary = {
        "axes": [a["name"] for a in data["axes"]],
        "c_layout_sha256": data["c_layout_sha256"],
        "file": args.file,
        "ok": True,
        "rig": data["rig_name"],
        "schema": doc["schema"],
        "sha256": doc["sha256"],
        "verified": doc["verified"],
    }
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    verified = "verified" if doc["verified"] else "NOT verified (exported --unverified)"
    print(f"{args.file}: ok: {doc['schema']}, rig {data['rig_name']}, axes "
          f"{', '.join(summary['axes'])}, {verified}; every CRC and digest matches "
          f"(sha256 {doc['sha256'][:12]}…)", file=sys.stderr)  # fmt: skip
    return EXIT_OK


def _cmd_compare(args: argparse.Namespace) -> int:
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
    rig, spec = load_rig(args.rig), load_spec(args.spec)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    preset = DemoPreset(generations=args.generations, population=args.population,
                        seeds=tuple(range(args.seeds)), heldout_count=args.heldout_count,
                        pareto_ms=ms)  # fmt: skip
    cmp = run_comparison(rig, spec, args.out, preset=preset, seed=args.seed,
                         progress=_progress)  # fmt: skip
    print("\n".join(comparison_statement(cmp)), file=sys.stderr)
    if args.json:
        sys.stdout.write((Path(args.out) / "figure4.json").read_text())
    print(f"wrote figure4.png, figure4.json{', pareto.png' if ms else ''} to {args.out}",
          file=sys.stderr)  # fmt: skip
    return EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    from servotune.pipeline import comparison_table_text, run_demo

    Path(args.out).mkdir(parents=True, exist_ok=True)
    summary = run_demo(args.rig, args.out, seed=args.seed,
                       preset="full" if args.full else "quick",
                       progress=_progress)  # fmt: skip
    for name, h in summary["lock_hold"].items():
        print(f"lock hold {name}: observed {h['observed_counts']} "
              f"predicted {h['predicted_counts']} counts", file=sys.stderr)  # fmt: skip
    for name, f in summary["identification"].items():
        err = f["relative_error"]
        print(f"fit {name}: {'+'.join(f['structure'])}; gain {err['gain_cps_per_v']:+.2%}, "
              f"tau {err['tau_s']:+.2%} vs the virtual rig's truth", file=sys.stderr)  # fmt: skip
    print("Figure 4 (slave tracking, each structure tuned with the same budget):\n"
          + comparison_table_text(summary["comparison"]), file=sys.stderr)  # fmt: skip
    print("\n".join(summary["figure4_statement"]), file=sys.stderr)
    v = summary["verification"]
    print("verify: " + ("PASSED" if v["passed"] else "FAILED: " + "; ".join(v["failures"])),
          file=sys.stderr)  # fmt: skip
    for name, a in summary["architectures"].items():
        print(f"{name}: {'checks passed' if a['passed'] else 'a check FAILED'}", file=sys.stderr)
    print(f"wrote demo_summary.json, report.html, lock_hold.png, track.png, fit_*.png, "
          f"fitted-rig.toml, tuning.json, figure4.png, sync.json, sync_*.png, linkage.json, "
          f"linkage_*.png, "
          f"{', '.join(summary['exported']) or 'no exports'} and logs to {args.out}",
          file=sys.stderr)  # fmt: skip
    return EXIT_OK


def _cmd_sync(args: argparse.Namespace) -> int:
    from servotune.arch.gantry import compare_topologies
    from servotune.arch.gantry.load import load_gantry
    from servotune.report.text import format_comparison

    cmp = compare_topologies(load_gantry(args.config), seed=args.seed,
                             montecarlo=args.montecarlo)  # fmt: skip
    _print_product(args.json, cmp.to_dict, lambda: format_comparison(cmp))
    if args.plot:
        from servotune.arch.gantry import CASES
        from servotune.plot import plot_sync_errors, save_figure

        Path(args.plot).mkdir(parents=True, exist_ok=True)
        for case in CASES:
            save_figure(plot_sync_errors(cmp.traces, case), Path(args.plot) / f"sync_{case}.png")
        print(f"wrote sync_{{{','.join(CASES)}}}.png to {args.plot}", file=sys.stderr)
    for reason in cmp.failed:
        print(f"servotune sync: check failed: {reason}", file=sys.stderr)
    return EXIT_OK if cmp.passed else EXIT_FAILED


def _cmd_linkage(args: argparse.Namespace) -> int:
    from servotune.arch.linkage import LinkageCheckError, load_linkage, run_linkage
    from servotune.report.text import format_linkage_summary

    config = load_linkage(args.config)
    try:
        result = run_linkage(config, seconds=args.seconds, seed=args.seed)
    except LinkageCheckError as exc:
        for check in exc.checks:
            print(f"servotune linkage: check failed: {check.detail}", file=sys.stderr)
        return EXIT_FAILED
    _print_product(args.json, result.to_dict, lambda: format_linkage_summary(result))
    if args.plot:
        from servotune.plot import plot_queue_levels, plot_radial_deviation, save_figure

        Path(args.plot).mkdir(parents=True, exist_ok=True)
        save_figure(plot_queue_levels(result), Path(args.plot) / "linkage_queues.png")
        save_figure(plot_radial_deviation(result), Path(args.plot) / "linkage_circle.png")
        print(f"wrote linkage_queues.png, linkage_circle.png to {args.plot}", file=sys.stderr)
    for check in result.failed_checks:
        print(f"servotune linkage: check failed: {check.detail}", file=sys.stderr)
    return EXIT_OK if result.passed else EXIT_FAILED


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="servotune",
        description="Control design and tuning workbench for synchronised position servos.",
    )
    p.add_argument("--version", action="version", version=f"servotune {__version__}")
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    p.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress on stderr (errors, warnings and summaries still go there)",
    )
    p.add_argument(
        "--max-memory",
        metavar="SIZE",
        help="memory budget a run may plan to allocate, e.g. 512M, 8G (default 2G, or "
        "$SERVOTUNE_MAX_MEMORY); a larger run is refused before it starts (exit 3)",
    )
    sub = p.add_subparsers(dest="verb", required=True, metavar="VERB")

    s = sub.add_parser("rig", help="print the derived facts of a rig file")
    s.add_argument("rig", help="rig file (TOML), e.g. plants/pc-dual-servo.toml")
    s.add_argument("--json", action="store_true", help="JSON on stdout")
    s.set_defaults(func=_cmd_rig)

    s = sub.add_parser("simulate", help="run a scenario on the virtual rig and write a log")
    s.add_argument("rig", help="rig file (TOML)")
    s.add_argument("--scenario", help="prbs, steps, chirp or track")
    s.add_argument("--input", help="excitation CSV to play (from servotune excite)")
    s.add_argument("--axis", help="axis to excite or move (default: the master)")
    s.add_argument("--seconds", type=float, default=10.0, help="duration [s] (default 10)")
    s.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    s.add_argument(
        "--closed-loop",
        action="store_true",
        help="excite with the lock module active (identification in closed loop)",
    )
    s.add_argument("--no-noise", action="store_true", help="switch the encoder noise off")
    s.add_argument("-o", "--output", required=True, help="log file to write ('-' for stdout)")
    s.set_defaults(func=_cmd_simulate)

    s = sub.add_parser("fit", help="identify an axis's motor + drive model from a logged run")
    s.add_argument(
        "log",
        nargs="+",
        help="log CSV (as `servotune simulate` writes it; see the README), or a LinuxCNC HAL "
        "capture (halsampler output or halscope's saved data) read with --map; several only "
        "with --fleet",
    )
    s.add_argument("--axis", help="axis to fit (needed for multi-axis logs)")
    s.add_argument("--rig", help="rig file: D/A, counter, period and compute time fallbacks")
    s.add_argument(
        "--structure", default=None, help="auto (default: BIC) or a list from delay,offset,coulomb"
    )
    s.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    s.add_argument("-o", "--output", help="write the axis's plant section into this rig file")
    s.add_argument("--plot", help="PNG: measured vs simulated position, velocity, residuals")
    s.add_argument(
        "--strict",
        action="store_true",
        help="an unknown metadata key in the log (# key: value, e.g. a typo) is an error, "
        "not a warning",
    )
    s.add_argument(
        "--name",
        help="name of the rig -o creates (default: the file's name without .toml); an "
        "existing rig file keeps its name",
    )
    s.add_argument("--counter-bits", type=int, help="counter width for raw counter columns")
    s.add_argument(
        "--dac-bits", type=int, help="D/A resolution for dac_code columns (a capture's code)"
    )
    s.add_argument("--dac-range-v", help="D/A range LOW,HIGH [V]")
    s.add_argument(
        "--period-s",
        type=float,
        help="sample period [s], e.g. 0.004; overrides the log's `# period_s:` line and its "
        "time_s column (default: that line, else the time_s column); a halsampler capture "
        "needs it (or period_s in the --map file)",
    )
    s.add_argument(
        "--compute-s",
        type=float,
        help="time from the sample to the D/A write [s], e.g. 0.0002, if known (default: the "
        "log's `# compute_s:` line, else the rig's; the fit then estimates only the rest of "
        "the delay)",
    )
    s.add_argument(
        "--method",
        choices=["auto", "iv", "oe"],
        default="auto",
        help="iv: instrumental variables, consistent in closed loop (needs exc_code or a moving "
        "reference); oe: least squares; auto (default): iv when the log allows it",
    )
    s.add_argument(
        "--friction",
        choices=["auto", "sym", "asym"],
        default="auto",
        help="friction form: sym, asym (gain and Coulomb level per direction), auto (default: BIC)",
    )
    s.add_argument(
        "--invert-encoder",
        action="store_true",
        help="negate the position first (an encoder counting against the D/A's direction)",
    )
    hal = s.add_argument_group(
        "LinuxCNC HAL captures", "halsampler output or halscope's saved data, read with --map"
    )
    hal.add_argument(
        "--map",
        metavar="KEY=PIN,...|FILE.toml",
        help="read LOG as a HAL capture: which pin (or 0-based column) is what, e.g. "
        "cmd=pid.0.output,pos=encoder.0.position; keys: cmd (pid output units) or code (D/A "
        "code), pos (machine units) or counts (encoder counts), optional ref (commanded "
        "position, machine units), exc (excitation, command units) and overruns (the "
        "sampler.N.overruns pin: a change = lost samples); or a TOML file with a "
        "[hal] table and [hal.map] (format, period_s, position_scale, output_scale, columns, "
        "sample_number); the options below override it",
    )
    hal.add_argument(
        "--hal-format",
        choices=["halsampler", "halscope"],
        help="the capture's format (default: detected; halscope's begins with '# Sampling "
        "period is')",
    )
    hal.add_argument(
        "--hal-columns",
        metavar="PIN,PIN,...",
        help="halsampler: the sampler's pins in its cfg order (the file names none), e.g. "
        "pid.0.output,encoder.0.position",
    )
    hal.add_argument(
        "--position-scale",
        type=float,
        metavar="COUNTS_PER_UNIT",
        help="the encoder's position-scale [counts per machine unit], > 0: counts = position "
        "× scale (needed for pos and ref)",
    )
    hal.add_argument(
        "--output-scale",
        type=float,
        metavar="UNITS_PER_V",
        help="pid output units per volt at the D/A, > 0 (default 1.0: the output is in volts)",
    )
    hal.add_argument(
        "--sample-number",
        action="store_const",
        const=True,
        help="halsampler: written with -t (first field the sample number; a gap, lost "
        "samples, is an error)",
    )
    fleet = s.add_argument_group(
        "fleet", "fit many machines' logs at once: a table, the fleet's spread, outliers, drift"
    )
    fleet.add_argument(
        "--fleet",
        metavar="TABLE.parquet|.csv",
        help="fit every LOG (every axis, or --axis) and write one row per log and axis to this "
        "table: parameters with 95 %% intervals, adequacy, fit %%, SHA-256, machine_id and date "
        "(a bad log is a row with its error); the summary on stderr (--json: stdout)",
    )
    fleet.add_argument(
        "--fleet-report", metavar="FILE.html", help="also write the report page (histograms)"
    )
    fleet.add_argument(
        "--baseline",
        "--previous",
        metavar="TABLE",
        help="an earlier --fleet table: each machine's previous fit, for drift",
    )
    fleet.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        help="fit on the Dask cluster of this scheduler (tcp://HOST:8786; default: "
        "$SERVOTUNE_SCHEDULER); see docs/scale.md",
    )
    fleet.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="worker processes of a cluster started on this machine (1: in-process; default: "
        "one per core from 200 logs)",
    )
    s.set_defaults(func=_cmd_fit)

    s = sub.add_parser("excite", help="design an identification excitation (D/A codes)")
    s.add_argument("--rig", required=True, help="rig file (TOML)")
    s.add_argument("--axis", help="axis (default: the master)")
    s.add_argument("--kind", required=True, choices=["prbs", "multisine", "steps"])
    s.add_argument("--seconds", type=float, required=True, help="duration [s]")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--amplitude-codes", type=int, help="requested amplitude [D/A codes]")
    s.add_argument("-o", "--output", required=True, help="excitation CSV to write")
    s.set_defaults(func=_cmd_excite)

    s = sub.add_parser(
        "tune",
        help="tune the master's PI and the slave's fuzzy-PID tables (a rig), or both drives' PI "
        "and the sync compensator (a gantry config)",
    )
    s.add_argument("rig", help="rig file or gantry config (TOML)")
    s.add_argument("-o", "--output", help="tuning file to write (default: stdout)")
    s.add_argument("--seed", type=int, default=0, help="optimiser and noise seed (default 0)")
    s.add_argument("--rule-base", default="default", choices=["default", "classic"])
    s.add_argument("--generations", type=int, default=40, help="optimiser budget (default 40)")
    s.add_argument("--population", type=int, default=32, help="candidates per generation")
    s.add_argument(
        "--max-overshoot-pct",
        type=float,
        help="largest lead of the slave over the master, %% of its largest lag (default 100)",
    )
    s.add_argument(
        "--max-saturation-pct",
        type=float,
        help="largest share of task ticks on a D/A rail, %% (default 2, or the spec's sync "
        "scenario's)",
    )
    s.add_argument(
        "--pm",
        type=float,
        dest="min_phase_margin_deg",
        help="least phase margin of every loop over the plant set [deg] (default 45, or the "
        "spec's)",
    )
    s.add_argument(
        "--gm",
        type=float,
        dest="min_gain_margin_db",
        help="least gain margin of every loop over the plant set [dB] (default 6, or the spec's)",
    )
    s.add_argument(
        "--ms",
        type=float,
        dest="max_sensitivity",
        help="largest peak sensitivity of every loop over the plant set (default 2, or the spec's)",
    )
    s.add_argument(
        "--spec",
        help="verification spec (TOML) to design for: its [margins] limits and latency, timer "
        "error, Monte-Carlo gain/tau spreads and its 'sync' scenario's run (other scenarios stay "
        "held out); flags given here win",
    )
    s.add_argument(
        "--json",
        action="store_true",
        help="the summary (gains, margins) as JSON on stdout (needs -o)",
    )
    s.add_argument(
        "--no-current",
        action="store_true",
        help="do not record the result as the workbench's current tuning",
    )
    s.set_defaults(func=_cmd_tune)

    s = sub.add_parser(
        "plan",
        help="plan a multi-CPU linkage: bus block budget, queue depths and watermarks, clock "
        "sync, the axes' gains as the CPUs run them",
    )
    s.add_argument("config", help="linkage config (TOML)")
    s.add_argument("-o", "--output", help="plan file to write (default: stdout)")
    s.add_argument("--json", action="store_true", help="the plan's design as JSON on stdout")
    s.set_defaults(func=_cmd_plan)

    s = sub.add_parser(
        "verify",
        help="verify a tuning (rig or gantry) or a linkage plan against a spec in the bit-true "
        "loop",
    )
    s.add_argument(
        "tuning", help="tuning file (from servotune tune) or linkage plan (from servotune plan)"
    )
    s.add_argument("--spec", required=True, help="spec file (TOML)")
    s.add_argument(
        "--rig",
        help="rig file: a copy of the tuning's rig (default: the path the tuning records, then "
        "plants/<rig name>.toml); another rig is refused (exit 1)",
    )
    s.add_argument(
        "--config",
        help="the gantry or linkage config a gantry tuning or a linkage plan was made from: a "
        "copy of it (default: the path the file records, then plants/<name>.toml); another "
        "is refused",
    )
    s.add_argument("--seed", type=int, default=None, help="Monte-Carlo seed (default: the spec's)")
    s.add_argument(
        "--montecarlo",
        type=int,
        default=None,
        metavar="N",
        help="Monte-Carlo plant sets (default: the spec's montecarlo.count; up to 1e8): run in "
        "chunks, in-process below 100,000, else on a Dask cluster (--scheduler, or one started "
        "on this machine's cores); the result is the same on any of them",
    )
    s.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        help="run the plant sets on the Dask cluster of this scheduler (tcp://HOST:8786; "
        "default: $SERVOTUNE_SCHEDULER); see docs/scale.md",
    )
    s.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="worker processes of a cluster started on this machine, whatever the size "
        "(1: in-process; default: one per core, from 100,000 plant sets, or a gantry's "
        "10,000 plant pairs)",
    )
    s.add_argument(
        "--plants-from",
        metavar="FLEET",
        default=None,
        help="draw the Monte-Carlo plants from this fleet table (servotune fit --fleet "
        "output, .parquet or .csv) instead of the spec's spread: each plant set takes the "
        "--plants-axis plant of one machine's latest adequate fit, machines drawn uniformly",
    )
    s.add_argument(
        "--plants-axis",
        metavar="AXIS",
        default=None,
        help="the rig axis whose plant --plants-from draws (the fleet's fits of that axis)",
    )
    s.add_argument("--json", action="store_true", help="the verification record as JSON on stdout")
    s.add_argument("--report", help="also write the HTML report into this directory")
    s.set_defaults(func=_cmd_verify)

    s = sub.add_parser(
        "margins",
        help="gain, phase and delay margins, Ms and Mt of every loop a tuning can run "
        "(exit 1 if one breaks a limit)",
    )
    s.add_argument("tuning", help="tuning file (from servotune tune)")
    s.add_argument(
        "--rig",
        help="rig file: a copy of the tuning's rig (default: the path the tuning records, then "
        "plants/<rig name>.toml); another rig is refused (exit 1)",
    )
    s.add_argument("--pm", type=float, default=45.0, help="least phase margin [deg] (default 45)")
    s.add_argument("--gm", type=float, default=6.0, help="least gain margin [dB] (default 6)")
    s.add_argument("--ms", type=float, default=2.0, help="largest peak sensitivity (default 2.0)")
    s.add_argument("--json", action="store_true", help="every loop's figures as JSON on stdout")
    s.set_defaults(func=_cmd_margins)

    s = sub.add_parser("export-table", help="export a verified tuning's tables (JSON or C)")
    s.add_argument(
        "tuning",
        nargs="?",
        help="tuning file or linkage plan (default: the workbench's current tuning)",
    )
    s.add_argument(
        "-o", "--output",
        help="file (JSON, HAL, .comp) or directory (C); default stdout (not for C)",
    )  # fmt: skip
    s.add_argument(
        "--format",
        choices=["json", "c", "linuxcnc-hal", "linuxcnc-comp"],
        default="json",
        help="json (default); c: header + runtime sources; linuxcnc-hal: a HAL file setting the "
        "stock pid component's parameters for the master axis; linuxcnc-comp: a realtime HAL "
        "component (build it with halcompile) running the verified runtime and its tables",
    )
    s.add_argument(
        "--position-scale",
        type=float,
        help="linuxcnc-hal: encoder counts per machine unit (the encoder's position-scale), "
        "e.g. 2000",
    )
    s.add_argument(
        "--output-scale",
        type=float,
        default=1.0,
        help="linuxcnc-hal: pid output units per volt at the D/A (default 1: output in volts)",
    )
    s.add_argument(
        "--pid",
        default="pid.x",
        help="linuxcnc-hal: the pid instance the file sets (default pid.x, as `loadrt pid "
        "names=pid.x`)",
    )
    s.add_argument(
        "--no-feedforward",
        action="store_true",
        help="linuxcnc-hal: FF1 = 0, exactly the verified law (default: FF1 = 1/plant gain, "
        "velocity feedforward on the command only, margins unchanged)",
    )
    s.add_argument(
        "--name",
        default="servotune",
        help="linuxcnc-comp: the component's name (default servotune)",
    )
    s.add_argument(
        "--rig",
        help="rig file: a copy of the tuning's rig (default: the path the tuning records, then "
        "plants/<rig name>.toml); another rig is refused",
    )
    s.add_argument(
        "--config",
        help="the gantry config of a gantry tuning (default: the path the tuning records); "
        "another is refused",
    )
    s.add_argument("--spec", help="also require that the verification used this spec file")
    s.add_argument("--unverified", action="store_true", help="export without a passed verify")
    s.set_defaults(func=_cmd_export_table)

    s = sub.add_parser(
        "check-table", help="check a tables export: every CRC and digest (any edit is refused)"
    )
    s.add_argument("file", help="tables export (JSON, from servotune export-table)")
    s.add_argument("--json", action="store_true", help="the check's summary as JSON on stdout")
    s.set_defaults(func=_cmd_check_table)

    s = sub.add_parser("demo", help="run the whole job on a rig and write into a directory")
    s.add_argument("rig", help="rig file (TOML)")
    s.add_argument("--out", default="reports", help="output directory (default reports)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument(
        "--full",
        action="store_true",
        help="the whole study: the default tuning budget, Figure 4 over three seeds and the "
        "tracking/robustness sweep (several minutes; default: the quick preset)",
    )
    s.set_defaults(func=_cmd_demo)

    s = sub.add_parser(
        "compare",
        help="Figure 4: PID, PID + feedforward and composite tuned alike, compared on held-out "
        "scenarios",
    )
    s.add_argument("rig", help="rig file (TOML)")
    s.add_argument("--spec", required=True, help="verification spec (TOML): limits, tuning run "
                   "and the held-out scenarios")  # fmt: skip
    s.add_argument("--out", default="reports", help="directory for figure4.png/json, pareto.png")
    s.add_argument("--seeds", type=int, default=3, help="optimiser seeds (default 3)")
    s.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    s.add_argument("--generations", type=int, default=40, help="optimiser budget (default 40)")
    s.add_argument("--population", type=int, default=32, help="candidates per generation")
    s.add_argument(
        "--heldout-count",
        type=int,
        default=64,
        help="Monte-Carlo plant draws per held-out verification (default 64)",
    )
    s.add_argument(
        "--pareto",
        default="",
        metavar="MS,MS,...",
        help="peak-sensitivity ceilings of the trade-off sweep, e.g. 1.3,1.5,1.7,2",
    )
    s.add_argument("--json", action="store_true", help="figure4.json on stdout as well")
    s.set_defaults(func=_cmd_compare)

    s = sub.add_parser("sync", help="compare gantry topologies on a gantry config")
    s.add_argument("config", help="gantry config (TOML), e.g. plants/gantry.toml")
    s.add_argument("--seed", type=int, default=0, help="noise and jitter seed (default 0)")
    s.add_argument(
        "--montecarlo",
        type=int,
        default=0,
        metavar="N",
        help="also run the deployed topology over N plant pairs drawn inside the [margins] "
        "spreads; a trip in any fails (default 0: none)",
    )
    s.add_argument("--json", action="store_true", help="JSON on stdout")
    s.add_argument("--plot", metavar="DIR", help="write sync-error plots (PNG) into DIR")
    s.set_defaults(func=_cmd_sync)

    s = sub.add_parser("linkage", help="simulate a multi-CPU linkage and check it")
    s.add_argument("config", help="linkage config (TOML), e.g. plants/linkage-6axis.toml")
    s.add_argument("--seconds", type=float, help="simulated time [s] (default: path + settle)")
    s.add_argument("--seed", type=int, default=0, help="encoder-noise seed (default 0)")
    s.add_argument("--json", action="store_true", help="the result as JSON on stdout")
    s.add_argument("--plot", metavar="DIR", help="write queue and circular-test PNGs into DIR")
    s.set_defaults(func=_cmd_linkage)
    for name, verb in sub.choices.items():  # --quiet also after the verb (where users type it)
        verb.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                          help="no progress on stderr")  # fmt: skip
        verb.formatter_class = argparse.RawDescriptionHelpFormatter
        verb.epilog = "examples:\n" + "\n".join(f"  {x}" for x in _EXAMPLES[name])
    return p


_EXAMPLES = {
    "rig": ["servotune rig plants/pc-dual-servo.toml", "servotune rig my-rig.toml --json"],
    "simulate": [
        "servotune simulate plants/pc-dual-servo.toml --scenario prbs --axis master "
        "--seconds 20 -o log.csv",
        "servotune simulate plants/pc-dual-servo.toml --input exc.csv --closed-loop -o my.csv",
    ],
    "fit": [
        "servotune fit my.csv --axis master                  # summary on stderr",
        "servotune fit my.csv --axis master -o my-rig.toml   # a new rig named my-rig",
        "servotune fit my.csv --axis master --json --plot fit.png",
        "servotune fit logs/*.csv --axis master --fleet fleet.parquet --fleet-report fleet.html",
        "servotune fit capture.txt --axis x --map cmd=pid.0.output,pos=encoder.0.position "
        "--hal-columns pid.0.output,encoder.0.position --period-s 0.001 "
        "--position-scale 2000   # LinuxCNC halsampler",
    ],
    "excite": [
        "servotune excite --rig my-rig.toml --axis master --kind prbs --seconds 40 -o exc.csv",
    ],
    "tune": [
        "servotune tune my-rig.toml -o tuning.json",
        "servotune tune my-rig.toml -o tuning.json --spec plants/pc-dual-servo.spec.toml",
        "servotune tune plants/gantry.toml -o gantry.tuning.json   # a gantry config",
    ],
    "plan": ["servotune plan plants/linkage-6axis.toml -o linkage.plan.json"],
    "verify": [
        "servotune verify tuning.json --spec plants/pc-dual-servo.spec.toml --report reports",
        "servotune verify gantry.tuning.json --spec plants/gantry.spec.toml",
        "servotune verify linkage.plan.json --spec plants/linkage-6axis.spec.toml",
    ],
    "margins": ["servotune margins tuning.json --pm 50 --gm 6 --ms 1.8"],
    "export-table": [
        "servotune export-table tuning.json -o fuzzy.json",
        "servotune export-table tuning.json --format c -o runtime/",
        "servotune export-table -o fuzzy.json   # the workbench's current tuning",
        "servotune export-table tuning.json --format linuxcnc-hal --position-scale 2000 "
        "-o pid-x.hal",
        "servotune export-table tuning.json --format linuxcnc-comp -o servotune.comp",
    ],
    "check-table": ["servotune check-table fuzzy.json"],
    "demo": [
        "servotune demo plants/pc-dual-servo.toml --out reports",
        "servotune demo plants/pc-dual-servo.toml --out reports --full",
    ],
    "compare": [
        "servotune compare plants/pc-dual-servo.toml --spec plants/pc-dual-servo.spec.toml "
        "--seeds 3 --json > figure4.json",
    ],
    "sync": [
        "servotune sync plants/gantry.toml",
        "servotune sync plants/gantry.toml --montecarlo 1000 --plot reports/",
    ],
    "linkage": ["servotune linkage plants/linkage-6axis.toml --json --plot reports/"],
}
"""One or more command lines per verb, shown under its ``--help``."""


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (module docstring)."""
    parser = _parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    _SIGNALLED.clear()
    format_warning = warnings.formatwarning

    def one_line(message: Warning | str, *_: object, **__: object) -> str:
        return f"servotune {args.verb}: warning: {message}\n"

    if not args.debug:  # a warning is one line naming the verb (the source line only on --debug)
        warnings.formatwarning = one_line
    try:
        if args.max_memory is not None:
            set_memory_budget(args.max_memory)
        if args.quiet or sys.stderr.isatty():  # tqdm only where it draws bars (--help stays lean)
            from servotune.progress import StderrProgress

            _SINK.append(StderrProgress(quiet=args.quiet))
        return func(args)
    except (ServotuneError, OSError, KeyboardInterrupt, _Terminated) as exc:
        if args.debug:
            raise
        message, code = _outcome(exc)
        print(f"servotune {args.verb}: {message}", file=sys.stderr)
        return code
    finally:
        signal.signal(signal.SIGTERM, previous)
        warnings.formatwarning = format_warning
        set_memory_budget(None)
        while _SINK:
            close = getattr(_SINK.pop(), "close", None)
            if close is not None:
                close()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
