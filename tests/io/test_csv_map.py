"""A machine's own CSV log, with its own column names, fitted through ``--map``.

The log comes from a simulator independent of servotune's: a speed-command drive (first-order
lag with gain ``K`` [counts/s per V] and time constant ``tau``) and an integrator (the
position [counts]), integrated by scipy's ``solve_ivp`` over each tick with the D/A held (zero
order hold; the new code written ``compute_s`` after the sample, as the rig's timer does), in
closed loop under a proportional position law plus a designed multisine added to its output,
the encoder flooring the position to whole counts after a little noise. ``K``, ``tau``, the
period, the D/A and the compute time are the example rig's master axis
(``plants/pc-dual-servo.toml``); the position starts just below the top of its 24-bit counter
register and runs past it, which an unwrapped position column simply carries on counting.

The logger writes every column as a number (``16776216.0``) under its own names
(``t,drive_volts,encoder,setpoint,exc_volts``); ``servotune fit --map`` reads it and must find
the gain and the time constant within 2 %.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLE_RIG
from numpy.testing import assert_allclose, assert_array_equal
from scipy.integrate import solve_ivp

import servotune as st
from servotune.cli import main
from servotune.io.hal import capture_format, hal_settings, read_hal_log
from servotune.logs import read_log

RIG = st.load_rig(EXAMPLE_RIG)
AXIS = RIG.axis("master")
K_CPS_PER_V = AXIS.plant.gain_cps_per_v  # 12288 counts/s per V
TAU_S = AXIS.plant.tau_s  # 25 ms
PERIOD_S = RIG.period_s  # 4.000235 ms: the 8253's divisor
COMPUTE_S = RIG.timer.compute_s  # sample → D/A write
DAC_BITS, DAC_RANGE_V = RIG.dac.bits, RIG.dac.range_v  # 12 bits, ±10 V
LSB_V = (DAC_RANGE_V[1] - DAC_RANGE_V[0]) / 2**DAC_BITS
ZERO_CODE = 2 ** (DAC_BITS - 1)
KP_CODES_PER_COUNT = AXIS.lock_gain_codes_per_count  # the lock module's gain
START_COUNTS = 2**RIG.counter.bits - 1500  # 1500 counts below the 24-bit register's top
N_TICKS = 7500  # 30 s
NOISE_COUNTS = 0.3  # rms, before the encoder's floor

MAP = "cmd=drive_volts,pos=encoder,ref=setpoint,exc=exc_volts,time=t"
FOREIGN = ["t", "drive_volts", "encoder", "setpoint", "exc_volts"]


def _multisine(n: int, rng: np.random.Generator) -> np.ndarray:
    """The excitation [D/A codes]: 24 tones from 0.2 to 30 Hz, Schroeder phases, 300 codes
    peak (1.5 V), rounded to whole codes."""
    t = np.arange(n) * PERIOD_S
    freqs = np.geomspace(0.2, 30.0, 24)
    k = np.arange(1, freqs.size + 1)
    phases = -np.pi * k * (k - 1) / freqs.size + rng.uniform(0, 0.1, freqs.size)
    x = np.sin(2 * np.pi * freqs[:, None] * t[None, :] + phases[:, None]).sum(axis=0)
    return np.rint(300.0 * x / np.max(np.abs(x))).astype(np.int64)


@pytest.fixture(scope="module")
def drive() -> dict[str, np.ndarray]:
    """The closed-loop run: row k holds the time t_k, the position the encoder read at t_k,
    the setpoint, the excitation and the command the law computed from them (written to the
    D/A at t_k + compute_s; the previous one holds until then)."""
    rng = np.random.default_rng(2024)
    exc = _multisine(N_TICKS, rng)
    # the setpoint: a move of 3000 counts up and back every 6 s, through the register's top
    ref = START_COUNTS + np.where((np.arange(N_TICKS) // 1500) % 2 == 1, 3000, 0)

    def rhs(_t: float, s: np.ndarray, u: float) -> list[float]:
        return [(K_CPS_PER_V * u - s[0]) / TAU_S, s[0]]  # speed [counts/s], position [counts]

    state = np.array([0.0, float(START_COUNTS)])
    held_v = 0.0  # the D/A's output before the first write
    codes = np.empty(N_TICKS, dtype=np.int64)
    counts = np.empty(N_TICKS, dtype=np.int64)
    for k in range(N_TICKS):
        counts[k] = np.floor(state[1] + rng.normal(0.0, NOISE_COUNTS))
        law = round(KP_CODES_PER_COUNT * (ref[k] - counts[k]))
        codes[k] = min(max(ZERO_CODE + law + exc[k], 0), 2**DAC_BITS - 1)
        new_v = DAC_RANGE_V[0] + codes[k] * LSB_V
        t0 = k * PERIOD_S
        for a, b, u in ((t0, t0 + COMPUTE_S, held_v), (t0 + COMPUTE_S, t0 + PERIOD_S, new_v)):
            sol = solve_ivp(rhs, (a, b), state, method="DOP853", rtol=1e-10, atol=1e-9, args=(u,))
            state = sol.y[:, -1]
        held_v = new_v
    assert np.max(counts) > 2**RIG.counter.bits + 1000  # past the 24-bit register's top
    assert np.ptp(codes) < 2**DAC_BITS - 1  # never saturated
    return {
        "t": np.arange(N_TICKS) * PERIOD_S,
        "volts": DAC_RANGE_V[0] + codes * LSB_V,
        "counts": counts,
        "ref": ref,
        "exc_code": exc,
        "exc_volts": exc * LSB_V,
    }


def write_foreign(
    path: Path, d: dict[str, np.ndarray], n: int | None = None, meta: dict[str, str] | None = None
) -> Path:
    """The run as the machine's own logger writes it: its names, every value a number."""
    lines = [f"# {k}: {v}" for k, v in (meta or {}).items()]
    lines.append(",".join(FOREIGN))
    for k in range(N_TICKS if n is None else n):
        lines.append(
            f"{d['t'][k]:.9f},{d['volts'][k]:.9g},{float(d['counts'][k]):.1f},"
            f"{float(d['ref'][k]):.1f},{d['exc_volts'][k]:.9g}"
        )
    path.write_text("\n".join(lines) + "\n")
    return path


def write_standard(path: Path, d: dict[str, np.ndarray], n: int, meta: dict[str, str]) -> Path:
    """The same run as a servotune log (its own column names), positions as numbers too."""
    lines = [f"# {k}: {v}" for k, v in meta.items()]
    lines.append("time_s,cmd_v,pos_counts,ref_counts,exc_code")
    for k in range(n):
        lines.append(
            f"{d['t'][k]:.9f},{d['volts'][k]:.9g},{float(d['counts'][k]):.1f},"
            f"{float(d['ref'][k]):.1f},{d['exc_code'][k]}"
        )
    path.write_text("\n".join(lines) + "\n")
    return path


def one_error_line(capsys: pytest.CaptureFixture[str], args: list[str]) -> str:
    """Run ``servotune ARGS``: exit 3 and one line on stderr, which is returned."""
    code = main(args)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 3, err
    assert len(lines) == 1 and lines[0].startswith("servotune fit: error:"), err
    assert "Traceback" not in err
    return lines[0]


# --- the fit ------------------------------------------------------------------------------------


def test_own_csv_fits_within_2_pct_through_map(
    drive: dict[str, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_foreign(tmp_path / "drive.csv", drive, meta={"compute_s": f"{COMPUTE_S}"})
    assert path.read_text().split("\n")[1] == ",".join(FOREIGN)
    assert capture_format(path) == "csv"  # by its header, whatever the options
    assert main(["fit", str(path), "--map", MAP, "--json"]) == 0, capsys.readouterr().err
    d = json.loads(capsys.readouterr().out)
    err_gain = d["params"]["gain_cps_per_v"] / K_CPS_PER_V - 1
    err_tau = d["params"]["tau_s"] / TAU_S - 1
    with capsys.disabled():  # shown with pytest -s
        print(f"\nmapped CSV fit: gain error {err_gain:+.3%}, tau error {err_tau:+.3%}")
    assert abs(err_gain) < 0.02 and abs(err_tau) < 0.02
    # the excitation column, mapped in volts, became the instruments (closed loop: IV)
    assert d["method"] == "iv" and "exc_code" in d["instruments"]["signals"]
    assert d["period_s"] == pytest.approx(PERIOD_S, rel=1e-9)  # from the t column


def test_mapped_csv_is_the_log_the_log_reader_makes(
    drive: dict[str, np.ndarray], tmp_path: Path
) -> None:
    n = 600
    meta = {
        "dac_bits": "12",
        "dac_range_v": "-10,10",
        "compute_s": f"{COMPUTE_S}",
        "machine_id": "lathe-3",
    }
    standard = read_log(write_standard(tmp_path / "std.csv", drive, n, meta))
    foreign = write_foreign(tmp_path / "own.csv", drive, n, meta)
    mapped = read_hal_log(foreign, hal_settings(MAP))
    a, b = standard.axis(), mapped.axis()
    assert_array_equal(b.cmd_v, a.cmd_v)
    assert_array_equal(b.pos_counts, a.pos_counts)
    assert_array_equal(b.ref_counts, a.ref_counts)
    assert_array_equal(b.exc_code, a.exc_code)
    assert_array_equal(a.exc_code, drive["exc_code"][:n])  # volts back to the codes exactly
    assert b.pos_counts.dtype == np.int64 and b.ref_counts.dtype == np.int64
    assert_array_equal(b.pos_counts, drive["counts"][:n])  # unwrapped: past 2**24 as it is
    for attr in ("period_s", "compute_s", "dac_bits", "dac_range_v", "metadata", "axis_names"):
        assert getattr(mapped, attr) == getattr(standard, attr), attr
    # positions in machine units: the encoder's scale makes them counts, as for LinuxCNC
    mm = tmp_path / "mm.csv"
    mm.write_text(
        "time_s,drive_volts,encoder_mm\n"
        + "".join(
            f"{drive['t'][k]:.9f},{drive['volts'][k]:.9g},{drive['counts'][k] / 2000:.6f}\n"
            for k in range(n)
        )
    )
    by_mm = read_hal_log(mm, hal_settings("cmd=drive_volts,pos=encoder_mm", position_scale=2000))
    assert_array_equal(by_mm.axis().pos_counts, drive["counts"][:n])
    assert by_mm.period_s == standard.period_s  # the time_s column, not mapped: the time base
    # a command logged in other units than volts: the output scale, as for a pid's output
    by_mv = read_hal_log(foreign, hal_settings(MAP.replace("exc=exc_volts,", ""), output_scale=0.5))
    assert_allclose(by_mv.axis().cmd_v, 2 * a.cmd_v, rtol=1e-15)


def test_period_from_metadata_option_or_rig(
    drive: dict[str, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    n = 300
    bare = tmp_path / "bare.csv"  # no time column
    bare.write_text(
        "u,y\n" + "".join(f"{drive['volts'][k]:.6f},{drive['counts'][k]}\n" for k in range(n))
    )
    line = one_error_line(capsys, ["fit", str(bare), "--map", "cmd=u,counts=y"])
    assert "no time column and no period" in line and "time=COLUMN" in line
    assert "--period-s" in line and str(bare) in line
    log = read_hal_log(bare, hal_settings("cmd=u,counts=y"), period_s=0.004)
    assert log.period_s == 0.004 and log.n_samples == n
    dated = tmp_path / "dated.csv"
    dated.write_text("# period_s: 0.002\n" + bare.read_text())
    assert read_hal_log(dated, hal_settings("cmd=u,counts=y")).period_s == 0.002
    # the rig's period, as for a log, when nothing else gives one
    with warnings.catch_warnings():  # 300 rows: the fit's verdict on them is not the point here
        warnings.simplefilter("ignore")
        code = main(
            [
                "fit",
                str(bare),
                "--map",
                "cmd=u,counts=y",
                "--rig",
                str(EXAMPLE_RIG),
                "--json",
                "--method",
                "oe",
            ]
        )
    out = capsys.readouterr()
    assert code == 0, out.err
    assert json.loads(out.out)["period_s"] == pytest.approx(PERIOD_S, rel=1e-12)
    timed = write_foreign(tmp_path / "timed.csv", drive, n)
    line = one_error_line(capsys, ["fit", str(timed), "--map", MAP, "--period-s", "0.001"])
    assert "disagrees with the t column" in line


# --- numbers in counts columns ----------------------------------------------------------------


def test_whole_numbers_in_counts_columns_are_read_as_integers(tmp_path: Path) -> None:
    rows = [
        f"{k},{0.004 * k:.3f},{0.1 * (k % 3):.1f},{k * 2}.0,{k}.000000000{k % 2}" for k in range(5)
    ]
    path = tmp_path / "log.csv"
    path.write_text("tick,time_s,cmd_v,pos_counts,ref_counts\n" + "\n".join(rows) + "\n")
    ax = read_log(path).axis()
    assert ax.pos_counts.dtype == np.int64 and ax.pos_counts.tolist() == [0, 2, 4, 6, 8]
    assert ax.ref_counts.dtype == np.int64 and ax.ref_counts.tolist() == [0, 1, 2, 3, 4]
    # integers as before (the plain form), and exactly: beyond a double's 2**53 too
    big = 2**60 + 1
    path.write_text(f"tick,cmd_v,pos_counts\n0,0.5,{big}\n1,0.5,{big + 1}\n2,0.5,{big + 2}\n")
    assert read_log(path, period_s=0.004).axis().pos_counts.tolist() == [big, big + 1, big + 2]


@pytest.mark.parametrize("column", ["ref_counts", "pos_counts"])
def test_a_count_that_is_not_whole_is_refused_with_its_row(
    drive: dict[str, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str], column: str
) -> None:
    path = write_standard(tmp_path / "log.csv", drive, 400, {"compute_s": f"{COMPUTE_S}"})
    lines = path.read_text().split("\n")
    j = lines[1].split(",").index(column)
    fields = lines[250].split(",")  # row 251 of the file
    fields[j] = "0.5"
    lines[250] = ",".join(fields)
    path.write_text("\n".join(lines))
    line = one_error_line(capsys, ["fit", str(path)])
    assert f"row 251, column {column!r}: 0.5 is not an integer" in line, line
    assert str(path) in line


def test_a_mapped_count_that_is_not_whole_is_refused_with_its_row(
    drive: dict[str, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_foreign(tmp_path / "own.csv", drive, 400)
    lines = path.read_text().split("\n")
    fields = lines[100].split(",")  # row 101
    fields[3] = "16775716.5"  # the setpoint
    lines[100] = ",".join(fields)
    path.write_text("\n".join(lines))
    line = one_error_line(capsys, ["fit", str(path), "--map", MAP])
    assert "row 101, column 'setpoint': map ref" in line and "16775716.5 is not an integer" in line
    assert "--position-scale" in line and str(path) in line


# --- what a mapping cannot read -----------------------------------------------------------------


def test_a_mapped_column_not_in_the_header_is_named_with_the_columns(
    drive: dict[str, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_foreign(tmp_path / "own.csv", drive, 200, meta={"machine_id": "lathe-3"})
    line = one_error_line(capsys, ["fit", str(path), "--map", MAP.replace("encoder", "encodr")])
    assert "map pos: column 'encodr' is not in the log's header (line 2)" in line
    assert "t, drive_volts, encoder, setpoint, exc_volts" in line
    assert "did you mean 'encoder'?" in line and str(path) in line
    line = one_error_line(capsys, ["fit", str(path), "--map", "cmd=drive_volts,pos=9"])
    assert "map pos: column 9 is out of range: the log has 5 columns (0..4)" in line


def test_options_and_keys_for_the_other_kind_of_file(
    drive: dict[str, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    own = write_foreign(tmp_path / "own.csv", drive, 200)
    line = one_error_line(capsys, ["fit", str(own)])  # read as a servotune log: say --map
    assert "unknown column 't'" in line and "servotune fit --map" in line
    line = one_error_line(capsys, ["fit", str(own), "--map", MAP, "--hal-columns", "a,b"])
    assert "CSV log whose header names its columns" in line and "--hal-columns" in line
    line = one_error_line(capsys, ["fit", str(own), "--map", MAP, "--counter-bits", "24"])
    assert "counter_bits" in line and "unwrapped" in line
    # a halsampler capture stays one: numbers separated by spaces
    sampler = tmp_path / "capture.txt"
    sampler.write_text(
        "".join(f"{drive['volts'][k]:f} {drive['counts'][k]} \n" for k in range(200))
    )
    assert capture_format(sampler) == "halsampler"
    line = one_error_line(
        capsys, ["fit", str(sampler), "--map", "cmd=0,counts=1,time=2", "--period-s", "0.004"]
    )
    assert "map time names a CSV log's time column; a halsampler capture has none" in line
    scope = tmp_path / "scope.log"
    scope.write_text("# Sampling period is 4000000 ns\na;b\n1.0;2.0\n")
    assert capture_format(scope) == "halscope"
    # a CSV that begins with metadata, or without a header, is still a CSV
    meta_first = tmp_path / "m.csv"
    meta_first.write_text("# period_s: 0.004\n1,2\n3,4\n5,6\n")
    assert capture_format(meta_first) == "csv"
    line = one_error_line(capsys, ["fit", str(meta_first), "--map", "cmd=0,counts=1"])
    assert "looks like data, not a header" in line


def test_a_fleet_of_own_csv_logs_keeps_their_machine_ids(
    drive: dict[str, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from servotune.fleet import read_fleet_table

    logs = []
    for name, machine in (("a", "lathe-3"), ("b", "lathe-4")):  # named by their # lines
        meta = {"machine_id": machine, "date": "2025-03-01", "compute_s": f"{COMPUTE_S}"}
        logs.append(str(write_foreign(tmp_path / f"run-{name}.csv", drive, 3000, meta)))
    table = tmp_path / "fleet.csv"
    code = main(["fit", *logs, "--fleet", str(table), "--axis", "x", "--map", MAP])
    assert code == 0, capsys.readouterr().err
    rows = read_fleet_table(table)
    assert [(r.machine_id, r.date, r.axis) for r in rows] == [
        ("lathe-3", "2025-03-01", "x"),
        ("lathe-4", "2025-03-01", "x"),
    ]
    for r in rows:
        assert r.params["gain_cps_per_v"] == pytest.approx(K_CPS_PER_V, rel=0.02)
        assert r.params["tau_s"] == pytest.approx(TAU_S, rel=0.02)
