"""``servotune export-table --format linuxcnc-hal``: the master's PI as LinuxCNC's stock pid.

Three kinds of checks:

- the conversion, against the definitions written out here again (exact rational arithmetic
  on the tuning's q/f integers, the rig's D/A and the scales; not by calling
  ``pid_parameters``), its errors, the CLI and the bytes;
- servotune's float model of the stock pid (``servotune.laws.linuxcnc_pid``) with the exported
  parameters and no feedforward runs servotune's verified integer PI law: the same D/A codes
  as the engine;
- real LinuxCNC HAL (``halrun``; skipped where LinuxCNC is not installed, failed under CI): the
  file loads after ``loadrt pid`` and every pin reads back bit for bit; and the stock ``pid``
  closing the loop around servotune's plant component gives, tick by tick, what
  ``servotune.sim.linuxcnc_pid.simulate_pid_loop`` computes.
"""

from __future__ import annotations

import dataclasses
import json
import math
from fractions import Fraction

import numpy as np
import pytest
from halrun import hal_available, halcompile, installed_component, run_hal, share

import servotune as st
from servotune.cli import main
from servotune.errors import ExportError
from servotune.export.hal_component import plant_component
from servotune.export.json import to_string as tables_to_string
from servotune.export.linuxcnc import pid_hal_text, pid_parameters
from servotune.hw.dac import code_from_volts
from servotune.laws.axis import MODE_TASK
from servotune.laws.linuxcnc_pid import PidParameters, PidState, pid_step, thread_period_ns
from servotune.scenarios import Inputs
from servotune.sim.engine import Loop, simulate
from servotune.sim.linuxcnc_pid import simulate_pid_loop
from servotune.tuning import write_tuning

PIN_ORDER = ("Pgain", "Igain", "Dgain", "bias", "FF0", "FF1", "FF2", "FF3", "deadband",
             "maxerror", "maxerrorI", "maxerrorD", "maxcmdD", "maxcmdDD", "maxcmdDDD",
             "maxoutput")  # fmt: skip
"""The float pins the file sets, in its order (pin names of LinuxCNC 2.9's pid.c)."""

PLANT_COMP = "stpidplant"  # a name no other test's component uses (installed for the session)
NOISE_SEED = 7  # the plant component's encoder-noise stream: the same in HAL and the simulation


def expected_pins(tuning: st.Tuning, rig: st.Rig, s: float, o: float) -> dict[str, Fraction]:
    """The exported pins from their definitions, exactly (module docstring of
    servotune.export.linuxcnc): servotune's u [LSB] = Kp·e + I, e in counts, I += Ki·T·e."""
    i = tuning.roles.index("master")
    pi = tuning.controllers[i].task
    lo, hi = (Fraction(v) for v in rig.dac.range_v)
    lsb = (hi - lo) / 2**rig.dac.bits  # one D/A step [V]
    kp = Fraction(pi.kp.q) / 2**pi.kp.f  # [LSB/count]
    ki = Fraction(pi.ki_t.q) / 2**pi.ki_t.f / Fraction(tuning.period_s)  # [LSB/count/s]
    s_, o_ = Fraction(s), Fraction(o)
    # an error of 1 machine unit is s counts: Kp·s LSB = Kp·s·lsb V = Kp·s·lsb·o output units
    pgain = kp * s_ * lsb * o_
    igain = ki * s_ * lsb * o_  # the pid's errorI is Σ e_units·T [unit·s]
    # the largest output the D/A gives both ways: 0 V is code -lo/lsb (2048 of 0…4095 for
    # ±10 V and 12 bits), so 2047 LSB up and 2048 down: 2047 LSB
    zero, code_max = -lo / lsb, 2**rig.dac.bits - 1
    full = min(zero, code_max - zero) * lsb * o_
    gain = Fraction(rig.axis(tuning.axis_names[i]).plant.gain_cps_per_v)
    pins = dict.fromkeys(PIN_ORDER, Fraction(0))
    # FF1: a speed of v unit/s is v·s counts/s, which the drive runs at v·s/gain V
    pins.update(
        Pgain=pgain, Igain=igain, maxoutput=full, maxerrorI=full / igain, FF1=s_ * o_ / gain
    )
    return pins


@pytest.fixture(scope="module")
def tuning(quick_tuning: st.Tuning) -> st.Tuning:
    return quick_tuning


# --- the conversion, without HAL ---------------------------------------------------------------


@pytest.mark.parametrize("s, o", [(2000.0, 1.0), (2457.6, 0.1), (1.0, 1.0), (12288.0 / 5.0, 3.0)])
def test_parameters_are_the_definitions_rounded_once(tuning, rig, s, o):
    p = pid_parameters(tuning, rig, position_scale=s, output_scale=o)
    want = expected_pins(tuning, rig, s, o)
    # each pin is the exact value rounded once to a double (float(Fraction) rounds correctly)
    assert {k: getattr(p, k) for k in PIN_ORDER} == {k: float(v) for k, v in want.items()}
    assert p.error_previous_target is False  # e = command − feedback, as servotune's r(k) − y(k)


def test_conversion_round_trips_to_the_tuning_constants(tuning, rig):
    pi = tuning.controllers[0].task
    lsb = rig.dac.lsb_v
    for s, o in ((2000.0, 1.0), (2457.6, 0.1), (0.5, 7.0)):
        p = pid_parameters(tuning, rig, position_scale=s, output_scale=o)
        np.testing.assert_allclose(p.Pgain / (lsb * o * s), pi.kp.value, rtol=4e-16)
        np.testing.assert_allclose(
            p.Igain * tuning.period_s / (lsb * o * s), pi.ki_t.value, rtol=4e-16
        )
        np.testing.assert_allclose(p.Igain * p.maxerrorI, p.maxoutput, rtol=4e-16)
    # a power of two in a scale is exact: twice the counts per unit, twice the gains
    p1 = pid_parameters(tuning, rig, position_scale=1000.0)
    p2 = pid_parameters(tuning, rig, position_scale=2000.0)
    assert (p2.Pgain, p2.Igain, p2.FF1) == (2 * p1.Pgain, 2 * p1.Igain, 2 * p1.FF1)
    assert p2.maxoutput == p1.maxoutput == 2047 * lsb
    assert pid_parameters(tuning, rig, position_scale=2000.0, velocity_feedforward=False).FF1 == 0


@pytest.mark.parametrize("value", [0.0, -2000.0, math.nan, math.inf, -math.inf, True, "2000"])
@pytest.mark.parametrize("which", ["position_scale", "output_scale"])
def test_bad_scales_are_one_line_errors(tuning, rig, which, value):
    kw = {"position_scale": 2000.0, "output_scale": 1.0, which: value}
    with pytest.raises(ExportError) as err:
        pid_hal_text(tuning, rig=rig, unverified=True, **kw)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(f"{which} must be a number > 0 [")


@pytest.mark.parametrize("s, o", [(1e308, 1e10), (1e-300, 1e-300)])
def test_scales_beyond_a_double_are_refused(tuning, rig, s, o):
    # overflow, or a gain that is not 0 rounding to 0: never a silently wrong pin
    with pytest.raises(ExportError, match="beyond a double's range"):
        pid_parameters(tuning, rig, position_scale=s, output_scale=o)


@pytest.mark.parametrize("name", ["", "pid x", "pid#x", "pid,x", "$x", "p" * 26, 3])
def test_bad_pid_names(tuning, rig, name):
    with pytest.raises(ExportError, match=r"pid_name .* is not a pid instance name"):
        pid_hal_text(tuning, rig=rig, unverified=True, position_scale=2000.0, pid_name=name)


def test_pid_name_sets_the_instance(tuning, rig):
    text = pid_hal_text(tuning, rig=rig, unverified=True, position_scale=2000.0, pid_name="pid.0")
    setp = [ln for ln in text.splitlines() if not ln.startswith("#")]
    pgain = pid_parameters(tuning, rig, position_scale=2000.0).Pgain
    assert setp[0] == f"setp pid.0.Pgain {pgain!r}"
    assert all(ln.startswith("setp pid.0.") for ln in setp) and len(setp) == 17


def test_master_must_run_pi(tuning, rig):
    fuzzy = tuning.controllers[1]
    bad = dataclasses.replace(tuning, controllers=(fuzzy, fuzzy))
    with pytest.raises(ExportError, match=r"runs the fuzzy-PID law.*--format linuxcnc-comp"):
        pid_parameters(bad, rig, position_scale=2000.0)
    lock_only = dataclasses.replace(fuzzy, task=None)
    bad = dataclasses.replace(tuning, controllers=(lock_only, fuzzy))
    with pytest.raises(ExportError, match="runs no task law"):
        pid_parameters(bad, rig, position_scale=2000.0)
    with pytest.raises(ExportError, match="single rig's tuning"):
        pid_parameters(object(), rig, position_scale=2000.0)  # type: ignore[arg-type]


def test_verification_gate(tuning, rig):
    kw = {"rig": rig, "position_scale": 2000.0}
    with pytest.raises(ExportError, match="no verification summary"):
        pid_hal_text(tuning, **kw)
    with pytest.raises(ExportError, match="the verification failed"):
        pid_hal_text(tuning, verification={"passed": False}, **kw)
    ok = pid_hal_text(tuning, verification={"passed": True}, **kw)
    assert "# verified: yes" in ok
    assert "# verified: NO: exported with --unverified" in pid_hal_text(
        tuning, unverified=True, **kw
    )


def test_same_input_same_bytes_and_provenance(tuning, rig):
    a = pid_hal_text(tuning, rig=rig, unverified=True, position_scale=2457.6, output_scale=0.1)
    b = pid_hal_text(tuning, rig=rig, unverified=True, position_scale=2457.6, output_scale=0.1)
    assert a == b and a.endswith("\n")
    tables = json.loads(tables_to_string(tuning, rig=rig, unverified=True))
    for needed in (
        f"servotune {st.__version__}",
        f"rig: {tuning.rig_name}, sha256 {tuning.rig_sha256}",
        f"tuning sha256: {tables['provenance']['tuning_sha256']}",
        f"sha256 {tables['sha256']}",  # the tables export of the same tuning
        "position_scale S = 2457.6 ",
        "output_scale O = 0.1 ",
        f"run it at {thread_period_ns(tuning.period_s)} ns",
    ):
        assert needed in a, needed


# --- the CLI -----------------------------------------------------------------------------------


def test_cli_writes_the_file_to_stdout(tuning, rig, tmp_path, capsys):
    path = tmp_path / "t.json"
    write_tuning(tuning, path)
    argv = [
        "export-table",
        str(path),
        "--format",
        "linuxcnc-hal",
        "--position-scale",
        "2000",
        "--unverified",
    ]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert out == pid_hal_text(tuning, rig=rig, unverified=True, position_scale=2000.0)
    assert main([*argv, "--output-scale", "0.1"]) == 0
    assert capsys.readouterr().out == pid_hal_text(
        tuning, rig=rig, unverified=True, position_scale=2000.0, output_scale=0.1
    )
    assert main([*argv, "-o", str(tmp_path / "a.hal")]) == 0
    assert main([*argv, "-o", str(tmp_path / "b.hal")]) == 0
    assert (tmp_path / "a.hal").read_bytes() == (tmp_path / "b.hal").read_bytes() == out.encode()
    # --pid names the instance, --no-feedforward exports exactly the verified law (FF1 0)
    assert main([*argv, "--pid", "pid.y", "--no-feedforward"]) == 0
    assert capsys.readouterr().out == pid_hal_text(
        tuning,
        rig=rig,
        unverified=True,
        position_scale=2000.0,
        pid_name="pid.y",
        velocity_feedforward=False,
    )
    assert "setp pid.x.FF1 0.0\n" not in out  # the default has velocity feedforward


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--unverified"], "--format linuxcnc-hal needs --position-scale"),
        (["--position-scale", "0", "--unverified"], "position_scale must be a number > 0"),
        (["--position-scale", "nan", "--unverified"], "position_scale must be a number > 0"),
        (
            ["--position-scale", "2000", "--output-scale", "-1", "--unverified"],
            "output_scale must be a number > 0",
        ),
        (["--position-scale", "2000"], "verif"),  # no record: refused without --unverified
    ],
)
def test_cli_errors_are_one_line(tuning, tmp_path, capsys, argv, message):
    path = tmp_path / "t.json"
    write_tuning(tuning, path)
    code = main(["export-table", str(path), "--format", "linuxcnc-hal", *argv])
    cap = capsys.readouterr()
    assert code != 0 and cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], cap.err


@pytest.mark.parametrize(
    "schema, kind",
    [("servotune.gantry-tuning/1", "gantry tuning"), ("servotune.linkage-plan/1", "linkage plan")],
)
def test_cli_refuses_a_gantry_or_linkage(tmp_path, capsys, schema, kind):
    # the CLI tells the architecture by the schema before reading the rest
    path = tmp_path / "doc.json"
    path.write_text(json.dumps({"schema": schema}))
    code = main(
        [
            "export-table",
            str(path),
            "--format",
            "linuxcnc-hal",
            "--position-scale",
            "2000",
            "--unverified",
        ]
    )
    cap = capsys.readouterr()
    assert code == 3 and cap.out == ""
    assert cap.err.count("\n") == 1 and f"is a {kind}" in cap.err


# --- the stock pid's law, in servotune ---------------------------------------------------------


def test_pid_step_branches():
    # expected values worked out from pid.c's calc_pid, with its period in seconds
    t = 100_000_000 * 0.000000001  # periodfp of a 100 ms thread
    p = PidParameters(
        Pgain=2.0, Igain=10.0, deadband=0.5, maxoutput=3.0, error_previous_target=False
    )
    out, err, s = pid_step(p, PidState(), 1.0, 0.0, 100_000_000)  # e = 1 − 0.5 deadband
    assert (err, s.error_i) == (1.0, 0.5 * t) and out == 2.0 * 0.5 + 10.0 * (0.5 * t)
    i1 = s.error_i
    out, err, s = pid_step(p, s, 10.0, 0.0, 100_000_000)  # on the limit: +3, limit_state +1
    assert out == 3.0 and s.limit_state == 1.0 and s.error_i == i1 + 9.5 * t
    out, _, s2 = pid_step(p, s, 10.0, 0.0, 100_000_000)  # no wind-up while pushing on it
    assert s2.error_i == s.error_i and out == 3.0
    _, _, s3 = pid_step(p, s, -10.0, 0.0, 100_000_000)  # integrates back off the limit
    assert s3.error_i == s.error_i + -9.5 * t  # e = −10 + 0.5 deadband
    prev = PidParameters(Pgain=1.0)  # the component's default: error = previous command − fb
    out, err, _ = pid_step(prev, PidState(prev_cmd=4.0), 7.0, 1.0, 1_000_000)
    assert err == 3.0 and out == 3.0
    out, _, s = pid_step(p, s, 1.0, 0.0, 1_000_000, enable=False)
    assert out == 0.0 and s.error_i == 0.0 and s.limit_state == 0.0
    ff = PidParameters(Pgain=0.0, FF1=2.0, error_previous_target=False)
    out, _, s = pid_step(ff, PidState(prev_cmd=1.0), 1.5, 0.0, 250_000_000)
    t = 250_000_000 * 0.000000001
    assert s.cmd_d == 0.5 * (1.0 / t) and out == s.cmd_d * 2.0  # FF1 × the command's speed


def _trapezoid(n: int, distance: float, v_max: float, a: float, period_s: float, start: int):
    """A move of ``distance`` at most ``v_max`` [unit/s] and ``a`` [unit/s²], from tick
    ``start``; position per tick k (time k·period_s, integer tick arithmetic)."""
    t = (np.arange(n, dtype=np.int64) - start) * period_s
    t_acc = v_max / a
    t_flat = distance / v_max - t_acc
    assert t_flat > 0
    t_end = 2 * t_acc + t_flat
    tc = np.clip(t, 0.0, t_end)
    x = np.where(
        tc < t_acc,
        0.5 * a * tc**2,
        np.where(
            tc < t_acc + t_flat,
            0.5 * a * t_acc**2 + v_max * (tc - t_acc),
            distance - 0.5 * a * (t_end - tc) ** 2,
        ),
    )
    return x


def test_float_pid_without_feedforward_runs_the_verified_law(tuning, rig):
    """With position_scale 1 (machine unit = count), FF1 = 0 and the D/A quantising, the stock
    pid's float law gives the D/A codes of servotune's integer PI law in the engine: the
    conversion is the law, not only the formulas (no saturation here: the two anti-windups
    differ by when they look at the limit, pid.c at the previous output)."""
    master = rig.axis("master")
    plant = dataclasses.replace(master.plant, noise_counts=0.0)
    one = dataclasses.replace(rig, axes=(dataclasses.replace(master, plant=plant),))
    n = 2500
    ref = np.round(_trapezoid(n, 60_000.0, 30_000.0, 150_000.0, rig.period_s, 100)).astype(np.int64)
    z = np.zeros((n, 1), dtype=np.int64)
    inputs = Inputs(
        ref_counts=ref[:, None],
        mode=z + MODE_TASK,
        reset=z.astype(bool),
        dac_add_codes=z,
        load_v=np.zeros((n, 1)),
    )
    trace = simulate(Loop(rig=one, controllers=(tuning.controllers[0],)), inputs)
    params = pid_parameters(tuning, rig, position_scale=1.0, velocity_feedforward=False)
    res = simulate_pid_loop(
        params,
        plant,
        rig.period_s,
        ref.astype(float),
        position_scale=1.0,
        compute_s=rig.timer.compute_s,
        counts_per_rev=rig.counts_per_rev,
        dac=rig.dac,
    )
    codes = code_from_volts(res.volts, rig.dac.bits, rig.dac.range_v)
    assert np.all((codes > 0) & (codes < rig.dac.code_max))  # never on a rail
    assert np.max(np.abs(trace.err_counts[:, 0])) > 100  # a real move, not a hold
    np.testing.assert_array_equal(codes, trace.code[:, 0])
    np.testing.assert_array_equal(res.counts, trace.pos_counts[:, 0])


# --- real HAL ----------------------------------------------------------------------------------


def _exact_gain(x: float) -> int:
    """k with |x·2^k| in [2^52, 2^53): an integer-valued double, which halsampler's "%f" prints
    exactly (0 for x = 0)."""
    return 0 if x == 0 else 53 - math.frexp(x)[1]


def test_hal_file_loads_and_reads_back_exactly(tuning, rig, tmp_path):
    hal_available()
    s, o = 2457.6, 0.1  # 12288 counts/rev on a 5 mm lead screw; a D/A driver scaled ±1 = ±10 V
    (tmp_path / "pid.hal").write_text(
        pid_hal_text(tuning, rig=rig, unverified=True, position_scale=s, output_scale=o)
    )
    want = expected_pins(tuning, rig, s, o)
    gains = {pin: _exact_gain(float(v)) for pin, v in want.items()}
    # each pin, linked to a signal (which takes its value), through a `scale` of gain 2^k
    # (exact) into the sampler: the printed integer is the pin's double times 2^k
    names = ",".join(f"rb{i}" for i in range(len(PIN_ORDER)))
    script = [
        "loadrt threads name1=servo period1=1000000",
        "loadrt pid names=pid.x",
        "source pid.hal",
        f"loadrt scale names={names}",
        f"loadrt sampler depth=8 cfg={'f' * len(PIN_ORDER)}",
    ]
    for i, pin in enumerate(PIN_ORDER):
        script += [
            f"net p{i} pid.x.{pin} => rb{i}.in",
            f"setp rb{i}.gain {2.0 ** gains[pin]!r}",
            f"net q{i} rb{i}.out => sampler.0.pin.{i}",
            f"addf rb{i} servo",
        ]
    script += [
        "addf sampler.0 servo",
        "getp pid.x.error-previous-target",
        "start",
        "loadusr -w halsampler -n 1",
        "stop",
    ]
    share(tmp_path)
    res = run_hal("\n".join(script) + "\n", tmp_path)
    rows = [ln.split() for ln in res.stdout.splitlines()]
    assert ["FALSE"] in rows, res.stdout  # the bit pin (getp)
    (sample,) = [r for r in rows if len(r) == len(PIN_ORDER)]
    got = {pin: Fraction(sample[i]) / 2 ** gains[pin] for i, pin in enumerate(PIN_ORDER)}
    assert all(v.denominator & (v.denominator - 1) == 0 for v in got.values())  # dyadic: exact
    assert {k: float(v) for k, v in got.items()} == {k: float(v) for k, v in want.items()}


_SCALED = 2**100
"""Float signals are sampled times 2^100 (an exact scaling in `scale`): halsampler's "%f" then
prints every double of magnitude >= 2^-54 exactly (a multiple of 2^-106, times 2^100, has at
most 6 binary, so 6 decimal, fraction digits), and the sample reads back as that double."""


def _loop_script(n: int, period_ns: int, s: float, o: float) -> str:
    probes = ["pos", "fb", "err", "out", "volts"]
    lines = [
        f"loadrt threads name1=servo period1={period_ns}",
        f"loadrt {PLANT_COMP}",
        f"setp {PLANT_COMP}.seed {NOISE_SEED}",
        "loadrt pid names=pid.x",
        "source pid.hal",
        "loadrt conv_s32_float names=cnt2f",
        f"loadrt scale names=fbscale,dacscale,{','.join('x' + p for p in probes)}",
        f"loadrt streamer depth={n + 16} cfg=f",
        f"loadrt sampler depth={n + 16} cfg=fs{'f' * len(probes)}",
        "loadusr -w halstreamer command.txt",  # the whole reference is in before start
        f"setp fbscale.gain {1.0 / s!r}",  # encoder: counts · (1/position-scale)
        f"setp dacscale.gain {1.0 / o!r}",  # output units → volts at the D/A
        *(f"setp x{p}.gain {float(_SCALED)!r}" for p in probes),
        "setp pid.x.enable true",
        "net cmd streamer.0.pin.0 => pid.x.command sampler.0.pin.0",
        f"net counts {PLANT_COMP}.counts => cnt2f.in sampler.0.pin.1",
        "net countsf cnt2f.out => fbscale.in",
        "net fb fbscale.out => pid.x.feedback xfb.in",
        "net out pid.x.output => dacscale.in xout.in",
        f"net volts dacscale.out => {PLANT_COMP}.volts xvolts.in",
        f"net pos {PLANT_COMP}.position => xpos.in",
        "net err pid.x.error => xerr.in",
        *(f"net s{p} x{p}.out => sampler.0.pin.{i + 2}" for i, p in enumerate(probes)),
        # the plant first (it latches the count this period), then the controller
        "addf streamer.0 servo",
        f"addf {PLANT_COMP} servo",
        "addf cnt2f servo",
        "addf fbscale servo",
        "addf pid.x.do-pid-calcs servo",
        "addf dacscale servo",
        *(f"addf x{p} servo" for p in probes),
        "addf sampler.0 servo",
        "start",
        f"loadusr -w halsampler -n {n}",
        "stop",
        "getp sampler.0.overruns",
    ]
    return "\n".join(lines) + "\n"


def test_stock_pid_in_hal_matches_the_float_simulation(tuning, rig, tmp_path):
    """The stock pid (with the exported file) around servotune's plant component, on a thread
    of the rig's period, against simulate_pid_loop: the same law, plant and float arithmetic.

    Tolerance: none, bit for bit. Every value is an IEEE double computed by the same operations
    in the same order (pid.c's calc_pid, the plant's C mirror of servotune.plant with its
    coefficients as hex floats, `scale` = in·gain + offset, conv_s32_float exact), on x86-64
    SSE2 doubles without FMA contraction: HAL's float path differs from Python's by nothing
    that rounds differently. The counts are compared exactly, the float samples exactly through
    their printed text (_SCALED). The plant has the example rig's encoder noise (0.3 counts),
    drawn in HAL and in the simulation from the same seeded stream (NOISE_SEED).
    """
    hal_available()
    s, o = 2000.0, 0.1
    master = rig.axis("master")
    n = 2500
    period_ns = thread_period_ns(rig.period_s)
    # out 20 units at 50 unit/s (≈ 8.1 V of feedforward alone: the output reaches its limit
    # in the acceleration, so the anti-windup acts), hold, and back at 10 unit/s
    cmd = _trapezoid(n, 20.0, 50.0, 600.0, rig.period_s, 50) - _trapezoid(
        n, 20.0, 10.0, 100.0, rig.period_s, 1000
    )
    (tmp_path / "command.txt").write_text("".join(f"{x!r}\n" for x in cmd.tolist()))
    (tmp_path / "pid.hal").write_text(
        pid_hal_text(tuning, rig=rig, unverified=True, position_scale=s, output_scale=o)
    )
    comp = tmp_path / f"{PLANT_COMP}.comp"
    comp.write_text(
        plant_component(master.plant, rig.period_s, rig.timer.compute_s, name=PLANT_COMP)
    )
    share(tmp_path)
    with installed_component(halcompile(comp)):
        res = run_hal(_loop_script(n, period_ns, s, o), tmp_path, timeout=600.0)
    rows = [ln.split() for ln in res.stdout.splitlines()]
    samples = [r for r in rows if len(r) == 7]
    assert len(samples) == n, res.stdout[-400:]
    assert [r for r in rows if len(r) == 1][-1] == ["0"], res.stdout[-400:]  # no overrun
    # (the streamer runs dry only after the window: `stop` comes a few periods after the last
    # sample; the command column below shows each tick got its own reference value)
    params = pid_parameters(tuning, rig, position_scale=s, output_scale=o)
    sim = simulate_pid_loop(
        params,
        master.plant,
        rig.period_s,
        cmd,
        position_scale=s,
        output_scale=o,
        compute_s=rig.timer.compute_s,
        period_ns=period_ns,
        noise_seed=NOISE_SEED,
    )
    assert master.plant.noise_counts > 0  # the encoder noise is in, the same draws …
    quiet = dataclasses.replace(master.plant, noise_counts=0.0)
    kw = {"position_scale": s, "output_scale": o, "compute_s": rig.timer.compute_s}
    noiseless = simulate_pid_loop(params, quiet, rig.period_s, cmd, **kw)
    assert np.any(noiseless.counts != sim.counts)  # … and it moves counts
    assert np.max(np.abs(sim.output)) == params.maxoutput  # the limit was reached
    assert abs(sim.counts[-1]) <= 2 and np.max(sim.counts) > 39_000  # out and back
    hal_counts = np.array([int(r[1]) for r in samples])
    np.testing.assert_array_equal(hal_counts, sim.counts)
    assert [r[0] for r in samples] == [f"{x:.6f}" for x in cmd]
    worst = {}
    for col, (name, values) in enumerate(
        [
            ("position_counts", sim.position_counts),
            ("feedback_units", sim.feedback_units),
            ("error_units", sim.error_units),
            ("output", sim.output),
            ("volts", sim.volts),
        ],
        start=2,
    ):
        want = [f"{x * _SCALED:.6f}" for x in values.tolist()]
        got = [r[col] for r in samples]
        worst[name] = float(
            max(
                abs(Fraction(g) / _SCALED - Fraction(x))
                for g, x in zip(got, values.tolist(), strict=True)
            )
        )
        assert got == want, (name, next(k for k in range(n) if got[k] != want[k]))
    assert worst == dict.fromkeys(worst, 0.0)
    print(f"HAL vs simulation over {n} ticks: counts identical; largest differences {worst}")
