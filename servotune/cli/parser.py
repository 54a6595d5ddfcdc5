"""The verbs, their options, help texts and examples: :func:`build_parser` builds the argparse
parser, each verb pointing at its handler (``func``).

It imports only the handlers' modules, which import the library inside each handler: building
the parser (``servotune --help``) loads no heavy dependency.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any, NoReturn

from servotune._version import __version__
from servotune.cli.design import cmd_margins, cmd_plan, cmd_tune, cmd_verify
from servotune.cli.help_examples import EXAMPLES
from servotune.cli.machine_parsers import SHAPER_KINDS, add_autotune, add_shaper
from servotune.cli.measure import (
    cmd_excite,
    cmd_fit,
    cmd_frf,
    cmd_init,
    cmd_rig,
    cmd_simulate,
)
from servotune.cli.studies import cmd_compare, cmd_demo, cmd_linkage, cmd_sync
from servotune.cli.tables import cmd_check_table, cmd_export_table
from servotune.cli.warmup import cmd_warmup
from servotune.executor import local_workers
from servotune.export.formats import DEFAULT_FORMAT, FORMATS
from servotune.kernels import GROUPS
from servotune.validate import SEED_MAX, check_seed


def _executor_options(group: Any, what: str, from_size: str) -> None:
    """``--scheduler`` and ``--workers`` (where the work runs: servotune.executor)."""
    group.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        help=f"{what} on the Dask cluster of this scheduler (tcp://HOST:8786; default: "
        "$SERVOTUNE_SCHEDULER); see docs/scale.md",
    )
    group.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="worker processes of a cluster started on this machine, whatever the size "
        f"(1: in-process; default: one per core from {from_size}); at most the usable cores "
        f"({local_workers()} here), not with --scheduler: refused before any work (exit 3)",
    )


class _Parser(argparse.ArgumentParser):
    """argparse's parser with a usage error in one line on stderr, exit 2: what is wrong and
    where the usage is (argparse prints the whole usage block first); every verb's parser is
    one (``add_subparsers`` makes its parsers of the parent's class)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _seed(text: str) -> int:
    """A ``--seed`` value: an integer in ``0..SEED_MAX`` (:func:`~servotune.validate.check_seed`;
    argparse's type: a usage error if not)."""
    try:
        return check_seed(int(text))
    except ValueError:  # not an integer, or out of range
        raise argparse.ArgumentTypeError(
            f"must be an integer in 0..{SEED_MAX}, got {text!r}"
        ) from None


def _group(text: str) -> str:
    """A kernel group's name (``servotune warmup GROUP``; argparse's type: a usage error if
    not one of :data:`servotune.kernels.GROUPS`)."""
    names = [g.name for g in GROUPS]
    if text not in names:
        raise argparse.ArgumentTypeError(
            f"{text!r} is no kernel group; the groups: {', '.join(names)}"
        )
    return text


def _verb(sub: Any, func: Callable[..., int], name: str, **options: Any) -> Any:
    """A verb's sub-parser, running ``func`` (its handler; ``options``: ``add_parser``'s)."""
    s = sub.add_parser(name, **options)
    s.set_defaults(func=func)
    return s


def _add_init(sub: Any) -> None:
    """The ``init`` verb and its options."""
    s = _verb(
        sub,
        cmd_init,
        "init",
        help="write the example rig, gantry and linkage configs, their specs and a LinuxCNC "
        "capture map into DIR/plants/ (where the README's commands look for them)",
    )
    s.add_argument(
        "dir",
        nargs="?",
        default=".",
        metavar="DIR",
        help="directory to set up (default: the current one)",
    )
    s.add_argument(
        "--force",
        action="store_true",
        help="replace example files that are there with other content (default: refuse, "
        "writing nothing)",
    )


def _add_rig(sub: Any) -> None:
    """The ``rig`` verb and its options."""
    s = _verb(sub, cmd_rig, "rig", help="print the derived facts of a rig file")
    s.add_argument("rig", help="rig file (TOML), e.g. plants/pc-dual-servo.toml")
    s.add_argument("--json", action="store_true", help="JSON on stdout")


def _add_simulate(sub: Any) -> None:
    """The ``simulate`` verb and its options."""
    s = _verb(
        sub, cmd_simulate, "simulate", help="run a scenario on the virtual rig and write a log"
    )
    s.add_argument("rig", help="rig file (TOML)")
    s.add_argument("--scenario", help="prbs, steps, chirp or track")
    s.add_argument("--input", help="excitation CSV to play (from servotune excite)")
    s.add_argument("--axis", help="axis to excite or move (default: the master)")
    s.add_argument("--seconds", type=float, default=10.0, help="duration [s] (default 10)")
    s.add_argument("--seed", type=_seed, default=0, help="noise seed (default 0)")
    s.add_argument(
        "--closed-loop",
        action="store_true",
        help="excite with the lock module active (identification in closed loop)",
    )
    s.add_argument("--no-noise", action="store_true", help="switch the encoder noise off")
    s.add_argument(
        "--shaper",
        choices=("auto", *SHAPER_KINDS),
        help="shape the moved axis's task reference for its modes (see servotune shaper)",
    )
    s.add_argument("-o", "--output", required=True, help="log file to write ('-' for stdout)")


def _add_fit(sub: Any) -> None:
    """The ``fit`` verb and its options."""
    s = _verb(sub, cmd_fit, "fit", help="identify an axis's motor + drive model from a logged run")
    s.add_argument(
        "log",
        nargs="+",
        help="log CSV (as `servotune simulate` writes it; see the README), or a LinuxCNC HAL "
        "capture (halsampler output or halscope's saved data) or a CSV with other column "
        "names, read with --map; several only with --fleet",
    )
    s.add_argument("--axis", help="axis to fit (needed for multi-axis logs)")
    s.add_argument(
        "--structure", default=None, help="auto (default: BIC) or a list from delay,offset,coulomb"
    )
    s.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    s.add_argument("-o", "--output", help="write the axis's plant section into this rig file")
    s.add_argument("--plot", help="PNG: measured vs simulated position, velocity, residuals")
    s.add_argument(
        "--name",
        help="name of the rig -o creates (default: the file's name without .toml); an "
        "existing rig file keeps its name",
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
    s.add_argument(
        "--modes",
        help="also fit the plant's lightly damped modes to the log's frequency response (it "
        "needs a periodic excitation, as frf does): auto (chosen by held-out error) or a "
        "number; -o writes them into the rig file",
    )
    _log_options(s)
    _hal_options(s)
    _fit_fleet_options(s)


def _log_options(s: Any) -> None:
    """How a log is read (``fit`` and ``frf``): the rig and the settings it falls back on."""
    s.add_argument("--rig", help="rig file: D/A, counter, period and compute time fallbacks")
    s.add_argument(
        "--strict",
        action="store_true",
        help="an unknown metadata key in the log (# key: value, e.g. a typo) is an error, "
        "not a warning",
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


def _hal_options(s: Any) -> None:
    """Options for LinuxCNC HAL captures and mapped CSV logs (``fit`` and ``frf``)."""
    hal = s.add_argument_group(
        "LinuxCNC HAL captures and CSV logs with their own column names",
        "halsampler output, halscope's saved data or your logger's CSV, read with --map",
    )
    hal.add_argument(
        "--map",
        metavar="KEY=PIN,...|FILE.toml",
        help="read LOG through a mapping: a HAL capture, or a CSV log with its own column names "
        "(told apart by their content): which pin or CSV column (or 0-based column) is what, "
        "e.g. cmd=pid.0.output,pos=encoder.0.position or cmd=drive_volts,pos=encoder,"
        "ref=setpoint,time=t; keys: cmd (pid output units) or code (D/A code), pos (machine "
        "units; a CSV's, without --position-scale: counts) or counts (encoder counts, "
        "unwrapped), optional ref (commanded position, as pos), exc (excitation, command "
        "units), overruns (the sampler.N.overruns pin: a change = lost samples) and, for a "
        "CSV, time (its time column [s]) and tick; or a TOML file with a "
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
        "× scale (needed for a HAL capture's pos and ref; a CSV's are counts without it)",
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


def _fit_fleet_options(s: Any) -> None:
    """``fit``'s options for a fleet of logs."""
    fleet = s.add_argument_group(
        "fleet", "fit many machines' logs at once: a table, the fleet's spread, outliers, drift"
    )
    fleet.add_argument(
        "--fleet",
        metavar="TABLE.parquet|.csv",
        help="fit every LOG (every axis, or --axis) and write one row per log and axis to this "
        "table: parameters with 95 %% intervals, adequacy, fit %%, SHA-256, machine_id and date "
        "(a bad log is a row with its error); the summary on stderr (--json: stdout). Exit "
        "0 when at least one log fitted; 3 and no table when none did",
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
    _executor_options(fleet, "fit", "200 logs")


def _add_frf(sub: Any) -> None:
    """The ``frf`` verb and its options."""
    s = _verb(
        sub,
        cmd_frf,
        "frf",
        help="measure an axis's frequency response from a closed-loop log with a periodic "
        "excitation",
    )
    s.add_argument(
        "log",
        help="log CSV with an exc_code column (servotune simulate --input), or a HAL capture or "
        "CSV with other column names read with --map (exc=PIN: the excitation)",
    )
    s.add_argument("--axis", help="axis (needed for multi-axis logs)")
    s.add_argument(
        "--response",
        choices=["velocity", "position"],
        default="velocity",
        help="command [V] to velocity [counts/s] (default) or to position [counts]",
    )
    s.add_argument("--period-ticks", type=int, help="ticks per excitation period (default: found)")
    s.add_argument("--skip", type=int, default=1, help="periods discarded as transient (default 1)")
    s.add_argument("--band", help="only lines within F1:F2 [Hz]")
    s.add_argument(
        "-o", "--output", help="FRF file to write: .json (default) or .csv (default: stdout)"
    )
    s.add_argument(
        "--modes",
        help="also fit the rigid plant and its lightly damped modes to the response: auto "
        "(chosen by held-out error) or a number",
    )
    s.add_argument("--plot", help="Bode plot with bounds and coherence (PNG)")
    s.add_argument("--json", action="store_true", help="the summary as JSON on stdout")
    _log_options(s)
    _hal_options(s)


def _add_excite(sub: Any) -> None:
    """The ``excite`` verb and its options."""
    s = _verb(sub, cmd_excite, "excite", help="design an identification excitation (D/A codes)")
    s.add_argument("--rig", required=True, help="rig file (TOML)")
    s.add_argument("--axis", help="axis (default: the master)")
    s.add_argument("--kind", required=True, choices=["prbs", "multisine", "steps"])
    s.add_argument("--seconds", type=float, required=True, help="duration [s]")
    s.add_argument("--seed", type=_seed, default=0)
    s.add_argument("--amplitude-codes", type=int, help="requested amplitude [D/A codes]")
    s.add_argument("--periods", type=int, help="multisine: whole periods (>= 2), for frf")
    s.add_argument("--band", metavar="F1:F2", help="with --periods: band [Hz] (<= 0.9 × Nyquist)")
    phases = ["schroeder", "random"]  # crest factor about 1.6 and 3
    s.add_argument("--phases", choices=phases, help="with --periods (default schroeder)")
    s.add_argument("-o", "--output", required=True, help="excitation CSV to write")


def _add_tune(sub: Any) -> None:
    """The ``tune`` verb and its options."""
    s = _verb(
        sub,
        cmd_tune,
        "tune",
        help="tune the master's PI and the slave's fuzzy-PID tables (a rig), or both drives' PI "
        "and the sync compensator (a gantry config)",
    )
    s.add_argument("rig", help="rig file or gantry config (TOML)")
    s.add_argument("-o", "--output", help="tuning file to write (default: stdout)")
    s.add_argument("--seed", type=_seed, default=0, help="optimiser and noise seed (default 0)")
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
        "--frf",
        action="append",
        metavar="AXIS=FILE",
        help="an axis's measured frequency response (servotune frf -o FILE.json): its filters "
        "and every loop must also keep the margin limits on it and its 95 %% bounds (repeat "
        "for more axes)",
    )
    s.add_argument(
        "--shaper",
        choices=("auto", *SHAPER_KINDS),
        help="also design the input shaper of the master's task reference for its closed-loop "
        "modes (auto: the shortest that holds 5 %% over each mode's range); it is exported "
        "with the tables and run by verify's moves",
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


def _add_plan(sub: Any) -> None:
    """The ``plan`` verb and its options."""
    s = _verb(
        sub,
        cmd_plan,
        "plan",
        help="plan a multi-CPU linkage: bus block budget, queue depths and watermarks, clock "
        "sync, the axes' gains as the CPUs run them",
    )
    s.add_argument("config", help="linkage config (TOML)")
    s.add_argument("--json", action="store_true", help="the plan's design as JSON on stdout")
    s.add_argument("-o", "--output", help="plan file to write (default: stdout)")


def _add_verify(sub: Any) -> None:
    """The ``verify`` verb and its options."""
    s = _verb(
        sub,
        cmd_verify,
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
    s.add_argument(
        "--seed", type=_seed, default=None, help="Monte-Carlo seed (default: the spec's)"
    )
    s.add_argument(
        "--montecarlo",
        type=int,
        default=None,
        metavar="N",
        help="Monte-Carlo plant sets (default: the spec's montecarlo.count; up to 1e8): run in "
        "chunks, in-process below 100,000, else on a Dask cluster (--scheduler, or one started "
        "on this machine's cores); the result is the same on any of them",
    )
    _executor_options(
        s, "run the plant sets", "100,000 plant sets, or a gantry's 10,000 plant pairs"
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
    s.add_argument(
        "--frf",
        action="append",
        metavar="AXIS=FILE",
        help="with --report: an axis's measured frequency response (servotune frf -o "
        "FILE.json), drawn in the report's Resonance section beside the rig's model "
        "(repeat for more axes)",
    )


def _add_margins(sub: Any) -> None:
    """The ``margins`` verb and its options."""
    s = _verb(
        sub,
        cmd_margins,
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
    s.add_argument(
        "--frf",
        action="append",
        metavar="AXIS=FILE",
        help="an axis's measured frequency response (servotune frf -o FILE.json): every loop "
        "also on it and its 95 %% bounds, with and without the axis's filters, with 0 and 1 "
        "extra tick (repeat for more axes)",
    )
    s.add_argument("--json", action="store_true", help="every loop's figures as JSON on stdout")


def _add_export_table(sub: Any) -> None:
    """The ``export-table`` verb and its options."""
    s = _verb(
        sub, cmd_export_table, "export-table", help="export a verified tuning's tables (JSON or C)"
    )
    s.add_argument(
        "tuning",
        nargs="?",
        help="tuning file or linkage plan (default: the workbench's current tuning)",
    )
    s.add_argument(
        "-o",
        "--output",
        help="file (JSON, HAL, .comp) or directory (C); default stdout (not for C)",
    )
    s.add_argument(
        "--format",
        choices=list(FORMATS),
        default=DEFAULT_FORMAT,
        help="; ".join(
            f"{f.name}{' (default)' if f.name == DEFAULT_FORMAT else ''}: {f.help}"
            for f in FORMATS.values()
        ),
    )
    s.add_argument(
        "--position-scale",
        type=float,
        help="linuxcnc-hal: encoder counts per machine unit (the encoder's position-scale), "
        "e.g. 2000; linuxcnc-comp: with it, the component's command is a float in machine "
        "units (a LinuxCNC position command), converted to counts by it",
    )
    s.add_argument(
        "--output-scale",
        type=float,
        default=1.0,
        help="linuxcnc-hal: pid output units per volt at the D/A (default 1: output in volts)",
    )
    s.add_argument(
        "--pid",
        dest="pid_name",
        metavar="PID",
        default="pid.x",
        help="linuxcnc-hal: the pid instance the file sets (default pid.x, as `loadrt pid "
        "names=pid.x`)",
    )
    s.add_argument(
        "--no-feedforward",
        dest="velocity_feedforward",
        action="store_false",
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
        help="the gantry config of a gantry tuning or the linkage config of a plan (default: "
        "the path it records); another is refused",
    )
    s.add_argument("--spec", help="also require that the verification used this spec file")
    s.add_argument("--unverified", action="store_true", help="export without a passed verify")


def _add_check_table(sub: Any) -> None:
    """The ``check-table`` verb and its options."""
    s = _verb(
        sub,
        cmd_check_table,
        "check-table",
        help="check an export: every CRC and digest (any edit is refused)",
    )
    s.add_argument(
        "file",
        help="an export of servotune export-table: tables, gantry or linkage "
        "JSON, a LinuxCNC HAL file or HAL component (.comp)",
    )
    s.add_argument("--json", action="store_true", help="the check's summary as JSON on stdout")


def _add_demo(sub: Any) -> None:
    """The ``demo`` verb and its options."""
    s = _verb(sub, cmd_demo, "demo", help="run the whole job on a rig and write into a directory")
    s.add_argument("rig", help="rig file (TOML)")
    s.add_argument("--out", default="reports", help="output directory (default reports)")
    s.add_argument("--seed", type=_seed, default=0)
    s.add_argument(
        "--full",
        action="store_true",
        help="the whole study: the default tuning budget, Figure 4 over three seeds and the "
        "tracking/robustness sweep (several minutes; default: the quick preset)",
    )


def _add_compare(sub: Any) -> None:
    """The ``compare`` verb and its options."""
    s = _verb(
        sub,
        cmd_compare,
        "compare",
        help="Figure 4: PID, PID + feedforward and composite tuned alike, compared on held-out "
        "scenarios",
    )
    s.add_argument("rig", help="rig file (TOML)")
    s.add_argument(
        "--spec",
        required=True,
        help="verification spec (TOML): limits, tuning run and the held-out scenarios",
    )
    s.add_argument("--out", default="reports", help="directory for figure4.png/json, pareto.png")
    s.add_argument("--seeds", type=int, default=3, help="optimiser seeds (default 3)")
    s.add_argument("--seed", type=_seed, default=0, help="first seed (default 0)")
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


def _add_sync(sub: Any) -> None:
    """The ``sync`` verb and its options."""
    s = _verb(sub, cmd_sync, "sync", help="compare gantry topologies on a gantry config")
    s.add_argument("config", help="gantry config (TOML), e.g. plants/gantry.toml")
    s.add_argument("--seed", type=_seed, default=0, help="noise and jitter seed (default 0)")
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


def _add_linkage(sub: Any) -> None:
    """The ``linkage`` verb and its options."""
    s = _verb(sub, cmd_linkage, "linkage", help="simulate a multi-CPU linkage and check it")
    s.add_argument("config", help="linkage config (TOML), e.g. plants/linkage-6axis.toml")
    s.add_argument("--seconds", type=float, help="simulated time [s] (default: path + settle)")
    s.add_argument("--seed", type=_seed, default=0, help="encoder-noise seed (default 0)")
    s.add_argument("--json", action="store_true", help="the result as JSON on stdout")
    s.add_argument("--plot", metavar="DIR", help="write queue and circular-test PNGs into DIR")


def _add_warmup(sub: Any) -> None:
    """The ``warmup`` verb and its options."""
    s = _verb(
        sub,
        cmd_warmup,
        "warmup",
        help="compile every kernel the commands use now (numba, cached on disk): after an "
        "install or an update, so no later command stops to compile; a second run finds them "
        "compiled",
    )
    s.add_argument(
        "groups",
        nargs="*",
        type=_group,
        metavar="GROUP",
        help="only these kernel groups (default: all): "
        + "; ".join(f"{g.name} ({g.what})" for g in GROUPS),
    )
    s.add_argument("--json", action="store_true", help="what was compiled, as JSON on stdout")


def build_parser() -> argparse.ArgumentParser:
    """The ``servotune`` command line: the global options and every verb's."""
    p = _Parser(
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
    _add_init(sub)
    _add_rig(sub)
    _add_simulate(sub)
    add_shaper(sub, _verb)
    add_autotune(sub, _verb)
    _add_fit(sub)
    _add_frf(sub)
    _add_excite(sub)
    _add_tune(sub)
    _add_plan(sub)
    _add_verify(sub)
    _add_margins(sub)
    _add_export_table(sub)
    _add_check_table(sub)
    _add_demo(sub)
    _add_compare(sub)
    _add_sync(sub)
    _add_linkage(sub)
    _add_warmup(sub)
    for name, verb in sub.choices.items():  # --quiet also after the verb (where users type it)
        verb.add_argument(
            "-q",
            "--quiet",
            action="store_true",
            default=argparse.SUPPRESS,
            help="no progress on stderr",
        )
        verb.formatter_class = argparse.RawDescriptionHelpFormatter
        verb.epilog = "examples:\n" + "\n".join(f"  {x}" for x in EXAMPLES[name])
    return p
