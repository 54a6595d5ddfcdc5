"""Regenerate the malformed-input corpus (tests/corpus/<kind>/<name>.<ext>), its manifest and
README from valid files by small edits.

Every case is one realistic mistake or adversarial input; ``exit`` is the exit code the CLI
must give (3 bad input; 0 for the few ``accepted-*`` files, which are valid and must be read).
``hint`` is a field name the one-line message may name instead of the file. Cases marked
``generated`` are too big to commit (megabytes): the tests build them with :func:`build`.

Run from the repository root::

    .venv/bin/python tests/corpus/make_corpus.py           # corpus from tests/corpus/base/
    .venv/bin/python tests/corpus/make_corpus.py --bases   # first remake the bases (~20 s)

The bases: plants/*.toml as they are; ``base/log.csv`` (``servotune simulate`` prbs, 1 s),
``base/excitation.csv`` (``servotune excite`` prbs, 1 s), ``base/tuning.json`` (a 2-generation
tune, as tests/cli/test_verify_cli.py's quick tuning) and ``base/tables.json`` (its unverified
tables export). Remake them when a file format changes, then the corpus.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
BASE = HERE / "base"
PLANTS = ROOT / "plants"
KINDS = ("rig", "spec", "log", "excitation", "tuning", "tables", "gantry", "linkage")
EXT = {
    "rig": "toml",
    "spec": "toml",
    "gantry": "toml",
    "linkage": "toml",
    "log": "csv",
    "excitation": "csv",
    "tuning": "json",
    "tables": "json",
}


@dataclass(frozen=True)
class Case:
    kind: str
    name: str  # file name without the extension
    what: str  # what is wrong (README)
    build: Callable[[], bytes]
    exit: int = 3
    hint: str | None = None
    generated: bool = False

    @property
    def file(self) -> str:
        return f"{self.name}.{EXT[self.kind]}"


CASES: list[Case] = []


def case(kind: str, name: str, what: str, **kw: Any) -> Callable[[Callable[[], Any]], None]:
    def register(fn: Callable[[], Any]) -> None:
        def build() -> bytes:
            out = fn()
            return out.encode("utf-8") if isinstance(out, str) else out

        CASES.append(Case(kind, name, what, build, **kw))

    return register


def text_case(kind: str, name: str, what: str, edit: Callable[[str], str], **kw: Any) -> None:
    case(kind, name, what, **kw)(lambda: edit(base_text(kind)))


# --- the bases -------------------------------------------------------------------------------


def base_path(kind: str) -> Path:
    return {
        "rig": PLANTS / "pc-dual-servo.toml",
        "spec": PLANTS / "pc-dual-servo.spec.toml",
        "gantry": PLANTS / "gantry.toml",
        "linkage": PLANTS / "linkage-6axis.toml",
        "log": BASE / "log.csv",
        "excitation": BASE / "excitation.csv",
        "tuning": BASE / "tuning.json",
        "tables": BASE / "tables.json",
    }[kind]


def base_text(kind: str) -> str:
    return base_path(kind).read_text(encoding="utf-8")


def base_json(kind: str) -> Any:
    return json.loads(base_text(kind))


def make_bases() -> None:
    """Remake base/*.csv and base/*.json with the installed servotune."""
    BASE.mkdir(exist_ok=True)
    rig = PLANTS / "pc-dual-servo.toml"
    cli = [sys.executable, "-m", "servotune.cli"]
    subprocess.run(
        [
            *cli,
            "simulate",
            str(rig),
            "--scenario",
            "prbs",
            "--seconds",
            "1",
            "-o",
            str(BASE / "log.csv"),
        ],
        check=True,
        cwd=ROOT,
    )
    subprocess.run(
        [
            *cli,
            "excite",
            "--rig",
            str(rig),
            "--kind",
            "prbs",
            "--seconds",
            "1",
            "-o",
            str(BASE / "excitation.csv"),
        ],
        check=True,
        cwd=ROOT,
    )
    from servotune.export.json import to_string
    from servotune.tune.slave import SlaveTuneSpec
    from servotune.tune.workflow import tune_rig
    from servotune.tuning import write_tuning

    spec = SlaveTuneSpec(generations=2, population=6, max_overshoot_pct=300.0)
    tuning = tune_rig(Path("plants/pc-dual-servo.toml"), spec=spec)
    write_tuning(tuning, BASE / "tuning.json")
    (BASE / "tables.json").write_text(to_string(tuning, unverified=True), encoding="utf-8")


# --- edit helpers ----------------------------------------------------------------------------


def sub(text: str, old: str, new: str, count: int = 1) -> str:
    """Replace ``old`` (which must occur exactly ``count`` times) by ``new``."""
    n = text.count(old)
    if n != count:
        raise SystemExit(f"make_corpus: expected {count} of {old!r} in the base, found {n}")
    return text.replace(old, new)


def resub(
    text: str, pattern: str, new: str | Callable[[re.Match[str]], str], count: int = 1
) -> str:
    out, n = re.subn(pattern, new, text, flags=re.M)
    if n != count:
        raise SystemExit(f"make_corpus: expected {count} matches of {pattern!r}, found {n}")
    return out


def in_sync(text: str, line: str, new: str) -> str:
    """Replace the whole line ``line`` in the spec's ``[scenario.sync]`` table (other
    scenarios may have the same line)."""
    return resub(
        text,
        r"(^\[scenario\.sync\]\n(?:[^\[].*\n|\n)*?)" + re.escape(line) + "$",
        lambda m: m.group(1) + new,
    )


_SYNC_LIMIT = "max_sync_error_counts = 1843.0"  # plants/pc-dual-servo.spec.toml, [scenario.sync]


def drop_section(text: str, header: str) -> str:
    """Remove a TOML table ``[header]`` and its keys (up to the next header)."""
    return resub(text, r"^\[" + re.escape(header) + r"\][^\n]*\n(?:(?!\[)[^\n]*\n)*", "")


_NUM = r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"
_NUM_LIST = re.compile(r"\[\n\s*(" + _NUM + r"(?:,\n\s*" + _NUM + r")*)\n\s*\]")


def dumps(doc: Any) -> str:
    """JSON as servotune writes it (sorted keys, indent 2; number rows on one line)."""
    text = json.dumps(doc, sort_keys=True, indent=2, ensure_ascii=False)
    text = _NUM_LIST.sub(lambda m: "[" + re.sub(r",\n\s*", ", ", m.group(1)) + "]", text)
    return text + "\n"


def json_case(kind: str, name: str, what: str, edit: Callable[[Any], Any], **kw: Any) -> None:
    def build() -> str:
        doc = base_json(kind)
        out = edit(doc)
        return dumps(doc if out is None else out)

    case(kind, name, what, **kw)(build)


def slave_ctl(doc: Any) -> dict[str, Any]:
    """The fuzzy-PID axis's controller in a tuning file."""
    return next(a["controller"] for a in doc["axes"] if a["controller"]["law"] == "fuzzy_pid")


def slave_tables_axis(doc: Any) -> dict[str, Any]:
    """The fuzzy-PID axis in a tables export."""
    return next(a for a in doc["data"]["axes"] if a["law"] == "fuzzy_pid")


def csv_lines(kind: str) -> tuple[list[str], int]:
    """The base CSV's lines and the index of its header line."""
    lines = base_text(kind).splitlines()
    return lines, next(i for i, ln in enumerate(lines) if not ln.startswith("#"))


def csv_edit(kind: str, edit: Callable[[list[str], list[str], int], None]) -> Callable[[], str]:
    """``edit(lines, header, h)`` changes the lines in place; h is the header's index."""

    def build() -> str:
        lines, h = csv_lines(kind)
        edit(lines, lines[h].split(","), h)
        return "\n".join(lines) + "\n"

    return build


def set_cell(lines: list[str], header: list[str], row: int, col: str, value: str) -> None:
    cells = lines[row].split(",")
    cells[header.index(col)] = value
    lines[row] = ",".join(cells)


def set_column(lines: list[str], header: list[str], h: int, col: str, fn: Callable) -> None:
    for k, i in enumerate(range(h + 1, len(lines))):
        set_cell(lines, header, i, col, fn(k))


GARBAGE = bytes((i * 197 + 89) % 256 for i in range(700))  # deterministic binary noise


def common_cases(kind: str) -> None:
    """Empty, binary, truncated, UTF-16 and NUL-byte versions of a kind's base."""
    case(kind, "empty", "empty file (0 bytes)")(lambda: b"")
    case(kind, "whitespace-only", "only blank lines and spaces")(lambda: "\n  \n\t\n")
    case(kind, "binary-garbage", "700 bytes of binary noise, not text")(lambda: GARBAGE)
    case(kind, "utf16", "the base saved as UTF-16 (a Windows editor's 'Unicode')")(
        lambda: base_text(kind).encode("utf-16")
    )
    case(kind, "nul-byte", "a NUL byte in the middle of the file")(
        lambda: (lambda b: b[: len(b) // 2] + b"\x00" + b[len(b) // 2 :])(
            base_path(kind).read_bytes()
        )
    )
    case(kind, "truncated", "the base cut off at 60 % (a copy interrupted mid-way)")(
        lambda: (lambda b: b[: int(len(b) * 0.6)])(base_path(kind).read_bytes())
    )


# --- rig -------------------------------------------------------------------------------------

R = "rig"
common_cases(R)
text_case(
    R,
    "bits-float",
    "counter.bits = 24.0 (a float where an integer belongs)",
    lambda t: sub(t, "bits = 24 ", "bits = 24.0 "),
    hint="bits",
)
text_case(
    R,
    "bits-string",
    'counter.bits = "24" (a string)',
    lambda t: sub(t, "bits = 24 ", 'bits = "24" '),
    hint="bits",
)
text_case(
    R,
    "bits-100000",
    "counter.bits = 100000 (2**bits counts)",
    lambda t: sub(t, "bits = 24 ", "bits = 100000 "),
    hint="bits",
)
text_case(
    R,
    "bits-5000-digits",
    "counter.bits is a 5000-digit integer (beyond Python's int-string limit)",
    lambda t: sub(t, "bits = 24 ", "bits = " + "9" * 5000 + " "),
    hint="bits",
)
text_case(
    R, "dac-bits-zero", "dac.bits = 0", lambda t: sub(t, "bits = 12 ", "bits = 0 "), hint="bits"
)
text_case(
    R,
    "lock-gain-huge",
    "master lock_gain_codes_per_count = 1e10",
    lambda t: sub(
        t, "lock_gain_codes_per_count = 0.4     #", "lock_gain_codes_per_count = 1e10     #"
    ),
    hint="lock_gain_codes_per_count",
)
text_case(
    R,
    "lock-gain-nan",
    "master lock_gain_codes_per_count = nan",
    lambda t: sub(
        t, "lock_gain_codes_per_count = 0.4     #", "lock_gain_codes_per_count = nan     #"
    ),
    hint="lock_gain_codes_per_count",
)
text_case(
    R,
    "offset-1000v",
    "master plant offset_v = 1000.0 (the D/A spans ±10 V)",
    lambda t: sub(t, "offset_v = 0.005 ", "offset_v = 1000.0 "),
    hint="offset_v",
)
text_case(
    R,
    "period-zero",
    "timer.period_s = 0.0",
    lambda t: sub(t, "period_s = 0.004 ", "period_s = 0.0 "),
    hint="period_s",
)
text_case(
    R,
    "period-negative",
    "timer.period_s = -0.004",
    lambda t: sub(t, "period_s = 0.004 ", "period_s = -0.004 "),
    hint="period_s",
)
text_case(
    R,
    "period-inf",
    "timer.period_s = inf",
    lambda t: sub(t, "period_s = 0.004 ", "period_s = inf "),
    hint="period_s",
)
text_case(
    R,
    "period-1e-300",
    "timer.period_s = 1e-300 (divisor 0)",
    lambda t: sub(t, "period_s = 0.004 ", "period_s = 1e-300 "),
    hint="period_s",
)
text_case(
    R,
    "period-date",
    "timer.period_s = 2024-01-01 (a TOML date)",
    lambda t: sub(t, "period_s = 0.004 ", "period_s = 2024-01-01 "),
    hint="period_s",
)
text_case(
    R,
    "clock-1e400",
    "timer.clock_hz = 1e400 (overflows to inf)",
    lambda t: sub(t, "clock_hz = 1193180 ", "clock_hz = 1e400 "),
    hint="clock_hz",
)
text_case(
    R,
    "range-reversed",
    "dac.range_v = [10.0, -10.0]",
    lambda t: sub(t, "range_v = [-10.0, 10.0]", "range_v = [10.0, -10.0]"),
    hint="range_v",
)
text_case(
    R,
    "range-one-value",
    "dac.range_v = [10.0]",
    lambda t: sub(t, "range_v = [-10.0, 10.0]", "range_v = [10.0]"),
    hint="range_v",
)
text_case(
    R,
    "range-strings",
    'dac.range_v = ["-10", "10"]',
    lambda t: sub(t, "range_v = [-10.0, 10.0]", 'range_v = ["-10", "10"]'),
    hint="range_v",
)
text_case(
    R,
    "lock-gain-near-miss",
    "unknown key lock_gain_codes_per_cnt (a typo) in [axis.master]",
    lambda t: sub(
        t, "lock_gain_codes_per_count = 0.4     #", "lock_gain_codes_per_cnt = 0.4     #"
    ),
    hint="lock_gain_codes_per_cnt",
)
text_case(
    R,
    "section-typo",
    "[encodr] instead of [encoder]",
    lambda t: sub(t, "[encoder]", "[encodr]"),
    hint="encodr",
)
text_case(
    R, "missing-timer", "no [timer] section", lambda t: drop_section(t, "timer"), hint="timer"
)
text_case(
    R, "no-axes", "no [axis.*] sections", lambda t: t[: t.index("[axis.master]")], hint="axis"
)
text_case(
    R,
    "two-masters",
    'both axes role = "master"',
    lambda t: sub(t, 'role = "slave"', 'role = "master"'),
    hint="role",
)
text_case(
    R,
    "role-boss",
    'slave role = "boss"',
    lambda t: sub(t, 'role = "slave"', 'role = "boss"'),
    hint="role",
)
text_case(
    R,
    "travel-reversed",
    "master travel_counts = [2000000, -2000000]",
    lambda t: sub(
        t,
        "travel_counts = [-2000000, 2000000]\ncounter_init = 0xFFC000",
        "travel_counts = [2000000, -2000000]\ncounter_init = 0xFFC000",
    ),
    hint="travel_counts",
)
text_case(
    R,
    "counter-init-negative",
    "master counter_init = -1",
    lambda t: sub(t, "counter_init = 0xFFC000", "counter_init = -1"),
    hint="counter_init",
)
text_case(
    R,
    "counter-init-25bit",
    "master counter_init = 0x1000000 (beyond the 24-bit register)",
    lambda t: sub(t, "counter_init = 0xFFC000", "counter_init = 0x1000000"),
    hint="counter_init",
)
text_case(
    R,
    "same-dac-channel",
    "both axes on dac_channel 0",
    lambda t: sub(t, "dac_channel = 1", "dac_channel = 0"),
    hint="dac_channel",
)
text_case(
    R,
    "pulses-zero",
    "encoder.pulses_per_rev = 0",
    lambda t: sub(t, "pulses_per_rev = 3072", "pulses_per_rev = 0"),
    hint="pulses_per_rev",
)
text_case(
    R,
    "tau-zero",
    "master plant tau_s = 0.0",
    lambda t: sub(t, "tau_s = 0.025", "tau_s = 0.0"),
    hint="tau_s",
)
text_case(
    R,
    "speed-limit-table",
    "master speed_limit_rpm = { value = 600 } (a table)",
    lambda t: sub(
        t,
        "speed_limit_rpm = 600\nfollowing_error_limit_counts = 12288   # one "
        "revolution\ntravel_counts = [-2000000, 2000000]\ncounter_init = 0xFFC000",
        "speed_limit_rpm = { value = 600 }\nfollowing_error_limit_counts = 12288"
        "   # one revolution\ntravel_counts = [-2000000, 2000000]\n"
        "counter_init = 0xFFC000",
    ),
    hint="speed_limit_rpm",
)
text_case(
    R,
    "speed-limit-subnormal",
    "master speed_limit_rpm = 5e-324 (> 0, but its counts per second underflow to 0)",
    lambda t: sub(
        t,
        "speed_limit_rpm = 600\nfollowing_error_limit_counts = 12288   # one "
        "revolution\ntravel_counts = [-2000000, 2000000]\ncounter_init = 0xFFC000",
        "speed_limit_rpm = 5e-324\nfollowing_error_limit_counts = 12288   # one "
        "revolution\ntravel_counts = [-2000000, 2000000]\ncounter_init = 0xFFC000",
    ),
    hint="speed_limit_rpm",
)
text_case(
    R,
    "array-nested-5000",
    "an unknown key holding an array nested 5000 deep",
    lambda t: t + "\nx = " + "[" * 5000 + "]" * 5000 + "\n",
)
case(R, "not-utf8", "a Latin-1 '±' byte (0xB1) in the description")(
    lambda: sub(base_text(R), "12-bit ±10 V", "12-bit @@10 V").encode().replace(b"@@", b"\xb1")
)
text_case(
    R,
    "accepted-bom",
    "VALID: a UTF-8 byte-order mark before the first line (Windows Notepad); must be read",
    lambda t: "\ufeff" + t,
    exit=0,
)
text_case(
    R,
    "accepted-crlf",
    "VALID: CRLF line ends; must be read",
    lambda t: t.replace("\n", "\r\n"),
    exit=0,
)

# --- spec ------------------------------------------------------------------------------------

S = "spec"
case(S, "empty", "empty file (0 bytes)")(lambda: b"")
case(S, "binary-garbage", "700 bytes of binary noise")(lambda: GARBAGE)
text_case(
    S,
    "count-negative",
    "montecarlo.count = -1",
    lambda t: sub(t, "count = 64\n", "count = -1\n"),
    hint="count",
)
text_case(
    S,
    "count-float",
    "montecarlo.count = 64.5",
    lambda t: sub(t, "count = 64\n", "count = 64.5\n"),
    hint="count",
)
text_case(
    S,
    "count-1e9",
    "montecarlo.count = 1000000000 (a run of years)",
    lambda t: sub(t, "count = 64\n", "count = 1000000000\n"),
    hint="count",
)
text_case(
    S,
    "seconds-zero",
    "scenario.sync.seconds = 0",
    lambda t: in_sync(t, "seconds = 2.4", "seconds = 0"),
    hint="seconds",
)
text_case(
    S,
    "seconds-1e12",
    "scenario.lock.seconds = 1e12",
    lambda t: sub(t, "seconds = 10.0", "seconds = 1e12"),
    hint="seconds",
)
text_case(
    S,
    "limit-nan",
    "scenario.sync.max_sync_error_counts = nan",
    lambda t: in_sync(t, _SYNC_LIMIT, "max_sync_error_counts = nan"),
    hint="max_sync_error_counts",
)
text_case(
    S,
    "limit-400-digits",
    "scenario.sync.max_sync_error_counts = 10**400 (an integer beyond the float range)",
    lambda t: in_sync(t, _SYNC_LIMIT, "max_sync_error_counts = 1" + "0" * 400),
    hint="max_sync_error_counts",
)
text_case(
    S,
    "spread-string",
    'montecarlo.gain_spread = "20%"',
    lambda t: sub(t, "gain_spread = 0.2 ", 'gain_spread = "20%" '),
    hint="gain_spread",
)
text_case(
    S,
    "tau-spread-1.5",
    "montecarlo.tau_spread = 1.5 (variants with a negative time constant)",
    lambda t: sub(t, "tau_spread = 0.3 ", "tau_spread = 1.5 "),
    hint="tau_spread",
)
text_case(
    S,
    "limit-near-miss",
    "unknown key max_sync_eror_counts (a typo) in [scenario.sync]",
    lambda t: in_sync(t, _SYNC_LIMIT, _SYNC_LIMIT.replace("error", "eror")),
    hint="max_sync_eror_counts",
)
text_case(
    S,
    "settle-after-end",
    "scenario.lock.settle_s = 20 > its seconds = 10",
    lambda t: sub(t, "settle_s = 2.0 ", "settle_s = 20.0 "),
    hint="settle_s",
)
text_case(
    S,
    "rig-other",
    'spec.rig = "gantry" (a spec for another rig)',
    lambda t: sub(t, 'rig = "pc-dual-servo"', 'rig = "gantry"'),
    hint="rig",
)
text_case(
    S,
    "no-scenarios",
    "every [scenario.*] section removed",
    lambda t: t[: t.index("[scenario.sync]")],
    hint="scenario",
)

# --- log -------------------------------------------------------------------------------------

L = "log"
common_cases(L)


case(L, "time-step-1e304", "time_s steps by 1e304 s (tick k at k·1e304)", hint="time_s")(
    csv_edit(L, lambda ln, hd, h: set_column(ln, hd, h, "time_s", lambda k: repr(k * 1e304)))
)
case(L, "time-step-1e-300", "time_s steps by 1e-300 s", hint="time_s")(
    csv_edit(L, lambda ln, hd, h: set_column(ln, hd, h, "time_s", lambda k: repr(k * 1e-300)))
)
case(L, "time-nan", "one time_s is nan", hint="time_s")(
    csv_edit(L, lambda ln, hd, h: set_cell(ln, hd, h + 40, "time_s", "nan"))
)
case(L, "time-backwards", "two rows swapped: time goes back", hint="time_s")(
    csv_edit(L, lambda ln, hd, h: ln.__setitem__(slice(h + 30, h + 32), ln[h + 30 : h + 32][::-1]))
)
case(L, "counter-float", "a counter reading 16760831.5", hint="counter")(
    csv_edit(L, lambda ln, hd, h: set_cell(ln, hd, h + 20, "master.counter", "16760831.5"))
)
case(L, "counter-25bit", "a counter reading 16777216 (beyond 24 bits)", hint="counter")(
    csv_edit(L, lambda ln, hd, h: set_cell(ln, hd, h + 20, "master.counter", "16777216"))
)
case(L, "counter-superscript", "a counter reading '16760831²' (a unicode digit)", hint="counter")(
    csv_edit(L, lambda ln, hd, h: set_cell(ln, hd, h + 20, "master.counter", "16760831²"))
)
case(
    L,
    "counter-arabic-digits",
    "a counter reading in Arabic-Indic digits '١٦٧٦٠٨٣١'",
    hint="counter",
)(csv_edit(L, lambda ln, hd, h: set_cell(ln, hd, h + 20, "master.counter", "١٦٧٦٠٨٣١")))
case(L, "dac-code-negative", "a dac_code of -1", hint="dac_code")(
    csv_edit(L, lambda ln, hd, h: set_cell(ln, hd, h + 20, "master.dac_code", "-1"))
)
case(L, "dac-code-plus-minus", "a dac_code of '+-5'", hint="dac_code")(
    csv_edit(L, lambda ln, hd, h: set_cell(ln, hd, h + 20, "master.dac_code", "+-5"))
)
case(L, "mode-typo", "a mode 'lokc'", hint="mode")(
    csv_edit(L, lambda ln, hd, h: set_cell(ln, hd, h + 20, "master.mode", "lokc"))
)
case(L, "header-duplicate-column", "master.counter twice in the header", hint="master.counter")(
    csv_edit(
        L, lambda ln, hd, h: ln.__setitem__(h, ln[h].replace("slave.counter", "master.counter"))
    )
)
case(L, "header-near-miss", "column master.countr (a typo)", hint="master.countr")(
    csv_edit(
        L, lambda ln, hd, h: ln.__setitem__(h, ln[h].replace("master.counter", "master.countr"))
    )
)
case(L, "header-only", "metadata and header, no rows")(
    csv_edit(L, lambda ln, hd, h: ln.__delitem__(slice(h + 1, None)))
)
case(L, "ragged-row", "a row with one field missing")(
    csv_edit(L, lambda ln, hd, h: ln.__setitem__(h + 50, ln[h + 50].rsplit(",", 1)[0]))
)
case(L, "extra-field", "a row with one field too many")(
    csv_edit(L, lambda ln, hd, h: ln.__setitem__(h + 50, ln[h + 50] + ",0"))
)
case(L, "meta-period-zero", "metadata '# period_s: 0'", hint="period_s")(
    csv_edit(L, lambda ln, hd, h: ln.__setitem__(1, "# period_s: 0"))
)
case(L, "meta-counter-bits-float", "metadata '# counter_bits: 24.0'", hint="counter_bits")(
    csv_edit(L, lambda ln, hd, h: ln.__setitem__(2, "# counter_bits: 24.0"))
)
case(L, "meta-dac-range-inf", "metadata '# dac_range_v: -inf,inf'", hint="dac_range_v")(
    csv_edit(L, lambda ln, hd, h: ln.__setitem__(4, "# dac_range_v: -inf,inf"))
)
case(
    L,
    "semicolon-decimal-comma",
    "exported by a European spreadsheet: ';' separators and decimal commas",
)(
    csv_edit(
        L,
        lambda ln, hd, h: ln.__setitem__(
            slice(h, None),
            [
                x.replace(",", ";")
                .replace(".", ",")
                .replace("master,", "master.")
                .replace("slave,", "slave.")
                for x in ln[h:]
            ],
        ),
    )
)
case(
    L,
    "field-5M-digits",
    "a time_s field of 5,000,000 digits (generated by the test)",
    hint="time_s",
    generated=True,
)(csv_edit(L, lambda ln, hd, h: set_cell(ln, hd, h + 20, "time_s", "1" + "0" * 4_999_999)))


def _drive_off(ln: list[str], hd: list[str], h: int) -> None:
    set_column(ln, hd, h, "master.dac_code", lambda k: "2048")
    set_column(ln, hd, h, "master.counter", lambda k: "16760831")


case(L, "drive-off", "the master never moved: D/A at 0 V and the counter still (nothing to fit)")(
    csv_edit(L, _drive_off)
)
case(L, "too-short-to-fit", "only 60 rows (the fit needs 100 samples)")(
    csv_edit(L, lambda ln, hd, h: ln.__delitem__(slice(h + 61, None)))
)
case(L, "accepted-crlf", "VALID: CRLF line ends (a Windows logger); must be read", exit=0)(
    lambda: base_text(L).replace("\n", "\r\n")
)

# --- excitation ------------------------------------------------------------------------------

E = "excitation"
case(E, "empty", "empty file (0 bytes)")(lambda: b"")
case(E, "binary-garbage", "700 bytes of binary noise")(lambda: GARBAGE)
case(E, "truncated-mid-row", "the last row cut inside its time_s field (no newline)")(
    lambda: (
        (lambda t: t[: t.rindex("\n", 0, len(t) - 1) + 1])(base_text(E))
        + (lambda last: last[: last.index(",") + 3])(base_text(E).splitlines()[-1])
    )
)
_EX_COL = "master.dac_code"
for _name, _value, _what in [
    ("code-superscript", "2²", "a code '2²' (a superscript digit)"),
    ("code-plus-minus", "+-5", "a code '+-5'"),
    ("code-4096", "4096", "a code 4096 (the 12-bit D/A ends at 4095)"),
    ("code-negative", "-1", "a code -1"),
    ("code-float", "2047.5", "a code 2047.5"),
    ("code-nan", "nan", "a code nan"),
    ("code-huge", "9" * 400, "a code of 400 digits"),
]:
    case(E, _name, _what, hint="dac_code")(
        csv_edit(E, lambda ln, hd, h, v=_value: set_cell(ln, hd, h + 30, _EX_COL, v))
    )
case(E, "two-axes", "a second column slave.dac_code", hint="dac_code")(
    csv_edit(
        E,
        lambda ln, hd, h: ln.__setitem__(
            slice(h, None), [ln[h] + ",slave.dac_code"] + [x + ",2048" for x in ln[h + 1 :]]
        ),
    )
)
case(E, "axis-unknown", "column gantry.dac_code: no such axis in the rig", hint="gantry")(
    csv_edit(E, lambda ln, hd, h: ln.__setitem__(h, ln[h].replace("master.", "gantry.")))
)
case(E, "tick-gap", "ticks jump from 9 to 13", hint="tick")(
    csv_edit(E, lambda ln, hd, h: ln.__delitem__(slice(h + 11, h + 14)))
)
case(E, "tick-1e30", "a tick of 10**30", hint="tick")(
    csv_edit(E, lambda ln, hd, h: set_cell(ln, hd, h + 5, "tick", "1" + "0" * 30))
)
case(E, "period-1ms", "metadata '# period_s: 0.001' on the 4 ms rig", hint="period_s")(
    csv_edit(E, lambda ln, hd, h: ln.__setitem__(1, "# period_s: 0.001"))
)
case(E, "dac-bits-16", "metadata '# dac_bits: 16' on the 12-bit rig", hint="dac_bits")(
    csv_edit(
        E,
        lambda ln, hd, h: ln.__setitem__(
            next(i for i, x in enumerate(ln) if x.startswith("# dac_bits")), "# dac_bits: 16"
        ),
    )
)
case(E, "nine-rows", "only 9 rows (the minimum is 10)")(
    csv_edit(E, lambda ln, hd, h: ln.__delitem__(slice(h + 10, None)))
)

# --- tuning ----------------------------------------------------------------------------------

T = "tuning"
case(T, "empty", "empty file (0 bytes)")(lambda: b"")
case(T, "binary-garbage", "700 bytes of binary noise")(lambda: GARBAGE)
case(T, "truncated", "the base cut off at 60 %")(
    lambda: (lambda b: b[: int(len(b) * 0.6)])(base_path(T).read_bytes())
)
case(T, "top-level-array", "a JSON array, not an object")(lambda: "[]\n")
json_case(
    T,
    "role-boss",
    'axes[1].role = "boss"',
    lambda d: d["axes"][1].__setitem__("role", "boss"),
    hint="role",
)
json_case(
    T,
    "n-string",
    'the slave\'s "n": "6" (a string)',
    lambda d: slave_ctl(d)["task"].__setitem__("n", "6"),
    hint="n",
)
json_case(
    T,
    "n-infinity",
    'the slave\'s "n": Infinity (non-standard JSON)',
    lambda d: slave_ctl(d)["task"].__setitem__("n", float("inf")),
    hint="n",
)
json_case(
    T,
    "n-float",
    'the slave\'s "n": 6.0',
    lambda d: slave_ctl(d)["task"].__setitem__("n", 6.0),
    hint="n",
)
json_case(
    T,
    "table-entry-float",
    "a table entry 1.7",
    lambda d: slave_ctl(d)["task"]["tables"]["kp"]["q"][3].__setitem__(4, 1.7),
    hint="kp",
)
json_case(
    T,
    "table-entry-int16-overflow",
    "a table entry 40000 (beyond int16)",
    lambda d: slave_ctl(d)["task"]["tables"]["kp"]["q"][3].__setitem__(4, 40000),
    hint="kp",
)
json_case(
    T,
    "table-row-short",
    "a table row with one entry missing",
    lambda d: slave_ctl(d)["task"]["tables"]["ki"]["q"][2].pop(),
    hint="ki",
)
json_case(
    T,
    "gain-f-1000",
    "the master's kp fraction bits f = 1000",
    lambda d: d["axes"][0]["controller"]["task"]["kp"].__setitem__("f", 1000),
    hint="kp",
)
json_case(
    T,
    "gain-q-2pow64",
    "the master's kp q = 2**64 (beyond int64)",
    lambda d: d["axes"][0]["controller"]["task"]["kp"].__setitem__("q", 2**64),
    hint="kp",
)
json_case(
    T,
    "schema-old",
    'schema "servotune.tuning/1" (an old file)',
    lambda d: d.__setitem__("schema", "servotune.tuning/1"),
    hint="schema",
)
json_case(
    T,
    "period-negative",
    "period_s = -0.004",
    lambda d: d.__setitem__("period_s", -0.004),
    hint="period_s",
)
json_case(
    T,
    "period-string",
    'period_s = "0.004"',
    lambda d: d.__setitem__("period_s", "0.004"),
    hint="period_s",
)
json_case(
    T,
    "divisor-float",
    "timer_divisor = 4773.0",
    lambda d: d.__setitem__("timer_divisor", float(d["timer_divisor"])),
    hint="timer_divisor",
)
json_case(T, "axes-empty", "axes = []", lambda d: d.__setitem__("axes", []), hint="axes")
json_case(
    T,
    "axis-dropped",
    "the slave axis removed (the rig has two)",
    lambda d: d["axes"].pop(),
    hint="axes",
)
json_case(
    T,
    "controller-missing",
    "axes[0] without its controller",
    lambda d: d["axes"][0].pop("controller"),
    hint="controller",
)
json_case(
    T,
    "period-near-miss",
    'unknown key "perod_s" (a typo for period_s)',
    lambda d: d.__setitem__("perod_s", d.pop("period_s")),
    hint="perod_s",
)
json_case(
    T,
    "law-unknown",
    'the slave\'s law "fuzzy"',
    lambda d: slave_ctl(d).__setitem__("law", "fuzzy"),
    hint="law",
)
json_case(
    T,
    "rig-other",
    'a tuning of another rig (rig.name "gantry", path plants/gantry.toml, not here)',
    lambda d: d["rig"].update(name="gantry", path="plants/gantry.toml"),
    hint="gantry",
)
json_case(
    T,
    "sha-not-hex",
    'rig.sha256 = "not-a-hash"',
    lambda d: d["rig"].__setitem__("sha256", "not-a-hash"),
    hint="sha256",
)
case(T, "nested-200000", "an object nested 200,000 deep (generated by the test)", generated=True)(
    lambda: '{"schema": ' * 200_000 + "1" + "}" * 200_000
)

# --- tables ----------------------------------------------------------------------------------

B = "tables"
case(B, "empty", "empty file (0 bytes)")(lambda: b"")
case(B, "truncated", "the base cut off at 60 %")(
    lambda: (lambda b: b[: int(len(b) * 0.6)])(base_path(B).read_bytes())
)
case(B, "is-a-tuning", "a tuning file given where a tables export belongs")(
    lambda: base_path(T).read_bytes()
)
json_case(
    B,
    "verified-flag-edited",
    '"verified": false edited to true by hand',
    lambda d: d.__setitem__("verified", True),
    hint="verified",
    exit=1,
)
json_case(
    B,
    "period-edited",
    "data.period_s edited (0.004 → 0.002) by hand",
    lambda d: d["data"].__setitem__("period_s", d["data"]["period_s"] / 2),
    hint="period_s",
    exit=1,
)


def _table_recrc(d: Any) -> None:
    from servotune.export.json import table_crc32

    tab = slave_tables_axis(d)["task"]["tables"]["kp"]
    tab["q"][3][4] += 1
    tab["crc32"] = int(table_crc32(tab["q"], tab["f"]))


json_case(
    B,
    "one-table-crc-recomputed",
    "a kp entry changed by 1 and that table's CRC "
    "recomputed (the constants CRC and any document digest left)",
    _table_recrc,
    hint="crc",
    exit=1,
)
json_case(
    B,
    "table-crc-stale",
    "a kp entry changed by 1, CRC left as it was",
    lambda d: slave_tables_axis(d)["task"]["tables"]["kp"]["q"][3].__setitem__(
        4, slave_tables_axis(d)["task"]["tables"]["kp"]["q"][3][4] + 1
    ),
    hint="crc",
    exit=1,
)
json_case(
    B,
    "crc-string",
    'a table crc32 "0x1234abcd" (a string)',
    lambda d: slave_tables_axis(d)["task"]["tables"]["ki"].__setitem__("crc32", "0x1234abcd"),
    hint="crc32",
)
json_case(
    B,
    "counter-bits-20",
    "data.counter_bits = 20",
    lambda d: d["data"].__setitem__("counter_bits", 20),
    hint="counter_bits",
)
json_case(
    B,
    "dac-bits-1e12",
    "data.dac.bits = 10**12 (2**bits is a 125 GB integer)",
    lambda d: d["data"]["dac"].__setitem__("bits", 10**12),
    hint="bits",
)
json_case(
    B,
    "n-huge",
    "the slave's task n = 10**9 (tables of 2n+1 rows)",
    lambda d: slave_tables_axis(d)["task"].__setitem__("n", 10**9),
    hint="n",
)
json_case(
    B,
    "table-entry-nan",
    "a kd entry NaN",
    lambda d: slave_tables_axis(d)["task"]["tables"]["kd"]["q"][0].__setitem__(0, float("nan")),
    hint="kd",
)
json_case(
    B,
    "ref-source-self",
    "the slave's ref_source is its own index",
    lambda d: slave_tables_axis(d).__setitem__("ref_source", slave_tables_axis(d)["index"]),
    hint="ref_source",
)
json_case(
    B,
    "unknown-key-near-miss",
    'an unknown key "verifed" next to "verified"',
    lambda d: d.__setitem__("verifed", True),
    hint="verifed",
)
json_case(
    B,
    "schema-2",
    'schema "servotune.tables/2" (an export of an older servotune, before filters)',
    lambda d: d.__setitem__("schema", "servotune.tables/2"),
    hint="servotune.tables/2",
)
_UNIT_CIRCLE = {"a1": 0, "a2": 4096, "b0": 4096, "b1": 0, "b2": 0, "frac_bits": 12}
json_case(
    B,
    "filter-unstable",
    "a filter section with a2 = 1 (poles on the unit circle) added to the slave by hand",
    lambda d: slave_tables_axis(d)["filters"].append(_UNIT_CIRCLE),
    hint="filters",
)
_NOTCH = {"a1": -6695, "a2": 3544, "b0": 3835, "b1": -6694, "b2": 3804, "frac_bits": 12}
json_case(
    B,
    "filter-added",
    "a stable filter section added to the slave by hand (every CRC and digest left)",
    lambda d: slave_tables_axis(d)["filters"].append(_NOTCH),
    hint="crc",
    exit=1,
)

# --- gantry ----------------------------------------------------------------------------------

G = "gantry"
case(G, "empty", "empty file (0 bytes)")(lambda: b"")
case(G, "truncated", "the base cut off at 58 %, after a key (60 % ends inside a comment)")(
    lambda: (lambda b: b[: int(len(b) * 0.58)])(base_path(G).read_bytes())
)
text_case(
    G,
    "cycle-10s",
    "bus.cycle_s = 10.0 (longer than the 2 s run)",
    lambda t: sub(t, "cycle_s = 0.001 ", "cycle_s = 10.0 "),
    hint="cycle_s",
)
text_case(
    G,
    "cycle-1e-9",
    "bus.cycle_s = 1e-9 (2·10^9 cycles to simulate)",
    lambda t: sub(t, "cycle_s = 0.001 ", "cycle_s = 1e-9 "),
    hint="cycle_s",
)
text_case(
    G,
    "latency-1e9",
    "bus.latency_cycles = 1000000000",
    lambda t: sub(t, "latency_cycles = 1 ", "latency_cycles = 1000000000 "),
    hint="latency_cycles",
)
text_case(
    G,
    "latency-float",
    "bus.latency_cycles = 1.5",
    lambda t: sub(t, "latency_cycles = 1 ", "latency_cycles = 1.5 "),
    hint="latency_cycles",
)
text_case(
    G,
    "topology-typo",
    'gantry.topology = "listenning"',
    lambda t: sub(t, 'topology = "listening"', 'topology = "listenning"'),
    hint="topology",
)
text_case(
    G,
    "rig-missing",
    'gantry.rig = "no-such-rig.toml"',
    lambda t: sub(t, 'rig = "pc-dual-servo.toml"', 'rig = "no-such-rig.toml"'),
    hint="rig",
)
text_case(
    G,
    "rig-is-directory",
    'gantry.rig = "." (a directory)',
    lambda t: sub(t, 'rig = "pc-dual-servo.toml"', 'rig = "."'),
    hint="rig",
)
text_case(
    G,
    "seconds-1e12",
    "gantry.seconds = 1e12",
    lambda t: sub(t, "seconds = 2.0", "seconds = 1e12"),
    hint="seconds",
)
text_case(
    G,
    "jitter-negative",
    "bus.jitter_s = -1e-6",
    lambda t: sub(t, "jitter_s = 1e-6 ", "jitter_s = -1e-6 "),
    hint="jitter_s",
)
text_case(
    G,
    "load-axis-typo",
    'load.axis = "slaev"',
    lambda t: sub(t, 'axis = "slave" ', 'axis = "slaev" '),
    hint="axis",
)
text_case(
    G,
    "dead-zone-near-miss",
    "unknown key dead_zone_count (a typo) in [sync]",
    lambda t: sub(t, "dead_zone_counts = 1 ", "dead_zone_count = 1 "),
    hint="dead_zone_count",
)
text_case(
    G, "law-pid", 'sync.law = "pid"', lambda t: sub(t, 'law = "pi" ', 'law = "pid" '), hint="law"
)
text_case(
    G,
    "speed-zero",
    "move.speed_cps = 0.0 (the move never ends)",
    lambda t: sub(t, "speed_cps = 60000.0", "speed_cps = 0.0"),
    hint="speed_cps",
)
text_case(
    G,
    "trip-below-warn",
    "sync.trip_counts = 100 < warn_counts = 300",
    lambda t: sub(t, "trip_counts = 1500", "trip_counts = 100"),
    hint="trip_counts",
)
text_case(
    G,
    "tau-1e300",
    "the master plant tau_s = 1e300",
    lambda t: sub(t, "tau_s = 0.025", "tau_s = 1e300"),
    hint="tau_s",
)
text_case(
    G,
    "filter-above-nyquist",
    "a slave notch at 600 Hz, above the 1 ms bus cycle's 500 Hz Nyquist frequency",
    lambda t: (
        t
        + '\n[[axis.slave.filters]]\nkind = "notch"\ncenter_hz = 600.0\nwidth_hz = 20.0\n'
        + "depth_db = -20.0\n"
    ),
    hint="axis.slave.filters[0]",
)

# --- linkage ---------------------------------------------------------------------------------

K = "linkage"
case(K, "empty", "empty file (0 bytes)")(lambda: b"")
case(K, "truncated", "the base cut off at 60 %")(
    lambda: (lambda b: b[: int(len(b) * 0.6)])(base_path(K).read_bytes())
)
text_case(
    K,
    "length-1e300",
    "the first line move goes to x = 1e300 counts",
    lambda t: sub(t, "to = { x = 40000, z = 10000", "to = { x = 1e300, z = 10000"),
    hint="x",
)
text_case(
    K,
    "dwell-1e12",
    "a dwell of 1e12 s",
    lambda t: sub(t, "dwell_s = 0.5", "dwell_s = 1e12"),
    hint="dwell_s",
)
text_case(
    K, "baud-zero", "bus.baud = 0", lambda t: sub(t, "baud = 460800 ", "baud = 0 "), hint="baud"
)
text_case(
    K,
    "filter-above-nyquist",
    "a notch on y at 300 Hz, above the 2 ms period's 250 Hz Nyquist frequency",
    lambda t: (
        t
        + '\n[[axis.y.filters]]\nkind = "notch"\ncenter_hz = 300.0\nwidth_hz = 20.0\n'
        + "depth_db = -20.0\n"
    ),
    hint="axis.y.filters[0]",
)
text_case(
    K,
    "block-size-zero",
    "bus.block_size = 0",
    lambda t: sub(t, "block_size = 5 ", "block_size = 0 "),
    hint="block_size",
)
text_case(
    K,
    "axis-on-two-cpus",
    "axis x on both CPUs",
    lambda t: sub(t, 'axes = ["y", "b", "c"]', 'axes = ["y", "b", "c", "x"]'),
    hint="x",
)
text_case(
    K,
    "cpu-axis-unknown",
    "a CPU drives axis 'q', which has no [axis.q]",
    lambda t: sub(t, 'axes = ["x", "z", "a"]', 'axes = ["x", "z", "a", "q"]'),
    hint="q",
)
text_case(
    K,
    "arc-plane-same-axis",
    'arc plane = ["x", "x"]',
    lambda t: sub(t, 'plane = ["x", "y"]', 'plane = ["x", "x"]'),
    hint="plane",
)
text_case(
    K,
    "arc-direction-typo",
    'arc direction = "clockwise"',
    lambda t: sub(t, 'direction = "ccw"', 'direction = "clockwise"'),
    hint="direction",
)
text_case(
    K,
    "move-kind-typo",
    'a move kind = "lien"',
    lambda t: sub(t, 'kind = "line"\nto = { x = 40000', 'kind = "lien"\nto = { x = 40000'),
    hint="kind",
)
text_case(
    K,
    "clock-ppm-minus-1e6",
    "a CPU clock_ppm = -1000000 (a stopped clock)",
    lambda t: sub(t, "clock_ppm = -60.0 ", "clock_ppm = -1000000.0 "),
    hint="clock_ppm",
)
text_case(
    K,
    "period-1e-9",
    "period_s = 1e-9 (10^9 samples a second)",
    lambda t: sub(t, "period_s = 0.002 ", "period_s = 1e-9 "),
    hint="period_s",
)
text_case(
    K,
    "feed-negative",
    "a move feed_cps = -40000",
    lambda t: sub(t, "feed_cps = 40000", "feed_cps = -40000"),
    hint="feed_cps",
)
text_case(
    K, "kp-string", 'axis x kp = "0.36"', lambda t: sub(t, "kp = 0.3617", 'kp = "0.36"'), hint="kp"
)
text_case(
    K,
    "queue-near-miss",
    "unknown key queue_dept (a typo) in a [[cpu]]",
    lambda t: sub(
        t, "queue_depth = 20              # setpoints", "queue_dept = 20              # setpoints"
    ),
    hint="queue_dept",
)


# --- writing ---------------------------------------------------------------------------------


def manifest() -> list[dict[str, Any]]:
    return [
        {
            "kind": c.kind,
            "file": c.file,
            "what": c.what,
            "exit": c.exit,
            "hint": c.hint,
            "generated": c.generated,
        }
        for c in CASES
    ]


def build(kind: str, file: str) -> bytes:
    """The bytes of one case (the tests build the ``generated`` ones with this)."""
    return next(c for c in CASES if c.kind == kind and c.file == file).build()


def readme() -> str:
    n = {code: sum(c.exit == code for c in CASES) for code in (0, 1, 3)}
    lines = [
        "# Malformed-input corpus",
        "",
        "Each file is a valid example with one realistic mistake or adversarial edit, run by",
        "`tests/cli/test_corpus.py` through the command line as a user would, in a temporary",
        "working directory. A malformed file must give exit 3 (bad input data), exactly one",
        "non-empty line on stderr naming the file (or the field), no traceback, and leave the",
        "directory as it was (no output, no temporary file). Tables exports that are",
        "well-formed but were edited after export (a digest or a CRC differs) expect exit 1:",
        "the CLI documents 1 for inputs that are not the verified ones",
        "(`servotune.errors.TrustError`, printed as `refused:`). `accepted-*` files are valid",
        "variants (a BOM, CRLF line ends) that must be read: exit 0.",
        "",
        "| kind | command (in the working directory) |",
        "|---|---|",
        "| rig | `servotune rig FILE` |",
        "| log | `servotune fit FILE --axis master` |",
        "| spec | `servotune verify tuning.json --spec FILE --rig plants/pc-dual-servo.toml` |",
        "| tuning | `servotune verify FILE --spec plants/pc-dual-servo.spec.toml` |",
        "| tables | `servotune check-table FILE` |",
        "| excitation | `servotune simulate plants/pc-dual-servo.toml --input FILE -o out.csv` |",
        "| gantry | `servotune sync FILE` |",
        "| linkage | `servotune linkage FILE` |",
        "",
        "The working directory holds `plants/pc-dual-servo.toml` and its spec, a copy of the",
        "rig as `pc-dual-servo.toml` (gantry and linkage configs name it relative to",
        "themselves) and, for the spec cases, `base/tuning.json` as `tuning.json`.",
        "",
        "`base/` holds the valid files the log, excitation, tuning and tables cases are made",
        "from (the TOML cases start from `plants/`); they are not part of the corpus. Files",
        "marked *generated* are megabytes: the test builds them (`make_corpus.build`).",
        "Regenerate with `.venv/bin/python tests/corpus/make_corpus.py [--bases]` (see its",
        "docstring); edit the cases there, not the files.",
        "",
        f"{n[3]} malformed files (exit 3), {n[1]} edited exports (exit 1), {n[0]} valid variants"
        " (exit 0).",
        "",
    ]
    for kind in KINDS:
        lines += [f"## {kind}", "", "| file | what is wrong | exit |", "|---|---|---|"]
        for c in CASES:
            if c.kind == kind:
                gen = " *(generated)*" if c.generated else ""
                what = c.what.replace("|", "\\|")
                lines.append(f"| `{c.file}`{gen} | {what} | {c.exit} |")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bases", action="store_true", help="remake base/ first (needs servotune)")
    args = ap.parse_args()
    if args.bases:
        make_bases()
    names = [(c.kind, c.file) for c in CASES]
    dup = {x for x in names if names.count(x) > 1}
    if dup:
        raise SystemExit(f"make_corpus: duplicate cases {sorted(dup)}")
    built = {(c.kind, c.file): c.build() for c in CASES if not c.generated}  # all, or none
    for kind in KINDS:
        d = HERE / kind
        d.mkdir(exist_ok=True)
        for old in d.iterdir():
            old.unlink()
    for (kind, file), raw in built.items():
        (HERE / kind / file).write_bytes(raw)
    (HERE / "manifest.json").write_text(json.dumps(manifest(), indent=2) + "\n")
    (HERE / "README.md").write_text(readme())
    print(
        f"wrote {sum(not c.generated for c in CASES)} files, manifest.json and README.md "
        f"({len(CASES)} cases)"
    )


if __name__ == "__main__":
    main()
