"""LinuxCNC HAL components: the verified runtime as a realtime component, and a plant model.

:func:`to_string` is one ``.comp`` file (the ``linuxcnc-comp`` export format; :func:`to_file`
writes it; ``halcompile --compile``/``--install`` builds it) holding, verbatim, the same C the
golden runs prove bit-exact against the simulator (``servotune_filter.h``, ``servotune_rt.h``,
``servotune_tables.h``, ``servotune_rt.c``: :mod:`servotune.export.c`; the law's output filters
included, docs/runtime.md#filters-in-the-law) around a thin HAL wrapper. The wrapper adds no
arithmetic to the law: each servo-thread period it takes each axis's encoder count
(``<name>.counts-N``, s32: the low ``counter_bits`` bits are what the counter card latches), the
master's reference (``<name>.command``, counts; with ``position_scale``, machine units rounded
to counts: the one operation outside the law), the requested mode and reset, calls ``st_tick``
once and gives each axis's D/A code (``<name>.code-N``) and the voltage it stands for
(``<name>.volts-N`` = ``dac_lo + code · lsb`` [V], for a driver that takes volts), the flags,
the law's error and the extended position. At load (``loadrt``) it recomputes the SHA-256 of its
compiled-in constants and tables and compares it with the exported digest, and checks the
constants' ranges: a component whose tables were edited, or mixed with another tuning's digest,
refuses to load with the reason in HAL's log.

:func:`plant_component` writes a component moving one axis's plant model exactly as the
simulator does (``servotune_plant.h``, a C mirror of :mod:`servotune.plant` and of a resonant
plant's modes, :mod:`servotune.resonance`; the simulator's encoder noise where the plant has
some): for testing the loop in real HAL
before a machine runs it, and for LinuxCNC users who want servotune's model of their drive in a
simulated configuration.

Units: counts, D/A codes, volts. The component is one instance (``option singleton``); several
runtimes in one HAL session need several names (``name``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from string import Template
from typing import Any

from servotune._version import __version__
from servotune.digest import text_digest_problem, with_digest_line
from servotune.errors import DigestError, ExportError
from servotune.export.c import (
    FILTER_RUNTIME_FILES,
    PLANT_RUNTIME_FILES,
    RUNTIME_FILES,
    SHAPER_RUNTIME_FILES,
    runtime_source,
)
from servotune.export.c import to_string as tables_header
from servotune.export.document import write_export
from servotune.laws.filters import INPUT_BOUND_WIDE, SectionQ, state_bound
from servotune.laws.shaping import Shaper
from servotune.plant import NROW, Plant, plant_row
from servotune.rig import Dac, Rig
from servotune.tuning import Tuning

__all__ = [
    "MAX_FILTER_SECTIONS",
    "PLANT_HEADER",
    "SHAPER_HEADER",
    "check_component_source",
    "filter_component",
    "guard_component",
    "plant_component",
    "shaper_component",
    "to_file",
    "to_string",
]

PLANT_HEADER = PLANT_RUNTIME_FILES[0]
SHAPER_HEADER = SHAPER_RUNTIME_FILES[0]
MAX_FILTER_SECTIONS = 4
"""Most filter sections in series in one component (the runtime's law allows as many)."""
_NAME = re.compile(r"[a-z][a-z0-9_]{0,40}")
_LOCAL_INCLUDE = re.compile(r'^#include "servotune_[a-z]+\.h"\n', re.MULTILINE)


def _check_name(name: str) -> str:
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ExportError(
            f"component name {name!r} is not a HAL component name (lower-case letters, digits "
            "and _, starting with a letter, at most 41 characters)"
        )
    return name


def _template(template: str, **values: object) -> str:
    """A ``.comp`` template of the package data, filled in."""
    text = resources.files("servotune.export").joinpath("runtime", template).read_text("utf-8")
    return Template(text).substitute(version=__version__, **values)


def _inline(*texts: str) -> str:
    """C sources joined into one translation unit: their includes of each other dropped."""
    return "\n".join(_LOCAL_INCLUDE.sub("", t) for t in texts)


def _c_double(x: float) -> str:
    """An exact C literal of ``x`` (hex float; ``INFINITY`` for +inf)."""
    if math.isinf(x) and x > 0:
        return "INFINITY"
    if not math.isfinite(x):
        raise ExportError(f"plant coefficient {x!r} is not finite")
    return float(x).hex()


def to_string(
    tuning: Tuning,
    *,
    rig: Rig | None = None,
    verification: Any = None,
    unverified: bool = False,
    name: str = "servotune",
    position_scale: float | None = None,
) -> str:
    """The ``.comp`` source of the runtime component for ``tuning`` (arguments as
    :func:`servotune.export.c.to_string`; ``name`` the component's name: HAL calls it
    ``name`` with ``_`` as ``-``).

    Pins (``N`` = axis index in the tuning's order; the HAL name and ``.`` before each):

    - ``counts-N`` (s32 in): the encoder count; its low ``counter_bits`` bits are latched;
    - ``command`` (s32 in): the master's reference [counts]; with ``position_scale``
      [counts per machine unit] a float in machine units instead (a LinuxCNC position
      command), the reference ``round(command · position_scale)`` minus the master's count
      at the first period (the runtime's positions start from its first read, so a command
      equal to the feedback ``counts / position_scale`` is no error);
    - ``mode-N`` (s32 in): 0 lock, 1 task, 2 open; ``reset-N`` (bit in): clear latched faults;
      ``u-add-N`` (s32 in): D/A codes added to the output (an excitation; 0 normally);
    - ``code-N`` (s32 out): the D/A code; ``volts-N`` (float out): its voltage [V];
    - ``flags-N`` (s32 out, ST_FLAG_*), ``error-N`` (s32 out, the law's error [counts]),
      ``position-N`` (s32 out, the extended position [counts], modulo 2^32);
    - with a reference shaper in an axis's controller (docs/runtime.md#shapers-in-the-tables)
      the component shapes that axis's reference each period before the tick, as the
      firmware would (``st_shaper_step``);
    - ``filters-off-N`` (bit in, only when an axis has output filters): the axis runs without
      them while it is true; each change switches them out or back in before the period's
      tick, without a bump (``st_axis_switch_filters``;
      docs/runtime.md#switching-filters-while-running).

    Raises
    ------
    ExportError
        If the name is not a HAL name, or as :func:`servotune.export.c.to_string` (an
        unverified tuning without ``unverified``, a tuning of another rig, …).
    """
    _check_name(name)
    command = _command_text(tuning, position_scale)
    header = tables_header(tuning, rig=rig, verification=verification, unverified=unverified)
    digest = re.search(r'#define ST_TABLES_SHA256 "([0-9a-f]{64})"', header)
    assert digest is not None  # the header always defines it
    dac = rig.dac if rig is not None else Dac()  # the export's default hardware
    rt_c, rt_h, filter_h = (runtime_source(f) for f in RUNTIME_FILES)
    shaper = _shaper_text(tuning)
    axes = zip(tuning.axis_names, tuning.roles, strict=True)
    text = _template(
        "hal_runtime.comp.in",
        name=name,
        hal=name.replace("_", "-"),
        digest=digest.group(1),
        axes=", ".join(f"{i} = {a} ({r})" for i, (a, r) in enumerate(axes)),
        n=len(tuning.controllers),
        runtime=_inline(filter_h, rt_h, header, rt_c, shaper.pop("shaper_h")),
        dac_lo=_c_double(dac.range_v[0]),
        dac_lsb=_c_double(dac.lsb_v),
        **command,
        **_filter_text(tuning),
        **shaper,
    )
    return with_digest_line(text, "//", line=1)


def _shaper_text(tuning: Tuning) -> dict[str, str]:
    """The runtime component's reference shapers (:func:`to_string`): for each axis whose
    controller has a shaper, an ``st_shaper_t`` filled at load from the compiled-in constants
    (which ``st_check_digest`` and ``st_check_consts`` have just accepted, the amplitudes
    included), and each period the axis's reference shaped (``st_shaper_step``) before the
    tick; nothing without a shaper."""
    shaped = [a for a, c in enumerate(tuning.controllers) if c.shaper]
    if not shaped:
        return dict.fromkeys(("shaper_h", "shaper_state", "shaper_setup", "shaper_step"), "")
    taps = max(len(tuning.controllers[a].shaper) for a in shaped)
    setup, step = [], []
    for a in shaped:
        setup += [
            "    {",
            f"        const st_axis_consts_t *x = &st_hal_consts.axis[{a}];",
            "        int32_t k;",
            f"        st_hal_shaper[{a}].n = x->shaper_n;",
            "        for (k = 0; k < x->shaper_n; k++) {",
            f"            st_hal_shaper[{a}].a_q[k] = x->shaper_q[k];",
            "        }",
            "    }",
        ]
        step.append(
            f"    in[{a}].ref = st_shaper_step(&st_hal_shaper[{a}], &st_hal_shaper_state[{a}], "
            f"in[{a}].ref);"
        )
    return {
        "shaper_h": f"#define ST_SHAPER_MAX_TAPS {taps}\n" + runtime_source(SHAPER_HEADER),
        "shaper_state": (
            "static st_shaper_t st_hal_shaper[ST_MAX_AXES]; /* the task references' shapers */\n"
            "static st_shaper_state_t st_hal_shaper_state[ST_MAX_AXES];\n"
        ),
        "shaper_setup": "\n".join(setup) + "\n",
        "shaper_step": "\n".join(step) + "\n",
    }


def _filter_text(tuning: Tuning) -> dict[str, str]:
    """The runtime component's ``filters-off-N`` pins and their switch (:func:`to_string`):
    only when an axis has output filters."""
    if not any(c.filters for c in tuning.controllers):
        return {"filter_pin": "", "filter_state": "", "filter_switch": ""}
    n = len(tuning.controllers)
    return {
        "filter_pin": (
            f'pin in bit filters-off-#[{n}] "run the axis without its output filters '
            '(switched either way without a bump)";\n'
        ),
        "filter_state": "static int st_hal_filters_off[ST_MAX_AXES];\n",
        "filter_switch": (
            f"    for (a = 0; a < {n}; a++) {{\n"
            "        const int off = filters_off(a) ? 1 : 0;\n"
            "        if (off != st_hal_filters_off[a]) {\n"
            "            const st_axis_consts_t *x = &st_hal_consts.axis[a];\n"
            "            st_axis_state_t *s = &st_hal_state.axis[a];\n"
            "            (void)st_axis_switch_filters(&st_hal_live.axis[a], s,\n"
            "                                         off ? 0 : x->n_filters, x->filter);\n"
            "            st_hal_filters_off[a] = off;\n"
            "        }\n"
            "    }\n"
        ),
    }


def _command_text(tuning: Tuning, position_scale: float | None) -> dict[str, str]:
    """The runtime component's command pin and reference (:func:`to_string`)."""
    if position_scale is None:
        return {
            "command_pin": 'pin in s32 command "the master\'s reference [counts]";',
            "command_state": "",
            "command_origin": "",
            "command_ref": "(int64_t)command",
        }
    if not (isinstance(position_scale, int | float) and math.isfinite(position_scale)):
        raise ExportError(f"position_scale must be a finite number, got {position_scale!r}")
    if not 0 < position_scale <= 1e9:
        raise ExportError(f"position_scale must be > 0 and at most 1e9, got {position_scale}")
    master = next(i for i, r in enumerate(tuning.roles) if r == "master")
    return {
        "command_pin": 'pin in float command "the master\'s position command [machine units]";',
        "command_state": (
            "static int64_t st_hal_origin; /* the master's count at the first period */\n"
            "static int st_hal_started;\n"
        ),
        "command_origin": (
            "    if (!st_hal_started) {\n"
            f"        st_hal_origin = (int64_t)counts({master});\n"
            "        st_hal_started = 1;\n"
            "    }\n"
        ),
        "command_ref": (
            f"(int64_t)(command * {_c_double(float(position_scale))} "
            f"+ (command < 0.0 ? -0.5 : 0.5)) - st_hal_origin"
        ),
    }


def to_file(tuning: Tuning, path: str | Path, **options: Any) -> None:
    """Write the runtime component (:func:`to_string`, the same arguments) atomically; nothing
    is written on an error.

    Raises
    ------
    ExportError
        As :func:`to_string`, or if the file cannot be written.
    """
    write_export(path, to_string(tuning, **options))


def check_component_source(text: str, src: str = "<text>") -> None:
    """Check a ``.comp`` :func:`to_string` wrote: its digest line (the second, a
    ``//`` comment) matches the rest of the file (``servotune check-table``); any edit is
    refused. (The component also checks its compiled-in tables at load.)

    Raises
    ------
    DigestError
        The file was edited after export.
    ExportError
        Not such a component, or without its one digest line.
    """
    first = text.split("\n", 1)[0]
    if not (first.startswith("// ") and ".comp -- generated by servotune" in first):
        raise ExportError(
            f"{src}: not a HAL component of servotune export-table --format linuxcnc-comp"
        )
    problem = text_digest_problem(text, "//")
    if problem is not None:
        error = DigestError if problem.startswith("the file's sha256") else ExportError
        raise error(f"{src}: {problem}")


def _modes_text(plant: Plant) -> str:
    """The modes for the component's description line: empty for a rigid plant."""
    if not plant.modes:
        return ""
    each = "; ".join(
        f"{m.freq_hz!r} Hz, damping {m.damping!r}, gain {m.gain!r}" for m in plant.modes
    )
    n = len(plant.modes)
    return f", {n} mode{'s' if n > 1 else ''} ({each})"


def plant_component(
    plant: Plant,
    period_s: float,
    compute_s: float = 0.0,
    *,
    name: str,
    counter_init: int = 0,
    counts_per_rev: float = math.inf,
) -> str:
    """The ``.comp`` source of a component moving ``plant`` as the simulator does.

    Each period its function (add it to the thread *before* the controller): from the second
    period on, records the D/A output the controller wrote last period (``volts``, float in
    [V]) and moves the plant over one tick of ``period_s`` with the simulator's lag and model
    (:func:`servotune.plant.advance_tick_modal`, row of :func:`~servotune.plant.plant_row`,
    the ``load`` pin [V] of that period added); then latches ``counts`` = ``counter_init +
    floor(position)`` (s32 out) and gives ``position`` [counts] and ``speed`` [counts/s]. The
    HAL thread's own period does not enter: the model's tick is ``period_s``.

    A plant with ``modes`` (docs/frf.md) carries their state too: ``position`` and ``speed``
    are then the measured ones, the motor's plus its modes'
    (:func:`servotune.resonance.modes_output`, :func:`~servotune.resonance.modes_speed`);
    without modes the motor's, as before.

    A plant with encoder noise (``noise_counts`` > 0) latches ``floor(position + noise)``: one
    draw per period of the simulator's stream (:func:`servotune.sim.tick.draw_noise`:
    splitmix64, Box-Muller; ``st_noise`` of ``servotune_plant.h``) started from the ``seed``
    parameter (0 at load; a ``setp`` of another value restarts the stream from it), so a HAL
    machine can be run with independent noise as a logged one would be. ``position`` stays
    noiseless.

    Raises
    ------
    ExportError
        If the name is not a HAL name.
    """
    _check_name(name)
    row, lag = plant_row(plant, period_s, compute_s, counts_per_rev)
    assert row.size == NROW
    return _template(
        "hal_plant.comp.in",
        name=name,
        gain=repr(plant.gain_cps_per_v),
        tau=repr(plant.tau_s),
        lag=lag,
        modes=_modes_text(plant),
        noise=repr(plant.noise_counts),
        ring=lag + 2,
        last_slot=lag + 1,
        counter_init=int(counter_init),
        plant_h=_inline(runtime_source(PLANT_HEADER)),
        row=",\n    ".join(_c_double(float(x)) for x in row),
    )


def shaper_component(shaper: Shaper, *, name: str) -> str:
    """The ``.comp`` source of an input shaper (docs/runtime.md#input-shaping): each period its
    function (add it to the thread *before* the runtime component) takes ``command`` (s32, the
    reference [counts]) and gives ``shaped`` (s32), the integer step of
    :func:`servotune.laws.shaping.shaper_step` (``servotune_shaper.h``) with the shaper's Q15
    amplitudes compiled in; at load it checks that they sum to 2^15.

    Raises
    ------
    ExportError
        If the name is not a HAL name.
    """
    _check_name(name)
    modes = "; ".join(f"{f!r} Hz, damping {z!r}" for f, z in shaper.modes)
    return _template(
        "hal_shaper.comp.in",
        name=name,
        kind=shaper.kind,
        modes=modes,
        taps=shaper.n_taps,
        added_ticks=shaper.n_taps - 1,
        shaper_h=_inline(runtime_source(SHAPER_HEADER)),
        amplitudes=", ".join(str(a) for a in shaper.amplitudes_q),
    )


def filter_component(
    sections: Sequence[SectionQ], *, name: str, input_bound: int = INPUT_BOUND_WIDE
) -> str:
    """The ``.comp`` source of filter sections in series (docs/runtime.md#filters): each
    period its function takes ``in`` (s32, in the unit the sections were sized for), clamps it
    to ``±input_bound`` (``clipped`` set when it had to), and gives ``out`` (s32), the input
    through every section's :func:`servotune.laws.filters.biquad_step`
    (``servotune_filter.h``); with ``enable`` false ``out`` is the input, and switching it on
    sets each section's state by :func:`~servotune.laws.filters.bumpless_state` at the last
    input (the output does not move at a steady input).

    Raises
    ------
    ExportError
        A name that is not a HAL name, no section or more than 4, or a cascade whose output or
        accumulator could leave its integer range for inputs within ``input_bound`` (each
        section's bound, :func:`~servotune.laws.filters.state_bound`, taken at the previous
        one's largest output).
    """
    _check_name(name)
    if not 1 <= len(sections) <= MAX_FILTER_SECTIONS:
        raise ExportError(
            f"a filter component holds 1 to {MAX_FILTER_SECTIONS} sections, got {len(sections)}"
        )
    bound = int(input_bound)
    for k, q in enumerate(sections):
        sb = state_bound(q, bound)
        if sb.y_max > 2**31 - 1 or sb.acc_max >= 2**62:
            raise ExportError(
                f"filter section {k + 1}: inputs up to ±{bound} give outputs up to ±{sb.y_max} "
                f"(s32 holds ±{2**31 - 1}) and partial sums up to 2^{math.log2(sb.acc_max):.1f} "
                "(int64 keeps 2^62): lower input_bound"
            )
        bound = sb.y_max
    return _template(
        "hal_filter.comp.in",
        name=name,
        n=len(sections),
        bound=int(input_bound),
        summary=f"{len(sections)} section(s), "
        + ", ".join(f"{q.frac_bits} fraction bits" for q in sections),
        filter_h=_inline(runtime_source(FILTER_RUNTIME_FILES[0])),
        sections=", ".join(
            "{" + ", ".join(str(int(v)) for v in q.step_args()) + "}" for q in sections
        ),
    )


def guard_component(
    *,
    name: str,
    travel_counts: tuple[float, float],
    speed_cps: float,
    following_error_counts: float,
    max_volts: float,
    position_scale: float = 1.0,
) -> str:
    """The ``.comp`` source of an experiment's safety envelope (docs/autotune.md): each period
    its function (add it after the controller, before the D/A driver) checks the feedback
    ``position`` (times ``position_scale``: counts) against the travel window (relative to the
    position at the first period after load or reset), its speed (the change per period of
    the thread), the following error ``command − position`` and ``|volts_in|``; at the first
    breach it sets ``fault``, names the limit (``reason`` 1 travel, 2 speed, 3 following error,
    4 output, 5 the ``stop`` pin) with the breaching ``value`` and ``trip_period``, and gives
    ``volts_out = 0`` from that same period until ``reset``; otherwise ``volts_out = volts_in +
    excitation`` (``excitation``: the live run's signal [V]; the output limit is on the sum).
    The limits are compiled in: a ``setp`` cannot widen them.

    Raises
    ------
    ExportError
        A name that is not a HAL name, or a limit that is not a finite positive number (the
        travel window: low < 0 < high).
    """
    _check_name(name)
    lo, hi = travel_counts
    values = {
        "speed_cps": speed_cps,
        "following_error_counts": following_error_counts,
        "max_volts": max_volts,
        "position_scale": position_scale,
    }
    bad = [k for k, v in values.items() if not (math.isfinite(v) and v > 0)]
    if bad or not (math.isfinite(lo) and math.isfinite(hi) and lo < 0 < hi):
        raise ExportError(
            f"guard: every limit must be a finite number > 0 and the travel window low < 0 < "
            f"high, got {', '.join(bad) or f'travel {lo!r}..{hi!r}'}"
        )
    return _template(
        "hal_guard.comp.in",
        name=name,
        limits=(
            f"travel {lo:g}..{hi:g} counts, speed {speed_cps:g} counts/s, following error "
            f"{following_error_counts:g} counts, output {max_volts:g} V, {position_scale:g} "
            "counts per feedback unit"
        ),
        scale=_c_double(float(position_scale)),
        travel_lo=_c_double(float(lo)),
        travel_hi=_c_double(float(hi)),
        speed=_c_double(float(speed_cps)),
        following=_c_double(float(following_error_counts)),
        max_volts=_c_double(float(max_volts)),
    )
