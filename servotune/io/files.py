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
is removed and the target is untouched. An output of several files (a C export, a directory of
figures) is written as a whole (:func:`staged_directory`, :func:`write_files`): every file into a
new temporary directory beside the output, then moved into place by renames alone, with signals
held back while they run; a failure before that leaves nothing new at the output, and a failure
during it (which a full disk cannot cause: a rename allocates no data) puts back what was there.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import secrets
import shutil
import signal
import stat
import threading
from collections.abc import Callable, Iterator, Mapping
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
    "staged_directory",
    "write_files",
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
        try:
            _write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise _target_error(exc, target) from None
        raise


def _write_all(fd: int, data: bytes) -> None:
    """Write all of ``data`` to the open file ``fd`` (``os.write`` until done)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


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


@contextlib.contextmanager
def staged_directory(path: str | Path) -> Iterator[Path]:
    """A new empty directory to write an output of several files into, moved to ``path`` as a
    whole when the ``with`` block ends without an exception.

    The staging directory is a hidden sibling of ``path`` (of its nearest existing ancestor
    when ``path``'s parents are missing), so every move is a rename on one file system. When
    the block ends: if ``path`` does not exist, the staging directory is renamed to it (its
    missing parents created first); if it is a directory, each staged entry is renamed into it
    (a subdirectory merged entry by entry), an entry it replaces kept aside until all moves
    have succeeded, and deleted then; SIGINT and SIGTERM wait until the moves are done. On an
    exception in the block (a full disk, Ctrl-C, an error) the staging directory is removed
    and ``path`` is as it was; an error during the moves puts back every entry moved so far.

    Raises
    ------
    OSError
        ``path`` is a file, or the staging directory cannot be created (naming ``path``).
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "not a directory", str(target))
    anchor = target.absolute().parent
    while not anchor.exists() and anchor != anchor.parent:
        anchor = anchor.parent
    try:
        stage = Path(_new_hidden_dir(anchor, target.name))
    except OSError as exc:
        raise _target_error(exc, target) from None
    try:
        yield stage
        with _signals_held():
            if target.exists():
                _merge_into(stage, target)
            else:
                target.parent.mkdir(parents=True, exist_ok=True)
                os.rename(stage, target)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def write_files(path: str | Path, files: Mapping[str, str | bytes]) -> tuple[Path, ...]:
    """Write ``files`` (file name → text or bytes) into the directory ``path`` as a whole
    (:func:`staged_directory`): all of them or, on any failure, none. Returns their paths."""
    with staged_directory(path) as stage:
        for name, data in files.items():
            (stage / name).parent.mkdir(parents=True, exist_ok=True)
            with open(stage / name, "xb") as f:
                fd = f.fileno()
                _write_all(fd, data.encode("utf-8") if isinstance(data, str) else data)
                os.fsync(fd)
    return tuple(Path(path) / name for name in files)


def _new_hidden_dir(parent: Path, name: str) -> str:
    """A new directory ``.<name>.<random>.stage`` in ``parent``."""
    while True:
        d = parent / f".{name}.{secrets.token_hex(6)}.stage"
        try:
            d.mkdir(mode=0o777)
        except FileExistsError:
            continue
        return str(d)


def _merge_into(stage: Path, target: Path) -> None:
    """Rename every entry of ``stage`` into the directory ``target`` (see
    :func:`staged_directory`); on an error, undo the renames done and re-raise."""
    aside = Path(_new_hidden_dir(stage, "replaced"))
    undo: list[tuple[Path, Path]] = []  # (from, to) renames to run backwards on an error
    try:
        _merge_entries(stage, target, aside, undo)
    except BaseException:
        for src, dst in reversed(undo):
            with contextlib.suppress(OSError):
                os.rename(dst, src)
        raise


def _merge_entries(stage: Path, target: Path, aside: Path, undo: list[tuple[Path, Path]]) -> None:
    for entry in sorted(stage.iterdir()):
        if entry == aside:
            continue
        dst = target / entry.name
        if entry.is_dir() and dst.is_dir() and not dst.is_symlink():
            _merge_entries(entry, dst, Path(_new_hidden_dir(aside, entry.name)), undo)
            continue
        if dst.exists() or dst.is_symlink():
            kept = aside / entry.name
            os.rename(dst, kept)
            undo.append((dst, kept))
        os.rename(entry, dst)
        undo.append((entry, dst))


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM that arrive in the block are held and raised again when it ends
    (their handlers swapped for one that notes them: blocking the signal in this thread would
    not do, another thread of the process could take it). Outside the main thread, where no
    handler can be set, nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(sig) is not None:  # None: a handler set outside Python, left alone
            previous[sig] = signal.signal(sig, lambda signum, _frame: pending.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if pending:
            signal.raise_signal(pending[0])
