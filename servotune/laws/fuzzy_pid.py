"""Composite control of the slave axis: fuzzy-PID plus feedforward differential
(docs/systems.md#pc-dual-servo-synchronisation).

Design terms (``T`` the tick period, ``e = r − y`` [counts], ``ec = e(k) − e(k−1)``,
``Δr = r(k) − r(k−1)``, ``r`` the slave's reference, i.e. the master's position)::

    u = (Kp0 + ΔKp)·e + I + (Kd0 + ΔKd)·ec/T + (K10 + ΔK1)·Δr/T
    I(k) = I(k−1) + (Ki0 + ΔKi)·T·e

where each ``ΔKx`` is read from its **query table** at the fuzzy levels
``E = clamp(round(e·Ke), −n, n)``, ``EC = clamp(round(ec·Kec), −n, n)`` (row ``E``, column
``EC``). ``K10 + ΔK1`` is the feedforward differential coefficient ``K1``; its default is the
ideal velocity feedforward (``ΔK1 = 0``). Conventional PID is the same law with zero tables and
``K1 = 0``; PID + feedforward has zero tables.

At run time (docs/runtime.md#the-period-folded-into-the-gains) the period is folded into the
constants: ``Kp``, ``Ki·T``, ``Kd/T``, ``K1/T``, every base gain an int32 ``(q, f)`` pair, every
table int16 entries with their own ``f_t ≤ f``. A scheduled gain is ``q + t·2^(f − f_t)`` at ``f``
fraction bits (exact, no shift of a negative value). The base gain's ``f`` is chosen from the
largest magnitude the scheduled gain can take (:meth:`FuzzyPIDGains.quantize`), which bounds every
scheduled gain by ``2^32`` and so every product with a clamped error (``< 2^31``) by ``2^63``: the
products cannot overflow. The terms are aligned to ``F_U`` fraction bits (saturating) and summed
with saturating adds; the integrator, its conditional integration and the bumpless entry are the
PI's (:func:`~servotune.laws.pi.pi_step`, :func:`~servotune.laws.pi.pi_enter`): a change of the
scheduled ``Ki·T`` never makes ``u`` jump because ``I`` is stored as output.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from servotune._numba_cache import jit
from servotune.fixed import (
    F_U,
    Fixed,
    align,
    clamp_e,
    quantize,
    quantize_table,
    sat_add,
    shift_round,
)
from servotune.validate import check_keys, show_value

__all__ = [
    "TABLE_NAMES",
    "FuzzyPIDConstants",
    "FuzzyPIDGains",
    "feed_terms",
    "fuzzy_level",
    "int_rows",
    "scheduled_gain",
]

TABLE_NAMES = ("kp", "ki", "kd", "k1")
"""The four query tables, in the order the runtime stores them (ΔKp, ΔKi·T, ΔKd/T, ΔK1/T)."""

_GAIN_LIMIT = 2**32 - 1  # |Kx0 + ΔKx| in q units: keeps every product with |e| < 2^31 in int64
_LEVEL_LIMIT = 64  # largest n: tables of (2n+1)^2 int16 entries


def _table_array(name: str, x: Any, n: int) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    size = 2 * n + 1
    if a.shape != (size, size):
        raise ValueError(f"table {name} must have shape ({size}, {size}) for n={n}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"table {name} has non-finite entries")
    return a


@dataclass(frozen=True, slots=True, kw_only=True)
class FuzzyPIDGains:
    """Composite-law gains in design units (floats), before folding the period in.

    Parameters
    ----------
    kp0 : float
        Base proportional gain [codes/count].
    ki0 : float
        Base integral gain [codes/(count·s)].
    kd0 : float
        Base derivative gain [codes·s/count].
    k10 : float
        Base feedforward differential coefficient [codes·s/count] (codes per count/s of the
        reference's speed); the ideal velocity feedforward is ``1 / (gain_cps_per_v · lsb_v)``.
    ke : float
        Error scaling factor [levels/count].
    kec : float
        Error-change scaling factor [levels per count/tick].
    n : int
        Levels ``−n…n`` of ``E`` and ``EC``.
    dkp, dki, dkd, dk1 : ndarray, shape (2n+1, 2n+1), optional
        Query tables (row ``E``, column ``EC``) in the units of their base gain; default zero.

    Raises
    ------
    ValueError
        If a value is out of range or ``Kx0 + min ΔKx < 0`` for a gain.
    """

    kp0: float
    ki0: float
    kd0: float = 0.0
    k10: float = 0.0
    ke: float
    kec: float
    n: int = 6
    dkp: np.ndarray | None = field(default=None, compare=False)
    dki: np.ndarray | None = field(default=None, compare=False)
    dkd: np.ndarray | None = field(default=None, compare=False)
    dk1: np.ndarray | None = field(default=None, compare=False)
    tables_key: bytes = field(init=False, repr=False, default=b"")

    def __post_init__(self) -> None:
        units = {
            "kp0": "codes/count",
            "ki0": "codes/(count·s)",
            "kd0": "codes·s/count",
            "k10": "codes·s/count",
            "ke": "levels/count",
            "kec": "levels/(count/tick)",
        }
        for name, unit in units.items():
            v = getattr(self, name)
            if not isinstance(v, int | float) or not np.isfinite(v):
                raise ValueError(f"{name} must be a finite number [{unit}], got {show_value(v)}")
        for name in ("ke", "kec"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 [{units[name]}], got {getattr(self, name)}")
        if not isinstance(self.n, int) or not 1 <= self.n <= _LEVEL_LIMIT:
            raise ValueError(
                f"n must be an integer in 1..{_LEVEL_LIMIT} [levels], got {show_value(self.n)}"
            )
        for t in TABLE_NAMES:
            x = getattr(self, "d" + t)
            size = 2 * self.n + 1
            a = np.zeros((size, size)) if x is None else _table_array("d" + t, x, self.n)
            a = a.copy()
            a.setflags(write=False)
            object.__setattr__(self, "d" + t, a)
            object.__setattr__(self, "tables_key", self.tables_key + a.tobytes())
            base = getattr(self, t + "0")
            if base + float(a.min()) < 0:
                raise ValueError(
                    f"{t}0 + min Δ{t} must be >= 0 [{units[t + '0']}], "
                    f"got {base} + {float(a.min())}"
                )

    def quantize(self, period_s: float) -> FuzzyPIDConstants:
        """Fold the period in (``Ki·T``, ``Kd/T``, ``K1/T``) and quantise every constant.

        Each base gain's fraction bits are chosen (the one quantiser's rule) from the largest
        magnitude of the base, of its table and of their sum; the table is then quantised to
        int16 with ``f_t ≤ f``.
        """
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0 [s], got {show_value(period_s)}")
        factor = {"kp": 1.0, "ki": period_s, "kd": 1.0 / period_s, "k1": 1.0 / period_s}
        bases: dict[str, Fixed] = {}
        tables: dict[str, tuple[np.ndarray, int]] = {}
        for t in TABLE_NAMES:
            base = getattr(self, t + "0") * factor[t]
            tab = np.asarray(getattr(self, "d" + t)) * factor[t]
            mag = max(abs(base), float(np.max(np.abs(tab))), float(np.max(np.abs(base + tab))))
            f = quantize(mag).f
            bases[t] = quantize(base, f_max=f)
            tables[t] = quantize_table(tab, f_max=bases[t].f, bits=16)
        return FuzzyPIDConstants(
            kp=bases["kp"],
            ki_t=bases["ki"],
            kd_t=bases["kd"],
            k1_t=bases["k1"],
            ke=quantize(self.ke),
            kec=quantize(self.kec),
            n=self.n,
            tables=tuple(tables[t] for t in TABLE_NAMES),
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (tables as nested lists)."""
        out: dict[str, Any] = {
            k: getattr(self, k) for k in ("kp0", "ki0", "kd0", "k10", "ke", "kec", "n")
        }
        for t in TABLE_NAMES:
            out["d" + t] = np.asarray(getattr(self, "d" + t)).tolist()
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class FuzzyPIDConstants:
    """The composite law's constants as the runtime holds them.

    Parameters
    ----------
    kp, ki_t, kd_t, k1_t : Fixed
        Base gains ``Kp0`` [LSB/count], ``Ki0·T`` [LSB/count/tick], ``Kd0/T`` and ``K10/T``
        [LSB per count change per tick].
    ke, kec : Fixed
        Level scaling factors [levels/count], [levels per count/tick].
    n : int
        Levels ``−n…n``.
    tables : tuple of (ndarray of int16, int)
        ``(q, f_t)`` of ΔKp, ΔKi·T, ΔKd/T, ΔK1/T (:data:`TABLE_NAMES` order), shape
        (2n+1, 2n+1), row ``E``, column ``EC``.
    """

    kp: Fixed
    ki_t: Fixed
    kd_t: Fixed
    k1_t: Fixed
    ke: Fixed
    kec: Fixed
    n: int
    tables: tuple[tuple[np.ndarray, int], ...] = field(compare=False)
    tables_key: bytes = field(init=False, repr=False, default=b"")

    def __post_init__(self) -> None:
        if not isinstance(self.n, int) or not 1 <= self.n <= _LEVEL_LIMIT:
            raise ValueError(
                f"n must be an integer in 1..{_LEVEL_LIMIT} [levels], got {show_value(self.n)}"
            )
        if len(self.tables) != len(TABLE_NAMES):
            raise ValueError(f"need {len(TABLE_NAMES)} tables, got {len(self.tables)}")
        size = 2 * self.n + 1
        fixed_tables = []
        for name, base, (q, f_t) in zip(TABLE_NAMES, self.bases, self.tables, strict=True):
            q = np.asarray(q)
            if q.shape != (size, size):
                raise ValueError(f"table {name} must have shape ({size}, {size}), got {q.shape}")
            if not np.all((q >= -(2**15)) & (q <= 2**15 - 1)) or not np.all(q == np.round(q)):
                raise ValueError(f"table {name} entries must be int16")
            if not 0 <= int(f_t) <= base.f:
                raise ValueError(
                    f"table {name} fraction bits must be in 0..{base.f} (its base gain's), "
                    f"got {f_t}"
                )
            sched = base.q + q.astype(np.int64) * (1 << (base.f - int(f_t)))
            if sched.min() < 0:
                raise ValueError(f"{name}0 + min Δ{name} must be >= 0, got {sched.min()} q units")
            if sched.max() > _GAIN_LIMIT:
                raise ValueError(f"scheduled {name} exceeds 2^32 q units (product overflow)")
            q16 = q.astype(np.int16)
            q16.setflags(write=False)
            fixed_tables.append((q16, int(f_t)))
        object.__setattr__(self, "tables", tuple(fixed_tables))
        # equality and hashing by value (a batch discretises identical candidates once)
        key = b"".join(q.tobytes() + f_t.to_bytes(1, "little") for q, f_t in fixed_tables)
        object.__setattr__(self, "tables_key", key)

    @property
    def bases(self) -> tuple[Fixed, Fixed, Fixed, Fixed]:
        """Base gains in :data:`TABLE_NAMES` order."""
        return (self.kp, self.ki_t, self.kd_t, self.k1_t)

    def scheduled(self, name: str) -> np.ndarray:
        """The scheduled gain ``Kx0 + ΔKx`` over the table, as values (float)."""
        i = TABLE_NAMES.index(name)
        base = self.bases[i]
        q, f_t = self.tables[i]
        return (base.q + q.astype(np.int64) * (1 << (base.f - f_t))) * 2.0**-base.f

    def to_dict(self) -> dict[str, Any]:
        """Plain dict: every constant as its (q, f) pair, tables as ``{"q": rows, "f": f_t}``."""
        out: dict[str, Any] = {
            "k1_t": self.k1_t.to_dict(),
            "kd_t": self.kd_t.to_dict(),
            "ke": self.ke.to_dict(),
            "kec": self.kec.to_dict(),
            "ki_t": self.ki_t.to_dict(),
            "kp": self.kp.to_dict(),
            "n": self.n,
        }
        out["tables"] = {
            name: {"f": int(f_t), "q": q.astype(int).tolist()}
            for name, (q, f_t) in zip(TABLE_NAMES, self.tables, strict=True)
        }
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FuzzyPIDConstants:
        """Inverse of :meth:`to_dict` (no re-quantising).

        Every key exactly (no unknown ones), ``n`` and every table entry an integer (not
        ``6.0``, ``"6"`` nor ``1.7``), every table ``(2n+1)`` rows of ``(2n+1)`` entries.

        Raises
        ------
        ValueError
            Naming the key, table, row or entry that is wrong.
        """
        d = check_keys(d, "task", ("k1_t", "kd_t", "ke", "kec", "ki_t", "kp", "n", "tables"))
        n = d["n"]
        if type(n) is not int or not 1 <= n <= _LEVEL_LIMIT:
            raise ValueError(
                f"task.n must be an integer in 1..{_LEVEL_LIMIT} [levels], got {show_value(n)}"
            )
        tabs = check_keys(d["tables"], "task.tables", TABLE_NAMES)
        tables = []
        for t in TABLE_NAMES:
            tab = check_keys(tabs[t], f"task.tables.{t}", ("f", "q"))
            f_t = tab["f"]
            if type(f_t) is not int:
                raise ValueError(f"task.tables.{t}.f must be an integer, got {show_value(f_t)}")
            tables.append((int_rows(tab["q"], 2 * n + 1, f"task.tables.{t}.q"), f_t))

        def fx(key: str) -> Fixed:
            try:
                return Fixed.from_dict(d[key])
            except ValueError as exc:
                raise ValueError(f"task.{key}: {exc}") from None

        return cls(
            kp=fx("kp"),
            ki_t=fx("ki_t"),
            kd_t=fx("kd_t"),
            k1_t=fx("k1_t"),
            ke=fx("ke"),
            kec=fx("kec"),
            n=n,
            tables=tuple(tables),
        )


def int_rows(rows: object, size: int, where: str) -> np.ndarray:
    """A square table of int16 entries read from nested lists, every entry an exact integer.

    Parameters
    ----------
    rows : object
        ``size`` lists of ``size`` entries each (as parsed from JSON).
    size : int
        The side, ``2n + 1``.
    where : str
        The table's name in messages.

    Returns
    -------
    numpy.ndarray of int64, shape (size, size)

    Raises
    ------
    ValueError
        Naming the first wrong row or entry (not an int, a bool, or outside int16).
    """
    if not isinstance(rows, list) or len(rows) != size:
        raise ValueError(f"{where} must have {size} rows (E = -n..n)")
    for r, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != size:
            raise ValueError(f"{where}: row {r} must have {size} entries (EC = -n..n)")
        for c, v in enumerate(row):
            if type(v) is not int:
                raise ValueError(f"{where}[{r}][{c}] must be an integer, got {show_value(v)}")
            if not -(2**15) <= v <= 2**15 - 1:
                raise ValueError(f"{where}[{r}][{c}] = {v} is outside int16")
    return np.array(rows, dtype=np.int64)


# --- runtime arithmetic (numba; mirrored in the C runtime) ----------------------------------


@jit(inline="always")
def fuzzy_level(x: int, k_q: int, k_f: int, n: int) -> int:
    """Fuzzy level ``clamp(shift_round(clamp_e(x)·K_q, f_K), −n, n)``
    (docs/runtime.md#fuzzy-levels-and-scheduled-gains).

    ``|clamp_e(x)| < 2^31`` and ``|K_q| < 2^31``, so the product fits int64.
    """
    p = clamp_e(x) * k_q
    lv = shift_round(p, k_f) if k_f > 0 else p
    if lv > n:
        return n
    if lv < -n:
        return -n
    return lv


@jit(inline="always")
def scheduled_gain(base_q: int, base_f: int, t_q: int, t_f: int) -> int:
    """``Kx0 + ΔKx`` in ``q`` units at the base's ``f``: the entry aligned by ``2^(f − f_t)``."""
    return base_q + align(t_q, base_f - t_f)


@jit(inline="always")
def feed_terms(kd_q: int, kd_f: int, k1_q: int, k1_f: int, ec: int, dr: int) -> int:
    """Derivative and feedforward terms ``(Kd/T)·ec + (K1/T)·Δr`` [LSB, ``F_U`` fraction bits]."""
    d = align(kd_q * clamp_e(ec), F_U - kd_f)
    ff = align(k1_q * clamp_e(dr), F_U - k1_f)
    return sat_add(d, ff)
