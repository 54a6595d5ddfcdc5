"""Plant variants: the nominal plants and the Monte Carlo spread of a spec's
``[montecarlo]`` table, deterministic in the seed."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from servotune.errors import SpecError
from servotune.plant import Plant
from servotune.rig import Rig
from servotune.validate import show_value
from servotune.verify.spec import MonteCarlo

__all__ = [
    "Variant",
    "plant_variants",
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
    names = rig.axis_names
    for a in mc.axes:
        if a not in names:
            raise SpecError(
                f"montecarlo.axes names {show_value(a)}, the rig has axes {list(names)}"
            )
    vary = [n in mc.axes if mc.axes else True for n in names]
    nominal = tuple(a.plant for a in rig.axes)
    out = [Variant(label="nominal", plants=nominal)]
    rng = np.random.default_rng(_seed_seqs(mc.seed if seed is None else seed)[0])
    u = rng.uniform(-1.0, 1.0, size=(mc.count, len(names), 4))
    for i in range(mc.count):
        plants = []
        for j, p in enumerate(nominal):
            if not vary[j]:
                plants.append(p)
                continue
            g, t, o, c = (float(x) for x in u[i, j])
            g_f, c_f = 1.0 + mc.gain_spread * g, 1.0 + mc.coulomb_spread * c
            plants.append(
                replace(
                    p,
                    gain_cps_per_v=p.gain_cps_per_v * g_f,
                    tau_s=p.tau_s * (1.0 + mc.tau_spread * t),
                    offset_v=p.offset_v + mc.offset_spread_v * o,
                    coulomb_v=p.coulomb_v * c_f,
                    gain_neg_cps_per_v=_scaled(p.gain_neg_cps_per_v, g_f),
                    coulomb_neg_v=_scaled(p.coulomb_neg_v, c_f),
                )
            )
        out.append(Variant(label=f"mc{i + 1}", plants=tuple(plants)))
    return tuple(out)


def _scaled(value: float | None, factor: float) -> float | None:
    """``value · factor``; None (the positive direction's value) stays None."""
    return None if value is None else value * factor


def _seed_seqs(seed: int) -> list[np.random.SeedSequence]:
    """Independent seed sequences: [0] the variants, [1] the noise streams."""
    return np.random.SeedSequence(int(seed)).spawn(2)
