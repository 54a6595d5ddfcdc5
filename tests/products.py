"""Compare floating-point products with stated tolerances, field by field.

Byte pins hold only where the arithmetic is machine-independent (the runtime's integer chain,
the exports of a given tuning, the C runtime's outputs). Products computed in floating point
(the tuner's search, IPOPT, fits, margins, Monte-Carlo statistics) differ in their last bits
from one machine to another: numpy's SIMD transcendental functions (AVX-512 or not), the
OpenBLAS kernel chosen for the processor and libm all round differently. Those products are
compared here by structure (the same keys, list lengths, strings and integers) and by value
within the tolerance of the first :class:`Rule` whose pattern matches the field's path; every
rule says why its tolerance is enough (docs/reproducibility.md).

Paths are ``/key/key[index]`` (JSON, TOML) or ``column[row]`` (CSV); patterns are
:func:`fnmatch.fnmatchcase` patterns on them.
"""

from __future__ import annotations

import csv
import io
import json
import math
import tomllib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any


@dataclass(frozen=True, slots=True, kw_only=True)
class Rule:
    """How the fields whose path matches ``pattern`` may differ.

    A float passes when ``|a - b| <= rel * max(|a|, |b|) + abs_``; an integer when
    ``|a - b| <= int_abs``; ``skip`` leaves the field out (a digest of a float product, say).
    """

    pattern: str
    reason: str
    rel: float = 0.0
    abs_: float = 0.0
    int_abs: int = 0
    skip: bool = False


FLOATS = Rule(
    pattern="*",
    rel=1e-6,
    abs_=1e-9,
    reason="every float: IPOPT stops at 1e-10 on its scaled optimality error and the fits at "
    "least-squares tolerances of 1e-10 or tighter, so two machines whose last bits differ end "
    "within about 1e-8 of each other even when one takes an iteration more; 1e-6 relative "
    "leaves a factor of 100 (observed: 1.4e-13 between this machine and an emulated one "
    "without AVX-512 and with another OpenBLAS kernel). 1e-9 absolute covers differences of "
    "nearly equal numbers (a fit's relative error of 1e-5 carries its inputs' 1e-13 as 1e-8 "
    "of itself)",
)
PEAKS = Rule(
    pattern="*peak_rad_s",
    rel=1e-5,
    reason="where a flat maximum lies (the sensitivity peak's frequency) is found by a bounded "
    "scalar search to 1e-9 of its interval: the location is ill-conditioned (an error of eps "
    "in the value moves it by about sqrt(eps)); observed 1.5e-8 between machines",
)
DIGESTS = Rule(
    pattern="*sha256",
    skip=True,
    reason="a digest of a float product changes with its last bit; what it binds is checked by "
    "check-table and the trust-chain tests on each machine",
)


def differences(ref: Any, got: Any, rules: Sequence[Rule], path: str = "") -> list[str]:
    """Every way ``got`` differs from ``ref`` beyond the rules, one line each (empty: equal)."""
    return list(_walk(ref, got, rules, path))


def _rule(path: str, rules: Sequence[Rule]) -> Rule | None:
    return next((r for r in rules if fnmatchcase(path, r.pattern)), None)


def _walk(a: Any, b: Any, rules: Sequence[Rule], path: str) -> Iterator[str]:
    rule = _rule(path, rules)
    if rule is not None and rule.skip:
        return
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            sub = f"{path}/{key}"
            if key not in b:
                yield f"{sub}: missing"
            elif key not in a:
                yield f"{sub}: not in the reference"
            else:
                yield from _walk(a[key], b[key], rules, sub)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield f"{path}: {len(b)} items, the reference has {len(a)}"
            return
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            yield from _walk(x, y, rules, f"{path}[{i}]")
    elif isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str) or a is None:
        if a != b or type(a) is not type(b):
            yield f"{path}: {b!r}, the reference has {a!r}"
    elif isinstance(a, int) and isinstance(b, int):
        allowed = rule.int_abs if rule is not None else 0
        if abs(a - b) > allowed:
            yield f"{path}: {b}, the reference has {a} (allowed ±{allowed})"
    elif isinstance(a, float) and isinstance(b, float):
        if math.isnan(a) or math.isnan(b) or math.isinf(a) or math.isinf(b):
            if not (a == b or (math.isnan(a) and math.isnan(b))):
                yield f"{path}: {b!r}, the reference has {a!r}"
            return
        rel, abs_ = (rule.rel, rule.abs_) if rule is not None else (0.0, 0.0)
        if abs(a - b) > rel * max(abs(a), abs(b)) + abs_:
            yield (
                f"{path}: {b!r}, the reference has {a!r} "
                f"(differs by {abs(a - b):.3g}; allowed {rel:g} relative + {abs_:g})"
            )
    else:
        yield f"{path}: {type(b).__name__} {b!r}, the reference has {type(a).__name__} {a!r}"


# --- reading products ------------------------------------------------------------------------


def read_product(path: Path, replace: dict[str, str] | None = None) -> Any:
    """A product as plain data: JSON and TOML parsed, CSV as ``{"meta": [...], column: [...]}``
    (numbers parsed, ints kept ints); ``replace`` rewrites text (an output folder) first."""
    text = path.read_text(encoding="utf-8")
    for old, new in (replace or {}).items():
        text = text.replace(old, new)
    if path.suffix == ".json":
        return json.loads(text)
    if path.suffix == ".toml":
        return tomllib.loads(text)
    if path.suffix == ".csv":
        return _csv(text)
    raise ValueError(f"{path}: no reader for {path.suffix} products")


def _number(text: str) -> int | float | str:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _csv(text: str) -> dict[str, Any]:
    meta = [ln for ln in text.splitlines() if ln.startswith("#")]
    rows = list(
        csv.reader(io.StringIO("\n".join(ln for ln in text.splitlines() if not ln.startswith("#"))))
    )
    header, body = rows[0], rows[1:]
    table: dict[str, Any] = {"meta": meta}
    for j, name in enumerate(header):
        table[name] = [_number(row[j]) for row in body]
    return table


def column_differences(
    ref: dict[str, Any], got: dict[str, Any], *, int_abs: int, max_fraction: float
) -> list[str]:
    """A logged run's integer columns: each sample within ``int_abs``, and at most
    ``max_fraction`` of the samples of a column different at all."""
    out = []
    for name, col in ref.items():
        if name == "meta" or not col or not isinstance(col[0], int):
            continue
        other = got.get(name)
        if other is None or len(other) != len(col):
            out.append(f"{name}: missing or of another length")
            continue
        diff = [abs(a - b) for a, b in zip(col, other, strict=True) if isinstance(b, int)]
        if len(diff) != len(col):
            out.append(f"{name}: not all integers")
        elif max(diff) > int_abs:
            out.append(f"{name}: a sample differs by {max(diff)} (allowed {int_abs})")
        elif sum(d > 0 for d in diff) > max_fraction * len(col):
            out.append(f"{name}: {sum(d > 0 for d in diff)} of {len(col)} samples differ")
    return out
