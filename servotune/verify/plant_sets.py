"""A verification chunk's plant sets: drawn parameter rows or plants, and the engine's rows
of them (docs/formats.md#spec-file).

A verification's parameter row (:data:`NCOLUMNS` columns) is a plant's
:func:`~servotune.plant.parameter_row` (columns ``servotune.plant.P_*``, what
:func:`~servotune.plant.fill_plant_rows` reads) followed by its modes' drawn values: per mode
slot ``i`` of :data:`~servotune.resonance.MAX_MODES` its frequency [Hz] at
``mode_column(i, M_FREQ)`` and its damping ratio [-] at ``mode_column(i, M_DAMPING)``, NaN past
the plant's own modes (a rigid plant's are all NaN). A mode's gain is not drawn: it is the
nominal plant's (docs/frf.md#the-resonant-plant-in-the-simulation).
"""

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
from servotune.resonance import MAX_MODES, mode_rows
from servotune.rig import Rig

__all__ = [
    "M_DAMPING",
    "M_FREQ",
    "NCOLUMNS",
    "ChunkPlants",
    "mode_column",
    "nominal_parameters",
    "plant_columns",
    "plant_params_ok",
    "plants_from_parameters",
]

M_FREQ, M_DAMPING = 0, 1
"""A mode slot's two columns: its frequency [Hz] and its damping ratio [-]."""
NCOLUMNS = NPARAM + 2 * MAX_MODES
"""Columns of a verification parameter row (module docstring)."""


def mode_column(i: int, what: int) -> int:
    """The column of mode ``i``'s frequency (``what = M_FREQ``) or damping (``M_DAMPING``)."""
    return NPARAM + 2 * i + what


def plant_columns(plant: Plant, counts_per_rev: float) -> np.ndarray:
    """A plant's verification parameter row (:data:`NCOLUMNS`): its
    :func:`~servotune.plant.parameter_row` and its modes' frequencies and dampings."""
    out = np.full(NCOLUMNS, np.nan)
    out[:NPARAM] = parameter_row(plant, counts_per_rev)
    for i, m in enumerate(plant.modes):
        out[mode_column(i, M_FREQ)] = m.freq_hz
        out[mode_column(i, M_DAMPING)] = m.damping
    return out


def _modes_of(p: Plant, x: list[float]) -> dict[str, object]:
    """``replace`` arguments for the modes of row ``x``: each nominal mode with the row's
    frequency and damping (its gain and intervals kept); nothing for a rigid plant."""
    if not p.modes:
        return {}
    return {
        "modes": tuple(
            replace(m, freq_hz=x[mode_column(i, M_FREQ)], damping=x[mode_column(i, M_DAMPING)])
            for i, m in enumerate(p.modes)
        )
    }


def plants_from_parameters(
    nominal: tuple[Plant, ...], params: np.ndarray
) -> list[tuple[Plant, ...]]:
    """The plant sets of parameter rows (shape (sets, axes, :data:`NCOLUMNS`), module
    docstring): each axis's nominal plant with the drawn gain, time constant, offset and Coulomb
    levels (the negative direction's only where the nominal plant has its own) and its modes'
    drawn frequencies and dampings; the rest, the modes' gains included, the nominal's."""
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
                **_modes_of(p, x),
            )
            for p, x in zip(nominal, row, strict=True)
        )
        for row in params.tolist()
    ]


def nominal_parameters(rig: Rig) -> np.ndarray:
    """The rig's plants as verification parameter rows (:func:`plant_columns`), shape
    (axes, :data:`NCOLUMNS`)."""
    return np.array([plant_columns(a.plant, rig.counts_per_rev) for a in rig.axes]).reshape(
        len(rig.axes), NCOLUMNS
    )


def plant_params_ok(params: np.ndarray) -> bool:
    """Whether every parameter row's drawn columns are values a :class:`Plant` accepts (gains
    and tau finite and > 0, offset finite, Coulomb levels finite and >= 0; a mode slot's
    frequency finite and > 0 and its damping in (0, 1), or both NaN: no mode); rows are filled
    without building a plant, which would check them."""
    x = params[..., :P_VMAX]
    f = params[..., NPARAM::2]
    z = params[..., NPARAM + 1 :: 2]
    modes_ok = (np.isnan(f) & np.isnan(z)) | ((f > 0.0) & np.isfinite(f) & (z > 0.0) & (z < 1.0))
    return bool(
        np.isfinite(x).all()
        and (x[..., [P_GAIN, P_TAU, P_GAIN_NEG]] > 0.0).all()
        and (x[..., [P_COULOMB, P_COULOMB_NEG]] >= 0.0).all()
        and modes_ok.all()
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
                modes = _drawn_mode_rows(rig, self.params)
                if not plant_params_ok(self.params) or any(np.isnan(m).any() for m in modes):
                    self.plants()  # raises the Plant's ValueError, as the traced path does
                n, n_ax = self.params.shape[:2]
                pf = np.empty((n * n_ax, NROW))
                lags = np.empty(n * n_ax, dtype=np.int64)
                flat = np.ascontiguousarray(self.params[:, :, :NPARAM].reshape(n * n_ax, NPARAM))
                fill_plant_rows(flat, float(rig.period_s), float(rig.timer.compute_s), pf, lags)
                pf = pf.reshape(n, n_ax, NROW)
                lags = lags.reshape(n, n_ax)
                for a, m in enumerate(modes):  # each plant set's drawn modes
                    if m.shape[1]:
                        for b in range(n):
                            put_modes(pf[b, a], m[b])
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


def _drawn_mode_rows(rig: Rig, params: np.ndarray) -> list[np.ndarray]:
    """Per rig axis, its plant sets' modes as rows ``freq_hz, damping, gain``
    (:func:`~servotune.resonance.mode_rows`), shape (sets, the nominal plant's modes, 3): the
    drawn frequencies and dampings of ``params``, the nominal modes' gains."""
    out = []
    for a, axis in enumerate(rig.axes):
        k = len(axis.plant.modes)
        m = np.empty((params.shape[0], k, 3))
        m[:, :, 0] = params[:, a, mode_column(0, M_FREQ) : mode_column(k, M_FREQ) : 2]
        m[:, :, 1] = params[:, a, mode_column(0, M_DAMPING) : mode_column(k, M_DAMPING) : 2]
        m[:, :, 2] = mode_rows(axis.plant.modes)[:, 2]
        out.append(m)
    return out
