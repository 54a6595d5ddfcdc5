"""The input shaper's integer step in C (``servotune_shaper.h``) and as a HAL component, bit for
bit with the simulator's (:func:`servotune.laws.shaping.shape_reference`,
docs/runtime.md#input-shaping).

The C header is built strictly (C99, every warning an error) and under the undefined-behaviour
sanitizer; the HAL component runs in real HAL (``halrun`` as an unprivileged user, skipped where
LinuxCNC is not installed, failed under CI: tests/hal/halrun.py), fed by ``streamer`` and read by
``sampler``.
"""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path

import numpy as np
import pytest
from c_build import STRICT, UBSAN, cc, needs_cc

from servotune.cli import main
from servotune.export.c import SHAPER_RUNTIME_FILES, runtime_source
from servotune.export.hal_component import shaper_component
from servotune.laws.shaping import SHAPER_FRAC_BITS, shape_reference, shaper_for_modes

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "hal"))
import halrun

HARNESS = r"""
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "servotune_shaper.h"

static st_shaper_t shaper;
static st_shaper_state_t state;

/* n references through a fresh shaper with the given taps; returns st_shaper_check */
int h_shape(int32_t n_taps, const int32_t *a_q, int64_t n, const int64_t *ref, int64_t *out)
{
    int32_t i;
    int64_t k;
    int bad;
    shaper.n = n_taps;
    for (i = 0; i < n_taps; i++) {
        shaper.a_q[i] = a_q[i];
    }
    bad = st_shaper_check(&shaper);
    state.primed = 0;
    for (k = 0; k < n; k++) {
        out[k] = st_shaper_step(&shaper, &state, ref[k]);
    }
    return bad;
}

#ifdef H_MAIN
int main(void)
{
    int32_t n_taps;
    int64_t n;
    int32_t *a;
    int64_t *ref;
    int64_t *out;
    if (fread(&n_taps, 4, 1, stdin) != 1 || fread(&n, 8, 1, stdin) != 1) {
        return 2;
    }
    a = malloc(4 * (size_t)n_taps);
    ref = malloc(8 * (size_t)n);
    out = malloc(8 * (size_t)n);
    if (fread(a, 4, (size_t)n_taps, stdin) != (size_t)n_taps
        || fread(ref, 8, (size_t)n, stdin) != (size_t)n) {
        return 2;
    }
    if (h_shape(n_taps, a, n, ref, out) != 0) {
        return 3;
    }
    fwrite(out, 8, (size_t)n, stdout);
    return 0;
}
#endif
"""

SHAPER = shaper_for_modes(["zvd", "ei"], [(35.0, 0.04), (80.0, 0.02)], 0.004)
"""Two modes of a belt-driven axis (tests/export/test_c_runtime.py's PLANT_MODES' frequencies):
the product of a zvd and an ei, 14 taps."""


def _references(n: int, seed: int) -> np.ndarray:
    """Moves of every size: small and large steps and ramps, reversals, up to ±2^46 counts and
    the largest the step allows (±(2^47 − 1))."""
    rng = np.random.default_rng(seed)
    parts = [
        np.cumsum(rng.integers(-500, 501, n // 2)),
        rng.integers(-(1 << 46), 1 << 46, n // 4),
        np.repeat(rng.choice([-(1 << 47) + 1, (1 << 47) - 1, 0, 1, -1], n // 40), 10),
    ]
    ref = np.concatenate(parts)
    return np.concatenate([ref, np.full(n - ref.size, ref[-1])]).astype(np.int64)


@pytest.fixture(scope="module")
def shaper_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("c_shaper")
    (d / SHAPER_RUNTIME_FILES[0]).write_text(runtime_source(SHAPER_RUNTIME_FILES[0]))
    (d / "harness.c").write_text(HARNESS)
    return d


@needs_cc
def test_the_c_shaper_equals_the_simulators_step_bit_for_bit(shaper_dir: Path) -> None:
    cc(shaper_dir, *STRICT, "-O2", "-shared", "-fPIC", "harness.c", "-o", "libshaper.so")
    lib = ctypes.CDLL(str(shaper_dir / "libshaper.so"))
    lib.h_shape.restype = ctypes.c_int
    lib.h_shape.argtypes = [ctypes.c_int32, ctypes.c_void_p, ctypes.c_int64] + [ctypes.c_void_p] * 2
    ref = _references(40_000, seed=3)
    taps = np.asarray(SHAPER.amplitudes_q, dtype=np.int32)
    out = np.zeros_like(ref)
    assert lib.h_shape(taps.size, taps.ctypes.data, ref.size, ref.ctypes.data, out.ctypes.data) == 0
    want = shape_reference(ref, SHAPER)
    bad = np.flatnonzero(out != want)
    assert bad.size == 0, (
        f"first difference at tick {bad[0]}: C {out[bad[0]]}, python {want[bad[0]]}"
    )
    # the check refuses amplitudes that do not sum to 2^15
    taps[0] += 1
    assert lib.h_shape(taps.size, taps.ctypes.data, 0, ref.ctypes.data, out.ctypes.data) == 3


@needs_cc
def test_the_c_shaper_has_no_undefined_behaviour(shaper_dir: Path) -> None:
    import subprocess

    cc(shaper_dir, *STRICT, *UBSAN, "-DH_MAIN", "harness.c", "-o", "shaper_ubsan")
    ref = _references(8_000, seed=4)
    taps = np.asarray(SHAPER.amplitudes_q, dtype=np.int32)
    payload = (
        np.int32(taps.size).tobytes()
        + np.int64(ref.size).tobytes()
        + taps.tobytes()
        + ref.tobytes()
    )
    res = subprocess.run(
        [str(shaper_dir / "shaper_ubsan")], input=payload, capture_output=True, timeout=60
    )
    assert res.returncode == 0 and not res.stderr, res.stderr.decode()[-400:]
    assert np.array_equal(np.frombuffer(res.stdout, dtype=np.int64), shape_reference(ref, SHAPER))


def test_the_component_holds_the_shapers_amplitudes() -> None:
    src = shaper_component(SHAPER, name="st_shape")
    assert f"{{{SHAPER.n_taps}, {{{', '.join(map(str, SHAPER.amplitudes_q))}}}}}" in src
    assert sum(SHAPER.amplitudes_q) == 1 << SHAPER_FRAC_BITS
    assert "zvd×ei" in src and f"+{SHAPER.n_taps - 1} ticks" in src


N_HAL = 6000


def test_hal_shapes_the_reference_bit_for_bit_with_the_simulator(tmp_path: Path) -> None:
    halrun.hal_available()
    name = "st_test_shaper"
    (tmp_path / f"{name}.comp").write_text(shaper_component(SHAPER, name=name))
    so = halrun.halcompile(tmp_path / f"{name}.comp")
    rng = np.random.default_rng(9)
    # s32 pins: moves within ±2^31, with steps and reversals
    ref = np.clip(np.cumsum(rng.integers(-40_000, 40_001, N_HAL)), -(2**31), 2**31 - 1)
    ref[N_HAL // 2 : N_HAL // 2 + 50] = 2**31 - 1
    rows = halrun.run_component(so, tmp_path, {"command": ("s", ref.tolist())}, {"shaped": "s"})
    got = np.array([int(r[0]) for r in rows])
    want = shape_reference(ref.astype(np.int64), SHAPER)
    bad = np.flatnonzero(got != want)
    assert bad.size == 0, f"first difference at period {bad[0]}: HAL {got[bad[0]]}, {want[bad[0]]}"


def test_the_cli_writes_the_shaper_and_its_component(tmp_path: Path, capsys) -> None:
    from servotune.rig import EXAMPLES_DIR

    comp = tmp_path / "shaper.comp"
    rig = str(EXAMPLES_DIR / "belt-axis.toml")
    assert main(["shaper", rig, "--kind", "zvd", "--hal-output", str(comp), "--json"]) == 0
    import json

    doc = json.loads(capsys.readouterr().out)
    assert doc["kind"] == "zvd" and sum(doc["amplitudes_q"]) == 1 << SHAPER_FRAC_BITS
    assert f"{{{len(doc['amplitudes_q'])}, {{{', '.join(map(str, doc['amplitudes_q']))}}}}}" in (
        comp.read_text()
    )
