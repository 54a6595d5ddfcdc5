"""What every figure of the report must carry: axis labels with units."""

from __future__ import annotations

import re

from matplotlib.axes import Axes
from matplotlib.figure import Figure

UNIT = re.compile(r"[\[(][^\[\]()]+[\])]")
"""A unit in brackets or parentheses: ``[counts]``, ``[s]``, ``(deg)``, ``[1]``."""


def _labelled(label: str) -> bool:
    return bool(label.strip()) and UNIT.search(label) is not None


def _x_label(ax: Axes) -> str:
    """The axes' x label, or that of an axes sharing its x axis (stacked panels label the
    time axis once, under the bottom panel)."""
    if ax.get_xlabel().strip():
        return ax.get_xlabel()
    for other in ax.get_shared_x_axes().get_siblings(ax):
        if other is not ax and other.get_xlabel().strip():
            return other.get_xlabel()
    return ""


def axis_unit_problems(fig: Figure) -> list[str]:
    """Every axes of ``fig`` without an x or y label holding a unit (empty: all labelled).

    A colour bar's axes needs only its long axis labelled (the quantity the colours show).
    """
    out = []
    for i, ax in enumerate(fig.axes):
        name = f"axes {i} ({ax.get_title() or ax.get_label() or type(ax).__name__})"
        bar = getattr(ax, "_colorbar", None)
        if bar is not None:
            long_label = ax.get_ylabel() if bar.orientation == "vertical" else ax.get_xlabel()
            if not _labelled(long_label):
                out.append(f"{name}: colour bar label {long_label!r} has no unit")
            continue
        for which, label in (("x", _x_label(ax)), ("y", ax.get_ylabel())):
            if not _labelled(label):
                out.append(f"{name}: {which} label {label!r} has no unit in brackets")
    return out
