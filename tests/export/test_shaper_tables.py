"""A reference shaper in the tables (docs/runtime.md#shapers-in-the-tables): the trust chain
from the tuning to the JSON export, the C header, the C runtime's digest check and the HAL
component, which shapes the master's command with it.

- The tables document carries each axis's Q15 amplitudes under ``shaper`` (``[]`` without);
  they come back from ``load_tables``; the C layout's part 3 holds them (built here with
  :mod:`struct`).
- An edited amplitude (the sum kept) is refused by the document's digest; with that
  recomputed, by the C layout's digest (with both recomputed it is another valid document);
  amplitudes that no longer sum to 2^15 are refused by their own check. A
  ``servotune.tables/3`` file gets the one-line old-schema error.
- The C header compiles the amplitudes into the constants: ``st_check_digest`` accepts the
  exported header and refuses one whose amplitude was edited; ``st_check_consts`` names the
  shaper's fields (19: its count, 20: its amplitudes).
- The runtime's HAL component of a master with a shaper, in real HAL for 6,000 periods of
  steps and ramps of the command: its codes, errors and positions are the Python tick's fed
  the command shaped by :func:`servotune.laws.shaping.shaper_step` (the simulator's step),
  period by period; the same component without the shaper gives other codes.
"""

from __future__ import annotations

import dataclasses
import json
import re
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
from c_build import HARNESS_HEAD, export_harness, needs_cc, shared_harness
from test_c_filters import PERIOD_S, PythonTick, filtered_tuning

from servotune.digest import DIGEST_FIELD, document_sha256
from servotune.errors import DigestError, ExportError
from servotune.export import hal_component
from servotune.export.json import load_tables, tables_document
from servotune.export.json import to_string as tables_to_string
from servotune.export.layout import c_layout_bytes, c_layout_sha256
from servotune.laws.axis import MODE_LOCK, MODE_TASK
from servotune.laws.shaping import shaper_for_modes, shaper_state, shaper_step
from servotune.tuning import Tuning

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "hal"))
import halrun


def shaped_tuning(with_shaper: bool = True) -> Tuning:
    """The filtered two-axis tuning of tests/export/test_c_filters.py, its master with a ZVD
    shaper for a 9 Hz mode of damping 0.05 (27 taps at 4 ms) and no following-error limit."""
    t = filtered_tuning()
    sh = shaper_for_modes("zvd", [(9.0, 0.05)], PERIOD_S)
    master = dataclasses.replace(
        t.controllers[0],
        following_error_limit_counts=0,
        shaper=sh.amplitudes_q if with_shaper else (),
    )
    return dataclasses.replace(t, controllers=(master, t.controllers[1]))


@pytest.fixture(scope="module")
def tuning() -> Tuning:
    return shaped_tuning()


def test_the_document_carries_the_amplitudes_and_the_layout_holds_them(tuning: Tuning) -> None:
    doc = tables_document(tuning, unverified=True)
    taps = list(tuning.controllers[0].shaper)
    assert len(taps) > 10 and sum(taps) == 1 << 15
    assert [ax["shaper"] for ax in doc["data"]["axes"]] == [taps, []]
    back = load_tables(tables_to_string(tuning, unverified=True))
    assert back["data"]["axes"][0]["shaper"] == taps
    plain = tables_document(shaped_tuning(False), unverified=True)
    # part 3 of the layout: per axis int32 shaper_n, then the int32 amplitudes
    with_part = c_layout_bytes(doc["data"])
    without = c_layout_bytes(plain["data"])
    tail = struct.pack(f"<i{len(taps)}i", len(taps), *taps) + struct.pack("<i", 0)
    assert with_part.endswith(tail) and without.endswith(struct.pack("<ii", 0, 0))
    assert with_part[: -len(tail)] == without[:-8]  # the rest is the same bytes


def _refused(doc: dict, error: type, *fragments: str) -> None:
    with pytest.raises(error) as info:
        load_tables(json.dumps(doc))
    msg = str(info.value)
    assert "\n" not in msg and all(f in msg for f in fragments), msg


def test_an_edited_amplitude_is_refused_at_every_level(tuning: Tuning) -> None:
    doc = tables_document(tuning, unverified=True)
    taps = doc["data"]["axes"][0]["shaper"]
    taps[0] -= 1  # one unit of the first impulse moved to the next tick: still a valid shaper
    taps[1] += 1
    _refused(doc, DigestError, "sha256")
    doc[DIGEST_FIELD] = document_sha256(doc)  # the document's digest made to match
    _refused(doc, DigestError, "c_layout_sha256")
    doc["data"]["c_layout_sha256"] = c_layout_sha256(doc["data"])  # and the layout's
    doc[DIGEST_FIELD] = document_sha256(doc)
    assert load_tables(json.dumps(doc))["data"]["axes"][0]["shaper"] == taps
    taps[1] += 1  # no longer summing to 2^15 (the layout refuses to digest it), sha recomputed
    doc[DIGEST_FIELD] = document_sha256(doc)
    _refused(doc, ExportError, "shaper", "sum to exactly 32768")
    with pytest.raises(ExportError, match="sum to exactly 32768"):
        c_layout_sha256(doc["data"])
    old = tables_document(tuning, unverified=True)
    old["schema"] = "servotune.tables/3"
    _refused(old, ExportError, "servotune.tables/3", "export the tuning again")


HARNESS = (
    HARNESS_HEAD
    + r"""
/* st_check_consts on a copy with the master's shaper broken */
int h_check_shaper(int what)
{
    static int32_t bad[ST_MAX_SHAPER_N + 1];
    st_consts_t c = compiled;
    int32_t i;
    for (i = 0; i < c.axis[0].shaper_n; i++) {
        bad[i] = c.axis[0].shaper_q[i];
    }
    if (what == 0) {
        c.axis[0].shaper_n = ST_MAX_SHAPER_N + 1;
    } else if (what == 1) {
        c.axis[0].shaper_q = NULL;
    } else if (what == 2) {
        bad[0] += 1; /* the sum is 2^15 + 1 */
        c.axis[0].shaper_q = bad;
    } else {
        bad[0] = -bad[0];
        c.axis[0].shaper_q = bad;
    }
    return st_check_consts(&c);
}
"""
)


@needs_cc
def test_the_c_header_compiles_the_shaper_in_and_checks_it(tuning: Tuning, tmp_path) -> None:
    src = export_harness(tuning, tmp_path, HARNESS)
    header = (src / "servotune_tables.h").read_text()
    n = len(tuning.controllers[0].shaper)
    assert f"#define ST_MASTER_SHAPER_N {n}" in header
    assert ".shaper_q = st_master_shaper_q" in header and "ST_SLAVE_SHAPER_N" not in header
    lib = shared_harness(src, "libshaper.so")
    assert lib.h_check() == 0 and lib.h_check_digest() == 0
    assert [lib.h_check_shaper(w) for w in range(4)] == [20, 21, 21, 21]
    # an amplitude edited in the header (the sum kept: one unit moved to the next tap)
    m = re.search(r"st_master_shaper_q\[ST_MASTER_SHAPER_N\] = \{\n    (\d+), (\d+),", header)
    assert m is not None
    a0, a1 = int(m.group(1)), int(m.group(2))
    edited = header.replace(m.group(0), m.group(0).replace(f"{a0}, {a1},", f"{a0 - 1}, {a1 + 1},"))
    assert edited != header
    (src / "servotune_tables.h").write_text(edited)
    lib2 = shared_harness(src, "libshaper_edited.so")
    assert lib2.h_check() == 0  # still a valid shaper …
    assert lib2.h_check_digest() == 1  # … but not the exported one


def _commands(n: int) -> np.ndarray:
    """The master's command [counts]: steps and ramps, with dwells in between."""
    t = np.arange(n)
    cmd = np.zeros(n, dtype=np.int64)
    cmd[500:] += 3000
    cmd[1500:] -= 8000
    ramp = np.clip((t - 2500) * 12, 0, 9000)
    cmd += ramp
    cmd[4200:] += 2500
    cmd[5000:] -= 4000
    return cmd


def test_the_hal_component_shapes_the_masters_command_bit_for_bit(tuning: Tuning, tmp_path) -> None:
    halrun.hal_available()
    one = dataclasses.replace(
        tuning,
        axis_names=("master",),
        roles=("master",),
        controllers=(tuning.controllers[0],),
    )
    name = "st_test_shaper_rt"
    text = hal_component.to_string(one, unverified=True, name=name)
    assert "st_shaper_step(&st_hal_shaper[0]" in text
    (tmp_path / f"{name}.comp").write_text(text)
    so = halrun.halcompile(tmp_path / f"{name}.comp")
    n = 6000
    cmd = _commands(n)
    counts = (0xFFC000 + np.round(0.8 * cmd + 40 * np.sin(np.arange(n) / 37.0))).astype(np.int64)
    mode = np.full(n, MODE_TASK, dtype=np.int64)
    mode[:200] = MODE_LOCK
    rows = halrun.run_component(
        so,
        tmp_path,
        {
            "counts-0": ("s", (counts & 0xFFFFFFFF).astype(np.int32).tolist()),
            "command": ("s", cmd.tolist()),
            "mode-0": ("s", mode.tolist()),
        },
        {"code-0": "s", "flags-0": "s", "error-0": "s", "position-0": "s"},
        period_ns=250_000,
    )
    got = np.array(rows, dtype=np.int64)
    taps = np.array(one.controllers[0].shaper, dtype=np.int64)
    st = shaper_state(taps.size)
    shaped = np.array([shaper_step(taps, st, int(r)) for r in cmd], dtype=np.int64)
    assert not np.array_equal(shaped, cmd) and shaped[-1] == cmd[-1]
    data = tables_document(one, unverified=True)["data"]
    cols = [counts[:, None] & 0xFFFFFF, shaped[:, None], mode[:, None]]
    zeros = np.zeros((n, 1), dtype=np.int64)
    want = PythonTick(one, data, [-1]).run(*cols, zeros, zeros)[:, 0, :4]
    bad = np.argwhere(got != want)
    assert bad.size == 0, f"first difference at (period, column) {tuple(bad[0])}"
    unshaped = PythonTick(one, data, [-1]).run(cols[0], cmd[:, None], cols[2], zeros, zeros)
    assert np.sum(unshaped[:, 0, 0] != want[:, 0]) > 1000  # a component ignoring it fails
