"""Rig files: loading, validating and describing ``plants/*.toml``, and writing a plant into one.

A rig file (docs/formats.md#rig-file) describes the hardware around the loop and one
``[axis.<name>]`` table per axis with its plant under ``[axis.<name>.plant]``. Every field is
validated on load; an error names the field, the value and the unit. Unknown keys are errors (a
misspelt key would otherwise be silently ignored). The model itself (:class:`Rig`, its sections and
their bounds) is :mod:`servotune.rig.model`; the TOML tables are built into its dataclasses by
:func:`servotune.io.sections.build_section`, a plant table is edited in place by
:mod:`servotune.rig.edit`; this module checks files against the model. :mod:`servotune.rig`
re-exports the names of all three: it is where the rig is imported from.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from servotune.errors import RigError, SpecError
from servotune.examples import EXAMPLES_DIR
from servotune.hw import counter as hw_counter
from servotune.io.files import atomic_write_bytes, parse_toml_as, read_bytes
from servotune.io.sections import build_section
from servotune.laws.axis import MAX_FILTERS
from servotune.laws.filters import INPUT_BOUND_WIDE, Section, realize, section_from_dict
from servotune.laws.lock import lock_holding_band
from servotune.plant import Plant
from servotune.resonance import MAX_MODES, Mode
from servotune.rig.edit import edit_plant_text
from servotune.rig.model import (
    MAX_DAC_RANGE_V,
    MAX_SPEED_RPM,
    Axis,
    Counter,
    Dac,
    Encoder,
    PlantFit,
    Rig,
    Timer,
)
from servotune.validate import (
    check_keys,
    check_number,
    check_table,
    is_finite,
    is_number,
    name_and_description,
    show_value,
)

__all__ = [
    "EXAMPLE_RIG_PATH",
    "check_plant",
    "describe_rig",
    "filters_from_array",
    "load_rig",
    "modes_from_array",
    "plant_from_table",
    "rig_from_dict",
    "write_plant",
]


MAX_PLANT_GAIN = 1e9
"""Largest plant gain [counts/s/V]."""
MIN_TAU_S, MAX_TAU_S = 1e-6, 1000.0
"""Plant time-constant range [s]."""
MAX_DELAY_S = 1.0
"""Largest plant dead time [s] (the simulation keeps the pending D/A writes of that long)."""
MAX_NOISE_COUNTS = 1e6
"""Largest encoder noise [counts]."""


def check_plant(
    plant: Plant,
    path: str,
    dac_range_v: tuple[float, float] | None = None,
    *,
    error: type[Exception] = RigError,
    period_s: float | None = None,
) -> None:
    """Bounds of a plant read from a file, beyond :class:`~servotune.plant.Plant`'s own checks.

    The plant's own validation keeps the values finite and of the right sign; this keeps them
    within what a servo axis can be (so a typo such as ``offset_v = 1000`` or
    ``delay_s = 1e300`` is refused instead of sizing the simulation's arrays): gain up to 1e9
    counts/s/V, tau_s in 1 µs … 1000 s, delay_s up to 1 s, offset_v and coulomb_v within the
    D/A range (``dac_range_v``; ±1000 V if not given), max_speed_rpm up to 1e6 r/min,
    noise_counts up to 1e6 counts; the negative direction's gain_neg_cps_per_v and
    coulomb_neg_v, where given, as gain_cps_per_v and coulomb_v. With ``period_s`` (the rig's
    tick), every mode's frequency below the Nyquist frequency ``0.5 / period_s``: the loop
    samples the position once a tick, so a mode at or above it is not what the loop sees
    (it folds onto a lower frequency) and the model could not be simulated as it is sampled.

    Parameters
    ----------
    plant : Plant
    path : str
        The plant's table for the messages (``"axis.master.plant"``).
    dac_range_v : (float, float), optional
        The D/A output range [V].
    error : type of Exception
        What to raise.
    period_s : float, optional
        The rig's tick [s] (:attr:`Rig.period_s`, the achieved one), for the modes' bound.

    Raises
    ------
    error
        ``"axis.master.plant.offset_v must be a number in [-10, 10] [V], got 1000.0"``.
    """
    lo_v, hi_v = dac_range_v if dac_range_v is not None else (-MAX_DAC_RANGE_V, MAX_DAC_RANGE_V)
    span = max(abs(lo_v), abs(hi_v))
    checks = (
        ("gain_cps_per_v", "counts/s/V", 0.0, True, MAX_PLANT_GAIN),
        ("tau_s", "s", MIN_TAU_S, False, MAX_TAU_S),
        ("delay_s", "s", 0.0, False, MAX_DELAY_S),
        ("offset_v", "V", -span, False, span),
        ("coulomb_v", "V", 0.0, False, span),
        ("noise_counts", "counts", 0.0, False, MAX_NOISE_COUNTS),
        # the negative direction's (asymmetric model), where given
        ("gain_neg_cps_per_v", "counts/s/V", 0.0, True, MAX_PLANT_GAIN),
        ("coulomb_neg_v", "V", 0.0, False, span),
    )
    for name, unit, lo, strict, hi in checks:
        if getattr(plant, name) is None:  # a *_neg field left to the positive direction's
            continue
        check_number(
            f"{path}.{name}", getattr(plant, name), unit, lo=lo, strict=strict, hi=hi, error=error
        )
    if plant.max_speed_rpm is not None:
        check_number(
            f"{path}.max_speed_rpm",
            plant.max_speed_rpm,
            "r/min",
            lo=0.0,
            strict=True,
            hi=MAX_SPEED_RPM,
            error=error,
        )
    if period_s is not None:
        nyquist_hz = 0.5 / period_s
        for i, mode in enumerate(plant.modes):
            if not mode.freq_hz < nyquist_hz:
                raise error(
                    f"{path}.modes[{i}].freq_hz must be below the rig's Nyquist frequency "
                    f"0.5 / period_s = {nyquist_hz:.6g} [Hz], got {show_value(mode.freq_hz)} (the "
                    f"loop samples every {period_s * 1e3:.6g} ms: a mode there folds onto a lower "
                    "frequency)"
                )


def plant_from_table(
    table: Mapping[str, Any],
    path: str,
    dac_range_v: tuple[float, float] | None = None,
    *,
    error: type[Exception] = RigError,
    period_s: float | None = None,
) -> Plant:
    """The :class:`~servotune.plant.Plant` of a file's ``[axis.<name>.plant]`` table (``path``),
    built and bounded (:func:`check_plant`, the modes below ``0.5 / period_s`` when it is
    given); ``error`` names ``path.field``, value and unit. The table's ``modes``, an array of
    tables (``[[axis.<name>.plant.modes]]``), are read by :func:`modes_from_array`."""
    if "modes" in table:
        table = dict(table)
        table["modes"] = modes_from_array(table["modes"], f"{path}.modes", error=error)
    plant = build_section(Plant, table, path, error)
    check_plant(plant, path, dac_range_v, error=error, period_s=period_s)
    return plant


_MODE_KEYS = (
    # key, unit, lower bound (excluded), upper bound (excluded) or None
    ("freq_hz", "Hz", 0.0, None),
    ("damping", "-", 0.0, 1.0),
    ("gain", "-", -1.0, None),
)


def modes_from_array(
    value: object, path: str, *, error: type[Exception] = RigError
) -> tuple[Mode, ...]:
    """The :class:`~servotune.resonance.Mode` records of a plant table's ``modes`` (``path``):
    an array of tables, each ``freq_hz`` [Hz] > 0, ``damping`` [-] in (0, 1), ``gain`` [-]
    > −1 and optionally their 95 % intervals ``freq_hz_95``, ``damping_95``, ``gain_95``
    (``[low, high]``, low <= high), at most :data:`~servotune.resonance.MAX_MODES` of them
    (docs/formats.md#modes).

    Raises
    ------
    error
        Naming the mode and the key: ``"axis.master.plant.modes[0].damping must be a number
        in (0, 1) [-], got -0.1"``.
    """
    if not isinstance(value, list | tuple):
        raise error(
            f"{path} must be an array of tables ([[{path}]] with freq_hz, damping and gain), "
            f"got {type(value).__name__}"
        )
    if len(value) > MAX_MODES:
        raise error(f"{path} has {len(value)} modes; a plant carries at most {MAX_MODES}")
    modes = []
    for i, table in enumerate(value):
        where = f"{path}[{i}]"
        if not isinstance(table, Mapping):
            raise error(
                f"{where} must be a table (freq_hz, damping, gain), got {type(table).__name__}"
            )
        names = [k for k, *_ in _MODE_KEYS]
        kwargs = check_keys(table, where, names, [f"{k}_95" for k in names], error=error)
        for key, unit, lo, hi in _MODE_KEYS:
            bounds = {"lo": lo, "strict": True, "hi": hi, "hi_strict": True}
            check_number(f"{where}.{key}", kwargs[key], unit, **bounds, error=error)
            kwargs[key] = float(kwargs[key])
            pair = kwargs.get(f"{key}_95")
            if pair is None:
                continue
            ok = isinstance(pair, list | tuple) and len(pair) == 2
            ok = ok and all(is_number(x) and is_finite(x) for x in pair) and pair[0] <= pair[1]
            if not ok:
                raise error(
                    f"{where}.{key}_95 must be [low, high], two numbers with low <= high "
                    f"[{unit}], got {show_value(pair)}"
                )
            kwargs[f"{key}_95"] = (float(pair[0]), float(pair[1]))
        modes.append(Mode(**kwargs))
    return tuple(modes)


def filters_from_array(
    value: object, path: str, period_s: float, input_bound: int = INPUT_BOUND_WIDE
) -> tuple[Section, ...]:
    """The output filters of an axis table's ``filters`` (``path``), an array of tables
    (``[[axis.<name>.filters]]``: docs/formats.md#filters), each realisable at the rig's
    achieved ``period_s`` for inputs up to ``input_bound`` (the D/A's range on the filters'
    scale; its word length chosen: :func:`servotune.laws.filters.realize`).

    Raises
    ------
    RigError
        Naming the filter and the key: ``"axis.master.filters[0].center_hz must be ..."``.
    """
    if not isinstance(value, list) or len(value) > MAX_FILTERS:
        raise RigError(
            f"{path} must be an array of at most {MAX_FILTERS} tables "
            f"([[{path}]]), got {show_value(value)}"
        )
    out = []
    for i, item in enumerate(value):
        where = f"{path}[{i}]"
        try:
            section = section_from_dict(dict(item) if isinstance(item, Mapping) else item, where)
            realize(section, period_s, input_bound)
        except SpecError as exc:
            msg = str(exc)
            raise RigError(msg if msg.startswith(where) else f"{where}: {msg}") from None
        out.append(section)
    return tuple(out)


def _table(
    data: Mapping[str, Any], key: str, path: str, required: bool = True
) -> Mapping[str, Any]:
    return check_table(data, key, error=RigError, required=required, path=path)


def rig_from_dict(data: Mapping[str, Any], default_name: str = "rig") -> Rig:
    """Build and validate a :class:`Rig` from the parsed contents of a rig file.

    Raises
    ------
    RigError
        Naming the first invalid field, its value and unit.
    """
    check_keys(
        data,
        "",
        (),
        ("rig", "timer", "counter", "dac", "encoder", "axis"),
        error=RigError,
        noun="table",
    )
    meta = _table(data, "rig", "rig", required=False)
    check_keys(meta, "rig", (), ("name", "description"), error=RigError)
    timer = build_section(Timer, _table(data, "timer", "timer"), "timer")
    ctr = build_section(Counter, _table(data, "counter", "counter"), "counter")
    dac = build_section(Dac, _table(data, "dac", "dac"), "dac")
    enc = build_section(Encoder, _table(data, "encoder", "encoder"), "encoder")
    timer_period_s = timer.achieved_period_s  # what Rig.period_s is: the modes' Nyquist bound
    axes_t = _table(data, "axis", "axis")
    axes = []
    for name, at in axes_t.items():
        if not isinstance(at, Mapping):
            raise RigError(f"[axis.{name}] must be a table")
        at = dict(at)
        if "plant" not in at:
            raise RigError(f"missing table [axis.{name}.plant]")
        pt = at.pop("plant")
        if not isinstance(pt, Mapping):
            raise RigError(f"[axis.{name}.plant] must be a table")
        pt = dict(pt)
        fit_t = pt.pop("fit", None)  # the fit record (servotune fit -o), not a plant field
        plant = plant_from_table(pt, f"axis.{name}.plant", dac.range_v, period_s=timer_period_s)
        filters = filters_from_array(
            at.pop("filters", []),
            f"axis.{name}.filters",
            timer_period_s,
            dac.filter_input_bound,
        )
        plant_fit = None
        if fit_t is not None:
            if not isinstance(fit_t, Mapping):
                raise RigError(f"[axis.{name}.plant.fit] must be a table")
            plant_fit = build_section(PlantFit, fit_t, f"axis.{name}.plant.fit")
        axes.append(
            build_section(
                Axis,
                at,
                f"axis.{name}",
                name=name,
                plant=plant,
                plant_fit=plant_fit,
                filters=filters,
            )
        )
    return Rig(
        **name_and_description(meta, "rig", default_name, error=RigError),
        timer=timer,
        counter=ctr,
        dac=dac,
        encoder=enc,
        axes=tuple(axes),
    )


def load_rig(path: str | Path) -> Rig:
    """Read and validate a rig file (TOML).

    Parameters
    ----------
    path : str or Path
        The rig file, e.g. ``plants/pc-dual-servo.toml``.

    Returns
    -------
    Rig

    Raises
    ------
    RigError
        If the file is missing, not TOML, or any field is invalid.
    """
    p = Path(path)
    raw = read_bytes(p, RigError, "rig file")
    return parse_toml_as(raw, str(p), RigError, "rig file", lambda d: rig_from_dict(d, p.stem))


def describe_rig(rig: Rig) -> dict[str, Any]:
    """Derived facts of a rig (what ``servotune rig`` prints).

    Returns
    -------
    dict
        Timer divisor, achieved period and its error, counts per revolution, D/A LSB, the
        counter's speed limits (high-byte unwrap and input frequency) against each axis's speed
        limit, the time to wrap the counter at that speed, and the lock module's predicted
        holding band (docs/runtime.md#position-lock-and-its-holding-band) for each axis's drift and
        friction; an axis whose plant has modes (docs/formats.md#modes) also lists them
        (``modes``: each one's frequency, damping, gain, their 95 % intervals where the rig file
        has them, and the anti-resonance); an axis without has no such key. An axis with
        output filters lists them (``filters``: each one's design inputs and the quantised
        coefficients the runtime runs at the achieved period).
    """
    t, c = rig.timer, rig.counter
    unwrap_rpm = hw_counter.unwrap_speed_limit_rpm(c.bits, rig.counts_per_rev, rig.period_s)
    input_rpm = hw_counter.input_speed_limit_rpm(c.max_input_hz, rig.encoder.pulses_per_rev)
    axes = {}
    for i, a in enumerate(rig.axes):
        v_cps = a.speed_limit_rpm / 60.0 * rig.counts_per_rev
        try:
            lo, hi = lock_holding_band(
                a.lock_gain_codes_per_count, a.plant.offset_v, rig.dac.lsb_v, a.plant.coulomb_v
            )
        except ValueError as exc:
            raise RigError(
                f"axis.{a.name}: lock_gain_codes_per_count "
                f"{show_value(a.lock_gain_codes_per_count)} "
                f"[codes/count] with plant.offset_v {show_value(a.plant.offset_v)} [V]: {exc}"
            ) from None
        axes[a.name] = {
            "counts_per_tick_at_speed_limit": v_cps * rig.period_s,
            "lock_band_counts": [lo, hi],
            "lock_band_within_one_pulse": max(abs(lo), abs(hi)) <= c.multiplier,
            "role": a.role,
            "speed_limit_ok": a.speed_limit_rpm < min(unwrap_rpm, input_rpm),
            "speed_limit_rpm": a.speed_limit_rpm,
            # a subnormal speed limit underflows to 0 counts/s: it never wraps (inf; JSON null)
            "time_to_wrap_at_speed_limit_s": (1 << c.bits) / v_cps if v_cps > 0 else math.inf,
        }
        if a.plant.modes:
            axes[a.name]["modes"] = [m.to_dict() for m in a.plant.modes]
        if a.filters:
            axes[a.name]["filters"] = [
                f.to_dict() | q.to_dict()
                for f, q in zip(a.filters, rig.runtime_filters(i), strict=True)
            ]
    return {
        "achieved_period_s": rig.period_s,
        "axes": axes,
        "binding_speed_limit": "input_frequency" if input_rpm < unwrap_rpm else "unwrap",
        "counts_per_rev": rig.counts_per_rev,
        "dac_lsb_mv": rig.dac.lsb_v * 1e3,
        "input_frequency_speed_limit_rpm": input_rpm,
        "period_error_ppm": t.period_error_ppm,
        "requested_period_s": t.period_s,
        "rig": rig.name,
        "timer_divisor": t.divisor,
        "unwrap_max_counts_per_tick": hw_counter.max_counts_per_tick(c.bits),
        "unwrap_speed_limit_rpm": unwrap_rpm,
    }


# --- writing a plant section ---------------------------------------------------------------

EXAMPLE_RIG_PATH = EXAMPLES_DIR / "pc-dual-servo.toml"
"""The example rig (docs/systems.md#pc-dual-servo-synchronisation), the template :func:`write_plant`
starts a new rig file from: the package's copy (:mod:`servotune.examples`), so it is there without a
checkout."""


def write_plant(
    path: str | Path,
    axis: str,
    plant: Plant,
    *,
    template: str | Path = EXAMPLE_RIG_PATH,
    provenance: str | None = None,
    fit: PlantFit | None = None,
    new_name: str | None = None,
    new_header: str = "",
) -> None:
    """Write one axis's model into the ``[axis.<axis>.plant]`` table of a rig file.

    What ``servotune fit LOG -o RIG.toml`` does with the fitted plant. The file is edited, not
    regenerated: every comment and the layout of the rest of the file stay byte for byte; only
    the entries of that one table change.

    - The fitted parameters ``gain_cps_per_v`` [counts/s/V], ``tau_s`` [s], ``delay_s`` [s],
      ``offset_v`` [V] and ``coulomb_v`` [V] are always written (added if missing).
    - ``gain_neg_cps_per_v`` [counts/s/V] and ``coulomb_neg_v`` [V], the negative direction's
      (asymmetric model), are written when ``plant`` sets them and removed when it leaves them
      None (a symmetric plant), so the table records which structure was fitted.
    - The plant's lightly damped ``modes`` (docs/formats.md#modes) are written as an array of
      tables ``[[axis.<axis>.plant.modes]]``: ``freq_hz`` [Hz], ``damping`` [-], ``gain`` [-]
      and, where the mode has them, their 95 % intervals (``freq_hz_95 = [low, high]`` …),
      replacing the file's. A plant without modes removes the file's (they described another
      fit); a file without modes then stays byte for byte as it was.
    - ``max_speed_rpm`` [r/min] and ``noise_counts`` [counts] describe the drive and the encoder
      rather than the fit: the file's values stay unless ``plant`` sets them (differs from the
      :class:`~servotune.plant.Plant` default, ``None`` and ``0.0``); then they are replaced.
    - Numbers are rounded to 7 significant digits
      (:data:`~servotune.rig.edit.FLOAT_SIGNIFICANT_DIGITS`, relative error <= 5e-7) and written
      as the shortest text that reads back exactly as the rounded number
      (``12288.049999999999`` → ``12288.05``). An entry that already holds the rounded value
      keeps its text and its comments.
    - A replaced (or removed) entry's comments, trailing or on the lines directly above it, stay
      when they name the quantity (``# analog zero drift``) and go when they state a number or
      cite a source (``# 600 r/min at 10 V with 12288 counts/rev``, ``# from the data sheet``):
      those described the old value. Every other comment of the file stays.
    - Same inputs, same bytes.

    Parameters
    ----------
    path : str or Path
        The rig file to write. If it does not exist it is created from ``template``; its
        directory must exist.
    axis : str
        Axis name, the ``<axis>`` of ``[axis.<axis>]``; the axis must already be in the file.
    plant : Plant
        The model to write (units as in :class:`~servotune.plant.Plant`).
    template : str or Path
        Rig file a new ``path`` starts from; default the example rig
        ``pc-dual-servo.toml`` shipped in the package (:data:`EXAMPLE_RIG_PATH`).
    provenance : str or None
        One line saying where the numbers come from, e.g. ``"fitted by servotune 0.1.0 from
        log.csv, fit 98.1 %"``. It becomes the trailing comment of the table header
        (``[axis.master.plant]  # fitted by ...``), replacing whatever comment was there, so
        repeated writes do not accumulate lines. ``""`` removes that comment; ``None`` (default)
        leaves it as it is.
    new_name, new_header : str
        For a ``path`` that does not exist yet: make it a rig of its own named ``new_name``,
        with ``new_header`` (lines) as its leading comment, a description naming the template,
        and every other axis's plant marked as the template's, not fitted
        (:func:`servotune.rig.edit.new_rig_text`). Without ``new_name`` the template is copied
        as it is.

    Raises
    ------
    FileNotFoundError
        If the directory of ``path`` does not exist (it is named in the message; nothing is
        created).
    RigError
        If the file or the template cannot be read or is not TOML, if ``axis`` is not in it
        (the message lists the axes there are), if ``provenance`` is not one line, or if the
        result would not load with :func:`load_rig` (then nothing is written).
    OSError
        If writing fails; ``path`` is then unchanged and no temporary file is left.

    Examples
    --------
    >>> import tempfile
    >>> from servotune.plant import Plant
    >>> rig_file = Path(tempfile.mkdtemp()) / "my-rig.toml"
    >>> fitted = Plant(gain_cps_per_v=12288.049999999999, tau_s=0.0262, delay_s=0.0009,
    ...                offset_v=0.0048, coulomb_v=0.0021)
    >>> write_plant(rig_file, "master", fitted, provenance="fitted by servotune from log.csv")
    >>> p = load_rig(rig_file).axis("master").plant
    >>> p.gain_cps_per_v, p.tau_s, p.max_speed_rpm  # max_speed_rpm kept from the template
    (12288.05, 0.0262, 700)
    >>> [line for line in rig_file.read_text().splitlines() if "fitted by" in line]
    ['[axis.master.plant]  # fitted by servotune from log.csv']
    """
    if not isinstance(plant, Plant):
        raise TypeError(f"plant must be a servotune.plant.Plant, got {type(plant).__name__}")
    target = Path(path)
    new = None if new_name is None else {"name": new_name, "header": new_header}
    new_text, written = edit_plant_text(
        target,
        axis,
        plant,
        template=template,
        provenance=provenance,
        new=new,
        fit=None if fit is None else fit.to_dict(),
    )

    # The result must load as a rig, with the values just written, before anything is written.
    try:
        data = tomllib.loads(new_text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(
            f"writing [axis.{axis}.plant] would make {str(target)!r} invalid TOML ({exc}); "
            f"nothing written"
        ) from None
    try:
        loaded_axis = rig_from_dict(data, default_name=target.stem).axis(axis)
        loaded = loaded_axis.plant
    except RigError as exc:
        raise RigError(
            f"{str(target)!r} would not load after writing [axis.{axis}.plant] ({exc}); "
            f"nothing written"
        ) from None
    wrong = sorted(
        k for k, v in written.items() if k not in ("fit", "modes") and getattr(loaded, k) != v
    )
    if _mode_entries(loaded.modes) != written.get("modes", []):
        wrong.append("modes")
    if (loaded_axis.plant_fit.to_dict() if loaded_axis.plant_fit else None) != written.get("fit"):
        wrong.append("fit")
    if wrong:
        raise RigError(
            f"[axis.{axis}.plant] in {str(target)!r} reads back different values for "
            f"{', '.join(wrong)} (duplicate or dotted keys?); nothing written"
        )
    atomic_write_bytes(target, new_text.encode("utf-8"))


def _mode_entries(modes: tuple[Mode, ...]) -> list[dict[str, Any]]:
    """The modes as :func:`servotune.rig.edit.edit_plant_text` reports them written: per mode
    its values and the intervals it has."""
    keys = ("freq_hz", "damping", "gain", "freq_hz_95", "damping_95", "gain_95")
    return [{k: getattr(m, k) for k in keys if getattr(m, k) is not None} for m in modes]
