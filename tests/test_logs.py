"""Tests for servotune.logs: reading and validating log files (docs/formats.md#log-file), round trip
with the writer.

Row numbers in the messages are 1-based line numbers in the file: with no metadata the header is
line 1 and the first data row is line 2.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from servotune.errors import LogFormatError, ServotuneError
from servotune.hw import dac as hw_dac
from servotune.logs import MIN_ROWS, AxisLog, Log, format_log, read_log

# docs/runtime.md#da-quantisation: 12-bit D/A, LSB = 20 V / 4096, rails -10 V (code 0) and +9.99512
# V (code 4095)
LSB12 = 20.0 / 4096
TOP24 = 2**24 - 1
HEADER = "tick,time_s,dac_code,counter"


def _write(tmp_path: Path, text: str | bytes, name: str = "log.csv") -> Path:
    p = tmp_path / name
    if isinstance(text, bytes):
        p.write_bytes(text)
    else:
        p.write_text(text, encoding="utf-8", newline="")
    return p


def _log(
    tmp_path: Path,
    header: str = HEADER,
    rows: Sequence[str] | None = None,
    meta: Sequence[tuple[str, str]] = (),
    name: str = "log.csv",
) -> Path:
    lines = [f"# {k}: {v}" for k, v in meta] + [header] + list(_rows() if rows is None else rows)
    return _write(tmp_path, "\n".join(lines) + "\n", name)


def _rows(n: int = 6, period_s: float = 0.004) -> list[str]:
    """tick,time_s,dac_code,counter rows: a slow ramp, 3 counts per tick."""
    return [f"{k},{k * period_s:.9f},{2048 + k},{100 + 3 * k}" for k in range(n)]


def _error(path: Path, **options: object) -> str:
    """The message of the LogFormatError that reading ``path`` raises (checked to be one line)."""
    with pytest.raises(LogFormatError) as info:
        read_log(path, **options)  # type: ignore[arg-type]
    msg = str(info.value)
    assert "\n" not in msg and msg, msg
    return msg


# --- valid logs --------------------------------------------------------------------------------


@pytest.mark.parametrize("period_s", [0.001, 0.004, 0.020])
def test_uniform_logs_at_1_4_and_20_ms(tmp_path: Path, period_s: float) -> None:
    log = read_log(_log(tmp_path, rows=_rows(200, period_s)))
    assert log.period_s == pytest.approx(period_s, rel=1e-9)
    assert log.n_samples == 200 and log.axis().n == 200
    assert log.axis_names == ("",)
    assert_allclose(log.time_s, np.arange(200) * period_s, rtol=0, atol=1e-12)
    assert log.duration_s == pytest.approx(199 * period_s, rel=1e-9)
    ax = log.axis()
    assert_array_equal(ax.dac_code, 2048 + np.arange(200))
    assert_allclose(ax.cmd_v, np.arange(200) * LSB12, rtol=0, atol=1e-12)
    assert_array_equal(ax.pos_counts, 3 * np.arange(200))  # relative to the first row
    assert_array_equal(ax.counter, 100 + 3 * np.arange(200))
    assert ax.counter_faults.size == 0 and ax.mode is None and ax.ref_counts is None


def test_time_s_only_and_tick_only(tmp_path: Path) -> None:
    rows = [f"{k * 0.001:.9f},{2048},{k}" for k in range(5)]
    log = read_log(_log(tmp_path, "time_s,dac_code,counter", rows))
    assert log.period_s == pytest.approx(0.001, rel=1e-12)
    rows = [f"{k + 1000},{2048},{k}" for k in range(5)]  # ticks need not start at 0
    p = _log(tmp_path, "tick,dac_code,counter", rows, meta=[("period_s", "0.02")], name="t.csv")
    log = read_log(p)
    assert log.period_s == 0.02
    assert_allclose(log.time_s, [0.0, 0.02, 0.04, 0.06, 0.08], rtol=0, atol=1e-15)
    p = _log(tmp_path, "tick,dac_code,counter", rows, name="t2.csv")
    assert read_log(p, period_s=0.001).period_s == 0.001
    msg = _error(p)
    assert "no time_s column and no period" in msg and "period_s" in msg


def test_period_from_metadata_is_kept_exactly(tmp_path: Path) -> None:
    # the simulator writes time_s with 9 decimals and the exact period as metadata
    p = 0.0040002346670242545  # plants/pc-dual-servo.toml achieved period (test_simulate_cli)
    path = _log(tmp_path, rows=_rows(1000, p), meta=[("period_s", repr(p))])
    assert read_log(path).period_s == p
    # without the metadata the period comes from the column, end to end (not limited by the
    # 1 ns resolution of single intervals)
    assert read_log(_log(tmp_path, rows=_rows(1000, p), name="b.csv")).period_s == pytest.approx(
        p, rel=1e-9
    )


def test_cmd_v_and_pos_counts_taken_as_they_are(tmp_path: Path) -> None:
    rows = [f"{k},{k * 0.004:.9f},{0.5 * k - 1:.3f},{-7 + 5 * k},{3 * k}" for k in range(4)]
    log = read_log(_log(tmp_path, "tick,time_s,cmd_v,pos_counts,ref_counts", rows))
    ax = log.axis()
    assert_allclose(ax.cmd_v, [-1.0, -0.5, 0.0, 0.5], rtol=0, atol=0)
    assert_array_equal(ax.pos_counts, [-7, -2, 3, 8])  # not made relative
    assert ax.pos_counts.dtype == np.int64
    assert_array_equal(ax.ref_counts, [0, 3, 6, 9])
    assert ax.dac_code is None and ax.counter is None


def test_dac_codes_at_both_rails(tmp_path: Path) -> None:
    rows = [f"{k},{k * 0.004:.3f},{c},0" for k, c in enumerate([0, 2048, 4095])]
    ax = read_log(_log(tmp_path, rows=rows)).axis()
    assert_allclose(ax.cmd_v, [-10.0, 0.0, 10.0 - LSB12], rtol=0, atol=1e-12)  # the D/A's rails
    assert_array_equal(ax.cmd_v, hw_dac.volts_from_code(np.array([0, 2048, 4095])))


def test_counter_wraps_up_and_down(tmp_path: Path) -> None:
    # 24-bit register: 0xFFFFFE → 0xFFFFFF → 0 → 1 wraps up (high byte 0xFF → 0x00);
    # 1 → 0 → 0xFFFFFF → 0xFFFFFD wraps down again (hw/counter.py high-byte rule)
    raw = [TOP24 - 1, TOP24, 0, 1, 0, TOP24, TOP24 - 2]
    rows = [f"{k},{k * 0.004:.3f},2048,{c}" for k, c in enumerate(raw)]
    ax = read_log(_log(tmp_path, rows=rows)).axis()
    assert_array_equal(ax.pos_counts, [0, 1, 2, 3, 2, 1, -1])
    assert_array_equal(ax.counter, raw)
    assert ax.counter_faults.size == 0
    # 16-bit register from the metadata: 0xFFFF → 0x0000 wraps, a jump of 0x8000 is a fault
    raw16 = [65535, 0, 5, 0x8005, 0x8006]
    rows = [f"{k},{k * 0.004:.3f},2048,{c}" for k, c in enumerate(raw16)]
    p = _log(tmp_path, rows=rows, meta=[("counter_bits", "16")], name="c16.csv")
    log = read_log(p)
    assert log.counter_bits == 16
    assert_array_equal(log.axis().pos_counts[:3], [0, 1, 6])
    assert_array_equal(log.axis().counter_faults, [3])


def test_two_axes_modes_and_axis_choice(tmp_path: Path) -> None:
    header = "tick,time_s,master.dac_code,master.counter,master.mode,slave.cmd_v,slave.pos_counts"
    modes = ["lock", "task", "task", "open"]
    rows = [f"{k},{k * 0.004:.3f},2048,{k},{m},0.25,{-k}" for k, m in enumerate(modes)]
    log = read_log(_log(tmp_path, header, rows))
    assert log.axis_names == ("master", "slave")
    assert_array_equal(log.axis("master").mode, [0, 1, 1, 2])  # MODE_LOCK, MODE_TASK, MODE_OPEN
    assert_array_equal(log.axis("master").in_mode("task"), [False, True, True, False])
    assert log.axis("master").name == "master"
    assert_array_equal(log.axis("slave").pos_counts, [0, -1, -2, -3])
    with pytest.raises(LogFormatError, match="choose one"):
        log.axis()
    with pytest.raises(LogFormatError, match="no axis 'z'"):
        log.axis("z")
    with pytest.raises(LogFormatError, match="no mode column"):
        log.axis("slave").in_mode("task")


def test_metadata_compute_s_and_settings_are_reported(tmp_path: Path) -> None:
    meta = [("rig", "pc-dual-servo"), ("compute_s", "0.0002"), ("dac_range_v", "-10,10")]
    log = read_log(_log(tmp_path, meta=meta))
    assert log.metadata["rig"] == "pc-dual-servo"
    assert log.compute_s == 0.0002
    assert (log.counter_bits, log.dac_bits, log.dac_range_v) == (24, 12, (-10.0, 10.0))
    assert log.dac_lsb_v == LSB12
    assert log.path == str(tmp_path / "log.csv")


def test_options_override_metadata_override_defaults(tmp_path: Path) -> None:
    rows = [f"{k},{k * 0.004:.3f},4095,0" for k in range(3)]
    p = _log(tmp_path, rows=rows, meta=[("dac_range_v", "-5,5"), ("dac_bits", "12")])
    assert_allclose(read_log(p).axis().cmd_v, 5.0 - 10.0 / 4096, rtol=0, atol=1e-12)
    assert_allclose(
        read_log(p, dac_range_v=(-10.0, 10.0)).axis().cmd_v, 10.0 - LSB12, rtol=0, atol=1e-12
    )
    assert read_log(p, dac_range_v=(-10.0, 10.0)).dac_range_v == (-10.0, 10.0)
    # code 4095 read as a 16-bit D/A: option beats metadata
    assert_allclose(read_log(p, dac_bits=16).axis().cmd_v, -5.0 + 4095 * 10.0 / 2**16, rtol=1e-12)
    # defaults when neither is given: ±10 V
    q = _log(tmp_path, rows=rows, name="plain.csv")
    assert_allclose(read_log(q).axis().cmd_v, 10.0 - LSB12, rtol=0, atol=1e-12)
    # counter bits: option 32 beats metadata 16 (70000 is out of a 16-bit register)
    rows = [f"{k},{k * 0.004:.3f},2048,{70000 + k}" for k in range(3)]
    r = _log(tmp_path, rows=rows, meta=[("counter_bits", "16")], name="c.csv")
    assert "16-bit" in _error(r)
    assert read_log(r, counter_bits=32).counter_bits == 32
    # period: option beats metadata on a log without time_s
    rows = [f"{k},2048,{k}" for k in range(3)]
    s = _log(tmp_path, "tick,dac_code,counter", rows, meta=[("period_s", "0.004")], name="p.csv")
    assert read_log(s).period_s == 0.004
    assert read_log(s, period_s=0.001).period_s == 0.001


def test_round_trip_with_format_log(tmp_path: Path) -> None:
    n = 50
    k = np.arange(n, dtype=np.int64)
    raw = (0xFFFFF0 + 7 * k) & TOP24  # wraps upward at k = 3
    columns = {
        "master.dac_code": (2048 + 30 * np.sin(k / 5)).astype(np.int64),
        "master.counter": raw,
        "master.ref_counts": 7 * k,
        "master.mode": np.where(k < 10, 0, 1).astype(np.int8),
        "slave.cmd_v": np.linspace(-1.5, 2.5, n),
        "slave.pos_counts": -3 * k,
    }
    period = 0.0040002346670242545
    meta = {"rig": "pc-dual-servo", "period_s": repr(period), "counter_bits": 24}
    path = _write(tmp_path, format_log(period_s=period, columns=columns, metadata=meta))
    log = read_log(path)
    assert log.period_s == period and log.n_samples == n
    m, s = log.axis("master"), log.axis("slave")
    assert_array_equal(m.dac_code, columns["master.dac_code"])
    assert_array_equal(m.counter, raw)
    assert_array_equal(m.pos_counts, 7 * k)
    assert_array_equal(m.ref_counts, 7 * k)
    assert_array_equal(m.mode, columns["master.mode"])
    assert_allclose(s.cmd_v, columns["slave.cmd_v"], rtol=1e-8)  # written with 9 digits
    assert_array_equal(s.pos_counts, -3 * k)
    assert log.metadata == {"rig": "pc-dual-servo", "period_s": repr(period), "counter_bits": "24"}


def test_blank_lines_crlf_bom_and_spaces_are_tolerated(tmp_path: Path) -> None:
    rows = _rows(5)
    rows.insert(2, "")
    rows.insert(4, "   ")
    text = "\ufeff# period_s: 0.004\r\n" + "\r\n".join([HEADER, *rows]) + "\r\n\r\n"
    log = read_log(_write(tmp_path, text))
    assert log.n_samples == 5
    assert_array_equal(log.axis().pos_counts, [0, 3, 6, 9, 12])
    spaced = [" tick , time_s , dac_code , counter ", "0, 0.000, 2048, 5", "1, 0.004, +2049, 6 "]
    log = read_log(_write(tmp_path, "\n".join([*spaced, "2,0.008,2050,7"]), "s.csv"))
    assert_array_equal(log.axis().dac_code, [2048, 2049, 2050])


def test_row_numbers_count_metadata_and_blank_lines(tmp_path: Path) -> None:
    rows = _rows(5)
    rows.insert(1, "")  # metadata on lines 1-2, header on 3, first row on 4, blank line 5
    rows[4] = rows[4].replace("2051", "x")  # the row of tick 3, now on line 8
    p = _log(tmp_path, rows=rows, meta=[("rig", "a"), ("period_s", "0.004")])
    assert "row 8, column 'dac_code'" in _error(p)


def test_a_long_log_reads_and_unwraps(tmp_path: Path) -> None:
    # speed is measured by `make bench` (fit_1M_samples_s), not asserted here
    n = 200_000
    k = np.arange(n)
    raw = (0xFFC000 + 5 * k) & TOP24
    body = "\n".join(
        f"{a},{a * 0.004:.9f},{2048 + a % 100},{c}"
        for a, c in zip(k.tolist(), raw.tolist(), strict=True)
    )
    path = _write(tmp_path, f"{HEADER}\n{body}\n")
    log = read_log(path)
    assert log.n_samples == n
    assert_array_equal(log.axis().pos_counts[-3:], 5 * k[-3:])


# --- bad input: one test per case ---------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    msg = _error(tmp_path / "nope.csv")
    assert "nope.csv" in msg and "does not exist" in msg


def test_directory_instead_of_file(tmp_path: Path) -> None:
    assert "directory" in _error(tmp_path)


def test_empty_file(tmp_path: Path) -> None:
    assert "is empty" in _error(_write(tmp_path, ""))
    assert "is empty" in _error(_write(tmp_path, "\n  \n", "blank.csv"))


def test_metadata_only_no_header(tmp_path: Path) -> None:
    assert "no header row" in _error(_write(tmp_path, "# period_s: 0.004\n# rig: x\n"))


def test_data_without_header(tmp_path: Path) -> None:
    msg = _error(_write(tmp_path, "\n".join(_rows())))
    assert "line 1 looks like data" in msg and "tick,time_s" in msg


def test_header_only(tmp_path: Path) -> None:
    msg = _error(_log(tmp_path, rows=[], meta=[("rig", "x")]))
    assert "header (line 2)" in msg and "no data rows" in msg


def test_missing_command_column(tmp_path: Path) -> None:
    header = "tick,time_s,master.counter,slave.dac_code,slave.counter"
    rows = [f"{k},{k * 0.004:.3f},{k},2048,{k}" for k in range(3)]
    msg = _error(_log(tmp_path, header, rows))
    assert "axis 'master' has no command column" in msg
    assert "'master.dac_code' or 'master.cmd_v'" in msg


def test_missing_position_column(tmp_path: Path) -> None:
    rows = [f"{k},{k * 0.004:.3f},2048" for k in range(3)]
    msg = _error(_log(tmp_path, "tick,time_s,dac_code", rows))
    assert "no position column" in msg and "'counter' or 'pos_counts'" in msg


def test_misspelt_axis_prefix_is_pointed_out(tmp_path: Path) -> None:
    header = "tick,time_s,master.dac_code,mastr.counter"
    rows = [f"{k},{k * 0.004:.3f},2048,{k}" for k in range(3)]
    msg = _error(_log(tmp_path, header, rows))
    assert "axis 'master' has no position column" in msg and "'mastr'" in msg


def test_missing_time_column(tmp_path: Path) -> None:
    rows = [f"2048,{k}" for k in range(3)]
    msg = _error(_log(tmp_path, "dac_code,counter", rows))
    assert "no time column" in msg and "'time_s'" in msg and "'tick'" in msg


def test_no_axis_columns(tmp_path: Path) -> None:
    rows = [f"{k},{k * 0.004:.3f}" for k in range(3)]
    assert "no axis columns" in _error(_log(tmp_path, "tick,time_s", rows))


def test_misspelt_column_suggests_the_closest(tmp_path: Path) -> None:
    header = "tick,time_s,master.dac_cde,master.counter"
    rows = [f"{k},{k * 0.004:.3f},2048,{k}" for k in range(3)]
    msg = _error(_log(tmp_path, header, rows))
    assert "unknown column 'master.dac_cde'; did you mean 'master.dac_code'?" in msg
    msg = _error(_log(tmp_path, "tick,Time_s,dac_code,counter", name="t.csv"))
    assert "unknown column 'Time_s'; did you mean 'time_s'?" in msg


def test_unknown_column_without_a_close_name(tmp_path: Path) -> None:
    msg = _error(_log(tmp_path, "tick,time_s,dac_code,counter,temperature_c"))
    assert "unknown column 'temperature_c'" in msg and "expected" in msg


def test_duplicate_columns(tmp_path: Path) -> None:
    rows = [f"{k},{k * 0.004:.3f},2048,{k},{k}" for k in range(3)]
    msg = _error(_log(tmp_path, "tick,time_s,dac_code,counter,counter", rows))
    assert "duplicate column 'counter'" in msg and "columns 4 and 5" in msg


def test_empty_column_name(tmp_path: Path) -> None:
    rows = [f"{r}," for r in _rows()]
    assert "has no name (a trailing comma?)" in _error(_log(tmp_path, HEADER + ",", rows))


def test_both_command_columns(tmp_path: Path) -> None:
    rows = [f"{k},{k * 0.004:.3f},2048,0.0,{k}" for k in range(3)]
    msg = _error(_log(tmp_path, "tick,time_s,dac_code,cmd_v,counter", rows))
    assert "both 'dac_code' and 'cmd_v'" in msg


def test_unprefixed_next_to_prefixed_columns(tmp_path: Path) -> None:
    header = "tick,time_s,dac_code,counter,slave.dac_code,slave.counter"
    rows = [f"{k},{k * 0.004:.3f},2048,{k},2048,{k}" for k in range(3)]
    assert "no axis prefix" in _error(_log(tmp_path, header, rows))


def test_nan_or_inf_names_column_and_row(tmp_path: Path) -> None:
    rows = [f"{k},{k * 0.004:.3f},{0.1 * k:.2f},{k}" for k in range(5)]
    rows[3] = "3,0.012,nan,3"
    msg = _error(_log(tmp_path, "tick,time_s,cmd_v,pos_counts", rows))
    assert "row 5, column 'cmd_v'" in msg and "not finite" in msg
    rows = _rows()
    rows[2] = "2,inf,2050,106"
    assert "row 4, column 'time_s'" in _error(_log(tmp_path, rows=rows, name="b.csv"))
    rows = _rows()
    rows[1] = "1,0.004,NaN,103"
    msg = _error(_log(tmp_path, rows=rows, name="c.csv"))
    assert "row 3, column 'dac_code'" in msg and "not finite" in msg


def test_text_in_a_number(tmp_path: Path) -> None:
    rows = _rows()
    rows[2] = "2,0.00B,2050,106"
    msg = _error(_log(tmp_path, rows=rows))
    assert "row 4, column 'time_s': '0.00B' is not a number" in msg
    rows = _rows()
    rows[4] = "4,0.016,,112"
    assert "row 6, column 'dac_code': empty value" in _error(
        _log(tmp_path, rows=rows, name="e.csv")
    )


def test_time_not_increasing(tmp_path: Path) -> None:
    rows = [f"{t:.3f},2048,0" for t in [0.0, 0.004, 0.008, 0.004, 0.016]]
    msg = _error(_log(tmp_path, "time_s,dac_code,counter", rows))
    assert "row 5, column 'time_s'" in msg and "goes back" in msg


def test_time_repeated(tmp_path: Path) -> None:
    rows = [f"{t:.3f},2048,0" for t in [0.0, 0.004, 0.004, 0.008]]
    msg = _error(_log(tmp_path, "time_s,dac_code,counter", rows))
    assert "row 4, column 'time_s'" in msg and "repeats" in msg


def test_tick_repeated_or_skipped(tmp_path: Path) -> None:
    rows = [f"{k},2048,0" for k in [0, 1, 1, 2]]
    p = _log(tmp_path, "tick,dac_code,counter", rows, meta=[("period_s", "0.004")])
    msg = _error(p)
    assert "row 5, column 'tick'" in msg and "does not increase" in msg
    rows = [f"{k},2048,0" for k in [0, 1, 2, 4, 5]]
    p = _log(tmp_path, "tick,dac_code,counter", rows, meta=[("period_s", "0.004")], name="s.csv")
    msg = _error(p)
    assert "row 6, column 'tick'" in msg and "skips" in msg


def test_irregular_sampling_names_the_first_bad_row(tmp_path: Path) -> None:
    times = [0.004 * k for k in range(10) if k != 6]  # one dropped sample
    rows = [f"{t:.9f},2048,0" for t in times]
    msg = _error(_log(tmp_path, "time_s,dac_code,counter", rows))
    assert "row 8, column 'time_s': irregular sampling" in msg and "0.1 %" in msg
    # 0.05 % jitter is within the tolerance; 0.2 % is not
    ok = [f"{0.004 * k + (2e-6 if k == 3 else 0):.9f},2048,0" for k in range(8)]
    read_log(_log(tmp_path, "time_s,dac_code,counter", ok, name="ok.csv"))
    bad = [f"{0.004 * k + (8e-6 if k == 3 else 0):.9f},2048,0" for k in range(8)]
    assert "row 5" in _error(_log(tmp_path, "time_s,dac_code,counter", bad, name="bad.csv"))


def test_tick_and_time_s_must_agree(tmp_path: Path) -> None:
    rows = [f"{k + 5},{k * 0.004:.3f},2048,0" for k in range(4)]  # ticks from 5, time from 0
    msg = _error(_log(tmp_path, rows=rows))
    assert "row 2: tick 5" in msg and "must agree" in msg
    # metadata period 1 % off the time column
    p = _log(tmp_path, meta=[("period_s", "0.00404")], name="m.csv")
    msg = _error(p)
    assert "metadata 'period_s' (line 1)" in msg and "disagrees with the time_s column" in msg
    # an option period from another timebase is an error too, not a silent override
    msg = _error(_log(tmp_path, name="o.csv"), period_s=0.001)
    assert "option period_s" in msg and "disagrees" in msg


def test_counter_out_of_range_names_the_bits(tmp_path: Path) -> None:
    rows = _rows()
    rows[3] = f"3,0.012,2051,{2**24}"
    msg = _error(_log(tmp_path, rows=rows))
    assert "row 5, column 'counter'" in msg and "24-bit" in msg and "0..16777215" in msg
    rows[3] = "3,0.012,2051,-1"
    assert "24-bit" in _error(_log(tmp_path, rows=rows, name="neg.csv"))


def test_counter_not_an_integer(tmp_path: Path) -> None:
    rows = _rows()
    rows[2] = "2,0.008,2050,12.5"
    msg = _error(_log(tmp_path, rows=rows))
    assert "row 4, column 'counter': '12.5' is not an integer" in msg


def test_dac_code_not_an_integer_or_out_of_range(tmp_path: Path) -> None:
    rows = _rows()
    rows[1] = "1,0.004,2048.5,103"
    assert "row 3, column 'dac_code': '2048.5' is not an integer" in _error(
        _log(tmp_path, rows=rows)
    )
    rows = _rows()
    rows[2] = "2,0.008,4096,106"
    msg = _error(_log(tmp_path, rows=rows, name="r.csv"))
    assert "row 4, column 'dac_code'" in msg and "12-bit D/A range 0..4095" in msg


def test_wrong_number_of_fields(tmp_path: Path) -> None:
    rows = _rows()
    rows[3] = "3,0.012,2051"
    msg = _error(_log(tmp_path, rows=rows, meta=[("rig", "x")]))
    assert "row 6 has 3 fields" in msg and "header (line 2) has 4" in msg
    rows = _rows()
    rows[0] += ",7"
    assert "row 2 has 5 fields" in _error(_log(tmp_path, rows=rows, name="b.csv"))


def test_too_short(tmp_path: Path) -> None:
    assert MIN_ROWS == 3
    msg = _error(_log(tmp_path, rows=_rows(2)))
    assert "2 data rows" in msg and "at least 3" in msg


def test_unknown_mode(tmp_path: Path) -> None:
    rows = [f"{r},{m}" for r, m in zip(_rows(4), ["lock", "task", "run", "open"], strict=True)]
    msg = _error(_log(tmp_path, HEADER + ",mode", rows))
    assert "row 4, column 'mode': mode 'run' is not one of lock, task, open" in msg
    long = "lock" + " " * 20 + "x"  # not shortened into a valid name
    rows = [f"{r},{m}" for r, m in zip(_rows(3), ["lock", long, "open"], strict=True)]
    assert "row 3, column 'mode'" in _error(_log(tmp_path, HEADER + ",mode", rows, name="l.csv"))


def test_not_utf8_text(tmp_path: Path) -> None:
    data = (HEADER + "\n0,0.0,2048,1\n").encode() + b"1,0.004,2048,\xff\xfe\n"
    msg = _error(_write(tmp_path, data))
    assert "not UTF-8 text" in msg and "line 3" in msg
    msg = _error(_write(tmp_path, b"\x00\x01\x02binary", "b.bin"))
    assert "not a text file" in msg


@pytest.mark.parametrize(
    ("key", "value", "expected"),
    [
        ("counter_bits", "abc", "16, 24 or 32"),
        ("counter_bits", "20", "16, 24 or 32"),
        ("dac_bits", "12.5", "number of bits"),
        ("dac_range_v", "10", "'low,high'"),
        ("dac_range_v", "10,-10", "low < high"),
        ("period_s", "-0.004", "> 0"),
        ("period_s", "4ms", "> 0"),
        ("compute_s", "fast", ">= 0"),
    ],
)
def test_malformed_metadata_names_the_key(
    tmp_path: Path, key: str, value: str, expected: str
) -> None:
    msg = _error(_log(tmp_path, meta=[("rig", "x"), (key, value)]))
    assert f"line 2: metadata {key!r}" in msg and expected in msg and repr(value) in msg


def test_malformed_metadata_is_an_error_even_when_an_option_overrides_it(tmp_path: Path) -> None:
    assert "metadata 'dac_bits'" in _error(_log(tmp_path, meta=[("dac_bits", "x")]), dac_bits=12)


def test_conflicting_duplicate_metadata(tmp_path: Path) -> None:
    p = _log(tmp_path, meta=[("counter_bits", "24"), ("counter_bits", "16")])
    assert "'counter_bits' given twice" in _error(p)


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        ({"counter_bits": 20}, "option counter_bits"),
        ({"dac_bits": 0}, "option dac_bits"),
        ({"dac_range_v": (10.0, -10.0)}, "option dac_range_v"),
        ({"period_s": -1.0}, "option period_s"),
    ],
)
def test_invalid_options(tmp_path: Path, options: dict[str, object], expected: str) -> None:
    assert expected in _error(_log(tmp_path), **options)


def test_errors_are_value_errors_of_servotune() -> None:
    assert issubclass(LogFormatError, ValueError) and issubclass(LogFormatError, ServotuneError)


def test_data_objects_validate_their_fields() -> None:
    with pytest.raises(LogFormatError, match="pos_counts"):
        AxisLog(cmd_v=np.zeros(3), pos_counts=np.zeros(4, dtype=np.int64))
    ax = AxisLog(cmd_v=np.zeros(3), pos_counts=np.zeros(3, dtype=np.int64))
    with pytest.raises(LogFormatError, match="period_s must be > 0"):
        Log(period_s=0.0, axes={"": ax}, metadata={})
    short = AxisLog(cmd_v=np.zeros(2), pos_counts=np.zeros(2, dtype=np.int64))
    with pytest.raises(LogFormatError, match="same number of samples"):
        Log(period_s=0.004, axes={"a": ax, "b": short}, metadata={})


# --- reliability: bounds, options, JSON and TOML, atomic writes ------------------------------


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        ({"compute_s": float("nan")}, "option compute_s must be a finite number of seconds >= 0"),
        ({"compute_s": -1.0}, "option compute_s must be a finite number of seconds >= 0"),
        ({"compute_s": 0.004}, "option compute_s must be shorter than the sample period"),
        ({"compute_s": True}, "option compute_s must be"),
        ({"period_s": 1e-300}, "option period_s must be a number of seconds > 0, within 1e-06"),
        ({"dac_range_v": (-1e308, 1e308)}, "each within ±1000 V"),
    ],
)
def test_options_are_bounded(tmp_path: Path, options: dict, expected: str) -> None:
    msg = _error(_log(tmp_path), **options)
    assert expected in msg and str(tmp_path) in msg


def test_compute_s_option_overrides_metadata(tmp_path: Path) -> None:
    path = _log(tmp_path, meta=[("compute_s", "0.0002")])
    assert read_log(path).compute_s == 0.0002
    assert read_log(path, compute_s=0.001).compute_s == 0.001


@pytest.mark.parametrize("dt", [1e304, 1e-300, 1e-7, 61.0])
def test_period_from_time_s_is_bounded(tmp_path: Path, dt: float) -> None:
    rows = [f"{k * dt!r},{2048 + k},{3 * k}" for k in range(6)]
    msg = _error(_log(tmp_path, header="time_s,dac_code,counter", rows=rows))
    assert "sample period" in msg and "outside 1e-06 … 60 s" in msg


def test_long_fields_metadata_and_names(tmp_path: Path) -> None:
    rows = _rows()
    rows[2] = "2,0.008," + "7" * 65 + ",106"
    assert "row 4, column 'dac_code': a field of 65 characters" in _error(_log(tmp_path, rows=rows))
    long_meta = _log(tmp_path, meta=[("rig", "x" * 2000)])
    assert "metadata 'rig' value of 2000 characters" in _error(long_meta)
    assert "metadata key of 100 characters" in _error(_log(tmp_path, meta=[("k" * 100, "1")]))
    long_name = _log(tmp_path, header=HEADER + "," + "m" * 80, rows=[r + ",0" for r in _rows()])
    assert "header column 5 has a name of 80 characters" in _error(long_name)
    assert "is 70 characters long" in _error(_log(tmp_path, meta=[("period_s", "0" * 70)]))


def test_unknown_metadata_warns_declared_do_not(tmp_path: Path) -> None:
    from servotune.logs import LogMetadataWarning

    ok = _log(tmp_path, meta=[("machine_id", "m1"), ("date", "2024-01-01")])
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_log(ok).metadata["machine_id"] == "m1"
    odd = _log(tmp_path, meta=[("colour", "blue")], name="odd.csv")
    with pytest.warns(LogMetadataWarning, match=r"unknown metadata 'colour' \(line 1\)"):
        assert read_log(odd).metadata["colour"] == "blue"


def test_bom_csv(tmp_path: Path) -> None:
    text = "\ufeff# period_s: 0.004\n" + HEADER + "\n" + "\n".join(_rows()) + "\n"
    path = tmp_path / "bom.csv"
    path.write_text(text, encoding="utf-8")
    assert read_log(path).period_s == 0.004


def test_parse_json_refuses_what_json_is_not() -> None:
    from servotune.io.files import parse_json

    for text, expected in [
        ('{"n": NaN}', "NaN is not a JSON number"),
        ('{"n": Infinity}', "Infinity is not a JSON number"),
        ("[-Infinity]", "-Infinity is not a JSON number"),
        ("[" * 200_000 + "]" * 200_000, "nested 200000 levels deep"),
        ("[" * 65 + "]" * 65, "nested 65 levels deep"),
        ('{"n": 1' + "0" * 64 + "}", "a number of 65 characters"),
        ('{"s": "' + "x" * (1024**2 + 1) + '"}', "a string of 1048577 characters"),
        ("{", "not JSON"),
    ]:
        with pytest.raises(ServotuneError, match=expected) as info:
            parse_json(text, "t.json", LogFormatError)
        assert str(info.value).count("t.json") == 1 and "\n" not in str(info.value)
    assert parse_json('\ufeff{"a": "[[[[", "b": [[1]]}', "t.json", LogFormatError) == {
        "a": "[[[[",
        "b": [[1]],
    }


def test_read_json_bounds_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import servotune.io.files as files

    path = tmp_path / "big.json"
    path.write_text("[" + "1," * 100 + "1]")
    monkeypatch.setattr(files, "MAX_TEXT_FILE_BYTES", 64)
    with pytest.raises(LogFormatError, match="is 203 bytes; at most 64"):
        files.read_json(path, LogFormatError)


def test_parse_toml_bom_depth_and_huge_integers() -> None:
    from servotune.io.files import parse_toml

    assert parse_toml(b"\xef\xbb\xbfa = 1\n", "x.toml", LogFormatError) == {"a": 1}
    with pytest.raises(LogFormatError, match="nested too deeply"):
        parse_toml("a = " + "[" * 100_000 + "]" * 100_000, "x.toml", LogFormatError)
    with pytest.raises(LogFormatError, match="nested deeper than 64 levels"):
        parse_toml("a = " + "[" * 70 + "]" * 70, "x.toml", LogFormatError)
    with pytest.raises(LogFormatError, match="not accepted TOML"):
        parse_toml("a = " + "1" * 5000, "x.toml", LogFormatError)


def test_atomic_write_names_the_target_and_cleans_up(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import errno
    import os

    import servotune.io.files as files

    target = tmp_path / "out.csv"
    real_open = os.open

    def refuse(path: object, *args: object, **kwargs: object) -> int:
        if str(path).endswith(".tmp"):
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(files.os, "open", refuse)
    with pytest.raises(PermissionError) as info:
        files.atomic_write_bytes(target, b"x")
    assert info.value.filename == str(target) and info.value.errno == errno.EACCES
    monkeypatch.undo()

    def broken_replace(src: object, dst: object) -> None:
        raise OSError(errno.EXDEV, "Invalid cross-device link", str(src))

    monkeypatch.setattr(files.os, "replace", broken_replace)
    with pytest.raises(OSError) as info2:
        files.atomic_write_bytes(target, b"x")
    assert info2.value.filename == str(target)
    assert list(tmp_path.iterdir()) == []  # the temporary file is gone

    def interrupted(src: object, dst: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(files.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        files.atomic_write_bytes(target, b"x")
    assert list(tmp_path.iterdir()) == []


def test_read_table(tmp_path: Path) -> None:
    from servotune.logs import read_table

    table = read_table(_log(tmp_path, meta=[("period_s", "0.004")]), what="table")
    assert table.header == ["tick", "time_s", "dac_code", "counter"]
    assert table.n_rows == 6 and table.row_lines.tolist() == [3, 4, 5, 6, 7, 8]
    assert table.columns["dac_code"].dtype == np.int64 and table.metadata["period_s"] == "0.004"
    bad = _log(tmp_path, header="tick,speed", rows=["0,1"], name="bad.csv")
    with pytest.raises(LogFormatError, match=r"table '.*bad.csv': line 1: unknown column 'speed'"):
        read_table(bad, what="table")


# --- the excitation column (docs/decisions.md#5-excitation-is-logged) --------------------------


def test_exc_code_is_read_per_axis_and_optional(tmp_path: Path) -> None:
    # the excitation the law adds [D/A codes relative to the zero code], signed
    rows = [
        f"{k},{k * 0.004:.9f},{2048 + 7 * k},{100 + 3 * k},{(-1) ** k * 5 * k}" for k in range(6)
    ]
    log = read_log(_log(tmp_path, header=HEADER + ",exc_code", rows=rows))
    assert_array_equal(log.axis().exc_code, [0, -5, 10, -15, 20, -25])
    assert log.axis().exc_code.dtype == np.int64
    # a log without it reads as before (the column is optional)
    assert read_log(_log(tmp_path, name="old.csv")).axis().exc_code is None
    two = "tick,a.dac_code,a.counter,a.exc_code,b.dac_code,b.counter"
    rows2 = [f"{k},2048,{k},{k},2048,{2 * k}" for k in range(5)]
    log2 = read_log(
        _log(tmp_path, header=two, rows=rows2, meta=[("period_s", "0.004")], name="two.csv")
    )
    assert_array_equal(log2.axis("a").exc_code, np.arange(5))
    assert log2.axis("b").exc_code is None


def test_exc_code_beyond_the_dac_span_or_not_an_integer(tmp_path: Path) -> None:
    # a 12-bit D/A spans 4095 codes: an excitation of 4096 codes cannot have been added
    rows = [f"{k},{k * 0.004:.9f},2048,{k},{4096 if k == 3 else 0}" for k in range(6)]
    msg = _error(_log(tmp_path, header=HEADER + ",exc_code", rows=rows))
    assert "row 5, column 'exc_code'" in msg and "4096" in msg and "±4095" in msg
    rows[3] = "3,0.012000000,2048,3,-4095"
    assert (
        read_log(_log(tmp_path, header=HEADER + ",exc_code", rows=rows)).axis().exc_code[3] == -4095
    )
    rows[2] = "2,0.008000000,2048,2,1.5"
    assert "row 4, column 'exc_code'" in _error(
        _log(tmp_path, header=HEADER + ",exc_code", rows=rows)
    )


def test_exc_code_is_a_known_column_and_listed_in_the_help(tmp_path: Path) -> None:
    msg = _error(_log(tmp_path, header=HEADER + ",exc_codes", rows=[r + ",0" for r in _rows()]))
    assert "did you mean 'exc_code'" in msg
    msg = _error(_log(tmp_path, header=HEADER + ",zzz", rows=[r + ",0" for r in _rows()]))
    assert "exc_code" in msg  # the list of valid columns names it


def test_trace_columns_carry_the_excitation(tmp_path: Path, rig: object) -> None:
    import servotune as st
    from servotune.pipeline import run_scenario, trace_log_columns

    scen = st.build_scenario(rig, "prbs", axis="master", seconds=2.0, closed_loop=True)
    trace = run_scenario(rig, scen, seed=1)
    cols = trace_log_columns(trace, scen.inputs.dac_add_codes)
    assert_array_equal(cols["master.exc_code"], scen.inputs.dac_add_codes[:, 0])
    assert not np.any(cols["slave.exc_code"])
    assert "master.exc_code" not in trace_log_columns(trace)  # without it: as before
    path = tmp_path / "sim.csv"
    path.write_text(format_log(period_s=rig.period_s, columns=cols, metadata={}))
    assert_array_equal(read_log(path).axis("master").exc_code, scen.inputs.dac_add_codes[:, 0])


def test_long_field_check_counts_characters_not_bytes(tmp_path: Path) -> None:
    # the field-length scan works on bytes: a field of 40 two-byte characters (80 bytes) is
    # within the 64-character limit (and then refused as text), a later 65-digit field is named
    rows = _rows()
    rows[1] = "1,0.004," + "é" * 40 + ",103"
    assert "'" + "é" * 40 + "' is not a number" in _error(_log(tmp_path, rows=rows))
    rows[4] = "4,0.016," + "7" * 65 + ",112"
    assert "row 6, column 'dac_code': a field of 65 characters" in _error(_log(tmp_path, rows=rows))


@pytest.mark.parametrize(("sep", "word"), [(";", "semicolons"), ("\t", "tabs")])
def test_a_log_not_separated_by_commas_says_so(tmp_path: Path, sep: str, word: str) -> None:
    # as a spreadsheet in a comma-decimal locale saves it (the hint once misled)
    p = tmp_path / "log.csv"
    p.write_text(
        sep.join(["tick", "time_s", "dac_code", "counter"])
        + "\n"
        + sep.join(["0", "0", "2048", "0"])
        + "\n"
    )
    with pytest.raises(LogFormatError, match=f"separated by {word}, not commas"):
        read_log(p)
