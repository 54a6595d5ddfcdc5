"""Input shaping of the gantry's move (docs/systems.md#shaping-the-gantrys-move).

The CNC's command goes to both drives, so one shaper on it serves both sides: it is designed at
the bus cycle for the closed-loop modes of each drive whose plant has modes
(:func:`~servotune.analysis.shaping.closed_loop_modes` with the drive's PI, its compute time and
plant delay), a mode of the slave within :data:`SAME_MODE` of one already taken counted once.
``[move] shaper`` picks the kind: ``none`` (default), ``auto`` (the shortest that holds each
mode's residual vibration at 5 % over its range, :func:`~servotune.laws.shaping.choose_shaper`),
or ``zv``/``zvd``/``ei`` for every mode (a product for several). The shaped move ends
``n_taps − 1`` cycles later (``Shaper.added_time_s``), which :func:`gantry_shaper` states.
"""

from __future__ import annotations

from servotune.analysis.shaping import closed_loop_modes
from servotune.arch.gantry.config import GantryConfig
from servotune.errors import ConfigError, SpecError
from servotune.laws.shaping import Shaper, choose_shaper, shaper_for_modes
from servotune.resonance import Mode

__all__ = ["SAME_MODE", "drive_modes", "gantry_shaper"]

SAME_MODE = 0.02
"""Closed-loop modes of the two sides whose frequencies differ by at most this fraction are
one mode for the shaper (the master's is designed for)."""


def drive_modes(cfg: GantryConfig) -> list[tuple[str, Mode]]:
    """Each drive's closed-loop modes at the bus cycle, ``(side, mode)``, the master's first;
    a slave mode within :data:`SAME_MODE` of a master's left out.

    Raises
    ------
    ConfigError
        A drive's loop that rings or is unstable at a mode (no shaper helps).
    """
    out: list[tuple[str, Mode]] = []
    for side, drive in (("master", cfg.master), ("slave", cfg.slave)):
        if not drive.plant.modes:
            continue
        try:
            modes = closed_loop_modes(
                drive.plant,
                drive.gains,
                period_s=cfg.bus.cycle_s,
                lag_s=cfg.bus.compute_s + drive.plant.delay_s,
                lsb_volts=cfg.rig.dac.lsb_v,
            )
        except SpecError as exc:
            raise ConfigError(f"move.shaper: the {side}'s drive: {exc}") from None
        for m in modes:
            if all(abs(m.freq_hz - o.freq_hz) > SAME_MODE * o.freq_hz for _, o in out):
                out.append((side, m))
    return out


def gantry_shaper(cfg: GantryConfig) -> tuple[Shaper | None, list[str]]:
    """The shaper of the gantry's move (``cfg.move.shaper``; module docstring), with one line
    per mode saying what it is designed for and what it costs; ``(None, [])`` for ``none``.

    Raises
    ------
    ConfigError
        A shaper asked for where neither drive's plant has modes, or one that cannot be
        designed at the bus cycle.
    """
    kind = cfg.move.shaper
    if kind == "none":
        return None, []
    modes = drive_modes(cfg)
    if not modes:
        raise ConfigError(
            f"move.shaper = {kind!r}, but neither drive's plant has modes to shape for; give "
            '[[axis.master.plant.modes]] (docs/formats.md#modes) or set shaper = "none"'
        )
    cycle = cfg.bus.cycle_s
    try:
        if kind == "auto":
            sh, why = choose_shaper([m for _, m in modes], cycle)
        else:
            sh = shaper_for_modes(kind, [(m.freq_hz, m.damping) for _, m in modes], cycle)
            why = [f"{m.freq_hz:.4g} Hz: {kind}, as asked" for _, m in modes]
    except SpecError as exc:
        raise ConfigError(f"move.shaper: {exc}") from None
    lines = [
        f"the {side}'s closed-loop mode {m.freq_hz:.4g} Hz (damping {m.damping:.3g}): {w}"
        for (side, m), w in zip(modes, why, strict=True)
    ]
    lines.append(
        f"shaper {sh.kind}: {sh.n_taps} taps, the move ends {1000 * sh.added_time_s:.1f} ms "
        f"({sh.n_taps - 1} cycles) later"
    )
    return sh, lines
