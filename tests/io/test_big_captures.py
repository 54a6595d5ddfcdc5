"""Captures and logs of any length. halsampler and halscope captures are read a chunk of lines
at a time (memory: the capture's array, not its text), the estimate checked against the memory
budget before reading, progress lines for a large file, and every problem still named by its
line in the file when it sits in a later chunk; the chunked readers are checked against
``numpy.loadtxt`` of the whole file. Logs and mapped CSV files in the plain form are parsed
from their bytes by one compiled pass (no text, no per-line strings), checked against the
general reader of the same rows; the 10,000,000-line capture and log of the reliability
report run in ``make test-slow``."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import servotune.io.log_header as log_header
from servotune.budget import BudgetError, set_memory_budget
from servotune.cli import main
from servotune.errors import LogFormatError
from servotune.io.hal import read_halsampler, read_halscope, read_mapped_csv
from servotune.logs import read_table

COLUMNS = ["pid.0.output", "encoder.0.position", "pid.0.command"]


def _rows(n: int, start: int = 0) -> str:
    """``n`` rows as halsampler -t prints them (sample number, a float pin, two s32 pins)."""
    k = np.arange(start, start + n)
    return "".join(f"{i} {np.sin(i / 7):f} {i % 13 - 6} {i // 5} \n" for i in k)


@pytest.fixture
def small_chunks(monkeypatch) -> None:
    """Chunks of 256 bytes: a capture of a few hundred rows spans dozens of them."""
    monkeypatch.setattr(log_header, "TEXT_CHUNK_BYTES", 256)


def test_chunked_reading_is_the_whole_file_s_numbers(small_chunks, tmp_path) -> None:
    text = _rows(300) + "\n\n" + _rows(200, start=300)  # blank lines in the middle
    path = tmp_path / "cap.txt"
    path.write_text(text)
    cap = read_halsampler(path, columns=COLUMNS, sample_number=True)
    want = np.loadtxt(path, ndmin=2)  # numpy reading the whole file (blank lines skipped)
    np.testing.assert_array_equal(cap.values, want[:, 1:])
    np.testing.assert_array_equal(cap.sample_numbers, want[:, 0].astype(np.int64))
    lines = text.split("\n")
    want_rows = [i + 1 for i, ln in enumerate(lines) if ln.strip()]
    assert cap.lines.tolist() == want_rows  # each row's line in the file, across the blanks


def test_crlf_and_a_byte_order_mark_read_as_before(small_chunks, tmp_path) -> None:
    path = tmp_path / "cap.txt"
    path.write_bytes(b"\xef\xbb\xbf" + _rows(300).replace("\n", "\r\n").encode())
    cap = read_halsampler(path, columns=COLUMNS, sample_number=True)
    assert cap.n_samples == 300 and cap.lines[-1] == 300


@pytest.mark.parametrize(
    ("bad_line", "replace", "message"),
    [
        (251, "oops", "line 251, column 1 (encoder.0.position): 'oops' is not a number"),
        (263, "overrun", "line 263 is halsampler's 'overrun' mark"),
        (277, "nan", "line 277, column 0 (pid.0.output): nan is not finite"),
    ],
)
def test_a_problem_in_a_later_chunk_is_named_by_its_line(
    small_chunks, tmp_path, bad_line, replace, message
) -> None:
    lines = _rows(300).split("\n")
    fields = lines[bad_line - 1].split()
    if replace == "overrun":
        lines[bad_line - 1] = "overrun"
    elif replace == "nan":
        fields[1] = "nan"
        lines[bad_line - 1] = " ".join(fields)
    else:
        fields[2] = replace
        lines[bad_line - 1] = " ".join(fields)
    path = tmp_path / "cap.txt"
    path.write_text("\n".join(lines))
    with pytest.raises(LogFormatError, match=message.replace("(", r"\(").replace(")", r"\)")):
        read_halsampler(path, columns=COLUMNS, sample_number=True)


def test_a_row_of_another_width_in_a_later_chunk_is_named(small_chunks, tmp_path) -> None:
    lines = _rows(300).split("\n")
    lines[230] = lines[230] + " 7"  # line 231: five fields
    path = tmp_path / "cap.txt"
    path.write_text("\n".join(lines))
    with pytest.raises(LogFormatError, match=r"line 231 has 5 fields"):
        read_halsampler(path, columns=COLUMNS, sample_number=True)


def test_a_gap_in_the_sample_numbers_across_chunks_is_named(small_chunks, tmp_path) -> None:
    path = tmp_path / "cap.txt"
    path.write_text(_rows(200) + _rows(100, start=203))
    with pytest.raises(LogFormatError, match=r"jumps from 199 \(line 200\) to 203"):
        read_halsampler(path, columns=COLUMNS, sample_number=True)


def test_over_the_budget_is_refused_before_reading(tmp_path, capsys) -> None:
    """The estimate (rows from the first 64 KiB and the file's size) is refused in one line
    naming the file's size, the rows and the budget; no row is parsed."""
    path = tmp_path / "cap.txt"
    path.write_text(_rows(40_000))  # 1.2 MB; 40,000 rows × 4 fields
    try:
        set_memory_budget("2M")
        with pytest.raises(BudgetError) as err:
            read_halsampler(path, columns=COLUMNS, sample_number=True)
    finally:
        set_memory_budget(None)
    msg = str(err.value)
    assert "reading HAL capture" in msg and "2 MiB" in msg and "4 fields" in msg, msg
    rows = float(msg.split("about ")[2].split(" rows")[0].replace(",", ""))
    assert 40_000 <= rows <= 48_000  # at or above the 40,000 rows (the first ones are shorter)
    rc = main(
        [
            "--max-memory",
            "2M",
            "fit",
            str(path),
            "--map",
            "cmd=pid.0.output,pos=encoder.0.position",
            "--hal-columns",
            ",".join(COLUMNS),
            "--sample-number",
            "--period-s",
            "0.001",
        ]
    )
    err_lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 3 and len(err_lines) == 1 and "memory budget" in err_lines[0], err_lines


def test_a_large_capture_says_how_far_it_has_read(monkeypatch, tmp_path) -> None:
    monkeypatch.setattr(log_header, "TEXT_CHUNK_BYTES", 4096)
    path = tmp_path / "cap.txt"
    path.write_text(_rows(3000))  # about 90 KB: 22 chunks
    said: list[str] = []
    read_halsampler(path, columns=COLUMNS, sample_number=True, progress=said.append)
    assert 5 <= len(said) <= 10, said  # about one line per tenth
    assert all(x.startswith(f"reading HAL capture {path}: ") for x in said), said
    done, total = said[-1].split(": ")[1].split(" of ")
    assert done == total  # the last line: the whole file read


@pytest.mark.slow
def test_ten_million_lines_within_the_memory_budget(tmp_path) -> None:
    """The reliability report's case: a 10,000,000-line halsampler capture (here 3 pins,
    about 180 MB) is read within the default 2 GiB budget, in a process of its own whose peak
    resident memory (the interpreter and numpy included) stays under the reader's estimate."""
    block = "".join(f"{np.sin(i / 7):f} {i % 13 - 6} {i // 5} \n" for i in range(100_000))
    path = tmp_path / "cap10m.txt"
    with open(path, "w") as f:
        for _ in range(100):
            f.write(block)
    code = (
        "import resource, sys, time\n"
        "from servotune.io.hal import read_halsampler\n"
        "t0 = time.perf_counter()\n"
        f"cap = read_halsampler(sys.argv[1], columns={COLUMNS!r})\n"
        "s = time.perf_counter() - t0\n"
        "print(cap.n_samples, int(cap.lines[-1]), cap.values[-1].tolist(), s,\n"
        "      resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True
    ).stdout.split(maxsplit=2)
    n, last_line = int(out[0]), int(out[1])
    values, seconds, peak = out[2].rsplit(maxsplit=2)
    assert n == 10_000_000 and last_line == 10_000_000
    assert values == str(np.loadtxt(block.splitlines()[-1:], ndmin=2)[0].tolist())
    estimate = 10_000_000 * 3 * (8 * 3 + 8) + 8 * log_header.TEXT_CHUNK_BYTES
    assert int(peak) < estimate < 2 * 1024**3, (peak, estimate)
    print(
        f"10,000,000 lines ({path.stat().st_size / 1e6:.0f} MB): {float(seconds):.1f} s, "
        f"peak resident {int(peak) / 2**20:.0f} MiB"
    )


def _scope(n: int) -> str:
    """A halscope file: the period line, the channels, a display setting, ``n`` rows."""
    k = np.arange(n)
    rows = "".join(f"{np.sin(i / 7):f};{i % 13 - 6};{i // 5}\n" for i in k)
    return "# Sampling period is 1000000 ns\ncmd;pos;ref\n# Scale: 1\n" + rows


def test_halscope_is_read_a_chunk_at_a_time_as_numpy_reads_it(small_chunks, tmp_path) -> None:
    path = tmp_path / "scope.txt"
    path.write_text(_scope(400))  # about 9 KB: dozens of 256-byte chunks
    said: list[str] = []
    cap = read_halscope(path, progress=said.append)
    want = np.loadtxt(path, delimiter=";", skiprows=3, ndmin=2)  # numpy reading it whole
    np.testing.assert_array_equal(cap.values, want)
    assert cap.names == ("cmd", "pos", "ref") and cap.period_s == 1e-3
    assert cap.lines.tolist() == list(range(4, 404))
    assert said and all(x.startswith(f"reading HAL capture {path}: ") for x in said), said
    done, total = said[-1].split(": ")[1].split(" of ")
    assert done == total  # the last progress line: the whole file read


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda ls: ls.__setitem__(300, "0.5;x;2"), r"line 301, column 1 \(pos\): 'x' is not"),
        (lambda ls: ls.__setitem__(300, "0.5;1"), r"line 301 has 2 fields, the rows before it 3"),
        (lambda ls: ls.__setitem__(300, "0.5;1;inf"), r"line 301, column 2 \(ref\): inf is not"),
    ],
)
def test_a_halscope_problem_in_a_later_chunk_is_named_by_its_line(
    small_chunks, tmp_path, edit, message
) -> None:
    lines = _scope(400).split("\n")
    edit(lines)
    path = tmp_path / "scope.txt"
    path.write_text("\n".join(lines))
    with pytest.raises(LogFormatError, match=message):
        read_halscope(path)


def test_halscope_rows_of_another_width_than_the_channels_are_named(tmp_path) -> None:
    path = tmp_path / "scope.txt"
    path.write_text(_scope(300).replace("cmd;pos;ref", "cmd;pos;ref;extra"))
    with pytest.raises(LogFormatError, match=r"line 4 has 3 fields; line 2 names 4 channels"):
        read_halscope(path)


def _plain_log(n: int) -> str:
    k = np.arange(n)
    rows = "".join(f"{i},{np.sin(i / 7):.6f},{i // 5},{i % 7}\n" for i in k)
    return "# period_s: 0.001\ntick,u,y,note\n" + rows


def test_a_plain_mapped_csv_reads_as_the_general_reader_reads_it(tmp_path) -> None:
    """The same rows parsed from the bytes (plain ASCII) and by the general reader (the same
    file behind a byte-order mark, which the compiled pass leaves alone): equal columns and
    row lines, and a column that is not mapped may still hold text."""
    plain, marked = tmp_path / "plain.csv", tmp_path / "marked.csv"
    plain.write_text(_plain_log(500))
    marked.write_bytes(b"\xef\xbb\xbf" + _plain_log(500).encode())
    mapping = {"tick": "tick", "cmd": "u", "pos": "y"}
    a, b = read_mapped_csv(plain, mapping), read_mapped_csv(marked, mapping)
    np.testing.assert_array_equal(a.values, b.values)
    np.testing.assert_array_equal(a.lines, b.lines)
    assert a.lines[0] == 3 and a.lines[-1] == 502
    texty = tmp_path / "texty.csv"
    texty.write_text(_plain_log(500).replace(",0\n", ",zero\n"))  # text in 'note'
    np.testing.assert_array_equal(read_mapped_csv(texty, mapping).values[:, :3], a.values[:, :3])


def test_a_plain_table_keeps_mode_names_and_line_numbers(tmp_path) -> None:
    body = "".join(f"{i},{2048 + i % 9},{i * 3},{'lock' if i % 2 else 'task'}\n" for i in range(50))
    plain, marked = tmp_path / "plain.csv", tmp_path / "marked.csv"
    plain.write_text("tick,dac_code,counter,mode\n" + body)
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = read_table(plain), read_table(marked)
    assert a.columns.keys() == b.columns.keys()
    for h in a.columns:
        np.testing.assert_array_equal(a.columns[h], b.columns[h])
    assert a.columns["mode"][:2].tolist() == ["task", "lock"]
    np.testing.assert_array_equal(a.row_lines, np.arange(2, 52))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["halscope", "log", "mapped"])
def test_ten_million_lines_of_each_kind_within_the_budget(tmp_path, kind) -> None:
    """A 10,000,000-line halscope file, servotune log and mapped CSV are each read within the
    default 2 GiB budget, in a process of its own (peak resident memory measured)."""
    i = np.arange(100_000)
    if kind == "halscope":
        head = "# Sampling period is 1000000 ns\ncmd;pos;ref\n"
        block = "".join(f"{np.sin(k / 7):f};{k % 13 - 6};{k // 5}\n" for k in i.tolist())
        read = "read_halscope(sys.argv[1]).n_samples"
    elif kind == "log":
        head, block = "# period_s: 0.004\ntick,dac_code,counter\n", None
        read = "read_log(sys.argv[1]).axis().pos_counts.size"
    else:
        head = "# period_s: 0.001\nu,y,note\n"
        block = "".join(f"{np.sin(k / 7):f},{k // 5},{k % 3}\n" for k in i.tolist())
        read = "read_mapped_csv(sys.argv[1], {'cmd': 'u', 'pos': 'y'}).n_samples"
    path = tmp_path / "big.txt"
    with open(path, "w") as f:
        f.write(head)
        for b in range(100):
            if block is None:
                ticks = (i + b * 100_000).tolist()
                f.write("".join(f"{t},{2048 + t % 400},{t * 3 % 2**24}\n" for t in ticks))
            else:
                f.write(block)
    code = (
        "import resource, sys, time\n"
        "from servotune.io.hal import read_halscope, read_mapped_csv\n"
        "from servotune.logs import read_log\n"
        "t0 = time.perf_counter()\n"
        f"n = {read}\n"
        "print(n, time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True
    ).stdout.split()
    n, seconds, peak = int(out[0]), float(out[1]), int(out[2]) * 1024
    assert n == 10_000_000
    assert peak < 2 * 1024**3, peak  # the default budget
    print(f"{kind}: 10,000,000 lines: {seconds:.1f} s, peak resident {peak / 2**20:.0f} MiB")
