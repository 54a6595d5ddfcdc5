"""Command line: ``servotune <verb>``. Each handler is a few lines calling the library.

stdout carries only the product (JSON, CSV); diagnostics go to stderr. Exit codes: 0 ok,
1 verification failed, 2 usage error, 3 bad input data. Errors are one line on stderr; the
traceback only with ``--debug``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from servotune import __version__
from servotune.errors import ServotuneError

__all__ = ["main"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_BAD_INPUT = 0, 1, 2, 3


def _cmd_rig(args: argparse.Namespace) -> int:
    from servotune.rig import describe_rig, load_rig

    facts = describe_rig(load_rig(args.rig))
    if args.json:
        print(json.dumps(facts, indent=2, sort_keys=True))
    else:
        print(_format_facts(facts))
    return EXIT_OK


def _format_facts(f: dict) -> str:
    lines = [
        f"rig {f['rig']}",
        f"  timer divisor            {f['timer_divisor']}",
        f"  achieved period          {f['achieved_period_s'] * 1e3:.6f} ms "
        f"({f['period_error_ppm']:+.1f} ppm vs {f['requested_period_s'] * 1e3:g} ms)",
        f"  counts per revolution    {f['counts_per_rev']:g}",
        f"  D/A LSB                  {f['dac_lsb_mv']:.4f} mV",
        f"  unwrap speed limit       {f['unwrap_speed_limit_rpm']:.0f} r/min "
        f"({f['unwrap_max_counts_per_tick']} counts/tick)",
        f"  input-frequency limit    {f['input_frequency_speed_limit_rpm']:.0f} r/min "
        f"(binds first: {f['binding_speed_limit']})",
    ]
    for name, a in f["axes"].items():
        lo, hi = a["lock_band_counts"]
        lines += [
            f"  axis {name} ({a['role']})",
            f"    speed limit            {a['speed_limit_rpm']:g} r/min "
            f"({a['counts_per_tick_at_speed_limit']:.1f} counts/tick; "
            f"{'within' if a['speed_limit_ok'] else 'EXCEEDS'} the counter limits)",
            f"    counter wraps every    {a['time_to_wrap_at_speed_limit_s']:.1f} s at that speed",
            f"    lock holding band      [{lo}, {hi}] counts "
            f"({'within' if a['lock_band_within_one_pulse'] else 'outside'} ±1 pulse)",
        ]
    return "\n".join(lines)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from servotune.logs import write_log
    from servotune.pipeline import log_metadata, run_scenario, trace_log_columns
    from servotune.rig import load_rig
    from servotune.scenarios import build_scenario

    rig = load_rig(args.rig)
    axis = args.axis or next(a.name for a in rig.axes if a.role == "master")
    scen = build_scenario(
        rig, args.scenario, axis=axis, seconds=args.seconds, closed_loop=args.closed_loop
    )
    trace = run_scenario(rig, scen, seed=args.seed, noise=not args.no_noise)
    meta = log_metadata(
        rig, scenario=args.scenario, axis=axis, closed_loop=str(args.closed_loop).lower(),
        seed=args.seed,
    )  # fmt: skip
    kwargs = {"period_s": rig.period_s, "columns": trace_log_columns(trace), "metadata": meta}
    if args.output == "-":
        from servotune.logs import format_log

        sys.stdout.write(format_log(**kwargs))
    else:
        write_log(args.output, **kwargs)
        print(f"wrote {trace.n_ticks} ticks to {args.output}", file=sys.stderr)
    return EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    from servotune.pipeline import run_demo

    Path(args.out).mkdir(parents=True, exist_ok=True)
    summary = run_demo(args.rig, args.out, seed=args.seed)
    for name, h in summary["lock_hold"].items():
        print(f"lock hold {name}: observed {h['observed_counts']} "
              f"predicted {h['predicted_counts']} counts", file=sys.stderr)  # fmt: skip
    print(f"wrote demo_summary.json, lock_hold.png, track.png, track_log.csv to {args.out}",
          file=sys.stderr)  # fmt: skip
    return EXIT_OK


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="servotune",
        description="Control design and tuning workbench for synchronised position servos.",
    )
    p.add_argument("--version", action="version", version=f"servotune {__version__}")
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = p.add_subparsers(dest="verb", required=True, metavar="VERB")

    s = sub.add_parser("rig", help="print the derived facts of a rig file")
    s.add_argument("rig", help="rig file (TOML), e.g. plants/pc-dual-servo.toml")
    s.add_argument("--json", action="store_true", help="JSON on stdout")
    s.set_defaults(func=_cmd_rig)

    s = sub.add_parser("simulate", help="run a scenario on the virtual rig and write a log")
    s.add_argument("rig", help="rig file (TOML)")
    s.add_argument("--scenario", required=True, help="prbs, steps, chirp or track")
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

    s = sub.add_parser("demo", help="run the whole job on a rig and write into a directory")
    s.add_argument("rig", help="rig file (TOML)")
    s.add_argument("--out", default="reports", help="output directory (default reports)")
    s.add_argument("--seed", type=int, default=0)
    s.set_defaults(func=_cmd_demo)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except ServotuneError as exc:
        if args.debug:
            raise
        print(f"servotune {args.verb}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        if args.debug:
            raise
        where = f" {exc.filename!r}" if getattr(exc, "filename", None) else ""
        print(f"servotune {args.verb}: error:{where} {exc.strerror or exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
