"""The fleet's measured spread as a Monte-Carlo plant distribution.

``servotune verify TUNING --plants-from fleet.parquet --plants-axis master`` verifies the
tuning on plants resampled from the fleet instead of the spec's ``[montecarlo]`` spreads:
plant set ``i`` is the rig's plants with one axis's plant replaced by the plant one machine of
the fleet was fitted to: an **empirical resampling** (a bootstrap) of the fleet's machines, so
the parameters keep the correlations they have in the fleet (a machine with a high gain and a
long time constant stays one), and no distribution shape is assumed.

Which fit of a machine: its latest **adequate** fit of that axis (every residual test passed:
:func:`~servotune.fleet.rows.latest_fits` with ``adequate_only``); a machine without one is
left out. Its gain, time constant, offset, Coulomb level and delay replace the rig axis's (0
for a term the fit left out, as the fleet rows hold them); the negative direction's gain and
Coulomb level where the fit is asymmetric, else none (a symmetric plant). The rig's speed
limit and encoder noise stay the rig's.

Which machine: draw ``i`` picks machine ``⌊u · n⌋`` of the ``n`` machines (sorted by id),
``u`` uniform in [0, 1) from the first 53 bits of block ``i`` of a Philox-4×64 counter-based
generator keyed by the seed's third stream (``SeedSequence(seed, spawn_key=(2,))``; the
spec's spread draws from the first, the noise from the second): draw ``i`` depends only on
the seed and ``i``, so a verification is the same whatever its chunking
(docs/decisions.md#11-random-numbers). The
bias of ``⌊u · n⌋`` is below ``n / 2**53``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from servotune.digest import bytes_sha256
from servotune.errors import FleetTableError, SpecError
from servotune.fleet.rows import FleetRow, latest_fits
from servotune.fleet.summary import MIN_MACHINES
from servotune.fleet.table import parse_fleet_table, table_format
from servotune.identify.model import ALL_PARAMS, ASYM_PARAMS, PARAMS
from servotune.io.files import read_bytes
from servotune.plant import Plant
from servotune.rig import Rig
from servotune.validate import show_value

__all__ = ["FleetSpread", "fleet_spread"]

_STREAM = 2
"""The seed's stream of the fleet's draws (0: the spec's spread, 1: the noise streams)."""

_U53 = 2.0**-53


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetSpread:
    """:class:`~servotune.verify.montecarlo.PlantDistribution` of a fleet's machines: plant
    set ``i`` is the rig's plants with axis ``axis``'s plant replaced by one machine's fitted
    plant, the machine drawn uniformly (module docstring). Build it with
    :func:`fleet_spread`.

    Attributes
    ----------
    rig : Rig
        The rig whose plants the other axes keep.
    axis : str
        The rig axis whose plant is drawn from the fleet.
    machines : tuple of str
        The fleet's machine ids, sorted (draws index into it).
    files : tuple of str
        Per machine, the log whose fit is used.
    plants : tuple of Plant
        Per machine, the plant of that fit on this rig axis.
    values : tuple of tuple of float
        Per machine, the drawn values (:attr:`parameters` order) [units in the names].
    drawn : tuple of str
        The plant parameters drawn (units in the names; the ``*_neg`` ones only if some
        machine's fit is asymmetric: a symmetric machine's are its positive direction's).
    source : str
        Where the fleet came from (``"fleet.parquet sha256 1a2b3c4d5e6f"``; ``""`` for rows).
    source_files : tuple of tuple of str
        The file the fleet was read from as ``(kind, name, sha256)`` (the whole SHA-256 of its
        bytes as read; none for rows): a verification record binds it beside the tuning, rig
        and spec (:attr:`servotune.verify.montecarlo.PlantDistribution.source_files`).
    """

    rig: Rig
    axis: str
    machines: tuple[str, ...]
    files: tuple[str, ...]
    plants: tuple[Plant, ...]
    values: tuple[tuple[float, ...], ...]
    drawn: tuple[str, ...]
    source: str = ""
    source_files: tuple[tuple[str, str, str], ...] = ()

    @property
    def name(self) -> str:
        """What the verification's summary calls it (names the fleet and the axis)."""
        where = f" of {self.source}" if self.source else ""
        return f"fleet spread ({len(self.machines)} machines{where}, axis {self.axis})"

    @property
    def parameters(self) -> tuple[str, ...]:
        """``"<axis>.<parameter>"`` per drawn parameter."""
        return tuple(f"{self.axis}.{p}" for p in self.drawn)

    def machine_indices(self, seed: int, start: int, stop: int) -> np.ndarray:
        """The machine (index into :attr:`machines`) of draws ``start … stop − 1``."""
        n = max(0, int(stop) - int(start))
        bits = np.random.Philox(np.random.SeedSequence(int(seed), spawn_key=(_STREAM,)))
        bits.advance(int(start))  # block i (4 words) belongs to draw i
        raw = bits.random_raw(4 * n).reshape(n, 4)[:, 0] if n else np.empty(0, np.uint64)
        u = (raw >> np.uint64(11)).astype(np.float64) * _U53
        return np.floor(u * len(self.machines)).astype(np.int64)

    def _plant_set(self, m: int) -> tuple[Plant, ...]:
        """The rig's plants with machine ``m``'s on :attr:`axis`."""
        nominal = tuple(a.plant for a in self.rig.axes)
        j = self.rig.axis_names.index(self.axis)
        return (*nominal[:j], self.plants[m], *nominal[j + 1 :])

    @property
    def margin_plant_sets(self) -> tuple[tuple[str, tuple[Plant, ...]], ...]:
        """Every machine's plant set, labelled ``fleet <machine id>``
        (:attr:`~servotune.verify.montecarlo.PlantDistribution.margin_plant_sets`): the
        margins are judged on each measured machine, not only at the spec's corners."""
        return tuple((f"fleet {m}", self._plant_set(i)) for i, m in enumerate(self.machines))

    def draw(self, seed: int, start: int, stop: int) -> tuple[list[tuple[Plant, ...]], np.ndarray]:
        """Draws ``start … stop − 1``: per draw one plant per rig axis (rig order), and the
        drawn values, shape ``(stop − start, len(parameters))``
        (:meth:`~servotune.verify.montecarlo.PlantDistribution.draw`)."""
        k = self.machine_indices(seed, start, stop)
        sets = [self._plant_set(m) for m in k.tolist()]
        table = np.array(self.values, dtype=float).reshape(len(self.machines), len(self.drawn))
        return sets, np.ascontiguousarray(table[k])


def fleet_spread(
    rows_or_table_path: Sequence[FleetRow] | str | Path,
    rig: Rig,
    *,
    axis: str,
    fleet_axis: str | None = None,
) -> FleetSpread:
    """The fleet's measured spread of one rig axis's plant, as a Monte-Carlo distribution.

    Parameters
    ----------
    rows_or_table_path : sequence of FleetRow, or str or Path
        The fleet's rows, or a fleet table (``servotune fit --fleet`` output, Parquet or CSV).
    rig : Rig
        The rig verified: its other axes keep their plants.
    axis : str
        The rig axis whose plant is drawn from the fleet.
    fleet_axis : str, optional
        The fleet rows' axis name to take (default ``axis``; if the fleet has no fit of that
        axis and every fit is of a log's one unprefixed axis, ``""``, those).

    Returns
    -------
    FleetSpread

    Raises
    ------
    SpecError
        ``axis`` is not one of the rig's, the fleet has fewer than
        :data:`~servotune.fleet.summary.MIN_MACHINES` machines with an adequate fit of that
        axis, or a machine's fit is not a valid plant.
    FleetTableError
        The table cannot be read or is not a fleet table.
    """
    names = rig.axis_names
    if axis not in names:
        raise SpecError(
            f"axis {show_value(axis)} is not an axis of rig {show_value(rig.name)} (axes: "
            f"{', '.join(names)})"
        )
    source = ""
    source_files: tuple[tuple[str, str, str], ...] = ()
    if isinstance(rows_or_table_path, str | Path):
        path = rows_or_table_path
        raw = read_bytes(path, FleetTableError, "fleet table")
        recs = parse_fleet_table(raw, table_format(path), str(path))
        rows: Sequence[FleetRow] = [FleetRow.from_record(r) for r in recs]
        sha = bytes_sha256(raw)
        source = f"{Path(path).name} sha256 {sha[:12]}"
        source_files = (("fleet", Path(path).name, sha),)
    else:
        rows = rows_or_table_path
    fitted = [r for r in rows if r.ok]
    want = axis if fleet_axis is None else fleet_axis
    if fleet_axis is None and fitted and not any(r.axis == axis for r in fitted):
        if all(r.axis == "" for r in fitted):
            want = ""  # a fleet of one-axis logs without axis prefixes
    latest = {m: r for (a, m), r in latest_fits(fitted, adequate_only=True).items() if a == want}
    what = f"axis {show_value(want)}" if want else "the logs' unprefixed axis"
    if len(latest) < MIN_MACHINES:
        fleet_axes = sorted({r.axis for r in fitted})
        raise SpecError(
            f"the fleet has {len(latest)} machines with an adequate fit of {what} (of "
            f"{len({r.machine_id for r in fitted if r.axis == want})} with a fit; its axes: "
            f"{', '.join(show_value(a) for a in fleet_axes) or 'none'}); a fleet spread "
            f"needs at least {MIN_MACHINES}"
        )
    asym = any(p in r.params for r in latest.values() for p in ASYM_PARAMS)
    drawn = tuple(p for p in ALL_PARAMS if asym or p not in ASYM_PARAMS)
    base = rig.axis(axis).plant
    ordered = sorted(latest.items())
    plants, values = [], []
    for m, r in ordered:
        plant = _plant(base, r, m)
        plants.append(plant)
        (g, g_neg), (c, c_neg) = plant.gains_cps_per_v, plant.coulombs_v
        resolved = {
            "gain_cps_per_v": g,
            "tau_s": plant.tau_s,
            "delay_s": plant.delay_s,
            "offset_v": plant.offset_v,
            "coulomb_v": c,
            "gain_neg_cps_per_v": g_neg,
            "coulomb_neg_v": c_neg,
        }
        values.append(tuple(float(resolved[p]) for p in drawn))
    return FleetSpread(
        rig=rig,
        axis=axis,
        machines=tuple(m for m, _ in ordered),
        files=tuple(r.file for _, r in ordered),
        plants=tuple(plants),
        values=tuple(values),
        drawn=drawn,
        source=source,
        source_files=source_files,
    )


def _plant(base: Plant, row: FleetRow, machine: str) -> Plant:
    """``base`` with the fit's parameters (0 for a term it left out)."""
    p = {k: float(row.params.get(k, 0.0)) for k in PARAMS}
    if not all(math.isfinite(v) for v in p.values()) or "gain_cps_per_v" not in row.params:
        raise SpecError(
            f"machine {show_value(machine)} ({row.file}): its fit has no finite gain, time "
            "constant and terms; fit its log again or leave it out of the table"
        )
    try:
        return replace(
            base,
            gain_cps_per_v=p["gain_cps_per_v"],
            tau_s=p["tau_s"],
            delay_s=p["delay_s"],
            offset_v=p["offset_v"],
            coulomb_v=p["coulomb_v"],
            gain_neg_cps_per_v=row.params.get("gain_neg_cps_per_v"),
            coulomb_neg_v=row.params.get("coulomb_neg_v"),
        )
    except ValueError as exc:
        raise SpecError(f"machine {show_value(machine)} ({row.file}): {exc}") from None
