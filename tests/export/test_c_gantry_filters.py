"""The gantry's drives with output filters: config, margins, C runtime and export.

A gantry config gives each drive up to four output filter sections (``[[axis.<side>.filters]]``,
the rig file's format: docs/formats.md#filters). They are realised at the bus cycle, run by each
drive's law before its D/A (the same ``axis_control`` as the one-rig runtime), taken into the
drive and sync loops' margins, and carried in the gantry's C layout and digest
(``servotune.gantry-tables/2``).

- The margins of a filtered drive loop are rebuilt independently: the unfiltered loop's
  frequency response times the realised sections' own response (``scipy.signal.freqz`` of
  their integers), margins by python-control on that ``FrequencyResponseData``.
- The C gantry runtime equals the Python kernel at every cycle over the 110,000-cycle golden
  run of ``test_c_gantry.py`` with both drives filtered (trips, resets, counter wraps), and
  over short runs in every topology with command steps that hold the filters' inputs at the
  D/A's rails.
- The exported header of a tuned, verified filtered gantry replays its simulation, and an
  edited filter constant fails the digest; a ``/1`` export is refused in one line.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import control
import numpy as np
import pytest
import scipy.signal
from c_build import needs_cc
from filtered_configs import ROOT, filter_tables, with_filters
from test_c_gantry import (
    _assert_same,
    _c_run,
    _consts,
    _expected,
    _long_scenario,
    _short_scenario,
    _trip_events,
    build_lib,
    checker,
    write_sources,
)
from test_c_gantry_export import BUILD_FILES, _build

from servotune.analysis.margins import GainSet, loop_model, margin_grid
from servotune.arch.gantry.config import TOPOLOGIES, GantryConfig
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.margins import gantry_margins
from servotune.arch.gantry.run import compare_topologies, run_gantry
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.arch.gantry.tuning import tune_gantry, write_gantry_tuning
from servotune.arch.gantry.verify import load_gantry_for_export, verify_gantry_files
from servotune.errors import ConfigError, ExportError
from servotune.export import c as c_export
from servotune.export.formats import FORMATS
from servotune.export.gantry import check_gantry_tables
from servotune.export.gantry_layout import GANTRY_LAYOUT_FIELDS
from servotune.report.text import format_comparison

# the example gantry's drives with output filters: a notch and a low-pass on the master, a
# notch on the slave (well inside the 500 Hz Nyquist frequency of the 1 ms bus cycle)
FILTERS = {
    "master": [
        {"kind": "notch", "center_hz": 40.0, "width_hz": 12.0, "depth_db": -20.0},
        {"kind": "lowpass2", "corner_hz": 150.0, "damping": 0.7},
    ],
    "slave": [{"kind": "notch", "center_hz": 55.0, "width_hz": 15.0, "depth_db": -15.0}],
}


def write_filtered_gantry(d: Path, tables: str | None = None) -> Path:
    """``plants/gantry.toml`` with the filter tables (:data:`FILTERS`, or ``tables``) in ``d``."""
    return with_filters("gantry.toml", d, filter_tables(FILTERS) if tables is None else tables)


@pytest.fixture(scope="module")
def filtered(tmp_path_factory) -> GantryConfig:
    d = tmp_path_factory.mktemp("gantry_filtered")
    return resolve_gains(load_gantry(write_filtered_gantry(d)))


# --- the config -------------------------------------------------------------------------------


def test_the_config_realises_each_drives_filters_at_the_bus_cycle(filtered) -> None:
    """Two sections on the master, one on the slave, in file order, quantised at the 1 ms bus
    cycle: the realised notch's response at its centre is its depth (within the ±1 dB the
    realisation promises), computed from the integers with scipy."""
    m, s = filtered.drive_filters("master"), filtered.drive_filters("slave")
    assert len(m) == 2 and len(s) == 1
    for sec, centre, depth in ((m[0], 40.0, -20.0), (s[0], 55.0, -15.0)):
        b, a = sec.ba()
        _, h = scipy.signal.freqz(b, a, worN=[centre], fs=1.0 / filtered.bus.cycle_s)
        assert abs(20 * np.log10(abs(h[0])) - depth) <= 1.0
    for ctl, secs in zip(filtered.controllers(), (m, s), strict=True):
        assert ctl.filters == secs


def test_a_filter_the_bus_cycle_cannot_realise_is_one_config_error(tmp_path: Path) -> None:
    bad = filter_tables(FILTERS).replace("center_hz = 55.0", "center_hz = 600.0")  # > 500 Hz
    with pytest.raises(ConfigError, match=r"axis\.slave\.filters\[0\].*center_hz") as exc:
        load_gantry(write_filtered_gantry(tmp_path, bad))
    assert "\n" not in str(exc.value)
    five = filter_tables({"master": FILTERS["master"] * 2 + FILTERS["master"][:1]})  # 5
    with pytest.raises(ConfigError, match=r"axis\.master\.filters must be an array of at most 4"):
        load_gantry(write_filtered_gantry(tmp_path, five))


# --- margins ----------------------------------------------------------------------------------


def test_drive_margins_take_the_filters_rebuilt_independently(filtered) -> None:
    """Each drive's nominal loop margins as ``gantry_margins`` gives them equal python-control's
    margins of (the loop without filters) x (the realised sections' ``freqz``), on the same grid;
    and the filters cost gain margin (the loop without them has more)."""
    dt = filtered.bus.cycle_s
    figures = {
        m.axis: m
        for m in gantry_margins(filtered, loops=("master", "slave"))
        if m.plant == "nominal"
    }
    for side in ("master", "slave"):
        ax = getattr(filtered, side)
        g = GainSet(ax.gains.kp, ax.gains.ki * dt)
        lag = filtered.bus.compute_s + ax.plant.delay_s
        bare = loop_model(ax.plant, g, period_s=dt, lag_s=lag, lsb_volts=filtered.rig.dac.lsb_v)
        w = margin_grid(ax.plant, dt)
        resp = bare.frequency_response(w).complex.reshape(-1)
        for sec in filtered.drive_filters(side):
            b, a = sec.ba()
            resp = resp * scipy.signal.freqz(b, a, worN=w * dt)[1]
        gm, pm = control.stability_margins(control.frd(resp, w, dt))[:2]
        got = figures[side]
        assert got.phase_margin_deg == pytest.approx(pm, abs=0.05), side
        assert got.gain_margin_db == pytest.approx(20 * np.log10(gm), abs=0.05), side
        gm0 = control.stability_margins(bare.frequency_response(w))[0]
        assert 20 * np.log10(gm0) > got.gain_margin_db + 3.0, side


# --- the C runtime ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    """The harness of ``test_c_gantry.py`` built again (its fixture is module-scoped there)."""
    return build_lib(write_sources(tmp_path_factory.mktemp("c_gantry_filters")))


@needs_cc
def test_golden_long_run_with_filters_c_equals_the_kernel(lib, filtered) -> None:
    """The 110,000-cycle golden run (moves, load pulses that trip the monitor, resets, the
    master's counter wrapping) with both drives filtered: C == kernel at every cycle, with the
    filters in the layout (``master.n_filters`` 2, ``slave.n_filters`` 1) and changing what the
    drives do (the codes differ from the unfiltered drives' on most moving cycles)."""
    cfg = replace(filtered, master=replace(filtered.master, counter_init=2**24 - 60_000))
    cmd, load, resets = _long_scenario(cfg)
    tr = run_gantry(cfg, cmd, load, resets=resets)
    assert tr.command.size >= 100_000 and len(_trip_events(tr.sync_level, resets)) >= 4
    consts = _consts(cfg, "listening")
    at = {name: i for i, name in enumerate(GANTRY_LAYOUT_FIELDS)}
    assert consts[at["master.n_filters"]] == 2 and consts[at["slave.n_filters"]] == 1
    assert lib.h_check(consts.ctypes.data) == 0
    _assert_same(_c_run(lib, consts, tr), _expected(tr), "long run, filtered")
    bare = resolve_gains(
        replace(cfg, master=replace(cfg.master, filters=()), slave=replace(cfg.slave, filters=()))
    )
    moving = np.flatnonzero(np.diff(cmd, prepend=cmd[0]) != 0)
    other = run_gantry(bare, cmd, load, resets=resets).code
    assert np.mean(np.any(other[moving] != tr.code[moving], axis=1)) > 0.5


@needs_cc
def test_short_runs_every_topology_filters_at_the_rails(lib, filtered) -> None:
    """20,000 cycles in every topology with a command step of 20,000 counts and back at rest
    (the PI's output past the D/A's range: the filters' input held at each rail, both drives'
    codes at 0 and at 4095, inside the following-error limit), the load pulses and resets of
    the short golden runs, the sync monitor off (its trip would stop the drives before the
    step back): C == kernel at every cycle."""
    cfg = replace(filtered, sync=replace(filtered.sync, warn_counts=0, trip_counts=0))
    cmd, load, resets = _short_scenario()
    cmd = cmd.copy()
    cmd[5_900:] += 20_000
    cmd[6_300:] -= 20_000
    code_max = cfg.rig.dac.code_max
    for topo in TOPOLOGIES:
        tr = run_gantry(cfg, cmd, load, topology=topo, resets=resets)
        for a in (0, 1):
            assert tr.code[:, a].max() == code_max and tr.code[:, a].min() == 0, (topo, a)
        consts = _consts(cfg, topo)
        assert lib.h_check(consts.ctypes.data) == 0, topo
        _assert_same(_c_run(lib, consts, tr), _expected(tr), f"{topo}, filtered")


@needs_cc
def test_check_names_a_bad_filter_of_either_drive(lib, filtered) -> None:
    """``st_gantry_check`` code 10 for a drive's ``n_filters`` outside 0..4 or a section in use
    with a bad ``frac_bits`` or an unstable denominator (servotune_gantry.h)."""
    good = _consts(filtered, "listening")
    check = checker(lib, good)
    assert check() == 0
    f = good[GANTRY_LAYOUT_FIELDS.index("master.filter0.frac_bits")]
    for changes, code in (
        ({"master.n_filters": 5}, 110),
        ({"slave.n_filters": -1}, 210),
        ({"master.filter1.frac_bits": 0}, 110),
        ({"slave.filter0.frac_bits": 31}, 210),
        ({"master.filter0.a2": 2**f}, 110),  # |a2| = 1: a pole on the unit circle
        ({"slave.filter0.a1": 2 * 2**f}, 210),
    ):
        assert check(**{k.replace(".", "__"): v for k, v in changes.items()}) == code, changes
    # a slot past n_filters is not checked (it is hashed, zero in an exported header)
    assert check(slave__filter3__frac_bits=0) == 0


# --- the export -------------------------------------------------------------------------------

HARNESS = r"""
#include "servotune_gantry_consts.h"

static const st_gantry_consts_t consts = SERVOTUNE_GANTRY_INIT;

int h_check_digest(void) { return st_gantry_check_digest(&consts, st_gantry_consts_sha256); }
int h_check(void) { return st_gantry_check(&consts); }
int h_n_filters(int a) { return consts.drive[a].n_filters; }
"""


@pytest.fixture(scope="module")
def exported(tmp_path_factory, filtered):
    """The filtered gantry compared (``sync``'s text in ``sync.txt``), tuned, verified and
    exported as JSON and C (the calls the CLI makes, in process)."""
    d = tmp_path_factory.mktemp("gantry_filtered_export")
    cfg = write_filtered_gantry(d)
    (d / "sync.txt").write_text(format_comparison(compare_topologies(filtered)))
    write_gantry_tuning(tune_gantry(cfg), d / "g.json")
    result, _, _ = verify_gantry_files(
        d / "g.json", ROOT / "plants" / "gantry.spec.toml", montecarlo=4
    )
    assert result.passed, result.failures
    v = load_gantry_for_export(d / "g.json")
    FORMATS["json"].to_file(v.tuning, d / "tables.json", rig=v.config.rig, verification=v.record)
    c_export.to_file(v.tuning, d, rig=v.config.rig, verification=v.record)
    return d


@needs_cc
def test_the_exported_filtered_gantry_passes_its_checks_and_an_edit_fails(
    exported, tmp_path: Path
) -> None:
    """The tables carry each drive's sections (``servotune.gantry-tables/2``); the header
    compiled with the runtime holds them (2 and 1), passes ``st_gantry_check`` and its digest;
    one filter coefficient edited in the header fails the digest and nothing else."""
    doc = check_gantry_tables((exported / "tables.json").read_text())
    assert doc["schema"] == "servotune.gantry-tables/2"
    drives = doc["data"]["drives"]
    assert [len(x["controller"]["filters"]) for x in drives] == [2, 1]
    (exported / "harness.c").write_text(HARNESS)
    for name in BUILD_FILES:
        shutil.copy(exported / name, tmp_path / name)
    lib = _build(exported, "lib.so")
    assert [lib.h_n_filters(a) for a in (0, 1)] == [2, 1]
    assert lib.h_check() == 0 and lib.h_check_digest() == 0
    header = tmp_path / "servotune_gantry_consts.h"
    text = header.read_text()
    line = next(x for x in text.splitlines() if x.startswith("#define ST_SLAVE_FILT0_B1 "))
    value = int(re.search(r"-?\d+", line.split(maxsplit=2)[2]).group())  # 12 or INT32_C(-12)
    header.write_text(text.replace(line, f"#define ST_SLAVE_FILT0_B1 ({value + 1})"))
    edited = _build(tmp_path, "lib.so")
    assert edited.h_check() == 0  # still a stable section: only the digest tells
    assert edited.h_check_digest() != 0


def test_sync_names_each_drives_filters(exported) -> None:
    """``servotune sync`` states each drive's sections as designed, in order."""
    lines = (exported / "sync.txt").read_text().splitlines()
    master = next(x for x in lines if x.startswith("master drive's output filters: "))
    slave = next(x for x in lines if x.startswith("slave drive's output filters: "))
    assert master.index("notch (center_hz 40 Hz") < master.index("lowpass2 (corner_hz 150 Hz")
    assert "notch (center_hz 55 Hz, width_hz 15 Hz, depth_db -15 dB)" in slave


def test_an_old_gantry_export_is_one_line(exported, tmp_path: Path) -> None:
    """A ``servotune.gantry-tables/1`` file: ``check_gantry_tables`` and ``check-table`` say it
    was written by an older servotune, in one line, exit non-zero."""
    doc = json.loads((exported / "tables.json").read_text())
    doc["schema"] = "servotune.gantry-tables/1"
    old = tmp_path / "old.json"
    old.write_text(json.dumps(doc))
    with pytest.raises(ExportError, match="older servotune"):
        check_gantry_tables(old.read_text(), str(old))
    res = subprocess.run(
        [sys.executable, "-m", "servotune.cli", "check-table", str(old)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode != 0
    assert res.stderr.strip().count("\n") == 0 and "older servotune" in res.stderr
    assert "Traceback" not in res.stderr
