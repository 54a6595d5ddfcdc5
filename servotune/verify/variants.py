"""Plant variants: the nominal plants and the Monte Carlo spread of a spec's
``[montecarlo]`` table, deterministic in the seed."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune.analysis.plant_cases import damping_range, mode_factors, spread_factors
from servotune.errors import SpecError
from servotune.plant import (
    P_COULOMB,
    P_COULOMB_NEG,
    P_GAIN,
    P_GAIN_NEG,
    P_OFFSET,
    P_TAU,
    Plant,
)
from servotune.resonance import MAX_MODES
from servotune.rig import Rig
from servotune.validate import show_value
from servotune.verify.plant_sets import (
    M_DAMPING,
    M_FREQ,
    NCOLUMNS,
    mode_column,
    plant_columns,
    plants_from_parameters,
)
from servotune.verify.spec import MonteCarlo

__all__ = [
    "MODE_STREAM",
    "NOISE_STREAM",
    "SPREAD_PARAMETERS",
    "VARIANT_STREAM",
    "Variant",
    "chunk_generator",
    "drawn_columns",
    "plant_variants",
    "spread_parameters",
    "spread_plants",
]


# --- plant variants ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Variant:
    """One plant set the loop is verified on.

    Attributes
    ----------
    label : str
        ``"nominal"`` or ``"mc<i>"`` (1-based).
    plants : tuple of Plant
        One per rig axis.
    """

    label: str
    plants: tuple[Plant, ...]

    def to_dict(self, axis_names: Sequence[str]) -> dict[str, Any]:
        """Plain dict: the label and per axis the varied parameters (the negative direction's
        gain and Coulomb level only for an asymmetric plant that sets them; ``modes``, each
        mode's ``freq_hz`` and ``damping``, only for a plant with modes)."""
        keys = ("gain_cps_per_v", "tau_s", "offset_v", "coulomb_v")
        neg_keys = ("gain_neg_cps_per_v", "coulomb_neg_v")

        def modes(p: Plant) -> dict[str, Any]:
            if not p.modes:
                return {}
            return {
                "modes": [
                    {"freq_hz": float(m.freq_hz), "damping": float(m.damping)} for m in p.modes
                ]
            }

        return {
            "label": self.label,
            "plants": {
                n: {k: float(getattr(p, k)) for k in keys}
                | {k: float(getattr(p, k)) for k in neg_keys if getattr(p, k) is not None}
                | modes(p)
                for n, p in zip(axis_names, self.plants, strict=True)
            },
        }


def plant_variants(rig: Rig, mc: MonteCarlo, seed: int | None = None) -> tuple[Variant, ...]:
    """The nominal plants and ``mc.count`` random variants (deterministic in the seed).

    Each variant draws, for every axis in rig order, four uniforms in [−1, 1] (gain, tau,
    offset, Coulomb) and applies the spreads of ``mc`` to the axes it names. An asymmetric
    plant stays asymmetric: the gain draw scales both directions' gains by the same factor,
    the Coulomb draw both directions' Coulomb levels (the ratio between the directions is the
    drive's and is kept); a direction left None stays None, so a symmetric plant stays
    symmetric and draws exactly as before. A plant with modes also draws, from a stream of
    its own (:func:`spread_parameters`), each mode's frequency and damping; a rigid rig draws
    exactly as before.

    Raises
    ------
    SpecError
        If ``mc.axes`` names an axis the rig does not have.
    """
    nominal = tuple(a.plant for a in rig.axes)
    out = [Variant(label="nominal", plants=nominal)]
    plants = spread_plants(rig, mc, mc.seed if seed is None else seed, 0, mc.count)
    out += [Variant(label=f"mc{i + 1}", plants=p) for i, p in enumerate(plants)]
    return tuple(out)


_DRAWS_PER_AXIS = 4  # uniforms per axis and variant: gain, tau, offset, Coulomb
_MODE_DRAWS_PER_AXIS = 2 * MAX_MODES  # uniforms per axis and variant: each mode slot's freq, ζ
VARIANT_STREAM, NOISE_STREAM, MODE_STREAM = 0, 1, 2
"""Indices in :func:`seed_seqs`: the plant parameters' draws, the noise streams, the modes'."""
SPREAD_PARAMETERS = ("gain_cps_per_v", "tau_s", "offset_v", "coulomb_v")
"""The plant parameters a spec's spread varies, in draw order (units in the names)."""


def chunk_generator(
    seed: int, start: int, draws_per_item: int, stream: int = VARIANT_STREAM
) -> np.random.Generator:
    """The seed's variant stream (``stream``: another of :func:`seed_seqs`), jumped to item
    ``start``: item ``i`` always takes the ``draws_per_item`` uniforms at ``[i·d, (i + 1)·d)``
    of the stream (PCG64's ``advance``), so a chunk ``[start, stop)`` draws exactly what one
    pass over all items draws there, whatever the chunking
    (docs/decisions.md#11-random-numbers)."""
    bits = np.random.PCG64(seed_seqs(seed)[stream])
    bits.advance(int(start) * int(draws_per_item))
    return np.random.Generator(bits)


def _spread(rig: Rig, mc: MonteCarlo) -> list[bool]:
    """Per rig axis, whether the spread varies it (every axis if ``mc.axes`` is empty)."""
    return [not mc.axes or a.name in mc.axes for a in rig.axes]


def drawn_columns(rig: Rig, mc: MonteCarlo) -> tuple[tuple[str, int, int], ...]:
    """The values the spread draws, as ``("<axis>.<parameter>", axis index, column)`` of
    :func:`spread_parameters`' rows: per varied axis (rig order) its
    :data:`SPREAD_PARAMETERS`, then per mode ``k`` (1-based) ``mode<k>_freq_hz`` and, where its
    damping has an interval to draw in, ``mode<k>_damping``."""
    out: list[tuple[str, int, int]] = []
    for j, (axis, varied) in enumerate(zip(rig.axes, _spread(rig, mc), strict=True)):
        if not varied:
            continue
        cols = (P_GAIN, P_TAU, P_OFFSET, P_COULOMB)
        out += [(f"{axis.name}.{k}", j, c) for k, c in zip(SPREAD_PARAMETERS, cols, strict=True)]
        for i, m in enumerate(axis.plant.modes):
            out.append((f"{axis.name}.mode{i + 1}_freq_hz", j, mode_column(i, M_FREQ)))
            lo, hi = damping_range(m)
            if lo < hi:
                out.append((f"{axis.name}.mode{i + 1}_damping", j, mode_column(i, M_DAMPING)))
    return tuple(out)


def spread_plants(
    rig: Rig, mc: MonteCarlo, seed: int, start: int, stop: int
) -> list[tuple[Plant, ...]]:
    """The plant sets of Monte-Carlo draws ``start … stop − 1`` (0-based: draw ``i`` is variant
    ``mc<i + 1>`` of :func:`plant_variants`), one plant per rig axis, bit for bit what
    :func:`plant_variants` gives them, from a generator jumped to ``start``
    (:func:`chunk_generator`); their parameters are :func:`spread_parameters`'.

    Raises
    ------
    SpecError
        If ``mc.axes`` names an axis the rig does not have.
    """
    params = spread_parameters(rig, mc, seed, start, stop)
    return plants_from_parameters(tuple(a.plant for a in rig.axes), params)


def spread_parameters(rig: Rig, mc: MonteCarlo, seed: int, start: int, stop: int) -> np.ndarray:
    """The plant parameters of Monte-Carlo draws ``start … stop − 1`` (:func:`spread_plants`'
    plants), as verification parameter rows (:mod:`servotune.verify.plant_sets`: the columns
    :func:`servotune.plant.fill_plant_rows` reads, then the modes'), without a :class:`Plant`
    each: the one place a Monte-Carlo plant set is drawn.

    The gain, tau, offset and Coulomb draws come from the variant stream (four uniforms per
    axis and draw, :func:`chunk_generator`). The modes' from a stream of their own
    (:data:`MODE_STREAM`, ``2·MAX_MODES`` uniforms in [0, 1) per axis and draw, whether the
    axis has modes or not), so the parameter draws are the same with or without modes: each
    mode of a varied axis takes its frequency uniformly in the wider of its 95 % interval and
    ±10 % (:func:`~servotune.analysis.plant_cases.mode_factors`) and its damping uniformly in
    its 95 % interval kept inside (0, 1) (:func:`~servotune.analysis.plant_cases.damping_range`;
    the nominal damping where it has none), as the margins' samples draw them
    (docs/frf.md#the-resonant-plant-in-the-simulation).

    Returns
    -------
    ndarray, shape (stop − start, rig axes, NCOLUMNS)
        Columns ``servotune.plant.P_*``, then the mode slots' frequency and damping (NaN past
        a plant's modes); an axis the spread does not vary keeps its nominal plant's values.
        The speed limit is in counts/s of the rig's counter.

    Raises
    ------
    SpecError
        If ``mc.axes`` names an axis the rig does not have.
    """
    names = rig.axis_names
    for a in mc.axes:
        if a not in names:
            raise SpecError(
                f"montecarlo.axes names {show_value(a)}, the rig has axes {list(names)}"
            )
    n = max(0, int(stop) - int(start))
    rng = chunk_generator(seed, start, len(names) * _DRAWS_PER_AXIS)
    u = rng.uniform(-1.0, 1.0, size=(n, len(names), _DRAWS_PER_AXIS))
    out = np.empty((n, len(names), NCOLUMNS))
    for j, (axis, varied) in enumerate(zip(rig.axes, _spread(rig, mc), strict=True)):
        p = axis.plant
        nominal = plant_columns(p, rig.counts_per_rev)
        out[:, j] = nominal  # an axis the spec does not spread keeps them all
        if not varied:
            continue
        gain_neg, coulomb_neg = nominal[P_GAIN_NEG], nominal[P_COULOMB_NEG]
        # the draw's map onto each parameter: the spec's spread, or the identified 95 %
        # interval where that is wider (the fit record of a fitted rig); element by element the
        # same IEEE operations as on one draw's floats
        gain, tau, offset, coulomb = _maps(p, axis.plant_fit, mc)
        g_f, c_f = gain(u[:, j, 0]), coulomb(u[:, j, 3])
        out[:, j, P_GAIN] = p.gain_cps_per_v * g_f
        out[:, j, P_TAU] = p.tau_s * tau(u[:, j, 1])
        out[:, j, P_OFFSET] = p.offset_v + offset(u[:, j, 2])
        out[:, j, P_COULOMB] = p.coulomb_v * c_f
        out[:, j, P_GAIN_NEG] = gain_neg * g_f
        out[:, j, P_COULOMB_NEG] = coulomb_neg * c_f
    _draw_modes(rig, mc, seed, start, out)
    return out


def _draw_modes(rig: Rig, mc: MonteCarlo, seed: int, start: int, out: np.ndarray) -> None:
    """Draw the modes' columns of ``out`` (draws ``start …``) for every varied axis with modes
    (:func:`spread_parameters`); nothing is drawn for a rig without them."""
    axes = [j for j, v in enumerate(_spread(rig, mc)) if v and rig.axes[j].plant.modes]
    if not axes:
        return
    n_ax = len(rig.axes)
    rng = chunk_generator(seed, start, n_ax * _MODE_DRAWS_PER_AXIS, MODE_STREAM)
    u = rng.random(size=(out.shape[0], n_ax, MAX_MODES, 2))
    for j in axes:
        for i, m in enumerate(rig.axes[j].plant.modes):
            lo, hi = mode_factors(m)
            out[:, j, mode_column(i, M_FREQ)] = m.freq_hz * (lo + (hi - lo) * u[:, j, i, 0])
            z_lo, z_hi = damping_range(m)  # (ζ, ζ) without an interval: ζ itself
            out[:, j, mode_column(i, M_DAMPING)] = z_lo + (z_hi - z_lo) * u[:, j, i, 1]


def _linear(lo: float, hi: float, centre: float, half: float) -> Any:
    """``u ∈ [−1, 1]`` onto ``[lo, hi]``: ``centre + half·u`` when that is the interval
    (bit for bit the spec-spread draw), else the interval's own midpoint and half-width."""
    if (lo, hi) == (centre - half, centre + half):
        return lambda u: centre + half * u
    mid, rad = 0.5 * (lo + hi), 0.5 * (hi - lo)
    return lambda u: mid + rad * u


def _maps(plant: Plant, fit: Any, mc: MonteCarlo) -> tuple[Any, Any, Any, Any]:
    """Per parameter (gain factor, tau factor, offset shift [V], Coulomb factor) the map of a
    uniform draw in [−1, 1]: onto ``1 ± spread`` (``± offset_spread_v``), widened to the
    identification's 95 % interval where the axis's fit record has a wider one."""
    out = []
    for key, spread in (("gain_cps_per_v", mc.gain_spread), ("tau_s", mc.tau_spread)):
        out.append(_linear(*spread_factors(plant, fit, key, spread), 1.0, spread))
    ci = getattr(fit, "ci95", {}) if fit is not None else {}
    s = mc.offset_spread_v
    lo, hi = -s, s
    if "offset_v" in ci:
        lo = min(lo, ci["offset_v"][0] - plant.offset_v)
        hi = max(hi, ci["offset_v"][1] - plant.offset_v)
    out.append(_linear(lo, hi, 0.0, s))
    if plant.coulomb_v > 0:
        out.append(
            _linear(
                *spread_factors(plant, fit, "coulomb_v", mc.coulomb_spread), 1.0, mc.coulomb_spread
            )
        )
    else:
        out.append(
            _linear(1.0 - mc.coulomb_spread, 1.0 + mc.coulomb_spread, 1.0, mc.coulomb_spread)
        )
    return out[0], out[1], out[2], out[3]


def seed_seqs(seed: int) -> list[np.random.SeedSequence]:
    """Independent seed sequences: [0] the variants' plant parameters, [1] the noise streams,
    [2] the modes' draws (:data:`VARIANT_STREAM`, :data:`NOISE_STREAM`, :data:`MODE_STREAM`).
    Spawned children are keyed by their index, so [0] and [1] are what they were before [2]
    was added."""
    return np.random.SeedSequence(int(seed)).spawn(3)
