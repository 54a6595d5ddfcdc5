"""Rule tables and rule bases of the fuzzy-PID: the seven sets, parsing, the stored bases.

A rule table is 7×7 (rows ``e`` NB…PB, columns ``ec`` NB…PB), each entry the output set of a
ΔK for that pair; a :class:`RuleBase` holds the four tables ΔKp, ΔKi, ΔKd, ΔK1.
:data:`CLASSIC_RULES` are the textbook tables, :data:`DEFAULT_RULES` servotune's
direction-independent ones. Evaluated by :mod:`servotune.fuzzy.inference`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune.errors import SpecError
from servotune.laws.fuzzy_pid import TABLE_NAMES

__all__ = [
    "CLASSIC_RULES",
    "DEFAULT_RULES",
    "SETS",
    "RuleBase",
    "RuleTable",
    "format_rules",
    "parse_rules",
    "table_indices",
]

SETS = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")
"""The seven linguistic sets, from negative big to positive big."""

RuleTable = tuple[tuple[str, ...], ...]
"""A 7×7 rule table: rows ``e`` NB…PB, columns ``ec`` NB…PB, entries set names."""

N_SETS = len(SETS)
INDEX = {name: k for k, name in enumerate(SETS)}


def rule_table(x: Any, name: str) -> RuleTable:
    """Normalise a rule table (compact text or 7×7 names) to a tuple of tuples, validated."""
    if isinstance(x, str):
        rows: list[Any] = [r for r in x.replace("\n", "|").split("|") if r.strip()]
    elif isinstance(x, Sequence | np.ndarray):
        rows = list(x)
    else:
        raise SpecError(
            f"{name} must be a 7×7 rule table (text 'PB PB … | …' or rows of set names), "
            f"got {type(x).__name__}"
        )
    if len(rows) != N_SETS:
        raise SpecError(f"{name} must have 7 rows (e NB…PB), got {len(rows)}")
    out = []
    for i, row in enumerate(rows):
        if not isinstance(row, str | Sequence | np.ndarray):
            raise SpecError(f"{name} row {i} (e = {SETS[i]}) must be set names, got {row!r}")
        cells = row.split() if isinstance(row, str) else list(row)
        if len(cells) != N_SETS:
            raise SpecError(
                f"{name} row {i} (e = {SETS[i]}) must have 7 entries (ec NB…PB), got {len(cells)}"
            )
        for j, cell in enumerate(cells):
            if not isinstance(cell, str) or cell not in INDEX:
                raise SpecError(
                    f"{name}[{i}][{j}] (e = {SETS[i]}, ec = {SETS[j]}) must be one of "
                    f"{' '.join(SETS)}, got {cell!r}"
                )
        out.append(tuple(str(c) for c in cells))
    return tuple(out)


# --- rule tables and rule bases ---------------------------------------------------------------


def parse_rules(text: str, *, name: str = "rules") -> RuleTable:
    """Parse a rule table from its compact text form.

    Parameters
    ----------
    text : str
        Seven rows (``e`` NB…PB) separated by ``|`` (or newlines), each seven set names
        (``ec`` NB…PB) separated by spaces, e.g. ``"PB PB PM PM PS ZO ZO | PB PB …"``.
    name : str
        Field name used in error messages.

    Returns
    -------
    RuleTable
        Tuple of 7 rows of 7 set names.

    Raises
    ------
    SpecError
        If the text is not a 7×7 table of names from :data:`SETS`.

    Examples
    --------
    >>> t = parse_rules(" | ".join(["ZO ZO ZO ZO ZO ZO ZO"] * 6 + ["PB PB PB PB PB PB PB"]))
    >>> t[6][0], t[0][6]
    ('PB', 'ZO')
    """
    if not isinstance(text, str):
        raise SpecError(f"{name} must be a text rule table, got {type(text).__name__}")
    return rule_table(text, name)


def format_rules(table: RuleTable | str) -> str:
    """The compact text form of a rule table (rows joined by ``" | "``).

    Parameters
    ----------
    table : RuleTable or str
        A valid rule table.

    Returns
    -------
    str
        ``"r0c0 r0c1 … | r1c0 …"``; :func:`parse_rules` reads it back.
    """
    return " | ".join(" ".join(row) for row in rule_table(table, "table"))


def table_indices(table: RuleTable) -> np.ndarray:
    """A rule table as set indices 0 (NB) … 6 (PB), an int64 array of shape (7, 7)."""
    return np.array([[INDEX[c] for c in row] for row in table], dtype=np.int64)


_ALL_ZO = tuple(("ZO",) * N_SETS for _ in range(N_SETS))


@dataclass(frozen=True, slots=True, kw_only=True)
class RuleBase:
    """The four rule tables of the fuzzy self-tuning PID + feedforward.

    Each table has rows ``e`` NB…PB and columns ``ec`` NB…PB; an entry is the output set of
    ``ΔK`` for that pair. A table may be given as compact text (:func:`parse_rules`) or as rows
    of set names; it is stored as a :data:`RuleTable` (tuple of tuples).

    Parameters
    ----------
    kp : RuleTable or str
        ΔKp rules (normalised units; the law scales them to [codes/count]).
    ki : RuleTable or str
        ΔKi rules.
    kd : RuleTable or str
        ΔKd rules.
    k1 : RuleTable or str
        ΔK1 rules (feedforward differential coefficient); default all ZO.
    name : str
        A label carried into the query tables and exports.

    Raises
    ------
    SpecError
        If a table is not 7×7 or holds a name not in :data:`SETS`.
    """

    kp: RuleTable | str
    ki: RuleTable | str
    kd: RuleTable | str
    k1: RuleTable | str = _ALL_ZO
    name: str = "custom"

    def __post_init__(self) -> None:
        for t in TABLE_NAMES:
            object.__setattr__(self, t, rule_table(getattr(self, t), t))
        if not isinstance(self.name, str) or not self.name:
            raise SpecError(f"name must be a non-empty string, got {self.name!r}")

    def table(self, which: str) -> RuleTable:
        """The rule table ``which`` (one of :data:`TABLE_NAMES`)."""
        if which not in TABLE_NAMES:
            raise SpecError(f"table must be one of {', '.join(TABLE_NAMES)}, got {which!r}")
        return rule_table(getattr(self, which), which)

    def indices(self, which: str) -> np.ndarray:
        """Rule table ``which`` as set indices 0 (NB) … 6 (PB), int array of shape (7, 7)."""
        return table_indices(self.table(which))

    def to_dict(self) -> dict[str, str]:
        """Plain dict: the name and each table in compact text form (``RuleBase(**d)`` reads it)."""
        out = {t: format_rules(getattr(self, t)) for t in TABLE_NAMES}
        out["name"] = self.name
        return dict(sorted(out.items()))


CLASSIC_RULES = RuleBase(
    name="classic",
    kp=(
        "PB PB PM PM PS ZO ZO | PB PB PM PS PS ZO NS | PM PM PM PS ZO NS NS | "
        "PM PM PS ZO NS NM NM | PS PS ZO NS NS NM NM | PS ZO NS NM NM NM NB | "
        "ZO ZO NM NM NM NB NB"
    ),
    ki=(
        "NB NB NM NM NS ZO ZO | NB NB NM NS NS ZO ZO | NB NM NS NS ZO PS PS | "
        "NM NM NS ZO PS PM PM | NM NS ZO PS PS PM PB | ZO ZO PS PS PM PB PB | "
        "ZO ZO PS PM PM PB PB"
    ),
    kd=(
        "PS NS NB NB NB NM PS | PS NS NB NM NM NS ZO | ZO NS NM NM NS NS ZO | "
        "ZO NS NS NS NS NS ZO | ZO ZO ZO ZO ZO ZO ZO | PB NS PS PS PS PS PB | "
        "PB PM PM PM PS PS PB"
    ),
)
"""The classic textbook fuzzy self-tuning PID rules (ΔKp, ΔKi, ΔKd; ΔK1 all ZO).

These tables are not direction-independent: they assume a step that starts with a large
positive error, and give different gains to the mirrored state ``(−e, −ec)``.
"""

DEFAULT_RULES = RuleBase(
    name="default",
    # ΔKp: |e| large → more Kp (PB at ec = 0); e, ec same sign (error growing) → push harder;
    # opposite sign (converging) → back off, the faster the convergence the more.
    kp=(
        "PB PB PB PB PM PS ZO | PB PB PM PM PS ZO NS | PM PM PS PS ZO NS NS | "
        "PS PS ZO ZO ZO PS PS | NS NS ZO PS PS PM PM | NS ZO PS PM PM PB PB | "
        "ZO PS PM PB PB PB PB"
    ),
    # ΔKi: |e| large → least Ki (windup, overshoot); near zero → most Ki (the steady lag);
    # converging fast → less Ki (the integrator would carry the axis past the target).
    ki=(
        "NB NB NB NB NB NB NB | NM NM NS NS NM NM NB | PS PS PM PM PS ZO NS | "
        "ZO PS PM PB PM PS ZO | NS ZO PS PM PM PS PS | NB NM NM NS NS NM NM | "
        "NB NB NB NB NB NB NB"
    ),
    # ΔKd: converging (opposite signs) → more Kd to brake, more the faster; growing with a large
    # |e| → less Kd (the P term acts, no derivative kick); near zero → a little more Kd when ec is
    # large (damps the crossing), none when the axis is at rest (no noise amplification).
    kd=(
        "NS NS NM NM ZO PS PM | ZO ZO NS NS PS PM PB | PS PS ZO ZO PS PM PM | "
        "PM PS PS ZO PS PS PM | PM PM PS ZO ZO PS PS | PB PM PS NS NS ZO ZO | "
        "PM PS ZO NM NM NS NS"
    ),
)
"""servotune's rule base for position servos (ΔK1 all ZO).

**Direction-independent**: every table is invariant under 180° rotation,
``rule[6−i][6−j] == rule[i][j]``, so ``ΔK(−E, −EC) = ΔK(E, EC)``: a servo that tracks in both
directions sees the same gains either way. Each entry depends only on ``|e|``, ``|ec|`` and
whether the error is growing (``e``, ``ec`` of the same sign) or converging (opposite signs).

ΔKp
    Not decreasing with ``|E|`` at ``EC = 0`` (ZO, PS, PM, PB): a large error gets a stiff loop
    and a fast response. A growing error gets one step more (push harder); a converging error
    gets less, down to NS when it converges fast from a small or medium error, to brake before
    the target (no overshoot).
ΔKi
    Not increasing with ``|E|`` at ``EC = 0`` (PB, PM, NS, NB): a large error is the P term's
    job, and integrating it winds up and overshoots; near zero the integrator removes the steady
    lag (friction, drift, what the feedforward misses). It is cut further while the error
    converges fast, since the stored integral would carry the axis past the target.
ΔKd
    Raised when converging (opposite signs), the more the faster: the derivative brakes the
    approach. Lowered for a large growing error (the P term acts; no derivative kick at a
    reference step). At ``e ≈ 0`` a little more Kd when ``|ec|`` is large damps the crossing,
    none at rest so that encoder quantisation noise is not amplified.
ΔK1
    All ZO: ``K1`` stays at its base, the ideal velocity feedforward, over the whole table.
"""
