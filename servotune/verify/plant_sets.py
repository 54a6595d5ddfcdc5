"""A verification chunk's plant sets: drawn parameter rows or plants, and the engine's rows
of them (docs/formats.md#spec-file)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from servotune.plant import (
    NPARAM,
    NROW,
    P_COULOMB,
    P_COULOMB_NEG,
    P_GAIN,
    P_GAIN_NEG,
    P_OFFSET,
    P_TAU,
    P_VMAX,
    Plant,
    fill_plant_rows,
    parameter_row,
    plant_row,
    put_modes,
)
from servotune.resonance import mode_rows
from servotune.rig import Rig

__all__ = ["ChunkPlants", "nominal_parameters", "plant_params_ok", "plants_from_parameters"]


def plants_from_parameters(
    nominal: tuple[Plant, ...], params: np.ndarray
) -> list[tuple[Plant, ...]]:
    """The plant sets of parameter rows (shape (sets, axes, NPARAM), ``servotune.plant.P_*``):
    each axis's nominal plant with the drawn gain, time constant, offset and Coulomb levels (the
    negative direction's only where the nominal plant has its own); the rest, modes included,
    the nominal's."""
    return [
        tuple(
            replace(
                p,
                gain_cps_per_v=x[P_GAIN],
                tau_s=x[P_TAU],
                offset_v=x[P_OFFSET],
                coulomb_v=x[P_COULOMB],
                gain_neg_cps_per_v=None if p.gain_neg_cps_per_v is None else x[P_GAIN_NEG],
                coulomb_neg_v=None if p.coulomb_neg_v is None else x[P_COULOMB_NEG],
            )
            for p, x in zip(nominal, row, strict=True)
        )
        for row in params.tolist()
    ]


def nominal_parameters(rig: Rig) -> np.ndarray:
    """The rig's plants as parameter rows (``servotune.plant.P_*``), shape (axes, NPARAM)."""
    return np.array([parameter_row(a.plant, rig.counts_per_rev) for a in rig.axes]).reshape(
        len(rig.axes), NPARAM
    )


def plant_params_ok(params: np.ndarray) -> bool:
    """Whether every parameter row's drawn columns are values a :class:`Plant` accepts (gains
    and tau finite and > 0, offset finite, Coulomb levels finite and >= 0); rows are filled
    without building a plant, which would check them."""
    x = params[..., :P_VMAX]
    return bool(
        np.isfinite(x).all()
        and (x[..., [P_GAIN, P_TAU, P_GAIN_NEG]] > 0.0).all()
        and (x[..., [P_COULOMB, P_COULOMB_NEG]] >= 0.0).all()
    )


@dataclass(slots=True, kw_only=True)
class ChunkPlants:
    """A chunk's plant sets: as parameter rows or as plants; each form built when asked."""

    rig: Rig
    params: np.ndarray | None = None
    plant_sets: list[tuple[Plant, ...]] | None = None
    _rows: tuple[np.ndarray, np.ndarray] | None = None

    def plants(self) -> list[tuple[Plant, ...]]:
        """One plant per axis per plant set."""
        if self.plant_sets is None:
            assert self.params is not None
            nominal = tuple(a.plant for a in self.rig.axes)
            self.plant_sets = plants_from_parameters(nominal, self.params)
        return self.plant_sets

    def rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Plant rows ``(n, axes, NROW)`` and integer rows ``(n, axes, 2)`` (lag, counter
        start), as :func:`~servotune.sim.engine.prepare_batch` builds them."""
        if self._rows is None:
            rig = self.rig
            if self.params is not None:
                if not plant_params_ok(self.params):
                    self.plants()  # raises the Plant's ValueError, as the traced path does
                n, n_ax = self.params.shape[:2]
                pf = np.empty((n * n_ax, NROW))
                lags = np.empty(n * n_ax, dtype=np.int64)
                flat = np.ascontiguousarray(self.params.reshape(n * n_ax, NPARAM))
                fill_plant_rows(flat, float(rig.period_s), float(rig.timer.compute_s), pf, lags)
                pf = pf.reshape(n, n_ax, NROW)
                lags = lags.reshape(n, n_ax)
                for a, axis in enumerate(rig.axes):  # the modes are the nominal plant's
                    if axis.plant.modes:
                        modes = mode_rows(axis.plant.modes)
                        for b in range(n):
                            put_modes(pf[b, a], modes)
            else:
                sets = self.plants()
                n, n_ax = len(sets), len(rig.axes)
                pf = np.empty((n, n_ax, NROW))
                lags = np.empty((n, n_ax), dtype=np.int64)
                for b, ps in enumerate(sets):
                    for a, p in enumerate(ps):
                        pf[b, a], lags[b, a] = plant_row(
                            p, rig.period_s, rig.timer.compute_s, rig.counts_per_rev
                        )
            pi = np.empty((n, n_ax, 2), dtype=np.int64)
            pi[:, :, 0] = lags
            pi[:, :, 1] = [a.counter_init for a in rig.axes]
            self._rows = (pf, pi)
        return self._rows
