"""Tuning a rig end to end (what ``servotune tune`` runs) and the Figure-4 comparison.

:func:`tune_rig`: the master's PI by :func:`~servotune.tune.pi.tune_pi` on its axis model, the
slave's composite fuzzy-PID + feedforward by :func:`~servotune.tune.slave.tune_slave` starting
from a PI designed the same way for the slave, the rule base evaluated into query tables by
:mod:`servotune.fuzzy`; everything quantised into a :class:`~servotune.tuning.Tuning`.

:func:`compare_structures`: the paper's Figure 4 on our models. Conventional PID, PID + the same
feedforward, and composite control are each tuned by the same optimiser with the same budget,
then run on the nominal rig through the tuning scenario; the table holds max and RMS sync error
and the start transient's rise and settling (of the slave's speed, 10–90 % and 2 %).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from servotune import fuzzy
from servotune._version import __version__
from servotune.errors import InfeasibleError, SpecError
from servotune.io.files import json_float
from servotune.metrics import step_info
from servotune.rig import Rig, load_rig
from servotune.scenarios import _sync_move_for
from servotune.sim.engine import Loop, Trace, simulate
from servotune.tune.pi import DEFAULT_TARGETS, tune_pi_axis
from servotune.tune.slave import (
    STRUCTURES,
    SlaveTuneSpec,
    SlaveTuning,
    _master_slave,
    tune_slave,
)
from servotune.tuning import Tuning, file_sha256

__all__ = [
    "MASTER_TARGETS",
    "Comparison",
    "compare_structures",
    "rule_tables",
    "tune_rig",
]

MASTER_TARGETS: Mapping[str, float] = DEFAULT_TARGETS
"""Default robustness targets of the PI designs (master, and the slave's start point)."""


def rule_tables(rule_base: str = "default", *, n: int = 6) -> dict[str, np.ndarray]:
    """Normalised query tables (values in [−1, 1]) of a rule base: ``default`` or ``classic``."""
    bases = {"classic": fuzzy.CLASSIC_RULES, "default": fuzzy.DEFAULT_RULES}
    if rule_base not in bases:
        raise SpecError(f"rule_base must be one of {', '.join(sorted(bases))}, got {rule_base!r}")
    qt = fuzzy.query_tables(bases[rule_base], n=n)
    return {t: np.asarray(getattr(qt, t)) for t in ("kp", "ki", "kd", "k1")}


def _pi_designs(rig: Rig, targets: Mapping[str, float]) -> tuple[Any, Any]:
    i_m, i_s = _master_slave(rig)
    return (
        tune_pi_axis(rig, rig.axes[i_m].name, **targets),
        tune_pi_axis(rig, rig.axes[i_s].name, **targets),
    )


def tune_rig(
    rig_path: str | Path,
    *,
    seed: int = 0,
    spec: SlaveTuneSpec | None = None,
    rule_base: str = "default",
    master_targets: Mapping[str, float] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Tuning:
    """Tune a rig: master PI, slave composite law; the result as the runtime will run it.

    Parameters
    ----------
    rig_path : str or Path
        Rig file (its SHA-256 goes into the provenance).
    seed : int
        Optimiser and noise seed: same rig, options and seed give the same tuning file bytes.
    spec : SlaveTuneSpec, optional
        Slave tuning run, constraints and budget.
    rule_base : {"default", "classic"}
        Rule base of the query tables.
    master_targets : mapping, optional
        Keyword targets for :func:`~servotune.tune.pi.tune_pi` (default :data:`MASTER_TARGETS`).
    progress : callable, optional
        Receives one line per step (the CLI prints them on stderr).

    Returns
    -------
    Tuning
    """
    rig = load_rig(rig_path)
    spec = spec or SlaveTuneSpec()
    targets = dict(MASTER_TARGETS if master_targets is None else master_targets)
    say = progress or (lambda _msg: None)
    i_m, i_s = _master_slave(rig)
    say(f"tune: PI for {rig.axes[i_m].name} and the start point of {rig.axes[i_s].name}")
    master_pi, slave_pi = _pi_designs(rig, targets)
    tables = rule_tables(rule_base)
    slave = tune_slave(
        rig,
        master_pi.gains,
        structure="composite",
        tables=tables,
        start=slave_pi.gains,
        spec=spec,
        seed=seed,
        progress=progress,
    )
    if not slave.feasible:
        raise InfeasibleError(
            "no slave tuning met the constraints (saturation <= "
            f"{spec.max_saturation_pct} %, overshoot <= {spec.max_overshoot_pct} %); "
            f"best worst case: {dict(slave.worst)}"
        )
    gains: list[object | None] = [None] * len(rig.axes)
    gains[i_m], gains[i_s] = master_pi.gains, slave.gains
    ctls = Loop.from_rig(rig, gains).controllers
    kept = "keeps" if slave.start_feasible else "breaks"
    say(f"tune: sync-error ITAE {slave.start_objective:.4g} counts·s² at the start (which {kept} "
        f"the constraints), {slave.objective:.4g} tuned")  # fmt: skip
    rig_sha256 = file_sha256(rig_path)
    return Tuning.for_rig(
        rig,
        ctls,
        rig_sha256=rig_sha256,
        rig_path=rig_path,
        design={
            "master": {"axis": rig.axes[i_m].name, "pi": master_pi.to_dict()},
            "slave": {
                "axis": rig.axes[i_s].name,
                "start_pi": slave_pi.to_dict(),
                "tuning": slave.to_dict(),
            },
            "spec": spec.to_dict(),
            "pi_targets": targets,
        },
        provenance={
            "rig_sha256": rig_sha256,
            "rule_base": rule_base,
            "seed": seed,
            "tool": "servotune",
            "tool_version": __version__,
        },
    )


# --- Figure 4 --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Comparison:
    """The Figure-4 comparison: per structure its tuning, nominal trace and table row.

    Attributes
    ----------
    tunings : dict of str to SlaveTuning
    traces : dict of str to Trace
        Nominal rig (noise included), the tuning scenario.
    table : dict of str to dict
        Per structure: ``max_sync_counts``, ``rms_sync_counts`` (task ticks), ``rise_s`` and
        ``settling_s`` of the slave's speed over the start transient, ``itae`` (the objective).
    """

    tunings: Mapping[str, SlaveTuning]
    traces: Mapping[str, Trace] = field(repr=False)
    table: Mapping[str, Mapping[str, float]]

    def winner(self, column: str) -> str:
        """Structure with the smallest value of a table column."""
        return min(self.table, key=lambda s: self.table[s][column])

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (the table and the tunings)."""
        return {
            "table": {
                s: {k: json_float(v) for k, v in row.items()} for s, row in self.table.items()
            },
            "tunings": {s: t.to_dict() for s, t in self.tunings.items()},
        }


def _row(trace: Trace, rig: Rig, i_s: int, start: int, load_tick: int) -> dict[str, float]:
    task = trace.mode[:, i_s] == 1
    e = trace.err_counts[task, i_s].astype(float)
    # start transient: from the master's start to just before the load step
    t = trace.time_s[start:load_tick] - trace.time_s[start]
    v = trace.speed_cps[start:load_tick, i_s]
    info = step_info(t, v, y_init=0.0, y_final=float(np.mean(v[-10:])))
    return {
        "max_sync_counts": float(np.max(np.abs(e))),
        "rms_sync_counts": float(np.sqrt(np.mean(e * e))),
        "rise_s": info.rise_time_s,
        "settling_s": info.settling_time_s,
    }


def compare_structures(
    rig: Rig,
    *,
    rule_base: str = "default",
    spec: SlaveTuneSpec | None = None,
    seed: int = 0,
    master_targets: Mapping[str, float] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Comparison:
    """Tune PID, PID + feedforward and composite with the same optimiser and budget; compare.

    Returns
    -------
    Comparison
    """
    spec = spec or SlaveTuneSpec()
    targets = dict(MASTER_TARGETS if master_targets is None else master_targets)
    i_m, i_s = _master_slave(rig)
    master_pi, slave_pi = _pi_designs(rig, targets)
    tables = rule_tables(rule_base)
    scen = _sync_move_for(rig, spec)
    mode = scen.inputs.mode[:, i_s]
    start = int(np.argmax(mode == 1))
    load_tick = int(np.argmax(scen.inputs.load_v[:, i_s] != 0.0)) or mode.size
    tunings, traces, table = {}, {}, {}
    for structure in STRUCTURES:
        res = tune_slave(
            rig,
            master_pi.gains,
            structure=structure,
            tables=tables if structure == "composite" else None,
            start=slave_pi.gains,
            spec=spec,
            seed=seed,
            progress=progress,
        )
        gains: list[object | None] = [None] * len(rig.axes)
        gains[i_m], gains[i_s] = master_pi.gains, res.gains
        tr = simulate(Loop.from_rig(rig, gains), scen.inputs, seed=seed)
        tunings[structure], traces[structure] = res, tr
        table[structure] = {**_row(tr, rig, i_s, start, load_tick), "itae": res.objective}
    return Comparison(tunings=tunings, traces=traces, table=table)
