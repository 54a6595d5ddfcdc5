"""The verbs on a rig and its logs: ``init`` (the example rig, specs and map, written into
``plants/``), ``rig``, ``simulate``, ``excite`` and ``fit`` (one log, or a fleet's with
``--fleet``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from servotune._version import __version__
from servotune.cli.output import (
    EXIT_OK,
    EXIT_USAGE,
    check_outputs,
    print_product,
    print_summary,
    progress_line,
)
from servotune.cli.warmup import compile_kernels
from servotune.errors import ServotuneError

# The library is imported inside each handler, not here, so that ``servotune --help`` (and any
# verb) pays only for what it uses: numba, scipy, matplotlib and python-control stay unloaded
# until a handler needs them (tests/cli/test_help_imports.py). That is the only reason for an
# import inside a function in this module; none of them works around an import cycle.


def cmd_init(args: argparse.Namespace) -> int:
    import shlex

    from servotune.examples import ExamplesDifferError, write_examples

    root = Path(args.dir)
    try:
        done = write_examples(root / "plants", force=args.force)
    except ExamplesDifferError as exc:
        them = "it" if len(exc.paths) == 1 else "them"
        raise ServotuneError(f"{exc.strerror} (--force replaces {them})") from None
    said = {
        "wrote": "wrote {}",
        "replaced": "replaced {}",
        "unchanged": "{} is already there, the same bytes: left alone",
    }
    for f in done:
        print(said[f.action].format(f.path), file=sys.stderr)
    cd = "" if root == Path(".") else f"cd {shlex.quote(args.dir)}, then "
    print(
        f"next: {cd}servotune rig plants/pc-dual-servo.toml; the README's commands "
        "(plants/...) run there as written",
        file=sys.stderr,
    )
    return EXIT_OK


def cmd_rig(args: argparse.Namespace) -> int:
    from servotune.report.text import format_rig_facts
    from servotune.rig import describe_rig, load_rig

    facts = describe_rig(load_rig(args.rig))
    if args.json:
        from servotune.io.files import json_safe

        print(json.dumps(json_safe(facts), indent=2, sort_keys=True, allow_nan=False))
    else:
        print(format_rig_facts(facts) + _modes_text(facts))
    return EXIT_OK


def _modes_text(facts: dict) -> str:
    """Lines listing each axis's modes (:func:`servotune.rig.describe_rig`), after the facts;
    empty for a rig without modes."""
    lines = []
    for name, a in facts["axes"].items():
        for m in a.get("modes", ()):
            lines.append(
                f"  {'axis ' + name + ' mode':<25}{m['freq_hz']:.4g} Hz, damping "
                f"{m['damping']:.3g}, gain {m['gain']:.3g} (anti-resonance "
                f"{m['antiresonance_hz']:.4g} Hz)"
            )
    return "".join("\n" + line for line in lines)


def cmd_shaper(args: argparse.Namespace) -> int:
    from servotune.analysis.shaping import axis_shaper, format_shaper
    from servotune.pipeline import default_pi_gains
    from servotune.rig import load_rig

    check_outputs(args.hal_output, inputs=(args.rig,))
    rig = load_rig(args.rig)
    axis = args.axis or next(a.name for a in rig.axes if a.role == "master")
    filters = None  # the rig's
    if args.tuning:
        from servotune.analysis.shaping import task_filters, task_gains
        from servotune.tuning import read_tuning

        tuning = read_tuning(args.tuning)
        gains, filters = task_gains(tuning, rig, axis), task_filters(tuning, axis)
    else:
        gains = default_pi_gains(rig)[rig.axis_names.index(axis)]
    shaper, _, why = axis_shaper(rig, axis, gains, args.kind, filters)
    print_product(
        args.json,
        lambda: {"axis": axis, **shaper.to_dict(), "why": why},
        lambda: format_shaper(axis, shaper, why),
    )
    if args.hal_output:
        from servotune.export.hal_component import shaper_component
        from servotune.io.files import atomic_write_text

        atomic_write_text(args.hal_output, shaper_component(shaper, name=args.hal_name))
        print(f"wrote the HAL component {args.hal_name} to {args.hal_output}", file=sys.stderr)
    return EXIT_OK


def cmd_simulate(args: argparse.Namespace) -> int:
    from servotune.rig import load_rig
    from servotune.scenarios import Scenario, build_scenario

    check_outputs(args.output, inputs=(args.rig, args.input))
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
    compile_kernels("simulation")  # inputs checked; before the slow imports, so it says so early
    from servotune.io.log import format_log, write_log
    from servotune.pipeline import log_metadata, run_scenario, trace_log_columns

    if args.shaper:
        from servotune.analysis.shaping import shape_scenario
        from servotune.pipeline import default_pi_gains

        gains = default_pi_gains(rig)[rig.axis_names.index(scen.axis)]
        scen, why = shape_scenario(rig, scen, gains, args.shaper)
        progress_line(f"simulate: the {scen.axis} axis's reference shaped: " + "; ".join(why))
    trace = run_scenario(rig, scen, seed=args.seed, noise=not args.no_noise)
    meta = log_metadata(
        rig,
        scenario=scen.name,
        axis=scen.axis,
        closed_loop=str(args.closed_loop).lower(),
        seed=args.seed,
    )
    # with exc_code (docs/decisions.md#5-excitation-is-logged)
    cols = trace_log_columns(trace, scen.inputs.dac_add_codes)
    kwargs = {"period_s": rig.period_s, "columns": cols, "metadata": meta}
    if args.output == "-":
        sys.stdout.write(format_log(**kwargs))
    else:
        write_log(args.output, **kwargs)
        print(f"wrote {trace.n_ticks} ticks to {args.output}", file=sys.stderr)
    return EXIT_OK


def _rig_to_extend(path: str, axis: str | None) -> None:
    """Check, before a fit, that an existing ``-o`` file is a rig the fitted plant can be
    written into (with ``axis`` among its axes when it is given)."""
    from servotune.errors import RigError
    from servotune.rig import load_rig

    try:
        names = load_rig(path).axis_names
    except RigError as exc:
        raise RigError(
            f"-o {path!r} exists but is not a rig to write the fit into ({exc})"
        ) from None
    if axis is not None and axis not in names:
        raise RigError(
            f"-o {path!r} has no axis {axis!r} to write the fit into (its axes: {', '.join(names)})"
        )


def cmd_fit(args: argparse.Namespace) -> int:
    if (problem := _fleet_usage(args)) is not None:
        print(f"servotune fit: error: {problem}", file=sys.stderr)
        return EXIT_USAGE
    if args.fleet:
        return _cmd_fit_fleet(args)
    args.log = args.log[0]  # one log (the positional takes several for --fleet)
    from servotune.identify import fit_log
    from servotune.identify.result import FIT_SCHEMA
    from servotune.rig import load_rig, write_plant
    from servotune.tuning import file_sha256

    check_outputs(args.output, args.plot, inputs=(args.log,))
    n_modes = None if args.modes is None else _modes_arg(args.modes)
    if args.output and Path(args.output).exists():  # the rig the fit goes into: read first
        _rig_to_extend(args.output, args.axis)
    rig = load_rig(args.rig) if args.rig else None
    dac_range = _range(args.dac_range_v) if args.dac_range_v else None
    hal = _hal(args, args.log)
    result, log, axis = fit_log(
        args.log,
        axis=args.axis,
        rig=rig,
        structure=args.structure,
        counter_bits=args.counter_bits,
        dac_bits=args.dac_bits,
        dac_range_v=dac_range,
        period_s=args.period_s,
        compute_s=args.compute_s,
        method=args.method,
        friction=args.friction,
        invert_encoder=args.invert_encoder,
        need_axis_name=bool(args.output),
        strict=args.strict,
        hal=hal,
        progress=progress_line,
        modes=n_modes,
    )
    print(f"axis {axis or '(unprefixed)'}: " + result.summary(), file=sys.stderr)
    if args.plot:
        from servotune.identify import simulate_fit, validation_split
        from servotune.plot import plot_fit, save_figure

        ax = log.axis(None if list(log.axes) == [""] else axis)
        pos = -ax.pos_counts if result.inverted_encoder else ax.pos_counts
        sim = simulate_fit(result, ax.cmd_v, pos)
        save_figure(
            plot_fit(
                pos, sim, log.period_s, validation_split(sim.size), f"fit of {axis or 'axis'}"
            ),
            args.plot,
        )
    if args.output:
        prov = result.provenance(
            Path(args.log).name, file_sha256(args.log), log.metadata.get("date", "")
        )
        new = not Path(args.output).exists()
        name = args.name or Path(args.output).stem
        write_plant(
            args.output,
            axis,
            result.plant,
            provenance=prov,
            fit=result.plant_fit,
            new_name=name if new else None,
            new_header=f"Rig {name}: made by `servotune fit -o` ({prov}).\nUnits are "
            "in the key names; gains are D/A codes per count.",
            **({"template": args.rig} if args.rig else {}),
        )
        if new:
            source = f"{Path(args.rig).name}'s" if args.rig else "the example rig's"
            print(
                f"wrote a new rig {name!r} with [axis.{axis}.plant] to {args.output} (its "
                f"hardware facts are {source}: check them)",
                file=sys.stderr,
            )
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
            return (
                f"several logs need --fleet TABLE.parquet|.csv ({len(args.log)} given); "
                "without it fit takes one log"
            )
        for flag, v in (
            ("--baseline", args.baseline),
            ("--fleet-report", args.fleet_report),
            ("--scheduler", args.scheduler),
            ("--workers", args.workers),
        ):
            if v is not None:
                return f"{flag} needs --fleet TABLE.parquet|.csv"
        return None
    for flag, v in (
        ("-o", args.output),
        ("--plot", args.plot),
        ("--name", args.name),
        ("--modes", args.modes),
    ):
        if v is not None:
            return (
                f"{flag} is for one log, not with --fleet (the fleet's outputs are --fleet "
                "and --fleet-report)"
            )
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
    from servotune.fleet.table import table_format
    from servotune.rig import load_rig

    table_format(args.fleet)  # a wrong suffix fails before any work
    check_outputs(args.fleet, args.fleet_report, inputs=(*args.log, args.baseline, args.rig))
    baseline = read_fleet_table(args.baseline) if args.baseline else ()
    hal = _hal(args, None)
    options = FleetFitOptions(
        axis=args.axis,
        rig=load_rig(args.rig) if args.rig else None,
        structure=args.structure,
        counter_bits=args.counter_bits,
        dac_bits=args.dac_bits,
        dac_range_v=_range(args.dac_range_v) if args.dac_range_v else None,
        period_s=args.period_s,
        compute_s=args.compute_s,
        method=args.method,
        friction=args.friction,
        invert_encoder=args.invert_encoder,
        strict=args.strict,
        hal=hal,
    )
    compile_kernels("identification")  # here, not in each worker of a cluster
    with open_executor(
        len(args.log),
        scheduler=args.scheduler,
        workers=args.workers,
        min_items=FLEET_CLUSTER_MIN_LOGS,
    ) as ex:
        result = fit_fleet(
            args.log, options=options, executor=ex, baseline=baseline, progress=progress_line
        )
    s = result.summary
    if s.n_failed == s.n_rows:  # no log fitted: exit 3 and no table (README, "A fleet of machines")
        first = s.failures[0][2] if s.failures else "no rows"
        raise ServotuneError(
            f"none of the {s.n_logs} logs fitted, no table written; first error: {first}"
        )
    write_fleet_table(result, args.fleet)
    print_summary(args.json, result.to_dict(), s.text)
    if s.n_failed:
        failed = len({f for f, _, _ in s.failures})
        print(
            f"{failed} of {s.n_logs} logs failed to fit (their rows in the table hold the error)",
            file=sys.stderr,
        )
    print(f"wrote the fleet table ({len(result.rows)} rows) to {args.fleet}", file=sys.stderr)
    if args.fleet_report:
        from servotune.report.fleet import write_fleet_report

        write_fleet_report(result, args.fleet_report, title=Path(args.fleet).name)
        print(f"wrote the fleet report to {args.fleet_report}", file=sys.stderr)
    return EXIT_OK


def cmd_frf(args: argparse.Namespace) -> int:
    from servotune.analysis.frf import frf
    from servotune.identify.logfit import read_fit_log
    from servotune.io.files import atomic_write_text
    from servotune.rig import load_rig

    check_outputs(args.output, args.plot, inputs=(args.log,))
    band = None if args.band is None else _band(args.band)
    n_modes = None if args.modes is None else _modes_arg(args.modes)
    log, compute_s = read_fit_log(
        args.log,
        hal=_hal(args, args.log),
        rig=load_rig(args.rig) if args.rig else None,
        counter_bits=args.counter_bits,
        dac_bits=args.dac_bits,
        dac_range_v=_range(args.dac_range_v) if args.dac_range_v else None,
        period_s=args.period_s,
        compute_s=args.compute_s,
        strict=args.strict,
        progress=progress_line,
    )
    result = frf(
        log,
        args.axis,
        output=args.response,
        period_ticks=args.period_ticks,
        skip=args.skip,
        band_hz=band,
    )
    doc = result.to_dict()
    fitted = None
    if n_modes is not None:
        from servotune.identify.logfit import check_lines_for_modes
        from servotune.identify.modes import fit_modes

        check_lines_for_modes(result, n_modes)
        fitted = fit_modes(result, n_modes=n_modes, compute_s=compute_s or 0.0)
        doc["model"] = fitted.to_dict()
    as_json = json.dumps(doc, indent=2, sort_keys=True) + "\n"
    if args.output and args.output != "-":
        is_csv = args.output.lower().endswith(".csv")
        atomic_write_text(args.output, result.to_csv() if is_csv else as_json)
        print(f"wrote the frequency response to {args.output}", file=sys.stderr)
    elif not args.json:
        sys.stdout.write(as_json)
    if args.plot:
        from servotune.plot import plot_frf, save_figure

        model = None if fitted is None else fitted.response(result.freq_hz)
        title = f"{Path(args.log).name}: {args.response}"
        save_figure(plot_frf(result, title, model), args.plot)
        print(f"wrote the plot to {args.plot}", file=sys.stderr)

    def text() -> str:
        return result.summary() + ("" if fitted is None else "\n" + fitted.summary())

    print_summary(args.json, doc, text)
    return EXIT_OK


def _hal(args: argparse.Namespace, capture: str | None) -> object:
    """The HAL settings of ``--map`` and its options for ``capture`` (None: a servotune
    log)."""
    from servotune.io.hal import hal_settings

    return hal_settings(
        args.map,
        format=args.hal_format,
        columns=args.hal_columns,
        position_scale=args.position_scale,
        output_scale=args.output_scale,
        sample_number=args.sample_number,
        capture=capture,
    )


def _modes_arg(text: str) -> int | str:
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise ServotuneError(f"--modes must be auto or a number of modes, got {text!r}") from None


def _band(text: str) -> tuple[float, float]:
    return _pair(text, ":", "--band must be F1:F2 in Hz")


def _range(text: str) -> tuple[float, float]:
    return _pair(text, ",", "--dac-range-v must be LOW,HIGH in volts")


def _pair(text: str, sep: str, usage: str) -> tuple[float, float]:
    """Two numbers written ``A<sep>B``; else one line: ``usage``, and what was given."""
    try:
        lo, hi = (float(x) for x in text.split(sep))
    except ValueError:
        raise ServotuneError(f"{usage}, got {text!r}") from None
    return lo, hi


def cmd_excite(args: argparse.Namespace) -> int:
    from servotune.excite import design_excitation, write_excitation
    from servotune.rig import load_rig

    check_outputs(args.output, inputs=(args.rig,))
    if args.periods is None and (args.band is not None or args.phases is not None):
        raise ServotuneError("--band and --phases are for a periodic multisine: give --periods")
    if args.periods is not None and args.kind != "multisine":
        raise ServotuneError(f"--periods is for --kind multisine, not --kind {args.kind}")
    band = None if args.band is None else _band(args.band)
    rig = load_rig(args.rig)
    axis = args.axis or next(a.name for a in rig.axes if a.role == "master")
    exc = design_excitation(
        rig,
        axis,
        args.kind,
        args.seconds,
        periods=args.periods,
        band_hz=band,
        phases=args.phases or "schroeder",
        seed=args.seed,
        amplitude_codes=args.amplitude_codes,
    )
    write_excitation(args.output, exc, rig)
    lo, hi = exc.predicted_travel_counts
    periodic = ""
    if exc.periods is not None and exc.band_hz is not None:
        f1, f2 = exc.band_hz
        periodic = (
            f"; {exc.periods} periods × {exc.period_ticks} ticks, band {f1:.4g} … {f2:.4g} Hz, "
            f"{exc.excited_lines} excited and {exc.detection_lines} detection lines, "
            f"{exc.phases} crest factor {exc.crest_factor:.2f}"
        )
    print(
        f"wrote {exc.n_ticks} ticks of {args.kind} on {axis} to {args.output}: amplitude "
        f"{exc.amplitude_codes} codes (limited by {exc.limited_by}), predicted max speed "
        f"{exc.predicted_max_speed_rpm:.0f} r/min, travel {lo:.0f} … {hi:.0f} counts{periodic}",
        file=sys.stderr,
    )
    return EXIT_OK


def cmd_autotune(args: argparse.Namespace) -> int:
    from servotune.autotune import (
        check_session,
        format_plan,
        load_autotune_config,
        plan_autotune,
        with_target,
    )
    from servotune.io.halcmd import read_session

    check_outputs(args.guard_output, inputs=(args.config,))
    cfg = load_autotune_config(args.config)
    if args.target is not None:
        cfg = with_target(cfg, args.target)
    if not args.dry_run:
        from servotune.autotune_live import format_result, run_autotune

        compile_kernels("simulation")
        res = run_autotune(
            cfg,
            args.output_dir,
            guard=args.guard_name.replace("_", "-"),
            hal_user=args.hal_user,
            say=progress_line,
        )
        print_product(args.json, res.to_dict, lambda: format_result(res))
        return EXIT_OK
    session = read_session()
    if session is not None:
        check_session(cfg, session)
    compile_kernels("simulation")
    plan = plan_autotune(cfg)
    checked = session is not None
    doc = {**plan.to_dict(), "session_checked": checked}
    print_product(args.json, lambda: doc, lambda: format_plan(cfg, plan, checked))
    if args.guard_output:
        from servotune.export.hal_component import guard_component
        from servotune.io.files import atomic_write_text

        env = cfg.envelope
        atomic_write_text(
            args.guard_output,
            guard_component(
                name=args.guard_name,
                travel_counts=env.travel_counts,
                speed_cps=env.speed_cps,
                following_error_counts=env.following_error_counts,
                max_volts=env.max_volts,
                position_scale=cfg.hal.position_scale,
            ),
        )
        print(f"wrote the guard {args.guard_name} to {args.guard_output}", file=sys.stderr)
    return EXIT_OK
