"""The verified runtime as a LinuxCNC HAL component, run in real HAL.

The runtime component (``servotune export-table --format linuxcnc-comp``) and the rig's two
plant components (:func:`servotune.export.hal_component.plant_component`) are built with
``halcompile``, loaded on a servo thread of the rig's period, fed a reference and modes from
``halstreamer`` and captured with ``halsampler``. The oracle is servotune's simulator
(``servotune.sim.engine.simulate``) of the same loop: the HAL run must give the same D/A codes
and counter registers, every tick, for 10,000+ ticks (reference moves across the master's
24-bit counter wrap, an excitation added to the master's output). The capture is then fitted
with ``servotune fit`` (the halsampler reader) and must recover the master's plant within 2 %.

One HAL session serves all the checks (it takes about 45 s of real time: the thread runs at
4 ms); the tests judge its capture.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from halrun import hal_available, halcompile, installed_component, run_hal

from servotune.cli import main
from servotune.export import hal_component
from servotune.export.hal_component import plant_component
from servotune.laws.axis import MODE_LOCK, MODE_TASK
from servotune.rig import EXAMPLE_RIG_PATH, Rig, load_rig
from servotune.scenarios import Inputs, trapezoid_ref
from servotune.sim.engine import Loop, Trace, simulate
from servotune.tuning import Tuning

N_TICKS = 10_240  # at least 10,000 ticks bit for bit, through the 24-bit counter's wrap
THREAD_PERIOD_NS = 250_000
"""The servo thread's wall period [ns]: faster than the rig's 4 ms, since nothing here depends
on the wall clock. Both components take their period from the constants compiled into them (they
ignore HAL's ``period``), and the streamer's and the sampler's FIFOs hold the whole run, so a
late cycle loses nothing: 10,240 ticks take about 3 s instead of 41."""
# capture columns, in the sampler's cfg order (halsampler prints them in this order)
COLUMNS = ("counts-0", "counts-1", "code-0", "code-1", "flags-0", "flags-1", "u-add-0")


def noiseless_rig() -> Rig:
    """The example rig without encoder noise (HAL's plant is noiseless, as the golden run's)."""
    r = load_rig(EXAMPLE_RIG_PATH)
    axes = tuple(
        dataclasses.replace(a, plant=dataclasses.replace(a.plant, noise_counts=0.0)) for a in r.axes
    )
    return dataclasses.replace(r, axes=axes)


def scenario(rig: Rig) -> Inputs:
    """Lock, then task: moves back and forth through the master's counter wrap (it starts at
    0xFFC000), with a ±300-code PRBS-like excitation added to the master's output."""
    n, period = N_TICKS, rig.period_s
    v_max = rig.axes[0].speed_limit_rpm / 60.0 * rig.counts_per_rev
    ref = np.zeros(n, dtype=np.int64)
    t = 200
    for dist, frac in ((40_000, 0.5), (-60_000, 0.8), (25_000, 0.3), (-5_000, 0.2)):
        v = frac * v_max
        ref += trapezoid_ref(n, period, dist, v, v / 0.05, start_tick=t)
        t += 2_000
    mode = np.full((n, 2), MODE_TASK, dtype=np.int64)
    mode[:100] = MODE_LOCK
    u_add = np.zeros((n, 2), dtype=np.int64)
    rng = np.random.default_rng(21)
    u_add[100:, 0] = np.repeat(rng.choice([-300, 300], (n - 100) // 8 + 1), 8)[: n - 100]
    return Inputs(
        ref_counts=np.stack([ref, np.zeros(n, dtype=np.int64)], axis=1),
        mode=mode,
        reset=np.zeros((n, 2), dtype=bool),
        dac_add_codes=u_add,
        load_v=np.zeros((n, 2)),
    )


def session_script(rig: Rig, ctl: str, plants: tuple[str, str], stream: str) -> str:
    """The halcmd session: one servo thread in the engine's tick order (reference in, plants
    move by the last write and latch their counts, the runtime ticks, the capture)."""
    nets = {"counts-0": "cnt0", "counts-1": "cnt1", "u-add-0": "uadd0"}  # already on a net
    mods = (*plants, ctl)
    plants = tuple(p.replace("_", "-") for p in plants)  # HAL names: _ becomes -
    ctl = ctl.replace("_", "-")
    return (
        "\n".join(
            [
                f"loadrt threads name1=servo period1={THREAD_PERIOD_NS}",
                *(f"loadrt {m}" for m in mods),
                f"loadrt streamer depth={N_TICKS + 16} cfg=ssss",
                f"loadrt sampler depth={N_TICKS + 16} cfg={'s' * len(COLUMNS)}",
                "addf streamer.0 servo",
                f"addf {plants[0]} servo",
                f"addf {plants[1]} servo",
                f"addf {ctl} servo",
                "addf sampler.0 servo",
                f"net ref streamer.0.pin.0 {ctl}.command",
                f"net mode0 streamer.0.pin.1 {ctl}.mode-0",
                f"net mode1 streamer.0.pin.2 {ctl}.mode-1",
                f"net uadd0 streamer.0.pin.3 {ctl}.u-add-0",
                f"net cnt0 {plants[0]}.counts {ctl}.counts-0",
                f"net cnt1 {plants[1]}.counts {ctl}.counts-1",
                f"net volts0 {ctl}.volts-0 {plants[0]}.volts",
                f"net volts1 {ctl}.volts-1 {plants[1]}.volts",
                *(
                    f"net {nets[c]} sampler.0.pin.{i}"
                    if c in nets
                    else f"net cap{i} {ctl}.{c} sampler.0.pin.{i}"
                    for i, c in enumerate(COLUMNS)
                ),
                f"loadusr -w halstreamer {stream}",
                "start",
                f"loadusr -w halsampler -n {N_TICKS}",
                "stop",
            ]
        )
        + "\n"
    )


@pytest.fixture(scope="module")
def hal_run(quick_tuning: Tuning, tmp_path_factory) -> tuple[Rig, Tuning, Trace, np.ndarray, Path]:
    """Build, install and run the loop in real HAL once; the simulator's trace beside it."""
    hal_available()
    rig = noiseless_rig()
    tuning = quick_tuning
    work = tmp_path_factory.mktemp("hal_component")
    inputs = scenario(rig)
    trace = simulate(Loop(rig=rig, controllers=tuning.controllers), inputs)
    ctl = "st_test_rt"
    names = ("st_test_plant_m", "st_test_plant_s")
    (work / f"{ctl}.comp").write_text(
        hal_component.to_string(tuning, rig=rig, unverified=True, name=ctl)
    )
    for name, ax in zip(names, rig.axes, strict=True):
        src = plant_component(
            ax.plant,
            rig.period_s,
            rig.timer.compute_s,
            name=name,
            counter_init=ax.counter_init,
            counts_per_rev=rig.counts_per_rev,
        )
        (work / f"{name}.comp").write_text(src)
    sos = [halcompile(work / f"{n}.comp") for n in (ctl, *names)]
    stream = np.column_stack([inputs.ref_counts[:, 0], inputs.mode, inputs.dac_add_codes[:, 0]])
    np.savetxt(work / "stream.txt", stream, fmt="%d")
    with installed_component(sos[0]), installed_component(sos[1]), installed_component(sos[2]):
        res = run_hal(session_script(rig, ctl, names, "stream.txt"), work, timeout=300.0)
    rows = [ln.split() for ln in res.stdout.splitlines() if ln.strip()]
    capture = np.array(rows, dtype=np.int64)
    (work / "capture.txt").write_text(res.stdout)
    return rig, tuning, trace, capture, work


def test_hal_runs_the_runtime_bit_for_bit_with_the_simulator(hal_run) -> None:
    rig, _, trace, cap, _ = hal_run
    assert cap.shape == (N_TICKS, len(COLUMNS)), cap.shape
    mask = (1 << rig.counter.bits) - 1
    registers = cap[:, 0:2] & mask
    # the plants in HAL saw the same commands: the counter registers agree every tick …
    np.testing.assert_array_equal(registers, trace.counter)
    # … and the runtime gave the same D/A codes and flags
    np.testing.assert_array_equal(cap[:, 2:4], trace.code)
    np.testing.assert_array_equal(cap[:, 4:6], trace.flags)
    # the scenario did what it says: the master's register wrapped, the D/A moved widely
    assert np.any(np.diff(registers[:, 0]) < -(mask // 2)) or np.any(
        np.diff(registers[:, 0]) > mask // 2
    )
    assert np.ptp(cap[:, 2]) > 1000


def test_a_component_with_edited_tables_refuses_to_load(quick_tuning: Tuning, tmp_path) -> None:
    hal_available()
    rig = noiseless_rig()
    name = "st_test_bad"
    src = hal_component.to_string(quick_tuning, rig=rig, unverified=True, name=name)
    # one constant changed by hand (the master's Kp), the exported digest left as it was
    marker = "#define ST_MASTER_KP_Q INT32_C("
    start = src.index(marker) + len(marker)
    end = src.index(")", start)
    edited = src[:start] + str(int(src[start:end]) + 1) + src[end:]
    assert edited != src
    (tmp_path / f"{name}.comp").write_text(edited)
    so = halcompile(tmp_path / f"{name}.comp")
    with installed_component(so):
        script = f"loadrt {name}\n"
        with pytest.raises(AssertionError, match="SHA-256 mismatch"):
            run_hal(script, tmp_path)


def test_fit_on_the_halsampler_capture_recovers_the_plant(hal_run, capsys) -> None:
    rig, _, _, _, work = hal_run
    truth = rig.axes[0].plant
    capture = work / "capture.txt"
    code = main(
        [
            "fit",
            str(capture),
            "--rig",
            str(EXAMPLE_RIG_PATH),
            "--axis",
            "master",
            "--map",
            "counts=0,code=2,exc=6",
            "--period-s",
            repr(rig.period_s),
            "--json",
        ]
    )
    out = capsys.readouterr()
    assert code == 0, out.err
    fit = json.loads(out.out)
    gain, tau = fit["params"]["gain_cps_per_v"], fit["params"]["tau_s"]
    assert fit["adequate"] is True
    assert abs(gain / truth.gain_cps_per_v - 1.0) < 0.02, (gain, truth.gain_cps_per_v)
    assert abs(tau / truth.tau_s - 1.0) < 0.02, (tau, truth.tau_s)
