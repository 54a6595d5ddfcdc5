"""`servotune fit LOG --modes auto|N`: the plant's lightly damped modes fitted to the log's
frequency response beside the time-domain fit, printed, in ``--json``, and written by ``-o``
into the rig file (docs/frf.md#modes, docs/formats.md#modes).

The logs:

- a belt-driven axis (the example rig's master, plants/pc-dual-servo.toml, with the mode of
  plants/belt-axis.toml: 35 Hz, damping 0.04, load-to-motor inertia ratio 0.5) held by the
  example rig's lock law (P, 0.4 D/A codes per count, docs/systems.md#position-lock) while a
  periodic multisine is added at its 12-bit ±10 V D/A. The plant is sampled exactly by
  python-control (``sample_system``, zero-order hold) and the loop is written out below:
  nothing of servotune's plant model or engine makes this log;
- the rigid example rig's closed-loop log, as ``servotune excite`` and ``servotune simulate
  --input --closed-loop`` make it (friction, drift, quantisation; servotune's engine).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLE_RIG

import servotune as st
from servotune.cli import main
from servotune.excite import periodic_multisine
from servotune.logs import write_log

PERIOD_S = 0.004000235  # the example rig's achieved tick (docs/systems.md)
MODE_HZ, DAMPING, INERTIA_RATIO = 35.0, 0.04, 0.5  # plants/belt-axis.toml's mode
LOCK_GAIN = 0.4  # codes per count, the example rig's lock_gain_codes_per_count
LSB_V = 20.0 / 4096  # the example rig's 12-bit ±10 V D/A

# the rigid time-domain model does not explain a resonant axis, and the fit says so
RIGID_FIT_OF_A_MODE = pytest.mark.filterwarnings(
    "ignore::servotune.identify.InadequateModelWarning",
    "ignore::servotune.identify.PoorFitWarning",
)


def _belt_log(path: Path, seed: int = 0, *, invert: bool = False) -> Path:
    """The belt-driven axis's closed-loop log with a periodic multisine (module docstring):
    8 periods of 5 s, lines 0.5 … 50 Hz, 1000 codes; encoder noise 0.3 counts before the
    floor (the example rig's noise_counts). ``invert``: the position counted the other way."""
    import control

    plant = st.load_rig(EXAMPLE_RIG).axis("master").plant
    w = 2 * np.pi * MODE_HZ
    s = control.tf("s")
    rigid = plant.gain_cps_per_v / (s * (plant.tau_s * s + 1))
    belt = rigid * (1 + INERTIA_RATIO * s**2 / (s**2 + 2 * DAMPING * w * s + w**2))
    d = control.sample_system(control.ss(belt), PERIOD_S, method="zoh")
    a, b, c = np.asarray(d.A), np.asarray(d.B)[:, 0], np.asarray(d.C)[0]
    ms = periodic_multisine(1250, 8, PERIOD_S, 1000, band_hz=(0.5, 50.0))
    noise = np.random.default_rng(seed).normal(0.0, 0.3, ms.codes.size)
    x = np.zeros(a.shape[0])
    u = np.empty(ms.codes.size)
    y = np.empty(ms.codes.size, dtype=np.int64)
    for k, r in enumerate(ms.codes):
        y[k] = np.floor(c @ x + noise[k])
        code = np.clip(2048 + np.rint(-LOCK_GAIN * y[k]) + r, 0, 4095)
        u[k] = (code - 2048) * LSB_V
        x = a @ x + b * u[k]
    cols = {"cmd_v": u, "pos_counts": -y if invert else y, "exc_code": ms.codes}
    write_log(path, period_s=PERIOD_S, columns=cols, metadata={"compute_s": 0.0})
    return path


@pytest.fixture(scope="module")
def rigid_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The rigid example rig's closed-loop multisine log (module docstring)."""
    d = tmp_path_factory.mktemp("rigid")
    exc, log = d / "ms.csv", d / "log.csv"
    excite = ["excite", "--rig", str(EXAMPLE_RIG), "--axis", "master", "--kind", "multisine"]
    assert main([*excite, "--periods", "8", "--seconds", "40", "-o", str(exc)]) == 0
    simulate = ["simulate", str(EXAMPLE_RIG), "--input", str(exc), "--closed-loop"]
    assert main([*simulate, "--seed", "1", "-o", str(log)]) == 0
    return log


def _modes_in(rig_file: Path) -> tuple[st.Rig, str]:
    return st.load_rig(rig_file), rig_file.read_text()


@RIGID_FIT_OF_A_MODE
def test_auto_writes_the_belt_mode_into_the_rig_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _belt_log(tmp_path / "belt.csv")
    out = tmp_path / "fitted.toml"
    argv = ["fit", str(log), "--axis", "master", "--modes", "auto", "-o", str(out), "--json"]
    assert main(argv) == 0
    cap = capsys.readouterr()
    rig, text = _modes_in(out)
    (mode,) = rig.axis("master").plant.modes  # one mode, in the rig file
    assert abs(mode.freq_hz / MODE_HZ - 1) < 0.03
    assert text.count("[[axis.master.plant.modes]]") == 1
    lo, hi = mode.freq_hz_95
    assert lo <= mode.freq_hz <= hi and mode.damping_95 is not None and mode.gain_95 is not None
    assert rig.axis("slave").plant.modes == ()
    # the provenance says so; the summary prints it; the JSON has the whole mode fit
    assert "1 mode (auto) from its frequency response" in text
    assert f"mode {mode.freq_hz:.4g} Hz" in cap.err
    fit = json.loads(cap.out)["mode_fit"]
    assert [m["freq_hz"] for m in fit["modes"]] == [pytest.approx(mode.freq_hz, rel=1e-6)]
    assert fit["order_rule"] == "auto" and {h["modes"] for h in fit["held_out"]} >= {0, 1}
    assert fit["modes"][0]["freq_hz_95"] == [pytest.approx(x, rel=1e-6) for x in (lo, hi)]
    # the written plant's linear part is the frequency-domain fit's, the sampled plant's within
    # 5 % (the time-domain rigid fit, which has no mode, is not: docs/frf.md#modes)
    plant, truth = rig.axis("master").plant, st.load_rig(EXAMPLE_RIG).axis("master").plant
    assert plant.mean_gain_cps_per_v == pytest.approx(fit["rigid"]["gain_cps_per_v"], rel=1e-6)
    assert plant.mean_gain_cps_per_v == pytest.approx(truth.gain_cps_per_v, rel=0.05)
    assert plant.tau_s == pytest.approx(truth.tau_s, rel=0.05)
    written = json.loads(cap.out)["written_plant"]
    assert written["source"]["tau_s"] == "frequency-domain fit (with the modes)"
    assert written["fit_pct"]["velocity"] > 95.0


@RIGID_FIT_OF_A_MODE
def test_an_inverted_encoder_gives_the_same_mode(tmp_path: Path) -> None:
    log = _belt_log(tmp_path / "inverted.csv", invert=True)
    out = tmp_path / "fitted.toml"
    argv = ["fit", str(log), "--axis", "master", "--modes", "1", "--invert-encoder"]
    assert main([*argv, "-o", str(out)]) == 0
    (mode,) = st.load_rig(out).axis("master").plant.modes
    assert abs(mode.freq_hz / MODE_HZ - 1) < 0.03


def test_auto_on_the_rigid_example_rig_writes_none(
    rigid_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fitted.toml"
    argv = ["fit", str(rigid_log), "--axis", "master", "--modes", "auto", "-o", str(out)]
    assert main([*argv, "--json"]) == 0
    cap = capsys.readouterr()
    rig, text = _modes_in(out)
    assert rig.axis("master").plant.modes == () and "modes]]" not in text
    assert json.loads(cap.out)["mode_fit"]["modes"] == []
    assert "0 modes (auto)" in cap.err


def test_modes_0_or_absent_give_the_same_bytes(
    rigid_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    outputs = []
    for extra in ([], ["--modes", "0"]):
        d = tmp_path / ("zero" if extra else "absent")
        d.mkdir()
        out = d / "fitted.toml"
        argv = ["fit", str(rigid_log), "--axis", "master", "-o", str(out), "--json", *extra]
        assert main(argv) == 0
        cap = capsys.readouterr()
        outputs.append((cap.out, cap.err.replace(str(out), "OUT"), out.read_bytes()))
    assert outputs[0] == outputs[1]
    assert "mode_fit" not in json.loads(outputs[0][0])


@pytest.mark.parametrize(
    "args, message",
    [
        (["--modes", "two"], "--modes must be auto or a number"),
        (["--modes", "7"], "modes must be auto or a number of modes in 0..4"),
        (["--modes", "auto"], "the log has no exc_code column"),
    ],
)
def test_bad_requests_are_one_line_exit_3_nothing_written(
    rigid_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], args, message
) -> None:
    log = tmp_path / "no-exc.csv"
    lines = rigid_log.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    j = lines[head].split(",").index("master.exc_code")
    rows = [",".join(c for i, c in enumerate(r.split(",")) if i != j) for r in lines[head:]]
    log.write_text("\n".join([*lines[:head], *rows]) + "\n")
    out = tmp_path / "fitted.toml"
    assert main(["fit", str(log), "--axis", "master", "-o", str(out), *args]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err, err
    assert not out.exists()


def test_modes_is_for_one_log_not_a_fleet(
    rigid_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = tmp_path / "fleet.csv"
    argv = ["fit", str(rigid_log), "--fleet", str(table), "--modes", "auto"]
    assert main(argv) == 2
    assert "--modes is for one log" in capsys.readouterr().err
    assert not table.exists()
