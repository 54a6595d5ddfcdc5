"""The LinuxCNC HAL export: the master axis's verified PI law as LinuxCNC's stock ``pid``.

``servotune export-table --format linuxcnc-hal --position-scale S`` writes a HAL file of
``setp`` lines for one instance of the stock ``pid`` component (default ``pid.x``), for a
machine that closes the loop in LinuxCNC: encoder counter → ``encoder.N.position`` (counts /
``position-scale``) → ``pid`` → D/A. servotune tunes the master axis's PI law in its own units
(:mod:`servotune.laws.pi`): ``u = Kp·e + I``, ``I(k) = I(k−1) + Ki·T·e(k)``, ``u`` in D/A LSB,
``e`` in encoder counts, each constant an integer ``q`` with ``f`` fraction bits (value
``q·2^-f``, :mod:`servotune.fixed`), the tick ``T`` the rig's achieved period. The stock pid
computes, in machine units and output units (:mod:`servotune.laws.linuxcnc_pid`),
``output = Pgain·e + Igain·errorI + FF1·commandD``, ``errorI(k) = errorI(k−1) + e(k)·T``:
integrate, then output, as servotune's law; the same anti-windup (no integration on a tick
where the output is on its limit and the error pushes further).

Conversions (:func:`pid_parameters`). With ``lsb_v = (range_v[1] − range_v[0]) / 2^bits`` the
D/A step [V], ``S = position_scale`` [counts per machine unit], ``O = output_scale`` [output
units per V], ``T = period_s`` [s], ``g`` the master plant's ``gain_cps_per_v`` (its mean gain
if asymmetric) [counts/s per V]::

    Pgain     = Kp · lsb_v · O · S                       [output units per machine unit]
    Igain     = (Ki·T / T) · lsb_v · O · S               [output units per machine unit·s]
    FF1       = O · S / g                                [output units per machine unit/s]
    maxoutput = min(zero_code, code_max − zero_code) · lsb_v · O          [output units]
    maxerrorI = maxoutput / Igain   (0 if Igain is 0)                     [machine unit·s]
    Dgain = FF0 = FF2 = FF3 = bias = deadband = maxerror = maxerrorD = maxcmdD = maxcmdDD
          = maxcmdDDD = 0;  error-previous-target = false

with ``Kp = kp_q·2^-kp_f`` [LSB/count] and ``Ki·T = kit_q·2^-kit_f`` [LSB/count/tick] exactly
as the tuning file holds them. Each value is computed exactly (rational arithmetic on the
integers and on the doubles given) and rounded once to the nearest double, so it does not
depend on an evaluation order, and it is printed with ``repr`` (the shortest text that reads
back as that double: ``halcmd setp`` parses it with ``strtod``).

Why each choice:

- **Pgain, Igain**: ``Kp·e_counts`` LSB is ``Kp·(S·e_units)·lsb_v`` V, that is ``Kp·lsb_v·O·S``
  output units per machine unit of error; ``Ki·T·Σe_counts`` is ``(Ki·T/T)·lsb_v·O·S`` times
  ``Σ e_units·T``, the pid's ``errorI``. ``T`` is the tuning's period (the one folded into
  ``Ki·T``); the servo thread should run at the nearest whole nanosecond
  (:func:`~servotune.laws.linuxcnc_pid.thread_period_ns`: 4000235 ns for the 8253's 4.000235 ms
  tick): the pid then integrates ``e·period`` with a period a relative 8·10⁻⁸ off, of the
  order of the quantisation step of ``Ki·T`` itself (``1/q``). At another thread period the
  discrete loop is not the one servotune verified.
- **FF1** (velocity feedforward; LinuxCNC's tuning documents give no rule for it): from the
  master's identified model ``tau·dv/dt + v = g·(u + offset)`` at constant speed, ``v = g·u``,
  so a command speed of ``V`` machine units/s (``V·S`` counts/s) needs ``u = V·S/g`` V, that is
  ``V·S·O/g`` output units: ``FF1 = O·S/g`` against the pid's ``commandD`` (the command's
  difference per period). It acts on the command only, outside the feedback loop, so the
  verified stability margins are unchanged; the PI is left with the model's error, the drift
  and the transients. servotune's verified PI law has no feedforward:
  ``velocity_feedforward=False`` exports ``FF1 = 0``, exactly the verified law. ``FF2 = τ·FF1``
  would also cancel the drive's lag on a smooth command, but amplifies the command's
  quantisation by ``1/T²``; it is left 0.
- **bias = 0**: servotune models the analog zero drift (``offset_v``) and verifies the PI law
  against it: the integrator cancels it. The drift is the slow, temperature-dependent part of
  the analog chain (docs/systems.md#pc-dual-servo-synchronisation), so a fixed
  ``bias = −offset_v·O`` would be right only on the day of the fit, and it is not in the
  verified law.
- **deadband = 0**: servotune's law acts on every count of error (one count,
  ``1/S`` machine units, is the error's resolution anyway, and the D/A's half-LSB quantisation
  is in the verified simulation). A deadband would stop the integrator inside it and let the
  drift hold the axis up to a deadband off.
- **maxoutput**: the largest voltage the D/A gives both ways (``2047·lsb_v`` = 9.9951171875 V
  for a 12-bit ±10 V D/A), in output units: the pid's limit is symmetric, and at it the pid's
  anti-windup engages where the D/A saturates, as servotune's conditional integration does.
- **maxerrorI**: keeps the integral term within the D/A's span, as servotune clamps its
  integrator to the span.
- **maxerror = 0**: servotune clamps the error only at ±(2³¹−1) counts. The axis's
  following-error trip is LinuxCNC's job: the file's comments give ``[JOINT_n]FERROR``.
- **error-previous-target = false** (the component's default is true): servotune's law uses
  ``e(k) = r(k) − y(k)``, this tick's reference; true would give the loop the previous tick's
  command (the same feedback dynamics, the reference one tick late).

When the master axis's law has output filters (docs/runtime.md#filters-in-the-law), the file
goes on with them as LinuxCNC's stock ``biquad`` (one instance ``<pid_name>-filter<k>`` per
section, in series between the pid's output and the D/A;
:func:`servotune.export.linuxcnc_biquad.biquad_hal_text`): the quantised coefficients exactly,
run in floating point, so LinuxCNC's output differs from the runtime's fixed point by up to
:data:`FILTER_DIFFERENCE_CODES` D/A codes (measured in real HAL), as a comment in the file says.
Without filters nothing follows the pid's lines.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from fractions import Fraction
from pathlib import Path
from typing import Any

from servotune._version import __version__
from servotune.digest import text_digest_problem, with_digest_line
from servotune.errors import DigestError, ExportError
from servotune.export.document import write_export
from servotune.export.json import SCHEMA, Summary, tables_document
from servotune.export.linuxcnc_biquad import biquad_hal_text
from servotune.laws.linuxcnc_pid import PidParameters, thread_period_ns
from servotune.laws.pi import PIConstants
from servotune.rig import Rig
from servotune.tuning import Tuning
from servotune.validate import check_number, show_value

__all__ = [
    "DEFAULT_PID_NAME",
    "FILTER_DIFFERENCE_CODES",
    "HAL_FILE_FIRST_LINE",
    "PidParameters",
    "check_hal_file",
    "master_axis",
    "pid_hal_text",
    "pid_parameters",
    "to_file",
    "to_string",
]

DEFAULT_PID_NAME = "pid.x"
"""The pid instance the HAL file sets by default (``loadrt pid names=pid.x``)."""

HAL_FILE_FIRST_LINE = "# LinuxCNC HAL file:"
"""How a HAL file :func:`pid_hal_text` writes begins; its third line is its digest (a
comment: ``# sha256 of this file without this line: <hex>``, :mod:`servotune.digest`)."""

# a pid instance name: a HAL name that halcmd reads as one word (no '#' comment, no '$' or '['
# substitution, no ',' of the names= list); 25 characters leave room for the longest pin,
# '<name>.error-previous-target', within HAL_NAME_LEN (47)
_PID_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,24}")


def _scale(name: str, value: object, unit: str) -> Fraction:
    check_number(name, value, unit, strict=True, error=ExportError)
    return Fraction(value)  # type: ignore[arg-type]


def master_axis(tuning: Tuning) -> tuple[int, str, PIConstants]:
    """The axis the stock pid runs: the tuning's master, with its PI constants.

    Returns
    -------
    index : int
        Its index in the tuning (rig order).
    name : str
    pi : PIConstants

    Raises
    ------
    ExportError
        No master axis, or a master whose task law is not PI.
    """
    if not isinstance(tuning, Tuning):
        raise ExportError(
            f"--format linuxcnc-hal exports a single rig's tuning, got a "
            f"{type(tuning).__name__}: export a gantry or a linkage as JSON or C"
        )
    for i, (name, role, ctl) in enumerate(
        zip(tuning.axis_names, tuning.roles, tuning.controllers, strict=True)
    ):
        if role != "master":
            continue
        if not isinstance(ctl.task, PIConstants):
            law = "no task law" if ctl.task is None else "the fuzzy-PID law"
            raise ExportError(
                f"master axis {name!r} runs {law}, and the stock pid runs PI only: export "
                "it with --format linuxcnc-comp (the verified runtime as a HAL component)"
            )
        return i, name, ctl.task
    raise ExportError("the tuning has no master axis: the stock pid export is for the master's PI")


def pid_parameters(
    tuning: Tuning,
    rig: Rig,
    *,
    position_scale: float,
    output_scale: float = 1.0,
    velocity_feedforward: bool = True,
) -> PidParameters:
    """The stock pid's parameters for the tuning's master axis (module docstring: formulas).

    Parameters
    ----------
    tuning : Tuning
        A single rig's tuning; its master runs PI.
    rig : Rig
        Its rig (checked against the tuning): the D/A and the master's plant.
    position_scale : float
        Encoder counts per machine unit [counts/unit] (the encoder's ``position-scale``), > 0.
    output_scale : float
        pid output units per volt at the D/A [units/V] (1: the output is in volts), > 0.
    velocity_feedforward : bool
        FF1 from the plant's gain (default); False: FF1 = 0, the verified law alone.

    Returns
    -------
    PidParameters

    Raises
    ------
    ExportError
        A scale that is not a finite number > 0, a rig that is not the tuning's, or a tuning
        whose master does not run PI (:func:`master_axis`).

    Examples
    --------
    >>> p = pid_parameters(tuning, rig, position_scale=2000.0)  # doctest: +SKIP
    >>> p.maxoutput  # doctest: +SKIP
    9.9951171875
    """
    s = _scale("position_scale", position_scale, "encoder counts per machine unit")
    o = _scale("output_scale", output_scale, "pid output units per V at the D/A")
    _, name, pi = master_axis(tuning)
    if not isinstance(rig, Rig):
        raise ExportError(
            f"the tuning's rig is needed (its D/A and the master's plant), got {show_value(rig)}"
        )
    try:
        tuning.check_rig(rig)
    except ValueError as exc:
        raise ExportError(str(exc)) from None
    dac = rig.dac
    lsb = (Fraction(dac.range_v[1]) - Fraction(dac.range_v[0])) / 2**dac.bits  # [V]
    kp = Fraction(pi.kp.q, 2**pi.kp.f)  # [LSB/count]
    ki_t = Fraction(pi.ki_t.q, 2**pi.ki_t.f)  # [LSB/count/tick]
    period = Fraction(tuning.period_s)  # [s]
    per_unit = lsb * o * s  # output units per (LSB/count) per machine unit
    igain = ki_t / period * per_unit
    span = min(dac.zero_code, dac.code_max - dac.zero_code) * lsb * o
    ff1 = o * s / Fraction(rig.axis(name).plant.mean_gain_cps_per_v)
    exact = (kp * per_unit, igain, ff1, span, span / igain if igain else Fraction(0))
    try:
        values = [float(x) for x in exact]
        if any(x != 0 and v == 0 for x, v in zip(exact, values, strict=True)):
            raise OverflowError  # underflow: a gain that is not 0 would be exported as 0
    except OverflowError:
        raise ExportError(
            f"position_scale {float(s)!r} and output_scale {float(o)!r} give pid parameters "
            "beyond a double's range: give the scales in the units the machine uses"
        ) from None
    pgain, igain_f, ff1_f, maxoutput, maxerror_i = values
    return PidParameters(
        Pgain=pgain,
        Igain=igain_f,
        Dgain=0.0,
        bias=0.0,
        FF0=0.0,
        FF1=ff1_f if velocity_feedforward else 0.0,
        FF2=0.0,
        FF3=0.0,
        deadband=0.0,
        maxerror=0.0,
        maxerrorI=maxerror_i,
        maxerrorD=0.0,
        maxcmdD=0.0,
        maxcmdDD=0.0,
        maxcmdDDD=0.0,
        maxoutput=maxoutput,
        error_previous_target=False,
    )


def _value(v: float | bool) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return repr(float(v))


def pid_hal_text(
    tuning: Tuning,
    *,
    position_scale: float,
    output_scale: float = 1.0,
    rig: Rig,
    verification: Mapping[str, Any] | Summary | None = None,
    unverified: bool = False,
    pid_name: str = DEFAULT_PID_NAME,
    velocity_feedforward: bool = True,
) -> str:
    """The HAL file setting the stock pid's parameters for the tuning's master axis.

    Comments first (servotune version, rig name and SHA-256, tuning SHA-256, verified or not,
    the digest of the tables export of the same tuning, the scales, the thread period, the
    servotune constants and the conversions), then one ``setp <pid_name>.<pin> <value>`` line
    per pin of :class:`PidParameters`, in its field order; when the master axis has output
    filters (docs/runtime.md#filters-in-the-law), then their LinuxCNC ``biquad`` instances
    ``<pid_name>-filter<k>`` (:mod:`servotune.export.linuxcnc_biquad`: float, the quantised
    coefficients exactly) with a comment on how they differ from the runtime's fixed point.
    Without filters nothing follows the pid's lines. Deterministic bytes.

    Parameters
    ----------
    tuning : Tuning
    position_scale, output_scale, velocity_feedforward
        As :func:`pid_parameters`.
    rig : Rig
        The tuning's rig.
    verification, unverified
        As :func:`servotune.export.json.tables_document`: without a passing verification the
        export is refused unless ``unverified`` (then the file says it is not verified).
    pid_name : str
        The pid instance the lines set (``loadrt pid names=<pid_name>``; ``pid.0`` after
        ``loadrt pid num_chan=…``); default ``pid.x``.

    Returns
    -------
    str

    Raises
    ------
    ExportError
        As :func:`pid_parameters` and :func:`~servotune.export.json.tables_document`, or a
        ``pid_name`` that is not a HAL instance name.
    """
    if not isinstance(pid_name, str) or not _PID_NAME.fullmatch(pid_name):
        raise ExportError(
            f"pid_name {show_value(pid_name)} is not a pid instance name (letters, digits, "
            "'_', '.', '-', at most 25 characters), e.g. pid.x or pid.0"
        )
    params = pid_parameters(
        tuning,
        rig,
        position_scale=position_scale,
        output_scale=output_scale,
        velocity_feedforward=velocity_feedforward,
    )
    doc = tables_document(tuning, rig=rig, verification=verification, unverified=unverified)
    _, axis, pi = master_axis(tuning)
    ax = rig.axis(axis)
    prov = doc["provenance"]
    ns = thread_period_ns(tuning.period_s)
    dac = rig.dac
    s, o = float(position_scale), float(output_scale)
    n = pid_name
    if unverified:
        verified = "NO: exported with --unverified; this loop has not passed `servotune verify`"
    else:
        verified = "yes (a passing `servotune verify` record)"
        if prov["spec_sha256"]:
            verified += f", spec sha256 {prov['spec_sha256']}"
    ferror = (
        f"{ax.following_error_limit_counts / s!r} machine units "
        f"({ax.following_error_limit_counts} counts)"
        if ax.following_error_limit_counts
        else "none (the axis's following_error_limit_counts is 0)"
    )
    ff1 = (
        f"O·S / g, g = {ax.plant.mean_gain_cps_per_v!r} counts/s/V (velocity feedforward, "
        "not in the verified law)"
        if velocity_feedforward
        else "0 (no feedforward: the verified law alone)"
    )
    lines = [
        f"{HAL_FILE_FIRST_LINE} the stock pid's parameters for the master axis {axis!r}",
        f"# written by servotune {__version__} (export-table --format linuxcnc-hal): export "
        "again, do not edit",
        "#",
        f"# rig: {tuning.rig_name}, sha256 {tuning.rig_sha256}",
        f"# tuning sha256: {prov['tuning_sha256']}",
        f"# verified: {verified}",
        f"# tables export of the same tuning ({SCHEMA}):",
        f"#   sha256 {doc['sha256']}",
        f"#   c_layout_sha256 {doc['data']['c_layout_sha256']}",
        "#",
        f"# position_scale S = {s!r} encoder counts per machine unit: the encoder's position-scale",
        f"# output_scale O = {o!r} pid output units per volt at the D/A",
        f"# D/A: {dac.bits} bits, range_v {list(dac.range_v)!r}, lsb_v = {dac.lsb_v!r} V",
        f"# servo thread: the tuning's tick is T = {tuning.period_s!r} s: run it at {ns} ns",
        "#   (at another period the loop is not the one servotune verified)",
        "# servotune's PI law, u [D/A LSB] = Kp·e + I, I += Ki·T·e, e [counts]:",
        f"#   Kp = {pi.kp.q}·2^-{pi.kp.f} = {pi.kp.value!r} LSB/count",
        f"#   Ki·T = {pi.ki_t.q}·2^-{pi.ki_t.f} = {pi.ki_t.value!r} LSB/count/tick",
        "# conversions (exact, rounded once to a double; servotune.export.linuxcnc says why):",
        "#   Pgain = Kp·lsb_v·O·S            Igain = (Ki·T / T)·lsb_v·O·S",
        "#   maxoutput = min(zero_code, code_max - zero_code)·lsb_v·O",
        "#   maxerrorI = maxoutput / Igain",
        f"#   FF1 = {ff1}",
        "#   bias = deadband = 0: the integrator cancels the drift",
        "#   error-previous-target false: e = command - feedback, as servotune's r(k) - y(k)",
        "#   Dgain, FF0, FF2, FF3, maxerror, maxerrorD, maxcmdD, maxcmdDD, maxcmdDDD: 0 (off)",
        f"# following-error limit: {ferror}:",
        "#   [JOINT_n]FERROR in the INI",
        "#",
        "# Before this file, load the component and add its function to the servo thread:",
        f"#   loadrt pid names={n}",
        f"#   addf {n}.do-pid-calcs servo-thread",
        f"# and wire {n}.command, .feedback (the encoder's position), .enable and .output",
        "# (to the D/A, in units of O per volt); leave .command-deriv, .feedback-deriv and",
        "# .tune-mode unconnected.",
    ]
    lines += [f"setp {n}.{pin} {_value(v)}" for pin, v in params.hal_pins()]
    lines += _filter_lines(tuning, n)
    return with_digest_line("\n".join(lines) + "\n", "#", line=2)


FILTER_DIFFERENCE_CODES = 0.91
"""The largest difference between LinuxCNC's float ``biquad`` and the runtime's fixed-point
sections on D/A codes, measured in real HAL (tests/hal/test_linuxcnc_biquad.py: a notch and a
low-pass in series, steps and a chirp within ±1500 codes)."""


def _filter_lines(tuning: Tuning, pid_name: str) -> list[str]:
    """The master axis's output filters as LinuxCNC ``biquad`` instances
    ``<pid_name>-filter<k>`` (:func:`~servotune.export.linuxcnc_biquad.biquad_hal_text`, its
    own digest line left out: the file has one), or nothing when it has none."""
    i, _, _ = master_axis(tuning)
    sections = tuning.controllers[i].filters
    if not sections:
        return []
    names = [f"{pid_name}-filter{k}" for k in range(len(sections))]
    text = biquad_hal_text(sections, names=names, period_s=tuning.period_s)
    wiring = " -> ".join([f"{pid_name}.output", *(f"{m}.in/.out" for m in names), "the D/A"])
    return [
        "#",
        f"# The master axis's law filters its output before the D/A ({len(sections)} "
        "section(s), docs/runtime.md#filters-in-the-law):",
        "# here as LinuxCNC's stock biquad, a FLOAT implementation with the runtime's quantised",
        "# coefficients exactly. The verified runtime runs them in integer fixed point (each",
        "# section's input held to the D/A range, whole codes out): on D/A codes the two differ",
        f"# by at most {FILTER_DIFFERENCE_CODES} codes as measured in real HAL. A filter is "
        "linear, so the same",
        "# coefficients serve the pid's output in its own units. Wire them in series:",
        f"#   {wiring}",
        *(ln for ln in text.splitlines() if not ln.startswith("# sha256 of this file")),
    ]


def check_hal_file(text: str, src: str = "<text>") -> None:
    """Check a HAL file :func:`pid_hal_text` wrote: its digest line matches the rest of it
    (``servotune check-table``); any edit is refused.

    Raises
    ------
    DigestError
        The file was edited after export.
    ExportError
        Not such a HAL file, or without its one digest line.
    """
    if not text.startswith(HAL_FILE_FIRST_LINE):
        raise ExportError(f"{src}: not a HAL file of servotune export-table --format linuxcnc-hal")
    problem = text_digest_problem(text, "#")
    if problem is not None:
        error = DigestError if problem.startswith("the file's sha256") else ExportError
        raise error(f"{src}: {problem}")


def to_string(tuning: Tuning, *, position_scale: float | None = None, **kwargs: Any) -> str:
    """The HAL file's text (the ``linuxcnc-hal`` export format's; arguments as
    :func:`pid_hal_text`).

    Raises
    ------
    ExportError
        No ``position_scale`` (``--position-scale``: the file cannot be written without it), or
        as :func:`pid_hal_text`.
    """
    if position_scale is None:
        raise ExportError(
            "--format linuxcnc-hal needs --position-scale (encoder counts per machine unit, "
            "the encoder's position-scale parameter)"
        )
    return pid_hal_text(tuning, position_scale=position_scale, **kwargs)


def to_file(
    tuning: Tuning, path: str | Path, *, position_scale: float | None = None, **kwargs: Any
) -> None:
    """Write the HAL file (:func:`to_string`) atomically; nothing is written on an error.

    Raises
    ------
    ExportError
        As :func:`to_string`, or if the file cannot be written.
    """
    write_export(path, to_string(tuning, position_scale=position_scale, **kwargs))
