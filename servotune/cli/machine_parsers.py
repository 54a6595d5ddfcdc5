"""The parsers of the verbs for a machine's resonance and its live loop: ``shaper`` and
``autotune`` (:mod:`servotune.cli.parser` adds them with its verb factory)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from servotune.cli.measure import cmd_autotune, cmd_shaper

__all__ = ["SHAPER_KINDS", "add_autotune", "add_shaper"]

SHAPER_KINDS = ("zv", "zvd", "ei")
"""servotune.laws.shaping.KINDS, named here so that ``--help`` loads neither numba nor scipy
(tests/cli/test_shaper_cli.py checks they agree)."""


def add_autotune(sub: Any, verb: Callable[..., Any]) -> None:
    """The ``autotune`` verb and its options."""
    s = verb(
        sub,
        cmd_autotune,
        "autotune",
        help="auto-tune a LinuxCNC axis in its running HAL session (--dry-run: the plan only)",
    )
    s.add_argument("config", help="autotune config (TOML), e.g. plants/linuxcnc-autotune.toml")
    s.add_argument(
        "--dry-run",
        action="store_true",
        help="print the plan (signals, amplitudes, durations, predicted travel and speed) and "
        "touch nothing",
    )
    s.add_argument("--json", action="store_true", help="the plan (or the run's record) as JSON")
    s.add_argument(
        "--target",
        choices=("pid", "component"),
        help="what the run loads, instead of the config's autotune.target: the stock pid's "
        "parameters, or the verified runtime component (needs hal.counts_pin)",
    )
    s.add_argument(
        "-o",
        "--output-dir",
        default="autotune",
        help="the live run's files: capture, fitted rig, tuning, pid file, record (default "
        "./autotune)",
    )
    s.add_argument(
        "--guard-output",
        metavar="FILE",
        help="write the safety envelope's HAL component (.comp, halcompile it)",
    )
    s.add_argument(
        "--guard-name", default="servotune_guard", help="its name (default servotune_guard)"
    )
    s.add_argument(
        "--hal-user",
        metavar="USER",
        help="run HAL's programs as USER, the session's owner (when servotune runs as root)",
    )


def add_shaper(sub: Any, verb: Callable[..., Any]) -> None:
    """The ``shaper`` verb and its options."""
    s = verb(
        sub,
        cmd_shaper,
        "shaper",
        help="design an input shaper for an axis's modes (its taps, added move time, residual "
        "vibration) and optionally its HAL component",
    )
    s.add_argument("rig", help="rig file (TOML) whose axis has [[axis.X.plant.modes]]")
    s.add_argument("--axis", help="the axis (default: the master)")
    s.add_argument(
        "--kind",
        default="auto",
        choices=("auto", *SHAPER_KINDS),
        help="zv, zvd, ei, or auto (default): per mode the shortest that keeps the residual "
        "vibration at or below 5 %% over the mode's 95 %% interval (at least ±5 %%)",
    )
    s.add_argument(
        "--tuning",
        metavar="FILE",
        help="design for the loop this tuning runs (its task PI; a fuzzy-PID's base gains); "
        "default: the loop-shaping PI simulate uses",
    )
    s.add_argument("--json", action="store_true", help="JSON on stdout")
    s.add_argument(
        "--hal-output", metavar="FILE", help="also write the shaper's HAL component (.comp)"
    )
    s.add_argument(
        "--hal-name",
        default="servotune_shaper",
        help="the HAL component's name (default servotune_shaper)",
    )
