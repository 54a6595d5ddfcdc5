"""Bytes, JSON and TOML in and out: the one place text files are read and written.

Every file kind servotune reads goes through here before its own schema sees it (one reader per
format: :func:`parse_json` / :func:`read_json`, :func:`parse_toml` / :func:`read_toml`,
:func:`read_bytes`; the log CSV's reader is :func:`servotune.logs.read_log`). What is refused on
the bytes themselves, whatever the file kind: files over :data:`MAX_TEXT_FILE_BYTES`, nesting
deeper than :data:`MAX_NESTING`, numbers longer than :data:`MAX_NUMBER_CHARS` characters,
strings over :data:`MAX_STRING_CHARS`, NaN and infinities (not JSON), invalid UTF-8; a leading
UTF-8 byte-order mark is accepted. Each failure is one line of the caller's error class naming
the file as the user gave it.

Writes are atomic (:func:`atomic_write_bytes`): a temporary file in the same directory, then a
rename; on any error, Ctrl-C or SIGTERM (the CLI turns it into an exception) the temporary file
is removed and the target is untouched.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import secrets
import stat
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

__all__ = [
    "MAX_NESTING",
    "MAX_NUMBER_CHARS",
    "MAX_STRING_CHARS",
    "MAX_TEXT_FILE_BYTES",
    "atomic_write_bytes",
    "atomic_write_text",
    "json_float",
    "json_safe",
    "json_text",
    "parse_json",
    "parse_json_as",
    "parse_toml",
    "parse_toml_as",
    "read_bytes",
    "read_json",
    "read_toml",
]

_T = TypeVar("_T")


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a new file in the same directory and a rename.

    The file keeps the mode of the file it replaces (a new file gets 0o666 less the umask).
    On any error the temporary file is removed and ``path`` is untouched.

    Raises
    ------
    OSError
        If the directory does not exist or is not writable (nothing is left behind).
    """
    target = Path(path)
    d = target.parent if str(target.parent) else Path(".")
    if not d.is_dir():
        raise FileNotFoundError(
            errno.ENOENT, f"cannot write: directory {str(d)!r} does not exist", str(target)
        )
    try:
        mode: int | None = stat.S_IMODE(target.stat().st_mode)
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise _target_error(exc, target) from None
    while True:
        tmp = target.with_name(f".{target.name}.{secrets.token_hex(6)}.tmp")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        except OSError as exc:  # e.g. the directory is not writable: name the user's file
            raise _target_error(exc, target) from None
        break
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise _target_error(exc, target) from None
        raise


def _target_error(exc: OSError, target: Path) -> OSError:
    """The same kind of OSError, naming the target file instead of the temporary one."""
    why = exc.strerror or str(exc)
    if exc.errno is None:
        return OSError(f"cannot write {str(target)!r}: {why}")
    return OSError(exc.errno, f"cannot write: {why}", str(target))


def json_text(doc: Any) -> str:
    """A document as servotune writes its JSON files (tunings, plans, records): sorted keys,
    two-space indent, no NaN, a trailing newline; the same document gives the same bytes."""
    return json.dumps(doc, sort_keys=True, indent=2, allow_nan=False) + "\n"


def json_float(x: float) -> float | None:
    """A float for JSON: finite values as ``float``, ``inf`` and NaN as None."""
    return float(x) if math.isfinite(x) else None


def json_safe(x: Any) -> Any:
    """JSON-safe copy: mappings (keys as str), sequences and arrays as lists, numpy scalars as
    Python numbers, floats through :func:`json_float`.

    Raises
    ------
    TypeError
        For a value JSON cannot hold.
    """
    if isinstance(x, Mapping):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, np.ndarray):
        return [json_safe(v) for v in x.tolist()]
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return x
    if isinstance(x, int):
        return int(x)
    if hasattr(x, "item"):
        return json_safe(x.item())
    if isinstance(x, float):
        return json_float(x)
    raise TypeError(f"cannot store a {type(x).__name__} as JSON")


MAX_TEXT_FILE_BYTES = 64 * 1024**2
"""Largest JSON or TOML file read [bytes] (64 MiB); larger ones are refused unread."""

MAX_NESTING = 64
"""Deepest nesting of arrays and tables accepted in a JSON or TOML file."""

MAX_NUMBER_CHARS = 64
"""Longest number accepted in a file, as text [characters] (a log field, a JSON number)."""

MAX_STRING_CHARS = 1024**2
"""Longest string accepted in a JSON or TOML file [characters]."""

_BOM = "\ufeff"


def _json_number(kind: type) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        if len(text) > MAX_NUMBER_CHARS:
            raise _JsonLimit(
                f"a number of {len(text)} characters (at most {MAX_NUMBER_CHARS} are accepted)"
            )
        return kind(text)

    return parse


class _JsonLimit(Exception):
    """A bound of :func:`parse_json` was exceeded (the message says which)."""


def _json_constant(name: str) -> Any:
    raise _JsonLimit(f"{name} is not a JSON number (JSON has no NaN or infinity)")


def _nesting_depth(text: str) -> int:
    """Deepest ``[``/``{`` nesting of JSON text (brackets inside strings are not counted)."""
    if text.count("[") + text.count("{") <= MAX_NESTING:
        return 0  # cannot be deeper than the bound
    flat = re.sub(r'"(?:[^"\\]|\\.)*"', '""', text)
    b = np.frombuffer(flat.encode("utf-8", "replace"), dtype=np.uint8)
    step = np.zeros(b.shape, dtype=np.int32)
    step[(b == ord("[")) | (b == ord("{"))] = 1
    step[(b == ord("]")) | (b == ord("}"))] = -1
    return int(np.cumsum(step).max(initial=0))


def _check_tree(value: Any, src: str, error: type[Exception], what: str) -> None:
    """Refuse nesting deeper than :data:`MAX_NESTING` and strings longer than
    :data:`MAX_STRING_CHARS` in a parsed document (iteratively: no recursion)."""
    stack: list[tuple[Any, int, str]] = [(value, 0, "")]
    while stack:
        v, depth, where = stack.pop()
        if isinstance(v, str):
            if len(v) > MAX_STRING_CHARS:
                at = f" at {where}" if where else ""
                raise error(
                    f"{what} {src!r}: a string of {len(v)} characters{at} (at most "
                    f"{MAX_STRING_CHARS} are accepted)"
                )
            continue
        if isinstance(v, Mapping | list | tuple):
            if depth >= MAX_NESTING:
                raise error(
                    f"{what} {src!r}: nested deeper than {MAX_NESTING} levels"
                    + (f" at {where[:80]}" if where else "")
                )
            items = v.items() if isinstance(v, Mapping) else enumerate(v)
            for k, x in items:
                if isinstance(k, str) and len(k) > MAX_STRING_CHARS:
                    raise error(f"{what} {src!r}: a key of {len(k)} characters")
                key = f"{where}.{k}" if isinstance(k, str) else f"{where}[{k}]"
                stack.append((x, depth + 1, key.lstrip(".")))


def parse_json(text: str, src: str, error: type[Exception]) -> Any:
    """``json.loads`` with a one-line ``error`` naming ``src`` on malformed or unsafe text.

    A leading UTF-8 byte-order mark is ignored. Refused, each in one line: text that is not
    JSON, ``NaN``/``Infinity``/``-Infinity`` (not JSON numbers), more than
    :data:`MAX_TEXT_FILE_BYTES` of text, nesting deeper than :data:`MAX_NESTING`, numbers
    longer than :data:`MAX_NUMBER_CHARS` characters, strings longer than
    :data:`MAX_STRING_CHARS`.
    """
    if text.startswith(_BOM):
        text = text[1:]
    if len(text) > MAX_TEXT_FILE_BYTES:
        raise error(
            f"{src}: {len(text)} characters of JSON is more than the {MAX_TEXT_FILE_BYTES} accepted"
        )
    depth = _nesting_depth(text)
    if depth > MAX_NESTING:
        raise error(f"{src}: JSON nested {depth} levels deep (at most {MAX_NESTING} are accepted)")
    try:
        doc = json.loads(
            text,
            parse_constant=_json_constant,
            parse_int=_json_number(int),
            parse_float=_json_number(float),
        )
    except json.JSONDecodeError as exc:
        where = "" if exc.msg.endswith(" at") else " at"  # "Unterminated string starting at"
        raise error(f"{src}: not JSON ({exc.msg}{where} line {exc.lineno})") from None
    except _JsonLimit as exc:
        raise error(f"{src}: not accepted JSON: {exc}") from None
    except RecursionError:
        raise error(f"{src}: JSON nested too deeply (at most {MAX_NESTING} levels)") from None
    except ValueError as exc:  # e.g. a number beyond a conversion limit
        raise error(f"{src}: not accepted JSON: {str(exc).splitlines()[0][:120]}") from None
    _check_tree(doc, src, error, "JSON file")
    return doc


def parse_json_as(
    raw: bytes,
    src: str,
    error: type[Exception],
    build: Callable[[Any], _T],
    encoding: str = "utf-8",
) -> _T:
    """``build`` of the JSON document in ``raw`` (:func:`parse_json`): a file kind's reader
    (tunings, plans). Every failure is one line of ``error`` starting ``"<src>: "`` (text
    that is not UTF-8 names the byte; ``build`` raises ``error`` naming the field)."""
    try:
        text = raw.decode(encoding)
    except UnicodeDecodeError as exc:
        raise error(f"{src}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    data = parse_json(text, src, error)
    try:
        return build(data)
    except error as exc:
        raise error(f"{src}: {exc}") from None


def read_bytes(
    path: str | Path, error: type[Exception], what: str, missing: str | None = None
) -> bytes:
    """The bytes of a text file of at most :data:`MAX_TEXT_FILE_BYTES`, read once; a failure is
    one line of ``error`` naming ``what`` and the path as given (``missing``: the message for a
    file that does not exist)."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            if size > MAX_TEXT_FILE_BYTES:
                raise error(
                    f"{what} {str(p)!r} is {size} bytes; at most {MAX_TEXT_FILE_BYTES} "
                    f"(64 MiB) are read"
                )
            raw = fh.read(MAX_TEXT_FILE_BYTES + 1)
    except FileNotFoundError:
        if missing is not None:
            raise error(f"{p}: {missing}") from None
        raise error(f"cannot read {what} {str(p)!r}: no such file") from None
    except OSError as exc:
        raise error(f"cannot read {what} {str(p)!r}: {exc.strerror or exc}") from None
    if len(raw) > MAX_TEXT_FILE_BYTES:  # grew while being read, or not a regular file
        raise error(f"{what} {str(p)!r} is larger than {MAX_TEXT_FILE_BYTES} bytes (64 MiB)")
    return raw


def read_json(path: str | Path, error: type[Exception], missing: str = "no such file") -> Any:
    """Read a JSON file; every failure is one line of ``error`` naming the file.

    ``missing`` is the message for a file that does not exist. See :func:`parse_json` for what
    is refused.
    """
    p = Path(path)
    raw = read_bytes(p, error, "JSON file", missing)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(
            f"{p}: cannot read: not UTF-8 text ({exc.reason} at byte {exc.start})"
        ) from None
    return parse_json(text, str(p), error)


def parse_toml(
    raw: bytes | str, src: str, error: type[Exception], what: str = "file"
) -> dict[str, Any]:
    """Parse TOML bytes or text; every failure is one line of ``error`` naming ``what`` and
    ``src``.

    A leading UTF-8 byte-order mark is ignored. Refused besides invalid TOML: more than
    :data:`MAX_TEXT_FILE_BYTES`, nesting deeper than :data:`MAX_NESTING`, integers beyond
    Python's conversion limit, strings longer than :data:`MAX_STRING_CHARS`.
    """
    import tomllib

    if len(raw) > MAX_TEXT_FILE_BYTES:
        raise error(f"{what} {src!r} is larger than {MAX_TEXT_FILE_BYTES} bytes (64 MiB)")
    try:
        text = raw.decode("utf-8") if isinstance(raw, bytes) else raw
    except UnicodeDecodeError as exc:
        raise error(f"{what} {src!r} is not valid TOML: {exc}") from None
    if text.startswith(_BOM):
        text = text[1:]
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {src!r} is not valid TOML: {exc}") from None
    except RecursionError:
        raise error(
            f"{what} {src!r} is not accepted TOML: nested too deeply (at most {MAX_NESTING} levels)"
        ) from None
    except ValueError as exc:  # e.g. an integer beyond Python's digit limit
        raise error(
            f"{what} {src!r} is not accepted TOML: {str(exc).splitlines()[0][:120]}"
        ) from None
    _check_tree(data, src, error, what)
    return data


def parse_toml_as(
    raw: bytes, src: str, error: type[Exception], what: str, build: Callable[[Any], _T]
) -> _T:
    """``build`` of the TOML document in ``raw`` (:func:`parse_toml`): a file kind's reader
    (rig files, configurations, specs). Every failure is one line of ``error`` naming ``what``
    and ``src`` (``build`` raises ``error`` naming the field)."""
    data = parse_toml(raw, src, error, what)
    try:
        return build(data)
    except error as exc:
        raise error(f"{what} {src!r}: {exc}") from None


def read_toml(path: str | Path, error: type[Exception], what: str = "file") -> dict[str, Any]:
    """Read a TOML file; every failure is one line of ``error`` naming ``what`` and the file.

    See :func:`parse_toml` for what is refused.
    """
    p = Path(path)
    return parse_toml(read_bytes(p, error, what), str(p), error, what)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write UTF-8 text atomically (:func:`atomic_write_bytes`), newlines as given."""
    atomic_write_bytes(path, text.encode("utf-8"))
