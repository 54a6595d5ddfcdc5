"""The C-layout digest: ``servotune.export.layout``, the header's ``ST_TABLES_SHA256`` and the
C runtime's SHA-256 and ``st_check_digest``.

- The C SHA-256 (``st_sha256``, incremental ``st_sha256_init/update/final``) against the
  FIPS 180-4 examples and :mod:`hashlib`, whole and fed in pieces;
- the exported header of a real tuning of the example rig passes ``st_check_digest``, and the
  digest the C recomputes from its compiled-in ``st_consts_t`` is :func:`c_layout_sha256`;
- a header edited after the export (a lock gain, a gain's fraction bits, one entry of each
  table, a table's fraction bits, the levels, the divisor, a reference source, a law, two
  tables swapped) is refused, and so is another tuning's digest;
- the layout itself pinned independently: the bytes built by hand with :mod:`struct` for a
  small three-axis case (PI, fuzzy-PID with 3 x 3 tables, lock only);
- the harness once more under the undefined-behaviour sanitizer.
"""

from __future__ import annotations

import copy
import ctypes
import hashlib
import json
import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from c_build import (
    STRICT,
    export_harness,
    needs_cc,
    run_cc,
    run_replay,
    shared_harness,
    ubsan_harness,
)

from servotune.errors import ExportError
from servotune.export.c import RUNTIME_FILES, runtime_source
from servotune.export.json import tables_document
from servotune.export.json import to_string as tables_to_string
from servotune.export.layout import c_layout_bytes, c_layout_sha256, pairs_bytes, table_bytes
from servotune.fixed import Fixed
from servotune.laws.axis import AxisController
from servotune.laws.filters import SectionQ
from servotune.laws.fuzzy_pid import FuzzyPIDConstants
from servotune.laws.pi import PIConstants
from servotune.plant import Plant
from servotune.rig import Axis, Counter, Dac, Encoder, Rig, Timer
from servotune.tuning import Tuning

ST_DIGEST_OK, ST_DIGEST_MISMATCH, ST_DIGEST_MALFORMED = 0, 1, 2

HARNESS = r"""
/* test harness: the C runtime's SHA-256 and digest check on the exported tables */
#include <stdio.h>
#include <stdlib.h>

#include "servotune_tables.h"

static const st_consts_t consts = SERVOTUNE_TABLES_INIT;

void h_sha256(const uint8_t *p, size_t len, uint8_t *out) { st_sha256(p, len, out); }

/* the same message fed to st_sha256_update in pieces of `chunk` bytes (the last shorter) */
void h_sha256_chunked(const uint8_t *p, size_t len, size_t chunk, uint8_t *out)
{
    st_sha256_ctx_t s;
    size_t done = 0;
    st_sha256_init(&s);
    st_sha256_update(&s, p, 0);
    while (done < len) {
        const size_t k = len - done < chunk ? len - done : chunk;
        st_sha256_update(&s, p + done, k);
        done += k;
    }
    st_sha256_final(&s, out);
}

int h_consts_sha256(uint8_t *out) { return st_consts_sha256(&consts, out); }
int h_check_digest(void) { return st_check_digest(&consts, st_tables_sha256); }
int h_check_digest_with(const uint8_t *expected) { return st_check_digest(&consts, expected); }
/* st_tables_sha256 into out; 1 if ST_TABLES_SHA256_BYTES holds the same bytes */
int h_exported_digest(uint8_t *out)
{
    static const uint8_t bytes[32] = ST_TABLES_SHA256_BYTES;
    int same = 1;
    int j;
    for (j = 0; j < 32; j++) {
        out[j] = st_tables_sha256[j];
        same = same && bytes[j] == st_tables_sha256[j];
    }
    return same;
}

/* st_check_digest on a copy that cannot be walked safely */
int h_check_broken(int what)
{
    st_consts_t c = consts;
    int fuzzy = -1;
    int other = -1;
    int a;
    for (a = 0; a < c.n_axes; a++) {
        if (c.axis[a].law == ST_LAW_FUZZY_PID) {
            fuzzy = fuzzy < 0 ? a : fuzzy;
        } else {
            other = other < 0 ? a : other;
        }
    }
    if (fuzzy < 0 || other < 0) {
        return -1;
    }
    if (what == 0) {
        c.n_axes = 0;
    } else if (what == 1) {
        c.n_axes = ST_MAX_AXES + 1;
    } else if (what == 2) {
        c.axis[fuzzy].n = 0;
    } else if (what == 3) {
        c.axis[fuzzy].n = ST_MAX_LEVELS + 1;
    } else if (what == 4) {
        c.axis[fuzzy].tab[ST_TAB_K1] = NULL;
    } else if (what == 5) {
        c.axis[other].law = ST_LAW_FUZZY_PID; /* no tables */
    }
    return st_check_digest(&c, st_tables_sha256);
}

#ifdef H_MAIN
/* in = a message; out = its SHA-256 whole and in pieces of 7 bytes, the constants' digest,
 * then the results of st_check_digest, of it against a zero digest and of h_check_broken */
static uint8_t msg[1 << 21];

int main(int argc, char **argv)
{
    static const uint8_t zero[32] = {0};
    uint8_t out[3 * 32 + 8];
    size_t len;
    int w;
    FILE *f;
    if (argc != 3) {
        return 2;
    }
    f = fopen(argv[1], "rb");
    if (f == NULL) {
        return 3;
    }
    len = fread(msg, 1, sizeof msg, f);
    fclose(f);
    h_sha256(msg, len, out);
    h_sha256_chunked(msg, len, 7, out + 32);
    if (h_consts_sha256(out + 64) != ST_DIGEST_OK) {
        return 4;
    }
    out[96] = (uint8_t)h_check_digest();
    out[97] = (uint8_t)st_check_digest(&consts, zero);
    for (w = 0; w < 6; w++) {
        out[98 + w] = (uint8_t)h_check_broken(w);
    }
    f = fopen(argv[2], "wb");
    if (f == NULL || fwrite(out, 1, 104, f) != 104) {
        return 5;
    }
    fclose(f);
    return 0;
}
#endif
"""


# --- building ---------------------------------------------------------------------------------


def _export(tuning: Tuning, out_dir: Path, rig: Rig | None = None) -> Path:
    return export_harness(tuning, out_dir, HARNESS, rig)


class DigestRuntime:
    """The compiled digest harness (shared library) through ctypes."""

    def __init__(self, src_dir: Path, name: str = "libdigest.so") -> None:
        lib = shared_harness(src_dir, name)
        p, size = ctypes.c_char_p, ctypes.c_size_t
        for fn_name, res, args in (
            ("h_sha256", None, [p, size, p]),
            ("h_sha256_chunked", None, [p, size, size, p]),
            ("h_consts_sha256", ctypes.c_int, [p]),
            ("h_check_digest", ctypes.c_int, []),
            ("h_check_digest_with", ctypes.c_int, [p]),
            ("h_exported_digest", ctypes.c_int, [p]),
            ("h_check_broken", ctypes.c_int, [ctypes.c_int]),
        ):
            fn = getattr(lib, fn_name)
            fn.restype = res
            fn.argtypes = args
        self.lib = lib

    def sha256(self, msg: bytes, chunk: int | None = None) -> str:
        out = ctypes.create_string_buffer(32)
        if chunk is None:
            self.lib.h_sha256(msg, len(msg), out)
        else:
            self.lib.h_sha256_chunked(msg, len(msg), chunk, out)
        return out.raw.hex()

    def consts_sha256(self) -> str:
        out = ctypes.create_string_buffer(32)
        assert self.lib.h_consts_sha256(out) == ST_DIGEST_OK
        return out.raw.hex()

    def exported_digest(self) -> str:
        out = ctypes.create_string_buffer(32)
        assert self.lib.h_exported_digest(out) == 1  # the array is ST_TABLES_SHA256_BYTES
        return out.raw.hex()

    def check(self, expected: str | None = None) -> int:
        if expected is None:
            return self.lib.h_check_digest()
        return self.lib.h_check_digest_with(bytes.fromhex(expected))


def _header_digest(src_dir: Path) -> str:
    m = re.search(r'^#define ST_TABLES_SHA256 "([0-9a-f]{64})"$', _header(src_dir), re.M)
    assert m, "no ST_TABLES_SHA256 in the header"
    return m.group(1)


def _header(src_dir: Path) -> str:
    return (src_dir / "servotune_tables.h").read_text()


# --- fixtures ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def example_tuning(quick_tuning) -> Tuning:
    """A real tuning of the example rig (tiny budget, seed 0: deterministic): master PI,
    slave fuzzy-PID + feedforward."""
    return quick_tuning


@pytest.fixture(scope="module")
def example_build(example_tuning: Tuning, tmp_path_factory) -> Path:
    return _export(example_tuning, tmp_path_factory.mktemp("c_digest"))


@pytest.fixture(scope="module")
def example_rt(example_build: Path) -> DigestRuntime:
    return DigestRuntime(example_build)


# fixed constants of the small case (d): (q, f) pairs and 3 x 3 tables (n = 1)
SECTION_KEYS = ("b0", "b1", "b2", "a1", "a2", "frac_bits")
LOCK = ((1717986918, 32), (3, 1), (-7, 3))
FE = (12288, 0, 3)
PI_KP, PI_KIT = (123456, 20), (-654321, 24)
FZ = {"kp": (1000, 10), "ki_t": (300, 12), "kd_t": (5000, 16), "k1_t": (77, 4)}
FZ_KE, FZ_KEC = (3, 2), (9, 5)
TABLES = (  # kp, ki, kd, k1: (rows, f)
    ([[-3, 0, 3], [1, 2, -1], [0, 4, -4]], 8),
    ([[1, 2, 3], [4, 5, 6], [7, 8, 9]], 12),
    ([[-2, -1, 0], [0, 1, 2], [3, -3, 0]], 16),
    ([[0, 0, 0], [0, 1, 0], [0, 0, -16]], 2),
)
# output filters (docs/runtime.md#filters-in-the-law): stable sections, integers chosen by hand;
# one on the PI axis, two on the lock-only axis, none on the fuzzy-PID axis
FILTERS = (
    ((1000, 2000, 1000, -20000, 7000, 14),),
    (),
    ((3835, -6694, 3804, -6695, 3544, 12), (-5, 123456, 77, 0, -536870912, 30)),
)
SHAPERS = ((5000, 22768, 5000), (), (32768,))
"""Reference shapers' Q15 amplitudes per axis (docs/runtime.md#shapers-in-the-tables)."""


def _fx(qf: tuple[int, int]) -> Fixed:
    return Fixed(q=qf[0], f=qf[1])


def small_case() -> tuple[Tuning, Rig]:
    """Three axes on a 16-bit counter and a 16-bit D/A: a PI master, a fuzzy-PID slave with
    3 x 3 tables, a lock-only slave (every unused constant (0, 0)); output filters on the first
    and the last (:data:`FILTERS`), reference shapers too (:data:`SHAPERS`)."""
    fuzzy = FuzzyPIDConstants(
        kp=_fx(FZ["kp"]),
        ki_t=_fx(FZ["ki_t"]),
        kd_t=_fx(FZ["kd_t"]),
        k1_t=_fx(FZ["k1_t"]),
        ke=_fx(FZ_KE),
        kec=_fx(FZ_KEC),
        n=1,
        tables=tuple((np.array(rows, dtype=np.int16), f) for rows, f in TABLES),
    )
    tasks = (PIConstants(kp=_fx(PI_KP), ki_t=_fx(PI_KIT)), fuzzy, None)
    ctls = tuple(
        AxisController(
            lock_gain=_fx(lock),
            task=task,
            following_error_limit_counts=fe,
            filters=tuple(SectionQ(**dict(zip(SECTION_KEYS, s, strict=True))) for s in filt),
            shaper=shaper,
        )
        for lock, task, fe, filt, shaper in zip(LOCK, tasks, FE, FILTERS, SHAPERS, strict=True)
    )
    plant = Plant(gain_cps_per_v=1000.0, tau_s=0.01)
    rig = Rig(
        name="digest-small",
        timer=Timer(period_s=0.001),
        counter=Counter(bits=16),
        dac=Dac(bits=16, range_v=(-10.0, 10.0)),
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


# --- (a) SHA-256 ------------------------------------------------------------------------------

# FIPS 180-4 examples (NIST CSRC "Examples with intermediate values", SHA256.pdf and
# SHA2_Additional; the same messages as FIPS 180-2 appendix B.1, B.2, B.3) and the empty string
FIPS_VECTORS = [
    (b"abc", "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"),
    (b"", "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"),
    (
        b"abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq",  # 448 bits, two blocks
        "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1",
    ),
    (b"a" * 1_000_000, "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0"),
]


@needs_cc
@pytest.mark.parametrize(("msg", "digest"), FIPS_VECTORS, ids=["abc", "empty", "448bit", "1M-a"])
def test_sha256_matches_the_fips_examples(example_rt: DigestRuntime, msg, digest) -> None:
    assert hashlib.sha256(msg).hexdigest() == digest
    assert example_rt.sha256(msg) == digest
    for chunk in (1, 3, 55, 56, 63, 64, 65, 1000):
        assert example_rt.sha256(msg, chunk) == digest, chunk


@needs_cc
def test_sha256_matches_hashlib_on_random_lengths(example_rt: DigestRuntime) -> None:
    rng = np.random.default_rng(20250101)
    for n in range(301):  # every padding case: 0..300 bytes (up to 5 blocks)
        msg = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        want = hashlib.sha256(msg).hexdigest()
        assert example_rt.sha256(msg) == want, n
        chunk = int(rng.integers(1, 80))
        assert example_rt.sha256(msg, chunk) == want, (n, chunk)


# --- (b) the exported header passes -----------------------------------------------------------


@needs_cc
def test_exported_header_passes_the_digest_check(
    example_rt: DigestRuntime, example_build: Path, example_tuning: Tuning
) -> None:
    data = tables_document(example_tuning, unverified=True)["data"]
    laws = [ax["law"] for ax in data["axes"]]
    assert laws == ["pi", "fuzzy_pid"]
    digest = c_layout_sha256(data)
    assert example_rt.check() == ST_DIGEST_OK
    # the C's recomputed digest of its compiled-in st_consts_t is the layout's digest, and the
    # header carries it as the string and the byte array
    assert example_rt.consts_sha256() == digest
    assert _header_digest(example_build) == digest
    assert example_rt.exported_digest() == digest
    assert digest == hashlib.sha256(c_layout_bytes(data)).hexdigest()
    if "c_layout_sha256" in data:  # the JSON export records the same digest
        assert data["c_layout_sha256"] == digest


@needs_cc
def test_golden_header_passes_the_digest_check(tmp_path) -> None:
    # the committed golden header (tests/export/golden, regenerated with the golden files)
    # carries the digest of what it compiles in
    golden = Path(__file__).resolve().parent / "golden" / "servotune_tables.h"
    (tmp_path / "servotune_tables.h").write_text(golden.read_text())
    for name in RUNTIME_FILES:
        (tmp_path / name).write_text(runtime_source(name))
    (tmp_path / "harness.c").write_text(HARNESS)
    rt = DigestRuntime(tmp_path)
    assert rt.check() == ST_DIGEST_OK
    assert rt.consts_sha256() == _header_digest(tmp_path) == rt.exported_digest()


@needs_cc
def test_check_refuses_another_digest(example_rt: DigestRuntime, example_tuning: Tuning) -> None:
    digest = c_layout_sha256(tables_document(example_tuning, unverified=True)["data"])
    assert example_rt.check(digest) == ST_DIGEST_OK
    for j in range(32):  # one bit off in any byte
        other = bytearray.fromhex(digest)
        other[j] ^= 1 << (j % 8)
        assert example_rt.check(other.hex()) == ST_DIGEST_MISMATCH, j
    # a mix-up: another tuning's digest
    small, rig = small_case()
    small_digest = c_layout_sha256(tables_document(small, rig=rig, unverified=True)["data"])
    assert example_rt.check(small_digest) == ST_DIGEST_MISMATCH


@needs_cc
def test_check_refuses_constants_it_cannot_walk(example_rt: DigestRuntime) -> None:
    # n_axes 0 / too many, fuzzy-PID n 0 / too large, a NULL table, a law without its tables
    assert [example_rt.lib.h_check_broken(w) for w in range(6)] == [ST_DIGEST_MALFORMED] * 6


# --- (c) a header edited after the export is refused ------------------------------------------


def _bump_define(text: str, name: str, step: int = 0) -> str:
    """``#define NAME [INT32_C(]v`` with v moved by ``step``, or by one towards 0 (0 → 1)."""
    m = re.search(rf"^#define {name} (?:INT32_C\()?(-?\d+)", text, re.M)
    assert m, name
    v = int(m.group(1))
    new = v + step if step else (v - 1 if v > 0 else v + 1)
    return text[: m.start(1)] + str(new) + text[m.end(1) :]


def _bump_table_entry(text: str, ident: str, table: str) -> str:
    """The first entry of row E = 0 of table ``st_<ident>_tab_<table>`` moved by one."""
    start = text.index(f"static const int16_t st_{ident}_tab_{table}[")
    m = re.compile(r"/\* E =\s+0 \*/ (-?\d+)").search(text, start)
    assert m, table
    v = int(m.group(1))
    return text[: m.start(1)] + str(v + 1 if v < 32767 else v - 1) + text[m.end(1) :]


def _replace_once(text: str, old: str, new: str) -> str:
    assert text.count(old) >= 1, old
    return text.replace(old, new, 1)


_SWAPPED = "{st_slave_tab_ki, st_slave_tab_kp,"  # a mix-up of two tables in the initialiser

TAMPERS = {
    "master-lock-q": (lambda t: _bump_define(t, "ST_MASTER_LOCK_Q"), ST_DIGEST_MISMATCH),
    "slave-lock-q": (lambda t: _bump_define(t, "ST_SLAVE_LOCK_Q"), ST_DIGEST_MISMATCH),
    "master-kp-f": (lambda t: _bump_define(t, "ST_MASTER_KP_F"), ST_DIGEST_MISMATCH),
    "slave-kit-f": (lambda t: _bump_define(t, "ST_SLAVE_KIT_F"), ST_DIGEST_MISMATCH),
    "slave-kec-q": (lambda t: _bump_define(t, "ST_SLAVE_KEC_Q"), ST_DIGEST_MISMATCH),
    "table-kp-entry": (lambda t: _bump_table_entry(t, "slave", "kp"), ST_DIGEST_MISMATCH),
    "table-ki-entry": (lambda t: _bump_table_entry(t, "slave", "ki"), ST_DIGEST_MISMATCH),
    "table-kd-entry": (lambda t: _bump_table_entry(t, "slave", "kd"), ST_DIGEST_MISMATCH),
    "table-k1-entry": (lambda t: _bump_table_entry(t, "slave", "k1"), ST_DIGEST_MISMATCH),
    "table-kd-f": (lambda t: _bump_define(t, "ST_SLAVE_TAB_KD_F"), ST_DIGEST_MISMATCH),
    "levels-up": (lambda t: _bump_define(t, "ST_SLAVE_N", +1), ST_DIGEST_MISMATCH),
    "timer-divisor": (lambda t: _bump_define(t, "ST_TIMER_DIVISOR"), ST_DIGEST_MISMATCH),
    "dac-zero": (lambda t: _bump_define(t, "ST_DAC_ZERO"), ST_DIGEST_MISMATCH),
    "fe-limit": (lambda t: _bump_define(t, "ST_SLAVE_FE_LIMIT"), ST_DIGEST_MISMATCH),
    "ref-source": (
        lambda t: _replace_once(t, ".ref_source = 0,", ".ref_source = -1,"),
        ST_DIGEST_MISMATCH,
    ),
    "law-fuzzy-to-pi": (
        lambda t: _replace_once(t, ".law = ST_LAW_FUZZY_PID,", ".law = ST_LAW_PI,"),
        ST_DIGEST_MISMATCH,
    ),
    "law-pi-to-fuzzy": (
        lambda t: _replace_once(t, ".law = ST_LAW_PI,", ".law = ST_LAW_FUZZY_PID,"),
        ST_DIGEST_MALFORMED,  # an axis without tables: not walked, refused all the same
    ),
    "tables-swapped": (
        lambda t: _replace_once(t, "{st_slave_tab_kp, st_slave_tab_ki,", _SWAPPED),
        ST_DIGEST_MISMATCH,
    ),
}


@needs_cc
@pytest.mark.parametrize("edit", list(TAMPERS))
def test_check_refuses_a_header_edited_after_the_export(
    edit: str, example_tuning: Tuning, tmp_path
) -> None:
    src = _export(example_tuning, tmp_path)
    text = _header(src)
    fn, expect = TAMPERS[edit]
    edited = fn(text)
    assert edited != text and _header_digest(src) in edited  # the exported digest kept
    (src / "servotune_tables.h").write_text(edited)
    rt = DigestRuntime(src)
    assert rt.check() == expect
    assert rt.exported_digest() == _header_digest(src)


@needs_cc
def test_fewer_levels_than_the_tables_do_not_compile(example_tuning: Tuning, tmp_path) -> None:
    # the tables are sized by the axis's N: with N lowered their entries do not fit, which the
    # strict build refuses (so st_check_digest never reads past a table either way)
    src = _export(example_tuning, tmp_path)
    text = _header(src)
    (src / "servotune_tables.h").write_text(_bump_define(text, "ST_SLAVE_N", -1))
    res = run_cc(src, *STRICT, "-c", "harness.c", "-o", "harness.o")
    assert res.returncode != 0 and "excess elements" in res.stderr


# --- (d) the layout, pinned by hand -----------------------------------------------------------


def _p(q: int, f: int = 0) -> bytes:
    return struct.pack("<ih", q, f)


def _filter_pairs(sections: tuple) -> bytes:
    """(n_filters, 0), then 4 slots of (b0, f) (b1, f) (b2, f) (a1, f) (a2, f), unused (0, 0)."""
    out = _p(len(sections))
    for k in range(4):
        *coefs, f = sections[k] if k < len(sections) else (0,) * 6
        out += b"".join(_p(q, f) for q in coefs)
    return out


def test_layout_bytes_built_by_hand() -> None:
    tuning, rig = small_case()
    data = tables_document(tuning, rig=rig, unverified=True)["data"]
    # the document holds the numbers the bytes below are built from
    assert [ax["law"] for ax in data["axes"]] == ["pi", "fuzzy_pid", "none"]
    assert [ax["ref_source"] for ax in data["axes"]] == [-1, 0, 0]
    assert [(ax["lock_gain"]["q"], ax["lock_gain"]["f"]) for ax in data["axes"]] == list(LOCK)
    assert (data["counter_bits"], data["dac"]["zero_code"], data["dac"]["code_max"]) == (
        16,
        32768,
        65535,
    )
    divisor = data["timer_divisor"]
    hw = _p(16) + _p(32768) + _p(65535)  # counter_bits, dac_zero, dac_max
    zero = _p(0, 0)
    constants = (
        _p(3)  # n_axes
        + _p(divisor)
        # axis 0, PI: law, lock, kp, kit, fe_limit, hw, kdt, k1t, ke, kec, n, ref_source
        + _p(1)
        + _p(*LOCK[0])
        + _p(*PI_KP)
        + _p(*PI_KIT)
        + _p(FE[0])
        + hw
        + zero * 4
        + _p(0)
        + _p(-1)
        + _filter_pairs(FILTERS[0])
        # axis 1, fuzzy-PID
        + _p(2)
        + _p(*LOCK[1])
        + _p(*FZ["kp"])
        + _p(*FZ["ki_t"])
        + _p(FE[1])
        + hw
        + _p(*FZ["kd_t"])
        + _p(*FZ["k1_t"])
        + _p(*FZ_KE)
        + _p(*FZ_KEC)
        + _p(1)
        + _p(0)
        + _filter_pairs(FILTERS[1])
        # axis 2, lock only
        + _p(0)
        + _p(*LOCK[2])
        + zero * 2
        + _p(FE[2])
        + hw
        + zero * 4
        + _p(0)
        + _p(0)
        + _filter_pairs(FILTERS[2])
    )
    tables = [
        struct.pack("<hh", 1, f) + struct.pack("<9h", *(v for row in rows for v in row))
        for rows, f in TABLES
    ]
    # part 3, per axis: int32 shaper_n, then its int32 amplitudes
    shapers = struct.pack("<4i", 3, 5000, 22768, 5000) + struct.pack("<i", 0)
    shapers += struct.pack("<2i", 1, 32768)
    expected = constants + b"".join(tables) + shapers
    # 35 pairs per axis: 14, then (n_filters, 0) and 4 filter slots of 5 (docs/runtime.md)
    assert len(constants) == 6 * (2 + 35 * 3)
    assert len(expected) == 642 + 4 * (4 + 2 * 9) + 4 * (3 + 3 + 1)
    assert [len(ax["filters"]) for ax in data["axes"]] == [1, 0, 2]
    assert [ax["shaper"] for ax in data["axes"]] == [list(s) for s in SHAPERS]
    assert c_layout_bytes(data) == expected
    assert c_layout_sha256(data) == hashlib.sha256(expected).hexdigest()
    # each part is the byte stream of its CRC
    assert zlib.crc32(constants) == data["constants_crc32"]
    fuzzy = data["axes"][1]["task"]["tables"]
    for name, block in zip(("kp", "ki", "kd", "k1"), tables, strict=True):
        assert zlib.crc32(block) == fuzzy[name]["crc32"]
    # the helpers give the same streams
    assert table_bytes(*TABLES[0]) == tables[0]
    assert pairs_bytes([(3, 0), (divisor, 0)]) == constants[:12]


@needs_cc
def test_small_case_c_digest_equals_the_hand_built_layout(tmp_path) -> None:
    tuning, rig = small_case()
    data = tables_document(tuning, rig=rig, unverified=True)["data"]
    rt = DigestRuntime(_export(tuning, tmp_path, rig=rig))
    assert rt.check() == ST_DIGEST_OK
    assert rt.consts_sha256() == hashlib.sha256(c_layout_bytes(data)).hexdigest()


def test_layout_of_the_json_text_is_the_same() -> None:
    # what a loaded export gives (plain JSON types) is what the in-memory document gives
    tuning, rig = small_case()
    doc = tables_document(tuning, rig=rig, unverified=True)
    loaded = json.loads(tables_to_string(tuning, rig=rig, unverified=True))
    assert c_layout_bytes(loaded["data"]) == c_layout_bytes(doc["data"])


def test_layout_covers_only_what_is_compiled_in() -> None:
    tuning, rig = small_case()
    data = tables_document(tuning, rig=rig, unverified=True)["data"]
    base = c_layout_bytes(data)
    other = copy.deepcopy(data)
    other["rig_name"] = "elsewhere"
    other["period_s"] = 0.5
    other["constants_crc32"] = 0
    other["dac"]["range_v"] = [0.0, 5.0]
    other["c_layout_sha256"] = "0" * 64
    for i, ax in enumerate(other["axes"]):
        ax["name"], ax["role"], ax["index"] = f"renamed{i}", "slave", 7
    for tab in other["axes"][1]["task"]["tables"].values():
        tab["crc32"] = 0
    assert c_layout_bytes(other) == base


def _set(d: dict, path: str, value: object) -> None:
    keys = path.split(".")
    for k in keys[:-1]:
        d = d[int(k)] if isinstance(d, list) else d[k]
    d[keys[-1]] = value


CHANGES = [
    ("timer_divisor", 1234),
    ("counter_bits", 24),
    ("dac.zero_code", 32767),
    ("axes.0.lock_gain", {"q": LOCK[0][0] - 1, "f": 32}),
    ("axes.0.task.kp", {"q": PI_KP[0], "f": PI_KP[1] + 1}),
    ("axes.0.ref_source", 2),
    ("axes.1.following_error_limit_counts", 1),
    ("axes.1.task.ke", {"q": 4, "f": 2}),
    ("axes.1.task.tables.kp.f", 7),
    ("axes.2.lock_gain", {"q": -7, "f": 4}),
]


@pytest.mark.parametrize(("path", "value"), CHANGES, ids=[c[0] for c in CHANGES])
def test_layout_changes_with_each_constant(path: str, value: object) -> None:
    tuning, rig = small_case()
    data = tables_document(tuning, rig=rig, unverified=True)["data"]
    other = copy.deepcopy(data)
    _set(other, path, value)
    assert c_layout_sha256(other) != c_layout_sha256(data)


def test_layout_table_entries_are_covered() -> None:
    tuning, rig = small_case()
    data = tables_document(tuning, rig=rig, unverified=True)["data"]
    digest = c_layout_sha256(data)
    for name in ("kp", "ki", "kd", "k1"):
        other = copy.deepcopy(data)
        other["axes"][1]["task"]["tables"][name]["q"][1][1] += 1
        assert c_layout_sha256(other) != digest, name


@pytest.mark.parametrize(
    ("path", "value", "match"),
    [
        ("dac.code_max", 4095, "code_max"),
        ("timer_divisor", 2**31, "does not fit"),
        ("timer_divisor", True, "integer"),
        ("axes.0.ref_source", "0", "integer"),
        ("axes.1.task.kp", {"q": 1.5, "f": 1}, r"axes\[1\]"),
        ("axes.1.law", "pid", r"axes\[1\]"),
    ],
)
def test_layout_refuses_malformed_data(path: str, value: object, match: str) -> None:
    tuning, rig = small_case()
    data = copy.deepcopy(tables_document(tuning, rig=rig, unverified=True)["data"])
    _set(data, path, value)
    with pytest.raises(ExportError, match=match):
        c_layout_bytes(data)


def test_layout_refuses_missing_fields() -> None:
    tuning, rig = small_case()
    data = tables_document(tuning, rig=rig, unverified=True)["data"]
    for drop in ("timer_divisor", "dac", "axes"):
        other = {k: v for k, v in data.items() if k != drop}
        with pytest.raises(ExportError, match=drop):
            c_layout_bytes(other)
    other = copy.deepcopy(data)
    del other["axes"][0]["lock_gain"]
    with pytest.raises(ExportError, match="lock_gain"):
        c_layout_bytes(other)


# --- under the sanitizer ----------------------------------------------------------------------


@needs_cc
def test_digest_harness_under_the_undefined_behaviour_sanitizer(
    example_build: Path, example_tuning: Tuning
) -> None:
    exe = ubsan_harness(example_build, "digest_ubsan")
    digest = c_layout_sha256(tables_document(example_tuning, unverified=True)["data"])
    rng = np.random.default_rng(3)
    for msg in (b"a" * 1_000_000, rng.integers(0, 256, 1000, dtype=np.uint8).tobytes(), b""):
        out = run_replay(exe, msg, timeout=60)
        assert out[:32].hex() == hashlib.sha256(msg).hexdigest()
        assert out[32:64].hex() == hashlib.sha256(msg).hexdigest()
        assert out[64:96].hex() == digest
        assert list(out[96:]) == [ST_DIGEST_OK, ST_DIGEST_MISMATCH] + [ST_DIGEST_MALFORMED] * 6
