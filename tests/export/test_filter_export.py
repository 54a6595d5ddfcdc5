"""The filter sections' C step (``servotune_filter.h``, docs/runtime.md#filters) against the
simulator's (:func:`servotune.laws.filters.filter_run`, the numba-compiled ``biquad_step``):

- a cascade of up to four sections (notches and low-passes at the 4 ms and 1 ms ticks, their
  word lengths chosen by :func:`~servotune.laws.filters.choose_frac_bits`) over 120,000 ticks of
  full-scale steps, ramps, noise and small signals, with one section re-tuned mid-run through
  ``st_filter_bumpless`` / :func:`~servotune.laws.filters.bumpless_state`: every output and the
  final state equal, bit for bit;
- built strictly (-std=c99 -Wall -Wextra -Werror -pedantic) and under UBSan (no signed
  overflow, no bad shift) on the same run;
- the HAL component (:func:`servotune.export.hal_component.filter_component`) in real HAL:
  switched off and on again (bumpless), fed inputs beyond its bound (clamped, ``clipped``
  set), equal to the simulator's step period by period; a cascade whose output could leave
  s32 is refused at export.
"""

from __future__ import annotations

import ctypes
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from c_build import STRICT, UBSAN, cc, needs_cc

from servotune.errors import ExportError
from servotune.export.c import FILTER_RUNTIME_FILES, runtime_source
from servotune.export.hal_component import filter_component
from servotune.laws.filters import (
    INPUT_BOUND_WIDE,
    N_FILTER_STATE,
    SectionQ,
    bumpless_state,
    choose_frac_bits,
    filter_run,
    lowpass2,
    notch,
    quantize_section,
    state_bound,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "hal"))
import halrun

HARNESS = r"""
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "servotune_filter.h"

/* n inputs through the cascade of n_sec sections (coefficients: 6 int32 each, b0 b1 b2 a1 a2
 * frac_bits); at tick k_switch section 0 is re-tuned to `retuned` from its last input and
 * output; out: the cascade's outputs; state: the sections' final states (6 each) */
void h_cascade(int32_t n_sec, const int32_t *coef, const int32_t *retuned, int64_t k_switch,
               int64_t n, const int64_t *x, int64_t *out, int64_t *state)
{
    st_section_t sec[4];
    int64_t last_in = 0;
    int64_t last_out = 0;
    int64_t k;
    int32_t i;
    for (i = 0; i < n_sec; i++) {
        const int32_t *c = coef + 6 * i;
        sec[i].b0 = c[0];
        sec[i].b1 = c[1];
        sec[i].b2 = c[2];
        sec[i].a1 = c[3];
        sec[i].a2 = c[4];
        sec[i].frac_bits = c[5];
    }
    for (k = 0; k < 6 * (int64_t)n_sec; k++) {
        state[k] = 0;
    }
    for (k = 0; k < n; k++) {
        int64_t v = x[k];
        if (k == k_switch) {
            sec[0].b0 = retuned[0];
            sec[0].b1 = retuned[1];
            sec[0].b2 = retuned[2];
            sec[0].a1 = retuned[3];
            sec[0].a2 = retuned[4];
            sec[0].frac_bits = retuned[5];
            st_filter_bumpless(state, last_in, last_out);
        }
        last_in = v;
        for (i = 0; i < n_sec; i++) {
            v = st_biquad_step(&sec[i], state + 6 * i, v);
            if (i == 0) {
                last_out = v;
            }
        }
        out[k] = v;
    }
}

#ifdef H_MAIN
int main(void)
{
    int32_t n_sec;
    int64_t k_switch;
    int64_t n;
    int32_t coef[24];
    int32_t retuned[6];
    int64_t *x;
    int64_t *out;
    int64_t state[24];
    if (fread(&n_sec, 4, 1, stdin) != 1 || fread(&k_switch, 8, 1, stdin) != 1
        || fread(&n, 8, 1, stdin) != 1 || n_sec < 1 || n_sec > 4) {
        return 2;
    }
    x = malloc(8 * (size_t)n);
    out = malloc(8 * (size_t)n);
    if (fread(coef, 4, 6 * (size_t)n_sec, stdin) != 6 * (size_t)n_sec
        || fread(retuned, 4, 6, stdin) != 6 || fread(x, 8, (size_t)n, stdin) != (size_t)n) {
        return 2;
    }
    h_cascade(n_sec, coef, retuned, k_switch, n, x, out, state);
    fwrite(out, 8, (size_t)n, stdout);
    fwrite(state, 8, 6 * (size_t)n_sec, stdout);
    return 0;
}
#endif
"""

N = 120_000
K_SWITCH = 70_000


def _q(section, period_s: float) -> SectionQ:
    return quantize_section(section, period_s, choose_frac_bits(section, period_s))


CASCADES = {
    # a belt axis at 4 ms: notches on its 35 Hz and 80 Hz modes and a low-pass; the first notch
    # re-tuned to 32 Hz mid-run
    "4ms": (
        0.004,
        [notch(35.0, 7.0, -30.0), notch(80.0, 8.0, -20.0), lowpass2(100.0, 0.5)],
        notch(32.0, 6.0, -25.0),
    ),
    # a gantry's 1 ms bus loop: a deep narrow notch, a resonant low-pass, a wide notch and a
    # low 5 Hz low-pass (the longest word length of the grid); the low-pass re-tuned
    "1ms": (
        0.001,
        [
            lowpass2(60.0, 0.3),
            notch(200.0, 2.0, -40.0),
            notch(120.0, 60.0, -6.0),
            lowpass2(5.0, 0.7),
        ],
        lowpass2(45.0, 0.5),
    ),
}


def _inputs(bound: int, seed: int) -> np.ndarray:
    """Full-scale steps and reversals, ramps, uniform noise and ±3 LSB small signals, all
    within ``bound``."""
    rng = np.random.default_rng(seed)
    parts = [
        np.repeat(rng.choice([-bound, bound, 0, bound // 3], N // 400), 100),
        np.clip(np.cumsum(rng.integers(-bound // 200, bound // 200 + 1, N // 4)), -bound, bound),
        rng.integers(-bound, bound + 1, N // 4),
        rng.integers(-3, 4, N // 4),
    ]
    x = np.concatenate(parts)
    return np.concatenate([x, np.zeros(N - x.size, dtype=np.int64)]).astype(np.int64)


def _reference(qs: list[SectionQ], retuned: SectionQ, x: np.ndarray):
    """The cascade by filter_run, section after section, the first re-tuned at K_SWITCH."""
    states = [np.zeros(N_FILTER_STATE, dtype=np.int64) for _ in qs]
    y0 = np.empty(N, dtype=np.int64)
    filter_run(*qs[0].step_args(), states[0], x[:K_SWITCH], y0[:K_SWITCH])
    states[0][:] = bumpless_state(retuned, int(x[K_SWITCH - 1]), int(y0[K_SWITCH - 1]))
    filter_run(*retuned.step_args(), states[0], x[K_SWITCH:], y0[K_SWITCH:])
    v = y0
    for q, st in zip(qs[1:], states[1:], strict=True):
        out = np.empty(N, dtype=np.int64)
        filter_run(*q.step_args(), st, v, out)
        v = out
    return v, np.concatenate(states)


def _case(name: str):
    period_s, sections, new = CASCADES[name]
    qs = [_q(s, period_s) for s in sections]
    retuned = _q(new, period_s)
    # inputs within what every section of the chain was sized for: the wide scale, divided by
    # the largest gain ahead of the last section (the L1 norms), so no partial sum leaves ±2^62
    gain = 1.0
    for q in (*qs, retuned):
        gain *= max(1.0, state_bound(q).l1)
    x = _inputs(int(INPUT_BOUND_WIDE / gain), seed=len(sections))
    coef = np.array([q.step_args() for q in qs], dtype=np.int32).ravel()
    return qs, retuned, x, coef, np.array(retuned.step_args(), dtype=np.int32)


@pytest.fixture(scope="module")
def filter_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("c_filter")
    (d / FILTER_RUNTIME_FILES[0]).write_text(runtime_source(FILTER_RUNTIME_FILES[0]))
    (d / "harness.c").write_text(HARNESS)
    return d


@needs_cc
@pytest.mark.parametrize("name", list(CASCADES))
def test_the_c_filter_cascade_equals_the_simulators_step_bit_for_bit(
    filter_dir: Path, name: str
) -> None:
    cc(filter_dir, *STRICT, "-O2", "-shared", "-fPIC", "harness.c", "-o", "libfilter.so")
    lib = ctypes.CDLL(str(filter_dir / "libfilter.so"))
    lib.h_cascade.restype = None
    lib.h_cascade.argtypes = [ctypes.c_int32, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64]
    lib.h_cascade.argtypes += [ctypes.c_int64] + [ctypes.c_void_p] * 3
    qs, retuned, x, coef, new = _case(name)
    out = np.zeros(N, dtype=np.int64)
    state = np.zeros(N_FILTER_STATE * len(qs), dtype=np.int64)
    args = (len(qs), coef.ctypes.data, new.ctypes.data, K_SWITCH, N, x.ctypes.data)
    lib.h_cascade(*args, out.ctypes.data, state.ctypes.data)
    want, want_state = _reference(qs, retuned, x)
    bad = np.flatnonzero(out != want)
    assert bad.size == 0, f"first difference at tick {bad[0]}: C {out[bad[0]]}, {want[bad[0]]}"
    assert np.array_equal(state, want_state)
    # what the run exercised: outputs near the scale the sections were sized for, and a
    # re-tune whose coefficients count (the same switch back to the old section differs)
    assert np.abs(out).max() > INPUT_BOUND_WIDE // 50
    plain, _ = _reference(qs, qs[0], x)
    assert np.any(plain[K_SWITCH:] != out[K_SWITCH:])


@needs_cc
@pytest.mark.parametrize("name", list(CASCADES))
def test_the_c_filter_has_no_undefined_behaviour(filter_dir: Path, name: str) -> None:
    exe = f"filter_ubsan_{name}"
    cc(filter_dir, *STRICT, *UBSAN, "-DH_MAIN", "harness.c", "-o", exe)
    qs, retuned, x, coef, new = _case(name)
    payload = (
        np.int32(len(qs)).tobytes()
        + np.int64(K_SWITCH).tobytes()
        + np.int64(N).tobytes()
        + coef.tobytes()
        + new.tobytes()
        + x.tobytes()
    )
    res = subprocess.run([str(filter_dir / exe)], input=payload, capture_output=True, timeout=120)
    assert res.returncode == 0 and not res.stderr, res.stderr.decode()[-400:]
    got = np.frombuffer(res.stdout, dtype=np.int64)
    want, want_state = _reference(qs, retuned, x)
    assert np.array_equal(got[:N], want) and np.array_equal(got[N:], want_state)


N_HAL = 5000


def _hal_reference(qs: list[SectionQ], x: np.ndarray, enable: np.ndarray, bound: int):
    """What the component gives, from filter_run: the input clamped to ±bound; passed through
    while disabled; at each switch-in every section set by bumpless_state at the last input."""
    v = np.clip(x, -bound, bound).astype(np.int64)
    out = v.copy()
    states = [np.zeros(N_FILTER_STATE, dtype=np.int64) for _ in qs]
    k = 0
    while k < x.size:
        if not enable[k]:
            k += 1
            continue
        k0 = k
        while k < x.size and enable[k]:
            k += 1
        last = int(v[k0 - 1]) if k0 > 0 else 0
        seg = v[k0:k]
        for q, st in zip(qs, states, strict=True):
            st[:] = bumpless_state(q, last, last)
            y = np.empty_like(seg)
            filter_run(*q.step_args(), st, seg, y)
            seg = y
        out[k0:k] = seg
    return out, np.abs(x) > bound


def test_hal_filters_bit_for_bit_with_the_simulator(tmp_path: Path) -> None:
    halrun.hal_available()
    period_s, sections, _ = CASCADES["4ms"]
    qs = [_q(s, period_s) for s in sections]
    bound = INPUT_BOUND_WIDE // 4
    name = "st_test_filter"
    (tmp_path / f"{name}.comp").write_text(filter_component(qs, name=name, input_bound=bound))
    so = halrun.halcompile(tmp_path / f"{name}.comp")
    rng = np.random.default_rng(11)
    x = np.concatenate(
        [
            np.repeat(rng.integers(-bound, bound + 1, 20), 100),  # steps: the modes ring
            rng.integers(-bound, bound + 1, 1000),
            np.full(1000, bound // 7),  # steady while switched off and on again
            np.repeat(rng.choice([-bound - 5000, bound + 5000, 0], 20), 50),  # beyond the bound
        ]
    ).astype(np.int64)
    assert x.size == N_HAL
    enable = np.ones(N_HAL, dtype=np.int64)
    enable[3200:3500] = 0
    enable[3700:3720] = 0
    rows = halrun.run_component(
        so,
        tmp_path,
        {"in": ("s", x.tolist()), "enable": ("b", enable.tolist())},
        {"out": "s", "clipped": "b"},
    )
    got = np.array([int(r[0]) for r in rows])
    clipped = np.array([int(r[1]) for r in rows]) == 1
    want, want_clipped = _hal_reference(qs, x, enable, bound)
    bad = np.flatnonzero(got != want)
    assert bad.size == 0, f"first difference at period {bad[0]}: HAL {got[bad[0]]}, {want[bad[0]]}"
    assert np.array_equal(clipped, want_clipped) and clipped.sum() > 0
    # the filter acted (the output is not the input where enabled), passed the input through
    # where disabled, and switching it on again at a steady input moved the output by 0 LSB
    assert np.any(got[:2000] != x[:2000]) and np.array_equal(got[3200:3500], x[3200:3500])
    assert np.all(got[3500:3700] == bound // 7)


def test_a_cascade_that_could_leave_s32_is_refused() -> None:
    qs = [_q(lowpass2(5.0, 0.05), 0.001)]
    with pytest.raises(ExportError, match="section 1: inputs up to"):
        filter_component(qs, name="st_f", input_bound=2**31 - 1)
    with pytest.raises(ExportError, match="1 to 4 sections"):
        filter_component(qs * 5, name="st_f")
