"""The tuning file: what ``servotune tune`` produces and ``verify`` and ``export-table`` read.

A tuning holds, per axis, the runtime's constants exactly as they run: every constant as its
quantised ``(q, f)`` pair (docs/runtime.md#fixed-point-constants: nothing is re-quantised later),
the query tables as int16 entries with their fraction bits, the tick period and the timer divisor,
the design values they came from (floats, for people), and provenance (rig hash, tool version,
seed).

The file is JSON with sorted keys, two-space indent and a trailing newline: the same tuning
gives the same bytes. ``"schema": "servotune.tuning/2"`` (``/2`` added the rig file's path;
a ``/1`` file is refused with a request to re-run ``servotune tune``).

Reading is strict: every key known (an unknown one is named with the closest known one), every
integer an integer (not ``6.0`` nor ``"6"``), roles ``master``/``slave``, numbers finite.
:func:`read_tuning_bytes` parses the bytes a caller already holds, so ``verify`` hashes exactly
what it verified.

The **workbench's current tuning** is ``.servotune/tuning.json`` under the working directory,
or under the directory named by the environment variable ``SERVOTUNE_WORKBENCH``;
``servotune tune`` writes it, ``servotune export-table`` without an argument reads it.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from servotune.errors import TuningError
from servotune.io.files import atomic_write_text, json_safe, json_text, parse_json_as, read_bytes
from servotune.laws.axis import AxisController
from servotune.rig import ROLES, Rig
from servotune.sim.engine import Loop
from servotune.validate import check_keys, show_value

__all__ = [
    "SCHEMA",
    "Tuning",
    "current_tuning_path",
    "file_sha256",
    "read_tuning",
    "read_tuning_bytes",
    "tuning_to_string",
    "write_tuning",
]

SCHEMA = "servotune.tuning/2"
_OLD_SCHEMAS = ("servotune.tuning/1",)
_SHA256 = re.compile(r"[0-9a-f]{64}")
_MAX_NAME = 256  # characters of a rig or axis name, a path: 4096
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
        The rig's name (its file's ``name``).
    rig_sha256 : str
        SHA-256 of the rig file the tuning was made for.
    rig_path : str
        That rig file's path as the user gave it to ``tune`` ("" if unknown); ``verify`` and
        ``export-table`` look for the rig there first.
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
    axis_names: tuple[str, ...]
    period_s: float
    timer_divisor: int
    roles: tuple[str, ...]
    controllers: tuple[AxisController, ...]
    design: Mapping[str, Any] = field(default_factory=dict, compare=False)
    provenance: Mapping[str, Any] = field(default_factory=dict, compare=False)
    rig_path: str = field(default="", compare=False)

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
        rig_path: str | Path = "",
        design: Mapping[str, Any] | None = None,
        provenance: Mapping[str, Any] | None = None,
    ) -> Tuning:
        """A tuning of ``rig``: its name, period, timer divisor, axes and roles, these
        controllers (rig order), and the hash and path of the rig file they were made for."""
        return cls(
            rig_name=rig.name,
            rig_sha256=rig_sha256,
            rig_path=Path(rig_path).as_posix() if str(rig_path) else "",
            period_s=rig.period_s,
            timer_divisor=rig.timer.divisor,
            axis_names=rig.axis_names,
            roles=tuple(a.role for a in rig.axes),
            controllers=controllers,
            design={} if design is None else design,
            provenance={} if provenance is None else provenance,
        )

    def check_rig(self, rig: Rig) -> None:
        """Raise :class:`TuningError` unless ``rig`` has the axes, roles, period and timer
        divisor of this tuning (the divisor is exported: the runtime programs its timer with
        it, so one the rig's clock does not turn into the verified period is refused)."""
        if rig.axis_names != self.axis_names:
            raise TuningError(
                f"tuning is for axes {list(self.axis_names)}, rig {rig.name!r} has "
                f"{list(rig.axis_names)}"
            )
        roles = tuple(a.role for a in rig.axes)
        if roles != self.roles:
            raise TuningError(
                f"tuning is for axis roles {list(self.roles)}, rig {rig.name!r} has {list(roles)}"
            )
        if abs(rig.period_s - self.period_s) > _PERIOD_RTOL * self.period_s:
            raise TuningError(
                f"tuning is for a period of {self.period_s!r} s, rig {rig.name!r} runs at "
                f"{rig.period_s!r} s"
            )
        if rig.timer.divisor != self.timer_divisor:
            raise TuningError(
                f"tuning is for timer divisor {self.timer_divisor}, rig {rig.name!r} programs "
                f"{rig.timer.divisor}"
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
            "rig": {"name": self.rig_name, "path": self.rig_path, "sha256": self.rig_sha256},
            "schema": SCHEMA,
            "timer_divisor": int(self.timer_divisor),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Tuning:
        """Inverse of :meth:`to_dict`; every field checked (see the module docstring).

        Raises
        ------
        TuningError
            Wrong or old schema, a missing, unknown or malformed field (the message names it).
        """
        if not isinstance(d, dict):
            raise TuningError("a tuning file must hold a JSON object")
        schema = d.get("schema")
        if schema in _OLD_SCHEMAS:
            raise TuningError(
                f"{schema} was written by an older servotune; re-run `servotune tune` (and "
                "`servotune verify`)"
            )
        if schema != SCHEMA:
            raise TuningError(f"schema must be {SCHEMA!r}, got {show_value(schema)}")
        try:
            check_keys(
                d,
                "",
                ("axes", "period_s", "rig", "schema", "timer_divisor"),
                ("design", "provenance"),
            )
            rig = check_keys(d["rig"], "rig", ("name", "path", "sha256"))
            axes = d["axes"]
            if not isinstance(axes, list) or not 1 <= len(axes) <= 16:
                raise ValueError("axes must be a list of 1 to 16 axes")
            names, roles, ctls = [], [], []
            for i, a in enumerate(axes):
                a = check_keys(a, f"axes[{i}]", ("controller", "name", "role"))
                names.append(_text(a["name"], f"axes[{i}].name", _MAX_NAME))
                if a["role"] not in ROLES:
                    got = show_value(a["role"])
                    raise ValueError(f"axes[{i}].role must be one of {', '.join(ROLES)}, got {got}")
                roles.append(a["role"])
                try:
                    ctls.append(AxisController.from_dict(a["controller"]))
                except ValueError as exc:
                    raise ValueError(f"axes[{i}].controller: {exc}") from None
            if len(set(names)) != len(names):
                raise ValueError(f"axis names must differ, got {names}")
            period, divisor = d["period_s"], d["timer_divisor"]
            if type(period) is not float or not 0 < period < 1:
                raise ValueError(
                    f"period_s must be a number in (0, 1) [s], got {show_value(period)}"
                )
            if type(divisor) is not int or not 2 <= divisor <= 65536:
                raise ValueError(
                    f"timer_divisor must be an integer in 2..65536, got {show_value(divisor)}"
                )
            sha = rig["sha256"]
            if not isinstance(sha, str) or not _SHA256.fullmatch(sha):
                raise ValueError(
                    f"rig.sha256 must be 64 lower-case hex digits, got {show_value(sha)}"
                )
            for key in ("design", "provenance"):
                if not isinstance(d.get(key, {}), dict):
                    raise ValueError(f"{key} must be an object")
            return cls(
                rig_name=_text(rig["name"], "rig.name", _MAX_NAME),
                rig_sha256=sha,
                rig_path=_text(rig["path"], "rig.path", 4096, empty=True),
                period_s=period,
                timer_divisor=divisor,
                axis_names=tuple(names),
                roles=tuple(roles),
                controllers=tuple(ctls),
                design=d.get("design", {}),
                provenance=d.get("provenance", {}),
            )
        except TuningError:
            raise
        except ValueError as exc:
            raise TuningError(str(exc)) from None


def _text(v: object, where: str, max_len: int, *, empty: bool = False) -> str:
    if not isinstance(v, str) or len(v) > max_len or (not v and not empty):
        what = "a string" if empty else "a non-empty string"
        raise ValueError(
            f"{where} must be {what} of at most {max_len} characters, got {show_value(v)}"
        )
    return v


def tuning_to_string(tuning: Tuning) -> str:
    """The tuning file's text: sorted keys, deterministic bytes."""
    return json_text(tuning.to_dict())


def write_tuning(tuning: Tuning, path: str | Path) -> None:
    """Write a tuning file atomically (temp file, then rename)."""
    atomic_write_text(path, tuning_to_string(tuning))


def read_tuning_bytes(raw: bytes, src: str) -> Tuning:
    """Parse and check a tuning from the file's bytes (``src`` names it in messages).

    Raises
    ------
    TuningError
        Not UTF-8 JSON, or not a valid tuning (one line naming ``src`` and the field).
    """
    return parse_json_as(raw, src, TuningError, Tuning.from_dict, "utf-8-sig")


def read_tuning(path: str | Path) -> Tuning:
    """Read and check a tuning file (:func:`read_tuning_bytes` of its bytes).

    Raises
    ------
    TuningError
        If the file is missing, not JSON, or not a valid tuning.
    """
    raw = read_bytes(path, TuningError, "tuning file", "no such tuning file")
    return read_tuning_bytes(raw, str(path))
