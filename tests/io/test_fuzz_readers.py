"""Fuzzing the file readers (the reliability contract: one line, exit 3).

Property: on any input, every reader returns or raises a :class:`ServotuneError` whose message
is one line (the CLI prints it as its one line on stderr, exit 3). Anything else escaping it
(a bare ``ValueError``, ``TypeError``, ``KeyError``, ``RecursionError``, ``MemoryError``,
``OverflowError``, ``ZeroDivisionError``, a numpy error, a run of over 20 s) fails.

Inputs, per reader: (a) random bytes and text; (b) byte mutations of a valid file (bit flips,
deletions, truncation, duplicated or dropped lines, CRLF, a BOM, and insertions or value
replacements by nasty tokens: ``nan``, ``Infinity``, ``1e400``, ``-0``, ``24.0``, ``"6"``,
``true``, 5000-digit numbers, ``[[[[``, NUL, ``²``, ``+-5``, unknown keys ...); (c) structural
mutations of the parsed TOML/JSON (a value replaced by one of another type, a key dropped, an
unknown or near-miss key added) or of the CSV (cells, columns, metadata).

Profiles (``HYPOTHESIS_PROFILE``): ``ci`` (default, what ``make test`` runs: deterministic,
60 examples per test) and ``fuzz`` (``make fuzz``: random, ``FUZZ_EXAMPLES`` per test, default
2000). ``FUZZ_FINDINGS=DIR`` collects instead of failing: each distinct finding (reader,
exception type, innermost servotune line) once, its smallest input saved in DIR, a line in
``DIR/findings.jsonl``; for surveying a tree with many open bugs.
"""

from __future__ import annotations

import contextlib
import copy
import datetime as dt
import json
import math
import os
import re
import shutil
import tomllib
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import guard
import pytest
from guard import GuardTimeout
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st
from hypothesis.database import DirectoryBasedExampleDatabase

from servotune.errors import ServotuneError

pytestmark = [
    pytest.mark.fuzz,
    # by design: a log's unknown metadata key is kept with a warning (the fuzzer makes many)
    pytest.mark.filterwarnings("ignore:.*unknown metadata:UserWarning"),
]

ROOT = Path(__file__).resolve().parents[2]
PLANTS = ROOT / "plants"
BASE = ROOT / "tests" / "corpus" / "base"

_HEALTH = [
    HealthCheck.too_slow,
    HealthCheck.data_too_large,
    HealthCheck.large_base_example,
    HealthCheck.filter_too_much,
]
settings.register_profile(
    "ci",
    max_examples=60,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=_HEALTH,
    print_blob=True,
)
settings.register_profile(
    "fuzz",
    max_examples=int(os.environ.get("FUZZ_EXAMPLES", "2000")),
    deadline=None,
    derandomize=False,
    suppress_health_check=_HEALTH,
    print_blob=True,
    database=DirectoryBasedExampleDatabase(ROOT / ".pytest_cache" / "hypothesis-fuzz"),
)
PROFILE = settings.get_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def budget(fraction: float = 1.0) -> settings:
    """The profile's settings, with a share of its examples (slow readers)."""
    return settings(PROFILE, max_examples=max(5, int(PROFILE.max_examples * fraction)))


TIMEOUT_S = 20  # one read [s]
MEMORY = 4 << 30  # address space a read may add [bytes]
MAX_MESSAGE = 1000  # characters

# --- the readers -----------------------------------------------------------------------------

EXT = {"rig": "toml", "spec": "toml", "gantry": "toml", "linkage": "toml", "log": "csv",
       "excitation": "csv", "tuning": "json", "tables": "json"}  # fmt: skip
BASES = {
    "rig": PLANTS / "pc-dual-servo.toml",
    "spec": PLANTS / "pc-dual-servo.spec.toml",
    "gantry": PLANTS / "gantry.toml",
    "linkage": PLANTS / "linkage-6axis.toml",
    "log": BASE / "log.csv",
    "excitation": BASE / "excitation.csv",
    "tuning": BASE / "tuning.json",
    "tables": BASE / "tables.json",
}
KINDS = tuple(BASES)


def _example_rig() -> Any:
    from servotune.rig import load_rig

    return load_rig(PLANTS / "pc-dual-servo.toml")


def reader(kind: str) -> Callable[[Path], Any]:
    """The reader under test (imported late: a broken module fails its tests, not the file)."""
    if kind == "rig":
        from servotune.rig import load_rig

        return load_rig
    if kind == "spec":
        from servotune.verify import load_spec

        return load_spec
    if kind == "gantry":
        from servotune.arch.gantry.load import load_gantry

        return lambda p: load_gantry(p)
    if kind == "gantry+resolve":
        from servotune.arch.gantry.load import load_gantry

        return load_gantry
    if kind == "linkage":
        from servotune.arch.linkage import load_linkage

        return load_linkage
    if kind == "log":
        from servotune.logs import read_log

        return read_log
    if kind == "excitation":
        from servotune.excite import read_excitation

        rig = _example_rig()
        return lambda p: read_excitation(p, rig)
    if kind == "tuning":
        from servotune.tuning import read_tuning

        return read_tuning
    if kind == "tables":
        from servotune.export.json import load_tables

        return load_tables
    if kind == "rig+describe":  # what `servotune rig` does with what load_rig accepts
        from servotune.rig import describe_rig, load_rig

        return lambda p: describe_rig(load_rig(p))
    if kind == "excitation+inputs":  # what `servotune simulate --input` does next
        from servotune.excite import excitation_inputs, read_excitation

        rig = _example_rig()

        def play(p: Path) -> Any:
            axis, codes = read_excitation(p, rig)
            excitation_inputs(rig, axis, codes, closed_loop=False)
            return excitation_inputs(rig, axis, codes, closed_loop=True)

        return play
    if kind == "tables-text":
        from servotune.export.json import load_tables

        return lambda p: load_tables(p.read_bytes().decode("utf-8", "replace"))
    raise AssertionError(kind)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Where inputs are written; gantry and linkage configs find the example rig next to them."""
    d = tmp_path_factory.mktemp("fuzz")
    shutil.copy(PLANTS / "pc-dual-servo.toml", d / "pc-dual-servo.toml")
    return d


# --- the property ----------------------------------------------------------------------------


def guarded(
    seconds: int = TIMEOUT_S, memory: int = MEMORY
) -> contextlib.AbstractContextManager[None]:
    """:func:`guard.guarded` with this module's limits."""
    return guard.guarded(seconds, memory)


_FINDINGS = os.environ.get("FUZZ_FINDINGS")
_seen: dict[str, int] = {}


def _where(exc: BaseException) -> str:
    """The innermost servotune frame of the traceback, as ``module.py:line``."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if "/servotune/" in f.filename]
    if not frames:
        return "outside servotune"
    f = frames[-1]
    return f"{f.filename.split('/servotune/')[-1]}:{f.lineno}"


def _record(kind: str, source: str, problem: str, where: str, detail: str, data: bytes) -> None:
    key = f"{kind} {problem} {where}"
    out = Path(_FINDINGS)  # type: ignore[arg-type]
    out.mkdir(parents=True, exist_ok=True)
    name = re.sub(r"[^A-Za-z0-9.]+", "-", f"{kind}-{problem}-{where}").strip("-")
    path = out / f"{name}.{EXT.get(kind.split('+')[0].split('-')[0], 'bin')}"
    if key in _seen and _seen[key] <= len(data):
        return
    new = key not in _seen
    _seen[key] = len(data)
    path.write_bytes(data)
    if new:
        with (out / "findings.jsonl").open("a") as f:
            f.write(
                json.dumps(
                    {
                        "kind": kind,
                        "source": source,
                        "problem": problem,
                        "where": where,
                        "detail": detail[:300],
                        "file": path.name,
                    }
                )
                + "\n"
            )


def check(kind: str, workdir: Path, data: bytes, source: str) -> None:
    """Write ``data`` as a file of ``kind`` and read it: it returns or raises ServotuneError."""
    path = workdir / f"input.{EXT.get(kind.split('+')[0].split('-')[0], 'txt')}"
    path.write_bytes(data)
    read = reader(kind)
    problem = where = detail = None
    try:
        with guarded():
            read(path)
        event("accepted")
    except ServotuneError as exc:
        event(f"refused: {type(exc).__name__}")
        msg = str(exc)
        if not msg.strip() or re.search(r"[\r\n]", msg):
            problem, where, detail = "message-not-one-line", _where(exc), repr(msg[:300])
        elif len(msg) > MAX_MESSAGE:
            problem, where, detail = "message-too-long", _where(exc), f"{len(msg)} characters"
    except GuardTimeout as exc:
        problem, where, detail = "Timeout", _where(exc), str(exc)
    except Exception as exc:  # what the property forbids
        problem, where = f"{type(exc).__module__}.{type(exc).__name__}", _where(exc)
        detail = str(exc).splitlines()[0][:300] if str(exc) else ""
    if problem is None:
        return
    if _FINDINGS:
        _record(kind, source, problem, where, detail or "", data)
        return
    raise AssertionError(
        f"{kind} reader on a {source} input ({len(data)} bytes, {data[:200]!r}): "
        f"{problem} at {where}: {detail}"
    )


# --- (a) random input ------------------------------------------------------------------------

random_input = st.one_of(
    st.binary(max_size=1024),
    st.text(max_size=512).map(lambda s: s.encode("utf-8", "surrogatepass")),
)

# --- (b) byte mutations of a valid file ------------------------------------------------------

NASTY = [
    b"nan", b"NaN", b"-nan", b"inf", b"-inf", b"+inf", b"Infinity", b"-Infinity", b"1e400",
    b"-1e400", b"1e-400", b"4.9e-324", b"1e308", b"-0", b"-0.0", b"0", b"24.0", b"6.0", b'"6"',
    b'""', b"true", b"false", b"null", b"9" * 5000, b"-" + b"9" * 400, b"1" + b"0" * 30,
    b"2147483648", b"9223372036854775808", b"-9223372036854775809", b"0x10", b"0b101",
    b"1_000", b"[[[[", b"]]]]", b"[" * 3000, b"{" * 3000, b"{}", b"[]", b"[1, 2]", b"\xef\xbb\xbf",
    b"\x00", b"\r\n", b"\r", b"\n", "²".encode(), "١٢".encode(), "\u2028".encode(), b"+-5",
    b"--5", b"5-", b",", b",,", b";", b"#", b"=", b"\"", b"'", b"\\", b"\\u0000", b"\xff\xfe",
    b"\x80", b"\nunknown_key = 1\n", b"\n[unknown]\n", b'"unknown": 1, ', b"\n# period_s: 0\n",
    b"\n# counter_bits: 64\n", b"2024-01-01", b"12:00:00", b"x" * 300,
]  # fmt: skip
_VALUE = re.compile(rb'-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?|"[^"\n]*"|\btrue\b|\bfalse\b|\bnull\b')
_OPS = ("flip", "delete", "insert", "replace", "replace", "replace", "truncate", "dup_line",
        "drop_line", "crlf", "bom")  # fmt: skip


@st.composite
def byte_mutation(draw: st.DrawFn, base: bytes) -> bytes:
    data = bytearray(base)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(_OPS))
        n = len(data)
        if op == "flip" and n:
            data[draw(st.integers(0, n - 1))] ^= 1 << draw(st.integers(0, 7))
        elif op == "delete" and n:
            i = draw(st.integers(0, n - 1))
            del data[i : i + draw(st.integers(1, 64))]
        elif op == "insert":
            i = draw(st.integers(0, n))
            data[i:i] = draw(st.sampled_from(NASTY))
        elif op == "replace":
            spans = [m.span() for m in _VALUE.finditer(data)]
            if spans:
                a, b = draw(st.sampled_from(spans))
                data[a:b] = draw(st.sampled_from(NASTY))
        elif op == "truncate" and n:
            del data[draw(st.integers(0, n - 1)) :]
        elif op in ("dup_line", "drop_line"):
            lines = bytes(data).split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            if op == "dup_line":
                lines.insert(i, lines[i])
            else:
                del lines[i]
            data = bytearray(b"\n".join(lines))
        elif op == "crlf":
            data = bytearray(bytes(data).replace(b"\n", b"\r\n"))
        elif op == "bom":
            data[0:0] = b"\xef\xbb\xbf"
    return bytes(data)


# --- (c) structural mutations ----------------------------------------------------------------

_TOML_VALUES: list[Any] = [
    0, -1, 1, 2**63, -(2**63) - 1, 10**30, 0.5, 24.0, -0.0, math.nan, math.inf, -math.inf,
    1e300, 1e-300, 5e-324, "6", "", "x" * 300, "nan", True, False, [], [1, 2], [[[]]], {},
    {"unknown": 1}, [1, "a"], dt.date(2024, 1, 1), dt.time(12, 0),
    dt.datetime(2024, 1, 1, 12, 0), dt.datetime(2024, 1, 1, tzinfo=dt.UTC),
]  # fmt: skip
_JSON_VALUES: list[Any] = [
    None, True, False, 0, -1, 1, 2**64, -(2**63) - 1, 10**400, 1.7, 6.0, -0.0, math.nan,
    math.inf, -math.inf, 1e308, 5e-324, "6", "", "x" * 300, [], {}, [[[]]], [1, "a"],
    {"unknown": 1}, [None], {"q": [[1]]},
]  # fmt: skip


def _near_miss(key: str) -> list[str]:
    out = [key + "s", key[:-1] or "x", key.upper(), key.replace("_", "-"), "unknown_key", key + " "]
    if len(key) > 2:
        out.append(key[0] + key[2] + key[1] + key[3:])
    return out


def _slots(doc: Any) -> list[tuple[Any, Any]]:
    """(container, key or index) of every value in ``doc``; long number rows: a few entries."""
    out: list[tuple[Any, Any]] = []

    def walk(x: Any) -> None:
        if isinstance(x, dict):
            for k, v in x.items():
                out.append((x, k))
                walk(v)
        elif isinstance(x, list):
            idx = range(len(x))
            if len(x) > 4 and all(not isinstance(v, dict | list) for v in x):
                idx = sorted({0, len(x) // 2, len(x) - 1})
            for i in idx:
                out.append((x, i))
                walk(x[i])

    walk(doc)
    return out


@st.composite
def structural_mutation(draw: st.DrawFn, kind: str) -> bytes:
    is_json = EXT[kind] == "json"
    doc = copy.deepcopy(_parsed(kind))
    pool = _JSON_VALUES if is_json else _TOML_VALUES
    for _ in range(draw(st.integers(1, 3))):
        slots = _slots(doc)
        if not slots:
            break
        box, key = draw(st.sampled_from(slots))
        op = draw(st.sampled_from(["replace", "replace", "swap", "drop", "add", "rename"]))
        if op == "replace":
            box[key] = copy.deepcopy(draw(st.sampled_from(pool)))
        elif op == "swap":  # another field's value (a realistic wrong type)
            other_box, other_key = draw(st.sampled_from(slots))
            box[key] = copy.deepcopy(other_box[other_key])
        elif op == "drop":
            del box[key]
        elif op == "add":
            if isinstance(box, dict):
                box[draw(st.sampled_from(_near_miss(str(key))))] = box[key]
            else:
                box.append(copy.deepcopy(box[key]))
        elif op == "rename" and isinstance(box, dict):
            new = draw(st.sampled_from(_near_miss(str(key))))
            box[new] = box.pop(key)
    if is_json:
        return json.dumps(doc, indent=1).encode()
    import tomlkit

    try:
        return tomlkit.dumps(doc).encode()
    except Exception:  # a document tomlkit cannot write: not the reader's fault
        assume(False)
        raise


_PARSED: dict[str, Any] = {}


def _parsed(kind: str) -> Any:
    if kind not in _PARSED:
        text = BASES[kind].read_text(encoding="utf-8")
        _PARSED[kind] = json.loads(text) if EXT[kind] == "json" else tomllib.loads(text)
    return _PARSED[kind]


# CSV: cells, columns and metadata

_CELLS = ["", " ", "0", "-1", "1.5", "2048", "4095", "4096", "16777215", "16777216", "-0",
          "nan", "inf", "-inf", "1e400", "1e-300", "1e304", "9" * 400, "9" * 5000, "2²", "+-5",
          "١٢", "lock", "task", "open", "lokc", '"3"', "0x10", "1_000", "true", " 7 ", "\x00",
          "4.000235", "0.004", "a,b"]  # fmt: skip
_META = ["# period_s: 0", "# period_s: -0.004", "# period_s: nan", "# period_s: 1e-300",
         "# counter_bits: 24.0", "# counter_bits: 64", "# counter_bits: 1000000",
         "# dac_bits: 0", "# dac_bits: 99999", "# dac_range_v: 10,-10", "# dac_range_v: -inf,inf",
         "# dac_range_v: 5", "# axis: nobody", "# period_s", "#", "# : 1", "# unknown: 1",
         "# dac_range_v: -10,10,20"]  # fmt: skip


_CSV_OPS = ("cell", "cell", "cell", "rename", "drop_col", "dup_col", "swap_cols", "meta",
            "drop_meta", "drop_row", "dup_row")  # fmt: skip
_COLUMNS = ("master.pos_counts", "slave.dac_code", "x.dac_code", "dac_code", "tick", "time_s", "")


def _csv_parts(kind: str) -> tuple[list[str], list[str], list[list[str]]]:
    lines = BASES[kind].read_text(encoding="utf-8").splitlines()
    h = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    return lines[:h], lines[h].split(","), [ln.split(",") for ln in lines[h + 1 :]]


@st.composite
def csv_mutation(draw: st.DrawFn, kind: str) -> bytes:
    meta, header, rows = _csv_parts(kind)
    rows = rows[: draw(st.integers(0, 120))]
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(_CSV_OPS))
        ncol = len(header)
        if op == "cell" and rows and ncol:
            r = draw(st.integers(0, len(rows) - 1))
            c = draw(st.integers(0, ncol - 1))
            if c < len(rows[r]):
                rows[r][c] = draw(st.sampled_from(_CELLS))
        elif op == "rename" and ncol:
            c = draw(st.integers(0, ncol - 1))
            names = [*_near_miss(header[c]), *header, *_COLUMNS]
            header[c] = draw(st.sampled_from(names))
        elif op in ("drop_col", "dup_col", "swap_cols") and ncol:
            c = draw(st.integers(0, ncol - 1))
            d = draw(st.integers(0, ncol - 1))
            for cells in (header, *rows):
                if max(c, d) >= len(cells):
                    continue
                if op == "drop_col":
                    del cells[c]
                elif op == "dup_col":
                    cells.insert(d, cells[c])
                else:
                    cells[c], cells[d] = cells[d], cells[c]
        elif op == "meta":
            meta.insert(draw(st.integers(0, len(meta))), draw(st.sampled_from(_META)))
        elif op == "drop_meta" and meta:
            del meta[draw(st.integers(0, len(meta) - 1))]
        elif op in ("drop_row", "dup_row") and rows:
            r = draw(st.integers(0, len(rows) - 1))
            if op == "drop_row":
                del rows[r]
            else:
                rows.insert(r, list(rows[r]))
    text = "\n".join([*meta, ",".join(header), *(",".join(r) for r in rows)]) + "\n"
    return text.encode("utf-8", "surrogatepass")


# --- the tests -------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
@budget()
@given(data=random_input)
def test_random_bytes(kind: str, data: bytes, workdir: Path) -> None:
    check(kind, workdir, data, "random")


@pytest.mark.parametrize("kind", KINDS)
@budget()
@given(data=st.data())
def test_byte_mutations_of_a_valid_file(kind: str, data: st.DataObject, workdir: Path) -> None:
    blob = data.draw(byte_mutation(BASES[kind].read_bytes()), label="input")
    check(kind, workdir, blob, "byte-mutated")


@pytest.mark.parametrize("kind", [k for k in KINDS if EXT[k] != "csv"])
@budget()
@given(data=st.data())
def test_structural_mutations(kind: str, data: st.DataObject, workdir: Path) -> None:
    blob = data.draw(structural_mutation(kind), label="input")
    check(kind, workdir, blob, "structurally mutated")


@pytest.mark.parametrize("kind", [k for k in KINDS if EXT[k] == "csv"])
@budget()
@given(data=st.data())
def test_csv_mutations(kind: str, data: st.DataObject, workdir: Path) -> None:
    blob = data.draw(csv_mutation(kind), label="input")
    check(kind, workdir, blob, "csv-mutated")


@budget(0.1)
@given(data=st.data())
def test_gantry_with_gain_tuning(data: st.DataObject, workdir: Path) -> None:
    """``servotune sync`` reads with ``resolve=True``: the gains left out are tuned on the
    config's plants (about a second per accepted input, hence fewer examples)."""
    strat = st.one_of(structural_mutation("gantry"), byte_mutation(BASES["gantry"].read_bytes()))
    check("gantry+resolve", workdir, data.draw(strat, label="input"), "mutated")


@pytest.mark.parametrize("kind", ["rig+describe", "excitation+inputs"])
@budget(0.5)
@given(data=st.data())
def test_what_the_verb_does_next(kind: str, data: st.DataObject, workdir: Path) -> None:
    """Past the reader: the rig's derived facts (``servotune rig``), the engine inputs of an
    excitation (``servotune simulate --input``), on whatever the reader accepts."""
    base = kind.split("+")[0]
    if EXT[base] == "csv":
        strat = st.one_of(csv_mutation(base), byte_mutation(BASES[base].read_bytes()))
    else:
        strat = st.one_of(structural_mutation(base), byte_mutation(BASES[base].read_bytes()))
    check(kind, workdir, data.draw(strat, label="input"), "mutated")


@budget(0.5)
@given(data=st.data())
def test_tables_given_as_text(data: st.DataObject, workdir: Path) -> None:
    """``load_tables`` also takes the JSON text itself."""
    strat = st.one_of(structural_mutation("tables"), byte_mutation(BASES["tables"].read_bytes()))
    blob = data.draw(strat, label="input")
    assume(blob.decode("utf-8", "replace").lstrip().startswith("{"))
    check("tables-text", workdir, blob, "mutated text")


@pytest.mark.parametrize("kind", KINDS)
def test_the_bases_are_read(kind: str, workdir: Path) -> None:
    """The mutations start from valid files (else the fuzzing only sees rejections)."""
    target = workdir / f"base-{kind}.{EXT[kind]}"
    shutil.copy(BASES[kind], target)
    reader(kind)(target)
