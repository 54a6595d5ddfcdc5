"""``servotune excite --kind multisine --periods P``: a periodic multisine for ``servotune frf``
(docs/frf.md#the-experiment, docs/formats.md#excitation-file).

The file is checked with numpy alone (not with servotune's period finder or reader): its codes
repeat exactly, one period's DFT carries energy only on the excited odd lines of the band, the
crest factor it reports is the codes'. Played in closed loop on the example rig, the axis stays
within its speed limit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLE_RIG

import servotune as st
from servotune.cli import main
from servotune.errors import SpecError
from servotune.excite import design_excitation, excitation_inputs, read_excitation
from servotune.logs import read_log

PERIODS = 4
SECONDS = 20.0
# 20 s / 4 periods at the achieved period 4.000235 ms (docs/runtime.md#timer-and-achieved-period)
PERIOD_TICKS = 1250
ZERO_CODE = 2048  # 12-bit D/A, ±10 V (plants/pc-dual-servo.toml)


def _excite(path: Path, *extra: str, kind: str = "multisine") -> int:
    head = ["excite", "--rig", str(EXAMPLE_RIG), "--kind", kind, "--seconds", str(SECONDS)]
    return main([*head, *extra, "-o", str(path)])


def _read(path: Path) -> tuple[dict[str, str], np.ndarray]:
    """Metadata and the codes relative to the 0 V code, parsed with numpy alone."""
    lines = path.read_text().splitlines()
    meta = dict(ln[2:].split(": ", 1) for ln in lines if ln.startswith("# "))
    rows = [ln for ln in lines if not ln.startswith("#")]
    assert rows[0] == "tick,time_s,master.dac_code"
    codes = np.loadtxt(io.StringIO("\n".join(rows[1:])), delimiter=",", usecols=2, dtype=np.int64)
    return meta, codes - ZERO_CODE


@pytest.fixture(scope="module")
def designed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """``excite --periods 4 --seconds 20`` (Schroeder phases, the default band): the file and
    the stderr summary."""
    path = tmp_path_factory.mktemp("frf") / "ms.csv"
    capture = io.StringIO()
    with contextlib.redirect_stderr(capture):
        assert _excite(path, "--periods", str(PERIODS)) == 0
    return path, capture.getvalue()


def test_codes_repeat_exactly_with_the_requested_periods(designed: tuple[Path, str]) -> None:
    meta, codes = _read(designed[0])
    assert meta["periods"] == str(PERIODS) and meta["period_ticks"] == str(PERIOD_TICKS)
    assert codes.size == PERIODS * PERIOD_TICKS
    rows = codes.reshape(PERIODS, PERIOD_TICKS)
    assert np.array_equal(rows, np.broadcast_to(rows[0], rows.shape))
    # and no shorter period divides it: one period is not itself a repetition
    for d in (2, 3, 5):
        if PERIOD_TICKS % d == 0:
            assert not np.array_equal(rows[0], np.roll(rows[0], PERIOD_TICKS // d))
    assert int(np.max(np.abs(codes))) == int(meta["amplitude_codes"])


def test_one_period_has_energy_only_on_the_excited_odd_lines(designed: tuple[Path, str]) -> None:
    meta, codes = _read(designed[0])
    period_s = float(meta["period_s"])
    f1, f2 = (float(f) for f in meta["band_hz"].split(","))
    assert (f1, f2) == pytest.approx((0.5, 0.4 * 0.5 / period_s), rel=1e-5)  # the default band
    spectrum = np.abs(np.fft.rfft(codes[:PERIOD_TICKS]))
    # the unrounded signal is exactly zero off its lines; rounding to whole codes (|error| <=
    # 0.5 a tick) adds at most 0.5 · ticks to any line
    rounding = 0.5 * PERIOD_TICKS
    excited = np.flatnonzero(spectrum > rounding)
    assert excited.size == int(meta["excited_lines"])
    assert np.all(excited % 2 == 1)
    hz = np.arange(spectrum.size) / (PERIOD_TICKS * period_s)
    assert np.all((hz[excited] >= f1 * (1 - 1e-9)) & (hz[excited] <= f2 * (1 + 1e-9)))
    # equal amplitudes, within the rounding, far above it
    assert np.ptp(spectrum[excited]) <= 2 * rounding
    assert spectrum[excited].min() > 50 * rounding
    # the odd lines of the band left out are the detection lines: about one in three, and empty
    in_band = np.flatnonzero((hz >= f1 * (1 - 1e-9)) & (hz <= f2 * (1 + 1e-9)))
    detection = np.setdiff1d(in_band[in_band % 2 == 1], excited)
    assert detection.size == int(meta["detection_lines"])
    assert 0.25 <= detection.size / (detection.size + excited.size) <= 0.4
    assert np.all(spectrum[detection] <= rounding)
    # the even lines (and DC) and everything outside the band are empty to the rounding level
    empty = np.setdiff1d(np.arange(spectrum.size), excited)
    assert np.all(spectrum[empty] <= rounding)


def test_schroeder_crest_factor_is_low_and_reported_as_computed(
    designed: tuple[Path, str], rig: st.Rig
) -> None:
    path, stderr = designed
    meta, codes = _read(path)
    crest = float(np.max(np.abs(codes)) / np.sqrt(np.mean(codes.astype(float) ** 2)))
    assert crest <= 1.8
    assert meta["phases"] == "schroeder"
    assert float(meta["crest_factor"]) == pytest.approx(crest, rel=1e-5)
    ex = design_excitation(rig, "master", "multisine", SECONDS, periods=PERIODS)
    assert ex.crest_factor == pytest.approx(crest, rel=1e-12)
    assert np.array_equal(ex.codes, codes)  # the file is the design
    # the summary: one line with periods × ticks, band, line counts and the crest factor
    assert stderr.count("\n") == 1
    assert f"{PERIODS} periods × {PERIOD_TICKS} ticks" in stderr
    assert "band 0.5 … 50 Hz" in stderr
    assert f"{meta['excited_lines']} excited and {meta['detection_lines']} detection lines" in (
        stderr
    )
    assert f"crest factor {crest:.2f}" in stderr


def test_closed_loop_play_stays_within_the_speed_limit(
    designed: tuple[Path, str], rig: st.Rig, tmp_path: Path
) -> None:
    path = designed[0]
    log_path = tmp_path / "log.csv"
    argv = ["simulate", str(EXAMPLE_RIG), "--input", str(path), "--closed-loop"]
    assert main([*argv, "-o", str(log_path)]) == 0
    log = read_log(log_path)
    ax = log.axis("master")
    _, codes = _read(path)
    assert np.array_equal(ax.exc_code, codes)  # the log records what was played
    limit_cps = rig.axis("master").speed_limit_rpm / 60.0 * rig.counts_per_rev
    speed = np.abs(np.diff(ax.pos_counts)) / log.period_s  # mean speed over each tick
    assert speed.max() <= limit_cps
    assert speed.max() >= 0.3 * limit_cps  # it does excite the axis
    # the instantaneous speed too, on the engine the verb runs
    _, absolute = read_excitation(path, rig)
    inputs = excitation_inputs(rig, "master", absolute, closed_loop=True)
    tr = st.simulate(st.Loop.from_rig(rig), inputs, seed=0)
    assert np.max(np.abs(tr.speed_cps[:, tr.axis("master")])) <= limit_cps


def _with_master(rig: st.Rig, **changes: object) -> st.Rig:
    master = dataclasses.replace(rig.axis("master"), **changes)
    return dataclasses.replace(rig, axes=(master, rig.axis("slave")))


@pytest.mark.parametrize(
    ("changes", "limited_by"),
    [({"speed_limit_rpm": 200.0}, "speed"), ({"travel_counts": (-1500, 1500)}, "travel")],
)
def test_speed_or_travel_sets_the_amplitude_of_a_periodic_multisine(
    rig: st.Rig, changes: dict[str, object], limited_by: str
) -> None:
    r = _with_master(rig, **changes)
    ex = design_excitation(r, "master", "multisine", SECONDS, periods=PERIODS, phases="random")
    assert ex.limited_by == limited_by and ex.amplitude_codes < 2047
    rows = ex.codes.reshape(PERIODS, PERIOD_TICKS)
    assert np.array_equal(rows, np.broadcast_to(rows[0], rows.shape))
    assert ex.phases == "random" and ex.crest_factor > 2.0
    ax = r.axis("master")
    assert ex.predicted_max_speed_rpm <= 0.9 * ax.speed_limit_rpm * (1 + 1e-12)
    inputs = excitation_inputs(r, "master", ex.absolute_codes)  # open loop, as designed
    tr = st.simulate(st.Loop.from_rig(r), inputs, seed=0)
    i = tr.axis("master")
    assert np.max(np.abs(tr.speed_cps[:, i])) <= ax.speed_limit_rpm / 60.0 * r.counts_per_rev
    if ax.travel_counts is not None:
        lo, hi = ax.travel_counts
        assert lo <= tr.pos_counts[:, i].min() and tr.pos_counts[:, i].max() <= hi


def test_summary_fields_only_for_a_periodic_multisine(rig: st.Rig) -> None:
    plain = design_excitation(rig, "master", "multisine", 2.0)
    assert plain.periods is None and "periods" not in plain.to_dict()
    ex = design_excitation(rig, "master", "multisine", 2.0, periods=2, band_hz=(5.0, 60.0))
    d = ex.to_dict()
    assert (d["periods"], d["period_ticks"], d["band_hz"]) == (2, 250, (5.0, 60.0))
    # lines 0.99994 Hz apart: the odd bins 7 … 59 (bin 5 is at 4.9997 Hz, below the band)
    assert d["excited_lines"] + d["detection_lines"] == 27
    with pytest.raises(SpecError, match="for a multisine"):
        design_excitation(rig, "master", "steps", 2.0, periods=2)
    with pytest.raises(SpecError, match="give periods"):
        design_excitation(rig, "master", "multisine", 2.0, band_hz=(5.0, 60.0))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--periods", "1"], "periods >= 2"),
        (["--periods", "4", "--band", "1:120"], "0.9 · Nyquist"),
        (["--kind", "prbs", "--periods", "4"], "--periods is for --kind multisine"),
        (["--periods", "4", "--band", "10.01:10.05"], "no odd line"),
        (["--band", "1:20"], "give --periods"),
        (["--phases", "random"], "give --periods"),
        (["--periods", "4", "--band", "1-20"], "--band must be F1:F2"),
    ],
)
def test_bad_input_is_one_line_exit_3_and_no_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    path = tmp_path / "ms.csv"
    kind = "multisine"
    if argv[0] == "--kind":
        kind, argv = argv[1], argv[2:]
    assert _excite(path, *argv, kind=kind) == 3
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1 and captured.err.startswith("servotune excite: error:")
    assert message in captured.err
    assert not path.exists() and list(tmp_path.iterdir()) == []
