"""The exported gantry header runs what was verified.

``servotune_gantry_consts.h`` as ``export-table --format c`` writes it for a verified gantry
tuning, compiled with the exported runtime (strict C99), passes its own digest and range checks
and, driven with the counters of the simulation of that tuning's integers
(:func:`~servotune.arch.gantry.tuning.apply_tuning`), gives the simulation's D/A codes, flags,
compensation and monitor levels at every cycle, across sync trips and operator resets. A
constant changed in the header fails the digest check.

The oracle is the Python gantry kernel (the C must equal it); ``test_c_gantry.py`` covers the
runtime's own edges, every topology, 100k-cycle runs and the sanitizer.
"""

from __future__ import annotations

import ctypes
import shutil
from pathlib import Path

import numpy as np
import pytest
from c_build import STRICT, cc, needs_cc
from test_c_gantry import PULSE_V, _moves, _seen_skew, _trip_events

from servotune.arch.gantry.run import run_gantry
from servotune.arch.gantry.tuning import tune_gantry, write_gantry_tuning
from servotune.arch.gantry.verify import load_gantry_for_export, verify_gantry_files
from servotune.export import c as c_export
from servotune.export.gantry import GANTRY_HEADER_NAME
from servotune.laws.axis import FLAG_SYNC_TRIP

pytestmark = needs_cc

ROOT = Path(__file__).resolve().parents[2]

HARNESS = r"""
#include "servotune_gantry_consts.h"

static const st_gantry_consts_t consts = SERVOTUNE_GANTRY_INIT;

int h_check_digest(void) { return st_gantry_check_digest(&consts, st_gantry_consts_sha256); }
int h_check(void) { return st_gantry_check(&consts); }

void h_replay(int64_t n, const int64_t *counter, const int64_t *command, const int32_t *reset,
              int32_t *code, int32_t *flags, int64_t *comp, int32_t *level)
{
    static st_gantry_state_t s;
    st_gantry_init(&s);
    for (int64_t k = 0; k < n; ++k) {
        st_gantry_in_t in;
        st_gantry_out_t out;
        in.counter[0] = counter[2 * k];
        in.counter[1] = counter[2 * k + 1];
        in.command = command[k];
        in.reset = reset[k];
        st_gantry_step(&consts, &s, &in, &out);
        code[2 * k] = out.code[0];
        code[2 * k + 1] = out.code[1];
        flags[2 * k] = out.flags[0];
        flags[2 * k + 1] = out.flags[1];
        comp[k] = out.sync_comp;
        level[k] = out.sync_level;
    }
}
"""


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The example gantry tuned, verified and exported as C; the config that runs the tuning."""
    d = tmp_path_factory.mktemp("gantry_c")
    tuning = tune_gantry(ROOT / "plants" / "gantry.toml")
    write_gantry_tuning(tuning, d / "g.json")
    result, _, _ = verify_gantry_files(
        d / "g.json", ROOT / "plants" / "gantry.spec.toml", montecarlo=4
    )
    assert result.passed, result.failures
    v = load_gantry_for_export(d / "g.json")
    c_export.to_file(v.tuning, d, rig=v.config.rig, verification=v.record)
    (d / "harness.c").write_text(HARNESS)
    return d, v.config


BUILD_FILES = (
    "harness.c",
    "servotune_rt.c",
    "servotune_rt.h",
    "servotune_filter.h",
    "servotune_gantry.c",
    "servotune_gantry.h",
    GANTRY_HEADER_NAME,
)
"""The files a harness of the exported header is built from (:func:`_build`)."""


def _build(d: Path, name: str) -> ctypes.CDLL:
    cc(
        d,
        *STRICT,
        "-O2",
        "-shared",
        "-fPIC",
        "harness.c",
        "servotune_rt.c",
        "servotune_gantry.c",
        "-o",
        name,
    )
    return ctypes.CDLL(str(d / name))


def _scenario(cfg, n: int = 30_000):
    """Two moves, a load pulse at rest on the slave's side that trips the monitor, a reset
    50 cycles later (the skew still past the threshold: refused, the monitor trips again), a
    reset once the stopped drives have drifted back inside the threshold (the drives and the
    compensator enter again), and two more moves (the pieces of ``test_c_gantry.py``)."""
    cmd = _moves(n, cfg.bus.cycle_s, [100, 3_100, 24_000, 27_000])
    load = np.zeros((n, 2))
    load[6_800:7_000, 1] = PULSE_V
    resets = np.zeros(n, dtype=bool)
    kt = _trip_events(run_gantry(cfg, cmd, load).sync_level, resets)[0]
    resets[kt + 50] = True
    skew = _seen_skew(run_gantry(cfg, cmd, load, resets=resets), cfg.bus.latency_cycles)
    back = kt + 100 + int(np.flatnonzero(np.abs(skew[kt + 100 :]) < cfg.sync.trip_counts - 50)[0])
    assert back < 23_000, back
    resets[back] = True
    return cmd, load, resets


def test_the_exported_header_replays_the_simulation_bit_for_bit(exported) -> None:
    d, cfg = exported
    lib = _build(d, "libgantry.so")
    assert lib.h_check_digest() == 0
    assert lib.h_check() == 0
    cmd, load, resets = _scenario(cfg)
    n = cmd.size
    tr = run_gantry(cfg, cmd, load, resets=resets)
    stopped = np.any(tr.flags & FLAG_SYNC_TRIP, axis=1)
    assert np.any(stopped) and np.any(~stopped[np.flatnonzero(stopped)[0] :])
    assert np.any(tr.sync_op[resets] == 1), "no reset after which the compensator entered again"
    counter = np.ascontiguousarray(tr.counter, dtype=np.int64)
    code = np.zeros((n, 2), dtype=np.int32)
    flags = np.zeros((n, 2), dtype=np.int32)
    comp = np.zeros(n, dtype=np.int64)
    level = np.zeros(n, dtype=np.int32)
    ptr = ctypes.c_void_p
    reset = resets.astype(np.int32)
    lib.h_replay.argtypes = [ctypes.c_int64] + [ptr] * 7
    lib.h_replay(
        n,
        counter.ctypes.data,
        cmd.ctypes.data,
        reset.ctypes.data,
        code.ctypes.data,
        flags.ctypes.data,
        comp.ctypes.data,
        level.ctypes.data,
    )
    for name, c_val, py_val in (
        ("code", code, tr.code),
        ("flags", flags, tr.flags),
        ("sync_comp", comp, tr.sync_comp),
        ("sync_level", level, tr.sync_level),
    ):
        bad = np.flatnonzero(np.any((c_val != py_val).reshape(n, -1), axis=1))
        assert bad.size == 0, f"{name} differs first at cycle {bad[0]}"


def test_a_constant_edited_in_the_header_fails_the_digest(exported, tmp_path: Path) -> None:
    d, _ = exported
    for name in BUILD_FILES:
        shutil.copy(d / name, tmp_path / name)
    header = tmp_path / GANTRY_HEADER_NAME
    text = header.read_text()
    line = next(x for x in text.splitlines() if x.startswith("#define ST_GANTRY_SYNC_TRIP "))
    trip = int(line.split()[2])
    header.write_text(text.replace(line, f"#define ST_GANTRY_SYNC_TRIP {trip + 1}"))
    lib = _build(tmp_path, "libedited.so")
    assert lib.h_check() == 0  # still in range: only the digest tells
    assert lib.h_check_digest() != 0
