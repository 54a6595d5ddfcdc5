"""The tuning file: what ``servotune tune`` produces and ``verify`` and ``export-table`` read.

A tuning holds, per axis, the runtime's constants exactly as they run: every constant as its
quantised ``(q, f)`` pair (SPEC §6: nothing is re-quantised later), the query tables as int16
entries with their fraction bits, the tick period and the timer divisor, the design values they
came from (floats, for people), and provenance (rig hash, tool version, seed).

The file is JSON with sorted keys, two-space indent and a trailing newline: the same tuning
gives the same bytes. ``"schema": "servotune.tuning/1"``.

The **workbench's current tuning** is ``.servotune/tuning.json`` under the working directory,
or under the directory named by the environment variable ``SERVOTUNE_WORKBENCH``;
``servotune tune`` writes it, ``servotune export-table`` without an argument reads it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from servotune.engine import Loop
from servotune.errors import TuningError
from servotune.laws.axis import AxisController
from servotune.logs import atomic_write_text, json_safe, read_json
from servotune.rig import Rig

__all__ = [
    "SCHEMA",
    "Tuning",
    "current_tuning_path",
    "file_sha256",
    "read_tuning",
    "tuning_to_string",
    "write_tuning",
]

SCHEMA = "servotune.tuning/1"
_PERIOD_RTOL = 1e-12


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes (hex), as recorded in provenance."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def current_tuning_path() -> Path:
    """Where the workbench keeps its current tuning (see the module docstring)."""
    root = os.environ.get("SERVOTUNE_WORKBENCH")
    return (Path(root) if root else Path(".servotune")) / "tuning.json"


@dataclass(frozen=True, slots=True, kw_only=True)
class Tuning:
    """A complete tuning of a rig, as the runtime will run it.

    Parameters
    ----------
    rig_name : str
        The rig's name.
    rig_sha256 : str
        SHA-256 of the rig file the tuning was made for.
    period_s : float
        Achieved tick period [s] (the constants fold it in).
    timer_divisor : int
        8253 divisor giving that period.
    axis_names, roles : tuple of str
        Axes in rig order.
    controllers : tuple of AxisController
        Per axis, the quantised constants (lock gain, task law, following-error limit).
    design : mapping
        Design values behind the constants (floats) and the tuner's results.
    provenance : mapping
        Tool version, seed, rig hash, rule base.
    """

    rig_name: str
    rig_sha256: str
    period_s: float
    timer_divisor: int
    axis_names: tuple[str, ...]
    roles: tuple[str, ...]
    controllers: tuple[AxisController, ...]
    design: Mapping[str, Any] = field(default_factory=dict, compare=False)
    provenance: Mapping[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        n = len(self.axis_names)
        if not (len(self.roles) == n == len(self.controllers)) or n == 0:
            raise TuningError(
                f"axis_names, roles and controllers must have one entry per axis, got "
                f"{len(self.axis_names)}, {len(self.roles)}, {len(self.controllers)}"
            )
        if not (self.period_s > 0 and math.isfinite(self.period_s)):
            raise TuningError(f"period_s must be > 0 [s], got {self.period_s!r}")

    @classmethod
    def for_rig(
        cls,
        rig: Rig,
        controllers: tuple[AxisController, ...],
        *,
        rig_sha256: str,
        design: Mapping[str, Any] | None = None,
        provenance: Mapping[str, Any] | None = None,
    ) -> Tuning:
        """A tuning of ``rig``: its name, period, timer divisor, axes and roles, these
        controllers (rig order), and the hash of the rig file they were made for."""
        return cls(
            rig_name=rig.name,
            rig_sha256=rig_sha256,
            period_s=rig.period_s,
            timer_divisor=rig.timer.divisor,
            axis_names=rig.axis_names,
            roles=tuple(a.role for a in rig.axes),
            controllers=controllers,
            design={} if design is None else design,
            provenance={} if provenance is None else provenance,
        )

    def check_rig(self, rig: Rig) -> None:
        """Raise :class:`TuningError` unless ``rig`` has the axes and period of this tuning."""
        if rig.axis_names != self.axis_names:
            raise TuningError(
                f"tuning is for axes {list(self.axis_names)}, rig {rig.name!r} has "
                f"{list(rig.axis_names)}"
            )
        if abs(rig.period_s - self.period_s) > _PERIOD_RTOL * self.period_s:
            raise TuningError(
                f"tuning is for a period of {self.period_s!r} s, rig {rig.name!r} runs at "
                f"{rig.period_s!r} s"
            )

    def loop(self, rig: Rig) -> Loop:
        """The closed loop of ``rig`` with these controllers (checked against the rig)."""
        self.check_rig(rig)
        return Loop(rig=rig, controllers=self.controllers)

    def controller(self, name: str) -> AxisController:
        """One axis's controller."""
        if name not in self.axis_names:
            raise TuningError(f"no axis {name!r} in the tuning; axes: {list(self.axis_names)}")
        return self.controllers[self.axis_names.index(name)]

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (the file's content)."""
        return {
            "axes": [
                {"controller": c.to_dict(), "name": name, "role": role}
                for name, role, c in zip(self.axis_names, self.roles, self.controllers, strict=True)
            ],
            "design": json_safe(self.design),
            "period_s": float(self.period_s),
            "provenance": json_safe(self.provenance),
            "rig": {"name": self.rig_name, "sha256": self.rig_sha256},
            "schema": SCHEMA,
            "timer_divisor": int(self.timer_divisor),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Tuning:
        """Inverse of :meth:`to_dict`; every field checked.

        Raises
        ------
        TuningError
            Wrong schema, missing or malformed field (the message names it).
        """
        if not isinstance(d, Mapping):
            raise TuningError("a tuning file must hold a JSON object")
        if d.get("schema") != SCHEMA:
            raise TuningError(f"schema must be {SCHEMA!r}, got {d.get('schema')!r}")
        try:
            axes = d["axes"]
            if not isinstance(axes, list) or not axes:
                raise TuningError("axes must be a non-empty list")
            ctls = []
            for i, a in enumerate(axes):
                try:
                    ctls.append(AxisController.from_dict(a["controller"]))
                except ValueError as exc:
                    raise TuningError(f"axes[{i}].controller: {exc}") from None
            period = d["period_s"]
            divisor = d["timer_divisor"]
            if not isinstance(period, float) or type(divisor) is not int:
                raise TuningError("period_s must be a number [s] and timer_divisor an integer")
            return cls(
                rig_name=str(d["rig"]["name"]),
                rig_sha256=str(d["rig"]["sha256"]),
                period_s=period,
                timer_divisor=divisor,
                axis_names=tuple(str(a["name"]) for a in axes),
                roles=tuple(str(a["role"]) for a in axes),
                controllers=tuple(ctls),
                design=d.get("design", {}),
                provenance=d.get("provenance", {}),
            )
        except KeyError as exc:
            raise TuningError(f"tuning file is missing the field {exc.args[0]!r}") from None
        except TypeError as exc:
            raise TuningError(f"tuning file is malformed: {exc}") from None


def tuning_to_string(tuning: Tuning) -> str:
    """The tuning file's text: sorted keys, deterministic bytes."""
    return json.dumps(tuning.to_dict(), sort_keys=True, indent=2, allow_nan=False) + "\n"


def write_tuning(tuning: Tuning, path: str | Path) -> None:
    """Write a tuning file atomically (temp file, then rename)."""
    atomic_write_text(path, tuning_to_string(tuning))


def read_tuning(path: str | Path) -> Tuning:
    """Read and check a tuning file.

    Raises
    ------
    TuningError
        If the file is missing, not JSON, or not a valid tuning.
    """
    p = Path(path)
    data = read_json(p, TuningError, "no such tuning file")
    try:
        return Tuning.from_dict(data)
    except TuningError as exc:
        raise TuningError(f"{p}: {exc}") from None
