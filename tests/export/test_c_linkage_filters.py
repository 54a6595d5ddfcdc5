"""The linkage's axes with output filters: config, margins, plan, C header and position loop.

A linkage config gives each axis up to four output filter sections (``[[axis.<name>.filters]]``,
the rig file's format: docs/formats.md#filters), realised at the linkage's period. The slave's
law runs them before its D/A (the same ``axis_control`` as every runtime); the axes' PI is
tuned and verified with them in the loop; the plan carries them, and the exported
``servotune_link_plan.h`` holds each axis's sections as ``STL_AXIS_<AXIS>_FILT<k>_*`` macros.

- The verify rows' margins of a filtered axis are rebuilt independently: the unfiltered loop's
  response times the realised sections' own (``scipy.signal.freqz`` of their integers),
  margins by python-control on that ``FrequencyResponseData``.
- A C position loop (``servotune_rt.c``'s ``st_axis_read`` and ``st_axis_control``) built from
  the exported header's macros alone, fed each tick's position and command of the linkage
  simulation (two CPUs with their clock errors, noise, a circle in x/y), gives the
  simulation's D/A code at every tick of the filtered axes.
"""

from __future__ import annotations

import ctypes
from dataclasses import replace
from pathlib import Path

import control
import numpy as np
import pytest
import scipy.signal
from c_build import STRICT, cc, needs_cc
from filtered_configs import ROOT, filter_tables, with_filters

from servotune.analysis.margins import GainSet, loop_model
from servotune.arch.linkage import load_linkage, plan_linkage
from servotune.arch.linkage.plan import run_plan
from servotune.arch.linkage.plan_file import plan_to_string, read_plan_bytes
from servotune.arch.linkage.spec import load_linkage_spec
from servotune.arch.linkage.synthesis import axis_gains
from servotune.arch.linkage.verify import verify_plan
from servotune.errors import ConfigError
from servotune.export import c as c_export
from servotune.export.linkage import LINK_HEADER_NAME

# a notch and a low-pass on x, a notch on y (inside the 250 Hz Nyquist frequency of 2 ms)
FILTERS = {
    "x": [
        {"kind": "notch", "center_hz": 30.0, "width_hz": 10.0, "depth_db": -20.0},
        {"kind": "lowpass2", "corner_hz": 80.0, "damping": 0.7},
    ],
    "y": [{"kind": "notch", "center_hz": 45.0, "width_hz": 12.0, "depth_db": -15.0}],
}


def write_filtered_linkage(d: Path, tables: str | None = None) -> Path:
    """``plants/linkage-6axis.toml`` with the filter tables (:data:`FILTERS`, or ``tables``)
    in ``d``."""
    tables = filter_tables(FILTERS) if tables is None else tables
    return with_filters("linkage-6axis.toml", d, tables)


@pytest.fixture(scope="module")
def filtered(tmp_path_factory):
    """(config path, config, plan) of the filtered linkage."""
    path = write_filtered_linkage(tmp_path_factory.mktemp("linkage_filtered"))
    return path, load_linkage(path), plan_linkage(path)


def test_the_config_realises_each_axis_filters_and_the_plan_keeps_them(filtered) -> None:
    """x has two sections, y one, the others none, realised at the 2 ms period (the notch's
    depth at its centre within ±1 dB, from the integers with scipy); the plan's controllers
    hold exactly them, and a plan file read back too."""
    _, cfg, plan = filtered
    got = {n: c.filters for n, c in plan.controller_map.items()}
    assert [len(got[n]) for n in plan.axis_names] == [
        {"x": 2, "y": 1}.get(n, 0) for n in plan.axis_names
    ]
    for name in plan.axis_names:
        assert got[name] == cfg.axis_filters(name)
    for sec, centre, depth in ((got["x"][0], 30.0, -20.0), (got["y"][0], 45.0, -15.0)):
        b, a = sec.ba()
        _, h = scipy.signal.freqz(b, a, worN=[centre], fs=1.0 / cfg.period_s)
        assert abs(20 * np.log10(abs(h[0])) - depth) <= 1.0
    back = read_plan_bytes(plan_to_string(plan).encode(), "<plan>")
    assert back.controllers == plan.controllers


def test_a_filter_the_period_cannot_realise_is_one_config_error(tmp_path: Path) -> None:
    bad = filter_tables(FILTERS).replace("center_hz = 45.0", "center_hz = 300.0")  # > 250 Hz
    with pytest.raises(ConfigError, match=r"axis\.y\.filters\[0\].*center_hz") as exc:
        load_linkage(write_filtered_linkage(tmp_path, bad))
    assert "\n" not in str(exc.value)


def test_an_axis_tuned_with_filters_gets_other_gains(filtered) -> None:
    """An axis without gains is tuned with its filters in the loop: x's tuned gains differ
    from those of the same axis without filters."""
    _, cfg, _ = filtered
    bare_x = replace(cfg.axis("x"), kp=None, ki=None)
    with_f = replace(cfg, axes=tuple(bare_x if a.name == "x" else a for a in cfg.axes))
    without = replace(
        with_f, axes=tuple(replace(a, filters=()) if a.name == "x" else a for a in with_f.axes)
    )
    g_f, g_0 = axis_gains(with_f)["x"].gains, axis_gains(without)["x"].gains
    assert g_f.kp != pytest.approx(g_0.kp, rel=0.01)


def test_verify_margins_take_the_filters_rebuilt_independently(filtered) -> None:
    """The phase and gain margin rows of x and y equal python-control's margins of (the loop
    without filters) x (the realised sections' ``freqz``); x's gain margin is lower than its
    unfiltered loop's."""
    _, cfg, plan = filtered
    spec = load_linkage_spec(ROOT / "plants" / "linkage-6axis.spec.toml")
    assert spec.margins is not None
    rows = {(r.check): r for r in verify_plan(plan, cfg, spec).rows}
    rig = cfg.rig
    w = np.logspace(-1, np.log10(np.pi / plan.period_s * (1 - 1e-9)), 4000)
    for name in ("x", "y"):
        ctl = plan.controller_map[name]
        plant = cfg.axis(name).plant
        g = GainSet(kp=ctl.task.kp.value, ki_t=ctl.task.ki_t.value)
        lag = rig.timer.compute_s + plant.delay_s
        bare = loop_model(plant, g, period_s=plan.period_s, lag_s=lag, lsb_volts=rig.dac.lsb_v)
        resp = bare.frequency_response(w).complex.reshape(-1)
        for sec in ctl.filters:
            b, a = sec.ba()
            resp = resp * scipy.signal.freqz(b, a, worN=w * plan.period_s)[1]
        gm, pm = control.stability_margins(control.frd(resp, w, plan.period_s))[:2]
        assert rows[f"phase_margin:{name}"].value == pytest.approx(pm, abs=0.1), name
        assert rows[f"gain_margin:{name}"].value == pytest.approx(20 * np.log10(gm), abs=0.1)
        if name == "x":
            gm0 = control.stability_margins(bare.frequency_response(w))[0]
            assert 20 * np.log10(gm0) > rows["gain_margin:x"].value + 1.0


HARNESS = r"""
#include "servotune_link_plan.h"
#include "servotune_rt.h"

#define FILT(A, K) {A##_FILT##K##_B0, A##_FILT##K##_B1, A##_FILT##K##_B2, A##_FILT##K##_A1, \
                    A##_FILT##K##_A2, A##_FILT##K##_FRAC_BITS}
/* one axis's PI, lock gain, following-error limit and output filters from its macros */
#define FROM_MACROS(c, A, SEC)                       \
    do {                                             \
        int k_;                                      \
        (c)->lock_q = A##_LOCK_Q;                    \
        (c)->lock_f = A##_LOCK_F;                    \
        (c)->kp_q = A##_KP_Q;                        \
        (c)->kp_f = A##_KP_F;                        \
        (c)->kit_q = A##_KIT_Q;                      \
        (c)->kit_f = A##_KIT_F;                      \
        (c)->fe_limit = A##_FE_LIMIT;                \
        (c)->n_filters = A##_N_FILTERS;              \
        for (k_ = 0; k_ < A##_N_FILTERS; k_++) {     \
            (c)->filter[k_] = SEC[k_];               \
        }                                            \
    } while (0)

/* axis X or Y's constants from the plan header's macros alone (the rig's counter and D/A
 * passed in) */
static void consts_of(int axis, int counter_bits, int dac_zero, int dac_max, st_axis_consts_t *c)
{
    static const st_section_t x_sec[] = {FILT(STL_AXIS_X, 0), FILT(STL_AXIS_X, 1)};
    static const st_section_t y_sec[] = {FILT(STL_AXIS_Y, 0)};
    const st_axis_consts_t zero = {0};
    *c = zero;
    c->law = ST_LAW_PI;
    c->counter_bits = (int16_t)counter_bits;
    c->dac_zero = dac_zero;
    c->dac_max = dac_max;
    c->ref_source = -1;
    if (axis == 0) {
        FROM_MACROS(c, STL_AXIS_X, x_sec);
    } else {
        FROM_MACROS(c, STL_AXIS_Y, y_sec);
    }
}

int h_check(int axis, int counter_bits, int dac_zero, int dac_max)
{
    st_consts_t one = {0};
    one.n_axes = 1;
    consts_of(axis, counter_bits, dac_zero, dac_max, &one.axis[0]);
    return st_check_consts(&one);
}

/* n ticks of one axis: raw counter registers and commands in, D/A codes out */
void h_run(int axis, int counter_bits, int dac_zero, int dac_max, int64_t n, const int64_t *raw,
           const int64_t *ref, int64_t *code)
{
    st_axis_consts_t c;
    st_axis_state_t s;
    int64_t k;
    consts_of(axis, counter_bits, dac_zero, dac_max, &c);
    st_axis_init(&s);
    for (k = 0; k < n; k++) {
        int32_t out;
        int32_t flags;
        (void)st_axis_read(&s, &c, raw[k], 0);
        (void)st_axis_control(&s, &c, ref[k], ST_MODE_TASK, 0, 0, &out, &flags);
        code[k] = out;
    }
}
"""


@needs_cc
def test_the_header_runs_the_filtered_axes_as_the_simulation(filtered, tmp_path: Path) -> None:
    """Every tick of x and y in a 4 s run of the plan: C == the simulation's D/A code, from the
    header's constants alone (a header without the sections would not give the simulation's
    codes: the simulation runs them)."""
    _, cfg, plan = filtered
    c_export.to_file(plan, tmp_path, unverified=True)
    header = (tmp_path / LINK_HEADER_NAME).read_text()
    for name, sec in (("X", plan.controller_map["x"].filters[1]), ("Y", None)):
        assert f"#define STL_AXIS_{name}_N_FILTERS" in header
        if sec is not None:
            assert f"#define STL_AXIS_{name}_FILT1_FRAC_BITS {sec.frac_bits}" in header
    (tmp_path / "harness.c").write_text(HARNESS)
    cc(
        tmp_path,
        *STRICT,
        "-O2",
        "-shared",
        "-fPIC",
        "harness.c",
        "servotune_rt.c",
        "-o",
        "libaxis.so",
    )
    lib = ctypes.CDLL(str(tmp_path / "libaxis.so"))
    i, p = ctypes.c_int, ctypes.c_void_p
    lib.h_check.argtypes = [i, i, i, i]
    lib.h_run.argtypes = [i, i, i, i, ctypes.c_int64, p, p, p]
    rig = cfg.rig
    dims = (rig.counter.bits, rig.dac.zero_code, rig.dac.code_max)
    res = run_plan(plan, cfg, seconds=4.0, trace=True)
    traces = {t.name: t for t in res.traces}
    mask = (1 << rig.counter.bits) - 1
    for axis, name in enumerate(("x", "y")):
        assert lib.h_check(axis, *dims) == 0
        tr = traces[name]
        n = tr.code.size
        assert n > 1500
        # the law sees positions relative to its first read: any origin gives them back
        raw = np.ascontiguousarray((cfg.axis(name).counter_init + tr.pos_counts) & mask)
        ref = np.ascontiguousarray(tr.ref_counts, dtype=np.int64)
        code = np.zeros(n, dtype=np.int64)
        lib.h_run(axis, *dims, n, raw.ctypes.data, ref.ctypes.data, code.ctypes.data)
        bad = np.flatnonzero(code != tr.code)
        assert bad.size == 0, f"{name}: C differs first at tick {bad[0]}"
