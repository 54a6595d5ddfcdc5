"""Output filters in the runtime's law (docs/runtime.md#filters-in-the-law): the C runtime and
every export of a filtered tuning, against the Python law.

- (a) Closed loop: a master with four sections (three notches and a low-pass) and a fuzzy-PID
  slave with two, on the example rig's hardware, the C runtime (``st_tick``) and the Python tick
  (``axis_read``/``axis_control``, what the engine calls) driven in lock step around a plant for
  120,000 ticks: moves, D/A saturation at both rails (task and open loop), lock/task/open
  switches, a following-error trip, a counter fault and resets, and the filters switched in,
  out and re-tuned twelve times while it runs (``st_axis_switch_filters`` /
  ``switch_filters``; the whole state equal right after each switch). Every D/A code, flag, error,
  position and mode is equal, and so is the whole state (the filters' words included) at every
  1,000th tick. Then replays of random inputs with injected counter jumps, extreme references and
  added commands on three D/A widths (the filters' clamp at both rails of each), against the
  Python tick, the strict build and the undefined-behaviour sanitizer's.
- (b) The runtime's HAL component (``export-table --format linuxcnc-comp``) of the master axis
  (four sections, no following-error limit) in real HAL for 20,000 periods, fed counts (with a
  counter fault), commands, modes, resets, added commands beyond both rails and its
  ``filters-off-0`` pin toggled four times: its codes, flags, errors and positions are the
  Python tick's, period by period.
- (c) An edited filter coefficient is refused: by ``load_tables`` and ``check-table`` (one line;
  with the constants CRC left, recomputed, and every digest recomputed too), and by the C
  runtime's ``st_check_digest`` on a header whose filter constant was edited;
  ``st_check_consts`` names a bad filter field.
- (d) A ``servotune.tables/2`` document gets the one-line old-schema error.
- (e) A tables document read back gives the controllers with their filters; the constants CRC
  and the C layout carry them in the documented order (built here with :mod:`struct`).
- (f) ``--format linuxcnc-hal`` writes the master's sections as LinuxCNC ``biquad`` lines when
  it has filters, and nothing more when it has none.
- The gantry's and the linkage's exports carry a filtered drive's or axis's sections (their C
  runs them: ``test_c_gantry_filters.py``, ``test_c_linkage_filters.py``); an export whose
  filter sums could leave ±2^62 is refused.
"""

from __future__ import annotations

import ctypes
import dataclasses
import hashlib
import json
import math
import re
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from c_build import (
    HARNESS_HEAD,
    STRICT,
    TICK_C,
    cc,
    export_harness,
    needs_cc,
    run_replay,
    shared_harness,
    ubsan_harness,
)

from servotune.arch.gantry.tuning import GantryTuning
from servotune.arch.linkage import plan_linkage
from servotune.cli import main
from servotune.digest import text_digest_problem
from servotune.errors import DigestError, ExportError
from servotune.export import hal_component
from servotune.export.gantry import gantry_document
from servotune.export.json import (
    SCHEMA,
    controllers_from_tables,
    load_tables,
    tables_document,
)
from servotune.export.json import to_string as tables_to_string
from servotune.export.layout import c_layout_bytes
from servotune.export.linkage import linkage_c_header
from servotune.export.linuxcnc import FILTER_DIFFERENCE_CODES, pid_hal_text
from servotune.fixed import Fixed
from servotune.hw import timer
from servotune.laws.axis import (
    C_NF,
    FILTER_F,
    FLAG_COUNTER_FAULT,
    FLAG_FOLLOWING_ERROR,
    FLAG_SATURATED,
    MODE_LOCK,
    MODE_OPEN,
    MODE_TASK,
    N_STATE,
    S_FILT,
    S_MODE,
    AxisController,
    axis_control,
    axis_read,
    filter_block,
    switch_filters,
)
from servotune.laws.filters import (
    SectionQ,
    choose_frac_bits,
    lowpass2,
    notch,
    quantize_section,
)
from servotune.laws.fuzzy_pid import FuzzyPIDGains
from servotune.laws.pi import PIConstants, PIGains
from servotune.laws.sync import SyncConstants
from servotune.plant import Plant
from servotune.rig import EXAMPLE_RIG_PATH, Axis, Counter, Dac, Encoder, Rig, Timer, load_rig
from servotune.scenarios import trapezoid_ref
from servotune.tuning import Tuning

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "hal"))
import halrun

HARNESS = (
    HARNESS_HEAD
    + r"""
/* st_axis_switch_filters with n sections from int64 words b0 b1 b2 a1 a2 frac_bits each */
int h_switch(int a, int n, const int64_t *w)
{
    st_section_t sec[ST_MAX_FILTERS + 1];
    int k;
    for (k = 0; k < n && k <= ST_MAX_FILTERS; k++) {
        sec[k].b0 = (int32_t)w[6 * k];
        sec[k].b1 = (int32_t)w[6 * k + 1];
        sec[k].b2 = (int32_t)w[6 * k + 2];
        sec[k].a1 = (int32_t)w[6 * k + 3];
        sec[k].a2 = (int32_t)w[6 * k + 4];
        sec[k].frac_bits = (int32_t)w[6 * k + 5];
    }
    return st_axis_switch_filters(&consts.axis[a], &state.axis[a], n, sec);
}

/* st_check_consts on a copy with one filter field of axis 0 broken */
int h_check_broken(int what)
{
    st_consts_t c = consts;
    if (what == 0) {
        c.axis[0].n_filters = ST_MAX_FILTERS + 1;
    } else if (what == 1) {
        c.axis[0].n_filters = -1;
    } else if (what == 2) {
        c.axis[0].filter[1].frac_bits = 0;
    } else if (what == 3) {
        c.axis[0].filter[1].frac_bits = 31;
    } else if (what == 4) {
        c.axis[0].filter[0].a2 = (int32_t)1 << c.axis[0].filter[0].frac_bits; /* |a2| = 1 */
    } else if (what == 5) {
        st_section_t *q = &c.axis[0].filter[0];
        q->a1 = -(q->a2 + ((int32_t)1 << q->frac_bits)); /* |a1| = 1 + a2 */
    }
    return st_check_consts(&c);
}

/* one axis's state in the Python state row's order (laws/axis.py S_*) */
void h_state(int a, int64_t *out)
{
    const st_axis_state_t *x = &state.axis[a];
    int k;
    int j;
    out[0] = x->init;
    out[1] = x->hi_prev;
    out[2] = x->wraps;
    out[3] = x->y;
    out[4] = x->mode;
    out[5] = x->fault;
    out[6] = x->lock_target;
    out[7] = x->integ;
    out[8] = x->u_last;
    out[9] = x->e_prev;
    out[10] = x->r_prev;
    out[11] = x->origin;
    for (k = 0; k < ST_MAX_FILTERS; k++) {
        for (j = 0; j < ST_FILTER_STATE; j++) {
            out[12 + ST_FILTER_STATE * k + j] = x->filt[k][j];
        }
    }
}

"""
    + TICK_C
    + r"""
#ifdef H_MAIN
/* file replay: in = n, axes, then raw, ref, mode, reset, u_add (int64, n * axes each);
 * out = the (n, axes, 5) outputs, then every axis's final state (N_STATE words) */
int main(int argc, char **argv)
{
    int64_t head[2];
    int64_t *buf;
    int64_t *out;
    size_t cells;
    size_t words;
    int a;
    FILE *f;
    if (argc != 3) {
        return 2;
    }
    f = fopen(argv[1], "rb");
    if (f == NULL || fread(head, sizeof head[0], 2, f) != 2 || head[1] != consts.n_axes) {
        return 3;
    }
    cells = (size_t)head[0] * (size_t)head[1];
    words = 5 * cells + 36 * (size_t)head[1];
    buf = malloc(5 * cells * sizeof *buf);
    out = malloc(words * sizeof *out);
    if (buf == NULL || out == NULL || fread(buf, sizeof *buf, 5 * cells, f) != 5 * cells) {
        return 4;
    }
    fclose(f);
    if (h_check() != 0 || h_check_digest() != 0) {
        return 5;
    }
    h_reset();
    h_run(head[0], buf, buf + cells, buf + 2 * cells, buf + 3 * cells, buf + 4 * cells, out);
    for (a = 0; a < consts.n_axes; a++) {
        h_state(a, out + 5 * cells + 36 * (size_t)a);
    }
    f = fopen(argv[2], "wb");
    if (f == NULL || fwrite(out, sizeof *out, words, f) != words) {
        return 6;
    }
    fclose(f);
    free(buf);
    free(out);
    return 0;
}
#endif
"""
)

ST_DIGEST_OK, ST_DIGEST_MISMATCH = 0, 1
SECTION_KEYS = ("b0", "b1", "b2", "a1", "a2", "frac_bits")


class Runtime:
    """The compiled harness (shared library) through ctypes."""

    def __init__(self, src_dir: Path, name: str = "libfilters.so") -> None:
        lib = shared_harness(src_dir, name)
        i64, p = ctypes.c_int64, ctypes.c_void_p
        for fn_name, res, args in (
            ("h_tick", None, [p] * 6),
            ("h_run", None, [i64] + [p] * 6),
            ("h_state", None, [ctypes.c_int, p]),
            ("h_check_broken", ctypes.c_int, [ctypes.c_int]),
            ("h_consts_crc32", ctypes.c_uint32, []),
            ("h_switch", ctypes.c_int, [ctypes.c_int, ctypes.c_int, p]),
        ):
            fn = getattr(lib, fn_name)
            fn.restype = res
            fn.argtypes = args
        self.lib = lib
        self.n_axes = lib.h_n_axes()

    def switch(self, a: int, block: np.ndarray) -> int:
        """``st_axis_switch_filters`` of axis ``a`` to a :func:`filter_block`."""
        words = np.ascontiguousarray(block[1:], dtype=np.int64)
        return self.lib.h_switch(a, int(block[0]), words.ctypes.data)

    def state(self) -> np.ndarray:
        out = np.zeros((self.n_axes, N_STATE), dtype=np.int64)
        for a in range(self.n_axes):
            self.lib.h_state(a, out[a].ctypes.data)
        return out

    def run(self, raw, ref, mode, reset, u_add) -> np.ndarray:
        """Replay per-tick inputs (arrays (ticks, axes)) from power-up; outputs (ticks, axes,
        5): code, flags, e, y, mode."""
        arrs = [np.ascontiguousarray(x, dtype=np.int64) for x in (raw, ref, mode, reset, u_add)]
        out = np.zeros((arrs[0].shape[0], self.n_axes, 5), dtype=np.int64)
        self.lib.h_reset()
        self.lib.h_run(arrs[0].shape[0], *(a.ctypes.data for a in arrs), out.ctypes.data)
        return out


class PythonTick:
    """The Python law, one tick at a time, as the engine calls it (reads, then the laws)."""

    def __init__(self, tuning: Tuning, hw: dict, refs: list[int]) -> None:
        rows = [
            c.consts(
                counter_bits=hw["counter_bits"],
                dac_bits=hw["dac"]["bits"],
                dac_zero=hw["dac"]["zero_code"],
            )
            for c in tuning.controllers
        ]
        self.c = np.zeros((len(rows), max(len(r) for r in rows)), dtype=np.int64)
        for a, r in enumerate(rows):
            self.c[a, : len(r)] = r
        self.st = np.zeros((len(rows), N_STATE), dtype=np.int64)
        self.refs = refs

    def tick(self, raw, ref, mode, reset, u_add) -> list[tuple[int, int, int, int, int]]:
        n_ax = len(self.refs)
        y = [axis_read(self.st, self.c, a, int(raw[a]), bool(reset[a])) for a in range(n_ax)]
        out = []
        for a in range(n_ax):
            r = int(ref[a]) if self.refs[a] < 0 else y[self.refs[a]]
            code, flags, e = axis_control(
                self.st, self.c, a, r, int(mode[a]), bool(reset[a]), int(u_add[a])
            )
            out.append((code, flags, e, y[a], int(self.st[a, S_MODE])))
        return out

    def switch(self, a: int, block: np.ndarray) -> None:
        switch_filters(self.st, self.c, a, block)

    def run(self, raw, ref, mode, reset, u_add, switches=None) -> np.ndarray:
        out = np.zeros((raw.shape[0], len(self.refs), 5), dtype=np.int64)
        for k in range(raw.shape[0]):
            for a, block in (switches or {}).get(k, ()):
                self.switch(a, block)
            out[k] = self.tick(raw[k], ref[k], mode[k], reset[k], u_add[k])
        return out


# --- the filtered tuning ----------------------------------------------------------------------

PERIOD_S = float(timer.achieved_period_s(int(timer.divisor(0.004))))
MASTER_FE_LIMIT = 20_000  # [counts]: trips on the 40,000-count reference step of the scenario


def sections(period_s: float, designs) -> tuple[SectionQ, ...]:
    """Quantised sections at the word length :func:`choose_frac_bits` picks."""
    return tuple(quantize_section(d, period_s, choose_frac_bits(d, period_s)) for d in designs)


MASTER_DESIGNS = (
    notch(22.0, 6.0, -25.0),
    lowpass2(70.0, 0.6),
    notch(40.0, 10.0, -15.0),
    notch(55.0, 12.0, -30.0),
)
SLAVE_DESIGNS = (notch(30.0, 8.0, -20.0), lowpass2(90.0, 0.45))


def filtered_tuning() -> Tuning:
    """The example rig's two axes, fixed gains (no optimiser): a PI master with four filter
    sections, a fuzzy-PID + feedforward slave with two."""
    divisor = int(timer.divisor(0.004))
    n = 3
    lv = np.arange(-n, n + 1)
    e, ec = np.meshgrid(lv, lv, indexing="ij")
    s = np.clip((e + ec) / n, -1.0, 1.0)
    slave = FuzzyPIDGains(
        kp0=0.5,
        ki0=2.0,
        kd0=0.004,
        k10=1.0 / (11700.0 * 20.0 / 4096),
        ke=0.02,
        kec=0.25,
        n=n,
        dkp=0.2 * np.abs(s),
        dki=-0.5 * np.abs(s),
        dkd=0.001 * s,
        dk1=0.01 * s,
    )
    ctls = tuple(
        dataclasses.replace(
            AxisController.from_gains(
                lock_gain_codes_per_count=0.4,
                task_gains=g,
                period_s=PERIOD_S,
                following_error_limit_counts=fe,
            ),
            filters=sections(PERIOD_S, designs),
        )
        for g, fe, designs in (
            (PIGains(kp=0.35, ki=1.4), MASTER_FE_LIMIT, MASTER_DESIGNS),
            (slave, 12288, SLAVE_DESIGNS),
        )
    )
    return Tuning(
        rig_name="pc-dual-servo",
        rig_sha256=hashlib.sha256(b"filtered rig").hexdigest(),
        period_s=PERIOD_S,
        timer_divisor=divisor,
        axis_names=("master", "slave"),
        roles=("master", "slave"),
        controllers=ctls,
        design={"note": "filtered tuning of tests/export/test_c_filters.py"},
        provenance={"seed": 0, "tool": "servotune"},
    )


def unfiltered(tuning: Tuning) -> Tuning:
    ctls = tuple(dataclasses.replace(c, filters=()) for c in tuning.controllers)
    return dataclasses.replace(tuning, controllers=ctls)


@pytest.fixture(scope="module")
def tuning() -> Tuning:
    return filtered_tuning()


@pytest.fixture(scope="module")
def doc(tuning: Tuning) -> dict:
    return tables_document(tuning, unverified=True)


@pytest.fixture(scope="module")
def build(tuning: Tuning, tmp_path_factory) -> Path:
    return export_harness(tuning, tmp_path_factory.mktemp("c_filters"), HARNESS)


@pytest.fixture(scope="module")
def runtime(build: Path) -> Runtime:
    return Runtime(build)


# --- (a) closed loop --------------------------------------------------------------------------

N_LOOP = 120_000


def loop_inputs(n: int = N_LOOP) -> dict[str, np.ndarray]:
    """References, modes, resets, added commands, load kicks and counter glitches: moves and
    steps in task (saturating the D/A both ways), open loop driven to both rails, a
    following-error trip of the master (a step) and of the slave (a load kick), a counter fault
    of the slave, resets in task and lock."""
    v_max = 600.0 / 60.0 * 12288.0  # [counts/s]
    ref = np.zeros(n, dtype=np.int64)
    mode = np.full((n, 2), MODE_LOCK, dtype=np.int64)
    reset = np.zeros((n, 2), dtype=np.int64)
    u_add = np.zeros((n, 2), dtype=np.int64)
    kick = np.zeros((n, 2))  # [counts/s] added to the plant's speed
    glitch = np.zeros((n, 2), dtype=np.int64)  # XORed into the register read

    def move(t0: int, dist: int, frac: float, accel_s: float) -> None:
        v = frac * v_max
        ref[:] += trapezoid_ref(n, PERIOD_S, dist, v, v / accel_s, start_tick=t0)
        dur = math.ceil((abs(dist) / v + accel_s) / PERIOD_S)
        mode[t0 - 100 : t0 + dur + 400, :] = MODE_TASK

    t = 1000
    pattern = ((60_000, 0.5, 0.1), (-90_000, 0.9, 0.02), (40_000, 0.95, 0.01), (-10_000, 0.2, 0.2))
    while t < 70_000:
        for dist, frac, acc in pattern:
            move(t, dist, frac, acc)
            t += 2500
    for t0, step in ((75_000, 7000), (77_000, -7000)):  # steps in task: both rails
        ref[t0:] += step
        mode[t0 - 100 : t0 + 1000, :] = MODE_TASK
    reset[76_000, 0] = 1  # a reset in task mode
    ref[80_000:] += 40_000  # past the master's following-error limit: a trip
    mode[79_900:80_300, :] = MODE_TASK
    ref[80_500:] -= 40_000
    reset[81_000, 0] = 1  # in lock
    rng = np.random.default_rng(3)
    u_add[85_000:87_000, 0] = np.repeat(rng.choice([-400, 400], 200), 10)  # excitation in lock
    mode[88_000:89_000, :] = MODE_OPEN  # open loop, driven to both rails
    u_add[88_000:88_150, :] = 3000
    u_add[88_150:88_300, :] = -3000
    u_add[88_300:89_000, :] = np.repeat(rng.integers(-300, 301, (70, 2)), 10, axis=0)
    move(90_000, 70_000, 0.9, 0.02)
    move(93_000, -70_000, 0.9, 0.02)
    glitch[100_000, 1] = 0x400000  # the slave's high byte jumps by 64 for one read: a fault
    reset[101_000, 1] = 1
    kick[104_000, 1] = 3.0e6  # a load kick on the slave in lock: a following-error trip
    reset[105_000, 1] = 1  # then lock to the end (the slave is far from the master now)
    return {
        "ref": ref,
        "mode": mode,
        "reset": reset,
        "u_add": u_add,
        "kick": kick,
        "glitch": glitch,
    }


ALT_MASTER_DESIGNS = (notch(19.0, 8.0, -20.0), lowpass2(80.0, 0.5))  # a re-tuned master
ALT_SLAVE_DESIGNS = (notch(26.0, 6.0, -25.0),)


def loop_switches(tuning: Tuning) -> dict[int, list[tuple[int, np.ndarray]]]:
    """Filters switched while the closed loop runs (tick → (axis, :func:`filter_block`)): in,
    out and re-tuned, during moves, at a rail (the steps, the open loop), after a fault and
    its reset; all after tick 20,000, where the replay without filters stops."""
    own = [filter_block(c.filters) for c in tuning.controllers]
    alt = [filter_block(sections(PERIOD_S, d)) for d in (ALT_MASTER_DESIGNS, ALT_SLAVE_DESIGNS)]
    none = filter_block(())
    return {
        25_000: [(0, alt[0]), (1, none)],
        32_517: [(1, own[1])],
        40_000: [(0, none)],
        47_003: [(0, own[0]), (1, alt[1])],
        60_250: [(0, alt[0])],
        75_050: [(0, own[0])],
        76_500: [(1, own[1])],
        88_100: [(0, alt[0]), (1, none)],
        88_200: [(1, alt[1])],
        95_000: [(0, own[0])],
        102_000: [(1, none)],
        110_000: [(1, own[1])],
    }


def closed_loop(
    rt: Runtime, py: PythonTick, ins: dict[str, np.ndarray], switches=None
) -> dict[str, object]:
    """C and Python in lock step around a first-order speed plant per axis (the example rig's
    gains and time constants; the D/A code acts one tick later). The plant moves by the C
    runtime's codes; both read the same registers. ``switches`` (:func:`loop_switches`): the
    filters switched before those ticks, in both."""
    n = ins["ref"].shape[0]
    gain, tau = (12288.0, 11700.0), (0.025, 0.030)
    init, mask = (0xFFC000, 0x000400), (1 << 24) - 1
    pos, spd, volts = [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]
    c_out = np.zeros((n, 2, 5), dtype=np.int64)
    py_out = np.zeros((n, 2, 5), dtype=np.int64)
    raw = np.zeros(2, dtype=np.int64)
    ref2 = np.zeros((n, 2), dtype=np.int64)
    ref2[:, 0] = ins["ref"]
    arrs = [np.ascontiguousarray(x) for x in (ref2, ins["mode"], ins["reset"], ins["u_add"])]
    stride = 2 * 8
    bases = [a.ctypes.data for a in arrs]
    tick, p_raw, p_out = rt.lib.h_tick, raw.ctypes.data, c_out.ctypes.data
    state_mismatch, clamped = [], np.zeros(2, dtype=np.int64)
    lo_hi = (-2048 << FILTER_F, (4095 - 2048) << FILTER_F)
    rt.lib.h_reset()
    for k in range(n):
        for a in range(2):
            raw[a] = ((init[a] + math.floor(pos[a])) & mask) ^ int(ins["glitch"][k, a])
        for a, block in (switches or {}).get(k, ()):
            assert rt.switch(a, block) == 0
            py.switch(a, block)
            if not np.array_equal(rt.state(), py.st):  # the bumpless state, word for word
                state_mismatch.append(-k)
        off = k * stride
        tick(p_raw, bases[0] + off, bases[1] + off, bases[2] + off, bases[3] + off, p_out + 5 * off)
        py_out[k] = py.tick(raw, ref2[k], ins["mode"][k], ins["reset"][k], ins["u_add"][k])
        for a in range(2):  # section 0's last input held to a rail: the clamp engaged
            clamped[a] += int(py.st[a, S_FILT]) in lo_hi
            spd[a] += (gain[a] * volts[a] - spd[a]) * PERIOD_S / tau[a] + ins["kick"][k, a]
            pos[a] += spd[a] * PERIOD_S
            volts[a] = (int(c_out[k, a, 0]) - 2048) * (20.0 / 4096)
        if k % 1000 == 999 and not np.array_equal(rt.state(), py.st):
            state_mismatch.append(k)
    return {"c": c_out, "py": py_out, "states": state_mismatch, "clamped": clamped}


@pytest.fixture(scope="module")
def loop(runtime: Runtime, tuning: Tuning, doc: dict) -> dict[str, object]:
    data = doc["data"]
    py = PythonTick(tuning, data, [ax["ref_source"] for ax in data["axes"]])
    res = closed_loop(runtime, py, loop_inputs(), loop_switches(tuning))
    res["final_equal"] = np.array_equal(runtime.state(), py.st)
    res["n_filters"] = py.c[:, C_NF].tolist()
    return res


def _onsets(flags: np.ndarray, bit: int) -> np.ndarray:
    on = (flags & bit) != 0
    return np.sum(on[1:] & ~on[:-1], axis=0)


@needs_cc
def test_runtime_and_filtered_tables_compile_cleanly_and_check(
    build: Path, runtime: Runtime, doc: dict
) -> None:
    cc(build, *STRICT, "-O2", "-c", "servotune_rt.c", "-o", "rt.o")
    header = (build / "servotune_tables.h").read_text()
    assert "#define ST_MASTER_N_FILTERS 4" in header and "#define ST_SLAVE_N_FILTERS 2" in header
    assert (
        ".filter[3] = {ST_MASTER_FILT3_B0," in header
        and ".filter[2]" not in header.split("/* slave */")[1]
    )
    assert runtime.lib.h_check() == 0 and runtime.lib.h_check_digest() == ST_DIGEST_OK
    assert runtime.lib.h_consts_crc32() == doc["data"]["constants_crc32"]
    # st_check_consts: 1 + 100·axis + 17 (n_filters) or 18 (a section in use)
    assert [runtime.lib.h_check_broken(w) for w in range(6)] == [18, 18, 19, 19, 19, 19]


@needs_cc
def test_st_axis_switch_filters_refuses_a_bad_chain_and_changes_nothing(
    runtime: Runtime, tuning: Tuning
) -> None:
    """A count beyond four, a negative one, or a section that fails st_check_consts' checks (a
    zero word length, an unstable denominator) is refused with its code; the state is
    untouched and the runtime keeps its own filters."""
    runtime.lib.h_reset()
    before = runtime.state().copy()
    own = filter_block(tuning.controllers[0].filters)
    five = np.concatenate([own[:1] + 1, own[1:], own[1:7]])
    assert runtime.switch(0, five) == 1
    assert runtime.switch(0, np.concatenate([[-1], own[1:]])) == 1
    bad_f = own.copy()
    bad_f[1 + 6 + 5] = 0  # section 1's frac_bits
    assert runtime.switch(0, bad_f) == 3
    unstable = own.copy()
    unstable[1 + 4] = 1 << int(own[6])  # section 0's a2 = 1
    assert runtime.switch(0, unstable) == 2
    assert np.array_equal(runtime.state(), before) and runtime.lib.h_check() == 0
    assert runtime.switch(1, filter_block(())) == 0
    runtime.lib.h_reset()


@needs_cc
def test_closed_loop_c_equals_the_python_tick(loop: dict[str, object]) -> None:
    c, py = loop["c"], loop["py"]
    assert c.shape == (N_LOOP, 2, 5)
    for i, name in enumerate(("code", "flags", "e", "y", "mode")):
        bad = np.argwhere(c[:, :, i] != py[:, :, i])
        assert bad.size == 0, f"{name} differs first at (tick, axis) {tuple(bad[0])}"
    assert loop["states"] == [] and loop["final_equal"]  # the filters' words too
    assert loop["n_filters"] == [4, 2]  # switched back to their own after the last switch
    # what the scenario must exercise
    code, flags, mode = py[:, :, 0], py[:, :, 1], py[:, :, 4]
    for a in range(2):
        task, open_ = mode[:, a] == MODE_TASK, mode[:, a] == MODE_OPEN
        assert np.sum(task & (code[:, a] == 4095)) >= 20 and np.sum(task & (code[:, a] == 0)) >= 20
        assert (
            np.sum(open_ & (code[:, a] == 4095)) >= 20 and np.sum(open_ & (code[:, a] == 0)) >= 20
        )
        # the flag: the filtered code beyond a rail (a law output beyond it is held at the rail
        # by the filters' input clamp, so fewer ticks than at the rails)
        assert np.sum((flags[:, a] & FLAG_SATURATED) != 0) >= 20
        assert loop["clamped"][a] >= 50  # the filters' input clamp at a rail
        to_task = (mode[1:, a] == MODE_TASK) & (mode[:-1, a] != MODE_TASK)
        assert to_task.sum() >= 20 and np.any(open_)
    assert _onsets(flags, FLAG_FOLLOWING_ERROR).tolist() == [1, 1]
    assert _onsets(flags, FLAG_COUNTER_FAULT).tolist() == [0, 1]
    assert not np.any(flags[-1000:] & (FLAG_FOLLOWING_ERROR | FLAG_COUNTER_FAULT))  # reset


@needs_cc
def test_the_filters_shape_the_closed_loops_codes(
    loop: dict[str, object], tuning: Tuning, doc: dict
) -> None:
    """The run is not the unfiltered law's: the same reads through the law without its filters
    give other codes on most task ticks (so a runtime that skipped them would fail above)."""
    data = doc["data"]
    bare = PythonTick(unfiltered(tuning), data, [ax["ref_source"] for ax in data["axes"]])
    ins = {k: v[:20_000] for k, v in loop_inputs().items()}
    py = loop["py"]
    # replay the first 20,000 ticks' registers, rebuilt from the positions read
    init, mask = np.array([0xFFC000, 0x000400]), (1 << 24) - 1
    regs = (init + py[:20_000, :, 3]) & mask
    ref2 = np.stack([ins["ref"], np.zeros(20_000, dtype=np.int64)], axis=1)
    out = bare.run(regs, ref2, ins["mode"], ins["reset"], ins["u_add"])
    task = py[:20_000, :, 4] == MODE_TASK
    diff = np.abs(out[:, :, 0] - py[:20_000, :, 0])
    print(f"task ticks {task.sum()}, differing {np.sum((diff > 0) & task)}, largest {diff.max()}")
    assert np.sum((diff > 0) & task) > 0.2 * task.sum() and diff.max() > 100


def replay_tuning(bits: int, dac: Dac) -> tuple[Tuning, Rig]:
    """Three axes at 1 ms: a PI master with four sections, a lock-only slave with two, a PI
    slave with three, gains that saturate the D/A often."""
    period = 0.001
    designs = (
        notch(50.0, 10.0, -20.0),
        lowpass2(150.0, 0.5),
        notch(120.0, 30.0, -10.0),
        notch(8.0, 2.0, -12.0),
    )
    ctls = (
        AxisController(
            lock_gain=Fixed(q=3, f=1),
            task=PIConstants(kp=Fixed(q=5, f=2), ki_t=Fixed(q=3, f=6)),
            following_error_limit_counts=2**31 - 1,
            filters=sections(period, designs),
        ),
        AxisController(
            lock_gain=Fixed(q=-7, f=3),
            following_error_limit_counts=40,
            filters=sections(period, designs[1:3]),
        ),
        AxisController(
            lock_gain=Fixed(q=1717986918, f=32),
            task=PIConstants(kp=Fixed(q=2**31 - 1, f=0), ki_t=Fixed(q=-(2**31 - 1), f=5)),
            filters=sections(period, designs[:3]),
        ),
    )
    plant = Plant(gain_cps_per_v=1000.0, tau_s=0.01)
    rig = Rig(
        name="filters",
        timer=Timer(period_s=period),
        counter=Counter(bits=bits),
        dac=dac,
        encoder=Encoder(pulses_per_rev=1000),
        axes=tuple(
            Axis(
                name=f"a{i}",
                role="master" if i == 0 else "slave",
                plant=plant,
                counter_channel=i,
                dac_channel=i,
            )
            for i in range(3)
        ),
    )
    return Tuning.for_rig(rig, ctls, rig_sha256="0" * 64), rig


def replay_inputs(bits: int, n: int = 20_000) -> tuple[np.ndarray, ...]:
    """Counter walks with injected jumps, random modes (3 is not a mode: run as open), resets,
    extreme references and added commands (beyond every rail)."""
    rng = np.random.default_rng(200 + bits)
    unit = 1 << (bits - 8)
    steps = rng.integers(-unit // 2, unit // 2 + 1, (n, 3))
    steps[rng.random((n, 3)) < 0.7] //= 64
    jumps = rng.random((n, 3)) < 0.0008
    steps[jumps] = rng.integers(2 * unit, 1 << bits, int(jumps.sum()))
    steps[:, 1] = np.where(jumps[:, 1], steps[:, 1], rng.integers(-1, 2, n))
    raw = (rng.integers(0, 1 << bits, 3) + np.cumsum(steps, axis=0)) % (1 << bits)
    seg = np.repeat(rng.choice([0, 1, 1, 2, 3], n // 50 + 1), 50)[:n]
    mode = np.stack([np.roll(seg, 23 * a) for a in range(3)], axis=1)
    reset = (rng.random((n, 3)) < 0.01).astype(np.int64)
    extreme = np.array([2**40, -(2**40), 2**62, -(2**62), 2**63 - 1, -(2**63 - 1), -(2**63)])
    ref = np.cumsum(rng.integers(-3000, 3001, (n, 3)), axis=0)
    pick = rng.random((n, 3)) < 0.01
    ref[pick] = rng.choice(extreme, int(pick.sum()))
    held = np.where(
        rng.random((n // 25 + 1, 3)) < 0.3, rng.integers(-70_000, 70_001, (n // 25 + 1, 3)), 0
    )
    u_add = np.repeat(held, 25, axis=0)[:n]  # held 25 ticks: the filters settle at a rail
    pick = rng.random((n, 3)) < 0.005
    u_add[pick] = rng.choice(extreme, int(pick.sum()))
    return raw, ref, mode, reset, u_add


REPLAYS = [
    pytest.param(24, Dac(bits=12, range_v=(-10.0, 10.0)), id="24bit-counter-12bit-dac"),
    pytest.param(16, Dac(bits=16, range_v=(-10.0, 10.0)), id="16bit-counter-16bit-dac"),
    pytest.param(32, Dac(bits=8, range_v=(0.0, 10.0)), id="32bit-counter-unipolar-8bit-dac"),
]


@needs_cc
@pytest.mark.parametrize(("bits", "dac"), REPLAYS)
def test_replay_with_extremes_matches_the_python_tick(bits: int, dac: Dac, tmp_path) -> None:
    tuning, rig = replay_tuning(bits, dac)
    data = tables_document(tuning, rig=rig, unverified=True)["data"]
    src = export_harness(tuning, tmp_path, HARNESS, rig)
    rt = Runtime(src)
    assert rt.lib.h_check() == 0 and rt.lib.h_consts_crc32() == data["constants_crc32"]
    ins = replay_inputs(bits)
    py = PythonTick(tuning, data, [ax["ref_source"] for ax in data["axes"]])
    want = py.run(*ins)
    got = rt.run(*ins)
    for i, name in enumerate(("code", "flags", "e", "y", "mode")):
        bad = np.argwhere(got[:, :, i] != want[:, :, i])
        assert bad.size == 0, f"{name} differs first at (tick, axis) {tuple(bad[0])}"
    assert np.array_equal(rt.state(), py.st)
    code, flags = want[:, :, 0], want[:, :, 1]
    assert np.any(flags & FLAG_COUNTER_FAULT) and np.any(flags & FLAG_FOLLOWING_ERROR)
    for a in range(3):  # both rails on every axis
        assert np.sum(code[:, a] == dac.code_max) >= 10 and np.sum(code[:, a] == 0) >= 10
    # the same replay under the undefined-behaviour sanitizer: outputs and final state
    arrs = [np.ascontiguousarray(x, dtype=np.int64) for x in ins]
    n = arrs[0].shape[0]
    payload = np.array([n, 3], dtype=np.int64).tobytes() + b"".join(a.tobytes() for a in arrs)
    raw_out = run_replay(ubsan_harness(src, "harness_ubsan"), payload, timeout=120)
    out = np.frombuffer(raw_out, dtype=np.int64)
    assert np.array_equal(out[: n * 15].reshape(n, 3, 5), want)
    assert np.array_equal(out[n * 15 :].reshape(3, N_STATE), py.st)


# --- (b) the HAL runtime component in real HAL ------------------------------------------------

N_HAL = 20_000


def hal_inputs(n: int = N_HAL) -> dict[str, np.ndarray]:
    """One axis's encoder counts (a smooth move with noise, a jump: a counter fault), the
    command, modes, resets and added commands beyond both rails."""
    rng = np.random.default_rng(11)
    t = np.arange(n)
    counts = (0xFFC000 + 30_000 * np.sin(2 * np.pi * t / 4000.0) + rng.integers(-3, 4, n)).astype(
        np.int64
    )
    counts[12_000:] += 0x300000  # the high byte jumps by 48: a counter fault
    command = np.repeat(rng.integers(-40_000, 40_001, n // 500 + 1), 500)[:n]
    mode = np.repeat(rng.choice([MODE_LOCK, MODE_TASK, MODE_TASK, MODE_OPEN], n // 400 + 1), 400)
    mode = mode[:n]
    reset = np.zeros(n, dtype=np.int64)
    reset[[5_000, 13_000, 16_000]] = 1
    u_add = np.where(rng.random(n) < 0.05, rng.integers(-5000, 5001, n), 0)
    off = np.zeros(n, dtype=np.int64)  # the filters switched out and back in, four times
    for t0, t1 in ((2_100, 3_900), (7_000, 7_001), (12_500, 14_200), (17_777, 19_000)):
        off[t0:t1] = 1
    return {
        "counts": counts,
        "command": command,
        "mode": mode,
        "reset": reset,
        "u_add": u_add,
        "filters_off": off,
    }


def off_switches(off: np.ndarray, own: np.ndarray) -> dict[int, list[tuple[int, np.ndarray]]]:
    """The component's switches of axis 0 for a ``filters-off-0`` signal: out when it rises,
    back in when it falls, before that period's tick."""
    prev = np.concatenate([[0], off[:-1]])
    return {int(k): [(0, filter_block(()) if off[k] else own)] for k in np.flatnonzero(off != prev)}


def test_hal_runtime_component_runs_the_filters_bit_for_bit(tuning: Tuning, tmp_path) -> None:
    halrun.hal_available()
    master = dataclasses.replace(tuning.controllers[0], following_error_limit_counts=0)
    one = dataclasses.replace(
        tuning, axis_names=("master",), roles=("master",), controllers=(master,)
    )
    name = "st_test_filt_rt"
    (tmp_path / f"{name}.comp").write_text(hal_component.to_string(one, unverified=True, name=name))
    so = halrun.halcompile(tmp_path / f"{name}.comp")
    ins = hal_inputs()
    rows = halrun.run_component(
        so,
        tmp_path,
        {
            "counts-0": ("s", (ins["counts"] & 0xFFFFFFFF).astype(np.int32).tolist()),
            "command": ("s", ins["command"].tolist()),
            "mode-0": ("s", ins["mode"].tolist()),
            "reset-0": ("b", ins["reset"].tolist()),
            "u-add-0": ("s", ins["u_add"].tolist()),
            "filters-off-0": ("b", ins["filters_off"].tolist()),
        },
        {"code-0": "s", "flags-0": "s", "error-0": "s", "position-0": "s"},
        period_ns=250_000,
    )
    got = np.array(rows, dtype=np.int64)
    data = tables_document(one, unverified=True)["data"]
    py = PythonTick(one, data, [-1])
    cols = [ins[k][:, None] for k in ("counts", "command", "mode", "reset", "u_add")]
    cols[0] = cols[0] & 0xFFFFFF  # the 24-bit register the card latches
    switches = off_switches(ins["filters_off"], filter_block(master.filters))
    assert len(switches) == 8
    want = py.run(*cols, switches=switches)[:, 0, :4]
    kept = PythonTick(one, data, [-1]).run(*cols)[:, 0, :4]  # the filters never switched
    assert np.sum(np.any(kept != want, axis=1)) > 500  # so a component ignoring the pin fails
    assert got.shape == (N_HAL, 4)
    bad = np.argwhere(got != want)
    assert bad.size == 0, f"first difference at (period, column) {tuple(bad[0])}"
    flags = want[:, 1]
    assert np.any(flags & FLAG_COUNTER_FAULT) and np.any(flags & FLAG_SATURATED)
    assert np.any(want[:, 0] == 0) and np.any(want[:, 0] == 4095)


# --- (c) edits of a filter coefficient are refused --------------------------------------------


def _struct_crc(data: dict) -> int:
    """The constants CRC (docs/runtime.md#integrity-crcs-and-the-c-layout) built here with
    :mod:`struct`: 14 pairs per axis as before, then (n_filters, 0) and 4 slots of 5."""
    law = {"none": 0, "pi": 1, "fuzzy_pid": 2}
    pairs = [(len(data["axes"]), 0), (data["timer_divisor"], 0)]
    for ax in data["axes"]:
        task = ax["task"] or {}

        def fx(key: str, task: dict = task) -> tuple[int, int]:
            c = task.get(key)
            return (c["q"], c["f"]) if c else (0, 0)

        pairs += [(law[ax["law"]], 0), (ax["lock_gain"]["q"], ax["lock_gain"]["f"])]
        pairs += [fx("kp"), fx("ki_t"), (ax["following_error_limit_counts"], 0)]
        pairs += [(data["counter_bits"], 0), (data["dac"]["zero_code"], 0)]
        pairs += [(data["dac"]["code_max"], 0), fx("kd_t"), fx("k1_t"), fx("ke"), fx("kec")]
        pairs += [(task.get("n", 0), 0), (ax["ref_source"], 0), (len(ax["filters"]), 0)]
        for k in range(4):
            sec = ax["filters"][k] if k < len(ax["filters"]) else dict.fromkeys(SECTION_KEYS, 0)
            pairs += [(sec[w], sec["frac_bits"]) for w in SECTION_KEYS[:-1]]
    return zlib.crc32(b"".join(struct.pack("<ih", q, f) for q, f in pairs))


def _redigest(doc: dict) -> dict:
    """The document's digest recomputed independently (canonical JSON without the field)."""
    body = {k: v for k, v in doc.items() if k != "sha256"}
    canon = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return {**body, "sha256": hashlib.sha256(canon.encode("utf-8")).hexdigest()}


def _one_line(doc: dict, cls: type, *fragments: str) -> None:
    with pytest.raises(cls) as info:
        load_tables(json.dumps(doc))
    msg = str(info.value)
    assert "\n" not in msg
    for frag in fragments:
        assert frag in msg, msg


def test_an_edited_filter_coefficient_is_refused(tuning: Tuning, tmp_path, capsys) -> None:
    base = json.loads(tables_to_string(tuning, unverified=True))
    assert _struct_crc(base["data"]) == base["data"]["constants_crc32"]
    for axis, k, word in ((0, 3, "b1"), (1, 0, "a2"), (0, 1, "frac_bits")):
        doc = json.loads(json.dumps(base))
        sec = doc["data"]["axes"][axis]["filters"][k]
        sec[word] += 1
        # the constants CRC left as it was
        _one_line(doc, DigestError, "constants_crc32: CRC mismatch")
        # the constants CRC recomputed: the document's digest refuses
        doc["data"]["constants_crc32"] = _struct_crc(doc["data"])
        _one_line(doc, DigestError, "sha256 does not match")
        # and with the document's digest recomputed too, the C layout's refuses
        _one_line(_redigest(doc), DigestError, "c_layout_sha256 does not match")
        # check-table: exit 1 (not the verified bytes), one line
        f = tmp_path / "edited.json"
        f.write_text(json.dumps(doc, indent=2))
        capsys.readouterr()
        assert main(["check-table", str(f)]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "refused" in err, err
    # malformed sections: exit 3, one line naming the field
    for edit, fragment in (
        (lambda s: s.update(a2=1 << s["frac_bits"]), "filters[0] is not stable"),
        (lambda s: s.update(frac_bits=31), "filters[0].frac_bits must be an integer in 1..30"),
        (lambda s: s.update(b0=2**31), "filters[0].b0 must be an integer"),
        (lambda s: s.pop("a1"), "filters[0]"),
        (lambda s: s.update(b3=0), "filters[0]"),
    ):
        doc = json.loads(json.dumps(base))
        edit(doc["data"]["axes"][1]["filters"][0])
        _one_line(doc, ExportError, "axes[1] (slave).filters[0]", fragment)
        f = tmp_path / "malformed.json"
        f.write_text(json.dumps(doc))
        capsys.readouterr()
        assert main(["check-table", str(f)]) == 3
        assert capsys.readouterr().err.count("\n") == 1
    doc = json.loads(json.dumps(base))
    doc["data"]["axes"][0]["filters"].append(doc["data"]["axes"][0]["filters"][0])
    _one_line(doc, ExportError, "filters must be a list of at most 4 sections")
    doc = json.loads(json.dumps(base))
    del doc["data"]["axes"][0]["filters"]
    _one_line(doc, ExportError, "missing key axes[0] (master).filters")


def _replace_once(text: str, old: str, new: str) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


def _bump_define(text: str, name: str) -> str:
    m = re.search(rf"^#define {name} (?:INT32_C\()?(-?\d+)", text, re.M)
    assert m, name
    return text[: m.start(1)] + str(int(m.group(1)) + 1) + text[m.end(1) :]


@needs_cc
@pytest.mark.parametrize(
    "macro",
    ["ST_MASTER_FILT2_B1", "ST_MASTER_FILT0_A2", "ST_SLAVE_FILT1_B0", "ST_SLAVE_FILT0_FRAC_BITS"],
)
def test_st_check_digest_refuses_a_header_with_an_edited_filter_constant(
    macro: str, build: Path, tmp_path
) -> None:
    for f in build.iterdir():
        if f.suffix in (".c", ".h"):
            (tmp_path / f.name).write_text(f.read_text())
    header = tmp_path / "servotune_tables.h"
    text = header.read_text()
    digest = re.search(r'^#define ST_TABLES_SHA256 "([0-9a-f]{64})"$', text, re.M)
    edited = _bump_define(text, macro)
    assert edited != text and digest is not None and digest.group(1) in edited
    header.write_text(edited)
    rt = Runtime(tmp_path, "libedited.so")
    assert rt.lib.h_check_digest() == ST_DIGEST_MISMATCH
    # a section dropped from the count (its constants left) is refused as well
    header.write_text(
        _replace_once(text, "#define ST_SLAVE_N_FILTERS 2", "#define ST_SLAVE_N_FILTERS 1")
    )
    assert Runtime(tmp_path, "libfewer.so").lib.h_check_digest() == ST_DIGEST_MISMATCH


# --- (d) an old schema ------------------------------------------------------------------------


def test_a_tables_2_document_gets_the_old_schema_line(tuning: Tuning, tmp_path, capsys) -> None:
    doc = json.loads(tables_to_string(unfiltered(tuning), unverified=True))
    for ax in doc["data"]["axes"]:  # as /2 wrote it: no filters key
        del ax["filters"]
    doc["schema"] = "servotune.tables/2"
    doc = _redigest(doc)
    _one_line(doc, ExportError, "servotune.tables/2 was written by an older servotune", "again")
    f = tmp_path / "old.json"
    f.write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(["check-table", str(f)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "export the tuning again" in err, err


# --- (e) round trip ---------------------------------------------------------------------------


def test_the_tables_document_holds_the_filters_exactly(tuning: Tuning, doc: dict) -> None:
    assert SCHEMA == "servotune.tables/4" and doc["schema"] == SCHEMA
    assert controllers_from_tables(load_tables(tables_to_string(tuning, unverified=True))) == (
        tuning.controllers
    )
    for ax, ctl in zip(doc["data"]["axes"], tuning.controllers, strict=True):
        assert ax["filters"] == [s.to_dict() for s in ctl.filters]
        assert [SectionQ.from_dict(s) for s in ax["filters"]] == list(ctl.filters)
    # an unfiltered tuning: "filters": [] on every axis, and the same controllers back
    plain = unfiltered(tuning)
    back = load_tables(tables_to_string(plain, unverified=True))
    assert [ax["filters"] for ax in back["data"]["axes"]] == [[], []]
    assert controllers_from_tables(back) == plain.controllers
    # the layout's part 1 starts with the constants CRC's bytes: 35 pairs per axis
    assert len(c_layout_bytes(doc["data"])) >= 6 * (2 + 35 * 2)
    assert (
        zlib.crc32(c_layout_bytes(doc["data"])[: 6 * (2 + 35 * 2)])
        == (doc["data"]["constants_crc32"])
    )


def test_an_export_whose_filter_sums_could_overflow_is_refused(tuning: Tuning) -> None:
    # a resonant section at 30 fraction bits: within ±2^27 codes its sums leave ±2^62
    d = lowpass2(2.0, 0.05)
    hot = quantize_section(d, PERIOD_S, 30)
    master = dataclasses.replace(tuning.controllers[0], filters=(hot,))
    bad = dataclasses.replace(tuning, controllers=(master, tuning.controllers[1]))
    with pytest.raises(ExportError, match=r"axis 'master': filters\[0\]: .*beyond ±2\^62"):
        tables_document(bad, unverified=True)
    # the gantry's export checks its drives' sections the same way
    gantry = _gantry_tuning(tuning.controllers[0])
    hot_drive = dataclasses.replace(gantry.slave, filters=(hot,))
    with pytest.raises(ExportError, match=r"the slave drive's filters\[0\]: .*beyond ±2\^62"):
        gantry_document(
            dataclasses.replace(gantry, slave=hot_drive),
            load_rig(EXAMPLE_RIG_PATH),
            unverified=True,
        )


# --- (f) the LinuxCNC HAL file ----------------------------------------------------------------


def test_linuxcnc_hal_writes_the_masters_filters_as_biquads(tuning: Tuning) -> None:
    rig = load_rig(EXAMPLE_RIG_PATH)
    tuning = dataclasses.replace(tuning, rig_name=rig.name)

    def hal(t: Tuning) -> str:
        return pid_hal_text(t, rig=rig, unverified=True, position_scale=2000.0)

    text, plain = hal(tuning), hal(unfiltered(tuning))
    assert text_digest_problem(text, "#") is None and text_digest_problem(plain, "#") is None
    names = [f"pid.x-filter{k}" for k in range(4)]
    assert f"#   loadrt biquad names={','.join(names)}" in text
    for name, sec in zip(names, tuning.controllers[0].filters, strict=True):
        b, a = sec.ba()
        assert f"setp {name}.type 0" in text and f"setp {name}.enable 1" in text
        assert (
            f"setp {name}.n1 {float(b[1])!r}" in text and f"setp {name}.d2 {float(a[2])!r}" in text
        )
    assert "FLOAT implementation" in text and f"at most {FILTER_DIFFERENCE_CODES} codes" in text
    assert FILTER_DIFFERENCE_CODES == 0.91  # tests/hal/test_linuxcnc_biquad.py's measurement
    # without filters: no biquad, and every other line as with them (the tables export's
    # digests aside, which cover the filters)
    assert "biquad" not in plain and "filter" not in plain.lower().replace("filtered", "")

    def skeleton(s: str) -> list[str]:
        return [ln for ln in s.splitlines() if "sha256" not in ln]

    lines = skeleton(text)
    assert lines[: len(skeleton(plain))] == skeleton(plain)
    assert all(ln.startswith(("#", "setp pid.x-filter")) for ln in lines[len(skeleton(plain)) :])


# --- the gantry's and the linkage's exports carry them ----------------------------------------

ROOT = Path(__file__).resolve().parents[2]


def _gantry_tuning(drive) -> GantryTuning:
    """A gantry tuning whose two drives are ``drive`` without its filters."""
    return GantryTuning(
        gantry_name="g",
        gantry_path="g.toml",
        gantry_sha256="0" * 64,
        rig_name="pc-dual-servo",
        rig_sha256="0" * 64,
        topology="listening",
        cycle_s=0.001,
        latency_cycles=1,
        master=dataclasses.replace(drive, filters=()),
        slave=dataclasses.replace(drive, filters=()),
        sync_law="pi",
        sync=SyncConstants(
            kp=Fixed(q=1, f=1),
            ki_t=Fixed(q=1, f=8),
            kd_t=Fixed(q=0, f=0),
            dead_zone_counts=0,
            limit_counts=100,
        ),
        warn_counts=0,
        trip_counts=0,
    )


def test_gantry_and_linkage_exports_carry_filters(tuning: Tuning) -> None:
    """A filtered gantry drive is exported with its sections, under the C-layout digest; a
    filtered linkage axis's sections are macros of the plan header (the C runs them:
    ``test_c_gantry_filters.py``, ``test_c_linkage_filters.py``)."""
    filters = tuning.controllers[0].filters[:2]
    drive = tuning.controllers[0]  # a PI law
    gantry = _gantry_tuning(drive)
    rig = load_rig(EXAMPLE_RIG_PATH)
    plain = gantry_document(gantry, rig, unverified=True)["data"]
    data = gantry_document(dataclasses.replace(gantry, slave=drive), rig, unverified=True)["data"]
    assert "filters" not in plain["drives"][1]["controller"]
    assert data["drives"][1]["controller"]["filters"] == [s.to_dict() for s in drive.filters]
    assert data["c_layout_sha256"] != plain["c_layout_sha256"]
    plan = plan_linkage(ROOT / "plants" / "linkage-6axis.toml")
    assert "_N_FILTERS 0" in linkage_c_header(plan, None, unverified=True)
    ctls = (dataclasses.replace(plan.controllers[0], filters=filters), *plan.controllers[1:])
    header = linkage_c_header(dataclasses.replace(plan, controllers=ctls), None, unverified=True)
    first = plan.axis_names[0].upper()
    assert f"#define STL_AXIS_{first}_N_FILTERS 2 " in header
    assert f"#define STL_AXIS_{first}_FILT1_FRAC_BITS {filters[1].frac_bits}" in header
