"""Building and running the exported C runtime with a test harness (the C runtime tests).

A test directory holds ``servotune_rt.c`` (and its headers) and a ``harness.c``; the harness is
built strictly (C99, every warning an error) as a shared library for ctypes, and with the
undefined-behaviour sanitizer as a program (``-DH_MAIN``) that replays an input file.
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path

import pytest

from servotune.export.c import to_file as write_c

CC = shutil.which("cc")
needs_cc = pytest.mark.skipif(
    CC is None, reason="no C compiler: `cc` is not on PATH, so the C runtime cannot be built"
)
STRICT = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic")
UBSAN = ("-O1", "-g", "-fsanitize=undefined", "-fno-sanitize-recover=all")
_HARNESS = ("harness.c", "servotune_rt.c")

HARNESS_HEAD = r"""
/* test harness: the exported tables and the reference runtime, driven from Python (ctypes)
 * or from a file (main, for the sanitizer runs) */
#include <stdio.h>
#include <stdlib.h>

#include "servotune_tables.h"

static const st_consts_t compiled = SERVOTUNE_TABLES_INIT;
static st_consts_t consts = SERVOTUNE_TABLES_INIT; /* the ticks' copy: filters switched */
static st_state_t state;

int h_n_axes(void) { return consts.n_axes; }
int h_check(void) { return st_check_consts(&consts); }
int h_check_digest(void) { return st_check_digest(&compiled, st_tables_sha256); }
uint32_t h_consts_crc32(void) { return st_consts_crc32(&compiled); }
void h_reset(void)
{
    consts = compiled;
    st_init(&state);
}
"""
"""The harnesses' head (C): the includes, the exported constants as compiled (``compiled``) and
the writable copy the ticks use (``consts``, so filters can be switched while running), the
runtime's ``state``, and ``h_n_axes``, ``h_check``, ``h_check_digest``, ``h_consts_crc32`` and
``h_reset`` (the copy restored, the state initialised)."""

TICK_C = r"""/* one tick; raw[a] is the register, handed to the runtime as its bytes, low first */
void h_tick(const int64_t *raw, const int64_t *ref, const int64_t *mode, const int64_t *reset,
            const int64_t *u_add, int64_t *out5)
{
    st_axis_in_t in[ST_MAX_AXES];
    st_axis_out_t out[ST_MAX_AXES];
    int a;
    int j;
    for (a = 0; a < consts.n_axes; a++) {
        for (j = 0; j < 4; j++) {
            in[a].bytes[j] = (uint8_t)(((uint64_t)raw[a] >> (8 * j)) & 0xFFu);
        }
        in[a].ref = ref[a];
        in[a].mode = (int32_t)mode[a];
        in[a].reset = reset[a] != 0;
        in[a].u_add = u_add[a];
    }
    st_tick(&consts, &state, in, out);
    for (a = 0; a < consts.n_axes; a++) {
        out5[5 * a + 0] = out[a].code;
        out5[5 * a + 1] = out[a].flags;
        out5[5 * a + 2] = out[a].e;
        out5[5 * a + 3] = out[a].y;
        out5[5 * a + 4] = out[a].mode;
    }
}

/* n ticks from arrays of shape (n, axes); out has shape (n, axes, 5) */
void h_run(int64_t n, const int64_t *raw, const int64_t *ref, const int64_t *mode,
           const int64_t *reset, const int64_t *u_add, int64_t *out)
{
    const int64_t m = consts.n_axes;
    int64_t k;
    for (k = 0; k < n; k++) {
        h_tick(raw + k * m, ref + k * m, mode + k * m, reset + k * m, u_add + k * m,
               out + k * m * 5);
    }
}
"""
"""The harnesses' ``h_tick`` and ``h_run`` (C, after ``consts`` and ``state``): one tick of
``st_tick`` from int64 arrays, and ``n`` of them."""


def run_cc(src_dir: Path, *args: str) -> subprocess.CompletedProcess:
    """Run the compiler in ``src_dir``; the caller judges the result."""
    return subprocess.run([CC, *args], cwd=src_dir, capture_output=True, text=True)


def cc(src_dir: Path, *args: str) -> None:
    """Compile in ``src_dir``; fail the test with the compiler's messages if it fails."""
    res = run_cc(src_dir, *args)
    assert res.returncode == 0, f"cc {' '.join(args)} failed:\n{res.stderr}"


def shared_harness(src_dir: Path, name: str) -> ctypes.CDLL:
    """The harness and runtime built strictly at -O2 as the shared library ``name``, loaded."""
    cc(src_dir, *STRICT, "-O2", "-shared", "-fPIC", *_HARNESS, "-o", name)
    return ctypes.CDLL(str(src_dir / name))


def ubsan_harness(src_dir: Path, name: str) -> Path:
    """The harness's file replay (``-DH_MAIN``) built with the sanitizer as program ``name``."""
    exe = src_dir / name
    if not exe.exists():
        cc(src_dir, *STRICT, *UBSAN, "-DH_MAIN", *_HARNESS, "-o", name)
    return exe


def run_replay(exe: Path, payload: bytes, timeout: float) -> bytes:
    """Run ``exe in.bin out.bin`` in its directory; no error and no sanitizer report allowed."""
    src_dir = exe.parent
    (src_dir / "in.bin").write_bytes(payload)
    res = subprocess.run(
        [str(exe), "in.bin", "out.bin"],
        cwd=src_dir,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert res.returncode == 0 and "runtime error" not in res.stderr, res.stderr
    return (src_dir / "out.bin").read_bytes()


def export_harness(tuning: object, out_dir: Path, harness: str, rig: object = None) -> Path:
    """Export ``tuning`` as C (marked unverified) into ``out_dir`` with ``harness.c`` beside it."""
    out_dir.mkdir(parents=True, exist_ok=True)
    write_c(tuning, out_dir, rig=rig, unverified=True)
    (out_dir / "harness.c").write_text(harness)
    return out_dir
