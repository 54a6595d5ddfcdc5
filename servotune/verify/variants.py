"""Plant variants: the nominal plants and the Monte Carlo spread of a spec's
``[montecarlo]`` table, deterministic in the seed."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune.analysis.plant_cases import spread_factors
from servotune.errors import SpecError
from servotune.plant import (
    NPARAM,
    P_COULOMB,
    P_COULOMB_NEG,
    P_GAIN,
    P_GAIN_NEG,
    P_OFFSET,
    P_TAU,
    Plant,
    parameter_row,
)
from servotune.rig import Rig
from servotune.validate import show_value
from servotune.verify.plant_sets import plants_from_parameters
from servotune.verify.spec import MonteCarlo

__all__ = [
    "SPREAD_PARAMETERS",
    "Variant",
    "chunk_generator",
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
        gain and Coulomb level only for an asymmetric plant that sets them)."""
        keys = ("gain_cps_per_v", "tau_s", "offset_v", "coulomb_v")
        neg_keys = ("gain_neg_cps_per_v", "coulomb_neg_v")
        return {
            "label": self.label,
            "plants": {
                n: {k: float(getattr(p, k)) for k in keys}
                | {k: float(getattr(p, k)) for k in neg_keys if getattr(p, k) is not None}
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
    symmetric and draws exactly as before.

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
SPREAD_PARAMETERS = ("gain_cps_per_v", "tau_s", "offset_v", "coulomb_v")
"""The plant parameters a spec's spread varies, in draw order (units in the names)."""


def chunk_generator(seed: int, start: int, draws_per_item: int) -> np.random.Generator:
    """The seed's variant stream, jumped to item ``start``: item ``i`` always takes the
    ``draws_per_item`` uniforms at ``[i·d, (i + 1)·d)`` of the stream (PCG64's ``advance``), so a
    chunk ``[start, stop)`` draws exactly what one pass over all items draws there, whatever
    the chunking (docs/decisions.md#11-random-numbers)."""
    bits = np.random.PCG64(seed_seqs(seed)[0])
    bits.advance(int(start) * int(draws_per_item))
    return np.random.Generator(bits)


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
    plants), as rows for :func:`servotune.plant.fill_plant_rows`, without a :class:`Plant` each.

    Returns
    -------
    ndarray, shape (stop − start, rig axes, NPARAM)
        Columns ``servotune.plant.P_*``; an axis the spread does not vary keeps its nominal
        plant's values. The speed limit is in counts/s of the rig's counter.

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
    out = np.empty((n, len(names), NPARAM))
    for j, axis in enumerate(rig.axes):
        p = axis.plant
        nominal = parameter_row(p, rig.counts_per_rev)
        out[:, j] = nominal  # an axis the spec does not spread keeps them all
        if mc.axes and axis.name not in mc.axes:
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
    return out


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
    """Independent seed sequences: [0] the variants, [1] the noise streams."""
    return np.random.SeedSequence(int(seed)).spawn(2)
