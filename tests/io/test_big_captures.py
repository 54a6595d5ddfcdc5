"""halsampler captures of any length: read a chunk of lines at a time (memory: the capture's
array, not its text), the estimate checked against the memory budget before reading, progress
lines for a large file, and every problem still named by its line in the file when it sits in
a later chunk. The chunked reader is checked against ``numpy.loadtxt`` of the whole file; the
10,000,000-line capture of the reliability report runs in ``make test-slow``."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import servotune.io.log_header as log_header
from servotune.budget import BudgetError, set_memory_budget
from servotune.cli import main
from servotune.errors import LogFormatError
from servotune.io.hal import read_halsampler

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
