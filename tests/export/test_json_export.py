"""The tables export (servotune.export.json) and the C header, against golden files.

The golden files in ``golden/`` are exports of a fixed tuning built here from fixed gains and
closed-form tables (no optimiser), so the bytes depend only on the exporter. They are rewritten
only on request: ``SERVOTUNE_REGEN_GOLDEN=1 pytest tests/export``. The tool version is part of
the provenance, so a version bump needs a regeneration too.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from servotune.errors import DigestError, ExportError
from servotune.export.c import RUNTIME_FILES, runtime_source
from servotune.export.c import to_file as write_c
from servotune.export.c import to_string as c_header_to_string
from servotune.export.json import (
    SCHEMA,
    constants_crc32,
    controllers_from_tables,
    load_tables,
    table_crc32,
)
from servotune.export.json import to_file as write_tables
from servotune.export.json import to_string as tables_to_string
from servotune.hw import timer
from servotune.laws.axis import AxisController
from servotune.laws.filters import SectionQ
from servotune.laws.fuzzy_pid import FuzzyPIDGains
from servotune.laws.pi import PIGains
from servotune.rig import EXAMPLE_RIG_PATH, load_rig
from servotune.tuning import Tuning

GOLDEN = Path(__file__).resolve().parent / "golden"
REGEN = os.environ.get("SERVOTUNE_REGEN_GOLDEN") == "1"

SUMMARY = {
    "passed": True,
    "scenarios": {"sync": {"max_sync_err_counts": 41, "saturated_pct": 0.5}},
    "spec_sha256": hashlib.sha256(b"golden spec").hexdigest(),
}


def fixed_tuning() -> Tuning:
    """A deterministic two-axis tuning of the example rig's hardware: master PI, slave
    fuzzy-PID + feedforward with 7 x 7 tables (n = 3) from closed-form rules."""
    divisor = int(timer.divisor(0.004))
    period_s = float(timer.achieved_period_s(divisor))
    n = 3
    lv = np.arange(-n, n + 1)
    e, ec = np.meshgrid(lv, lv, indexing="ij")  # row E, column EC
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
    master = PIGains(kp=0.35, ki=1.4)
    # the example rig: lock gain 0.4 codes/count; following-error limit one revolution (12288
    # counts)
    ctls = tuple(
        AxisController.from_gains(
            lock_gain_codes_per_count=0.4,
            task_gains=g,
            period_s=period_s,
            following_error_limit_counts=12288,
        )
        for g in (master, slave)
    )
    return Tuning(
        rig_name="pc-dual-servo",
        rig_sha256=hashlib.sha256(b"golden rig").hexdigest(),
        period_s=period_s,
        timer_divisor=divisor,
        axis_names=("master", "slave"),
        roles=("master", "slave"),
        controllers=ctls,
        design={"note": "golden tuning of tests/export"},
        provenance={"seed": 0, "tool": "servotune"},
    )


@pytest.fixture(scope="module")
def tuning() -> Tuning:
    return fixed_tuning()


def _golden(name: str, text: str) -> None:
    path = GOLDEN / name
    if REGEN:
        path.write_bytes(text.encode("utf-8"))
    assert path.exists(), f"{path} missing: regenerate with SERVOTUNE_REGEN_GOLDEN=1"
    assert path.read_bytes() == text.encode("utf-8"), (
        f"{name} differs from the golden file; if the change is intended, regenerate with "
        "SERVOTUNE_REGEN_GOLDEN=1"
    )


# --- golden files and determinism -------------------------------------------------------------


def test_json_export_matches_golden_file(tuning: Tuning) -> None:
    _golden("tables.json", tables_to_string(tuning, verification=SUMMARY))


def test_c_header_matches_golden_file(tuning: Tuning) -> None:
    _golden("servotune_tables.h", c_header_to_string(tuning, verification=SUMMARY))


def test_export_is_deterministic_and_written_atomically(tuning: Tuning, tmp_path) -> None:
    a = tables_to_string(tuning, verification=SUMMARY)
    b = tables_to_string(fixed_tuning(), verification=dict(SUMMARY))
    assert a == b and a.endswith("}\n") and "\r" not in a
    path = tmp_path / "fuzzy.json"
    write_tables(tuning, path, verification=SUMMARY)
    assert path.read_bytes() == a.encode()
    assert [p.name for p in tmp_path.iterdir()] == ["fuzzy.json"]  # no temp file left over
    json.loads(a)  # plain JSON


def test_export_holds_the_tuning_exactly(tuning: Tuning) -> None:
    doc = load_tables(tables_to_string(tuning, verification=SUMMARY))
    assert doc["schema"] == SCHEMA and doc["verified"] is True
    # no re-quantising: the controllers read back equal the tuning's, (q, f) for (q, f)
    assert controllers_from_tables(doc) == tuning.controllers
    slave = doc["data"]["axes"][1]
    t = tuning.controllers[1].task
    assert slave["task"]["kp"] == {"q": t.kp.q, "f": t.kp.f}
    for name, (q, f_t) in zip(("kp", "ki", "kd", "k1"), t.tables, strict=True):
        tab = slave["task"]["tables"][name]
        assert tab["q"] == q.tolist() and tab["f"] == f_t and tab["n"] == 3
    master = doc["data"]["axes"][0]
    assert master["law"] == "pi" and master["ref_source"] == -1 and slave["ref_source"] == 0
    assert doc["data"]["timer_divisor"] == 4773  # docs/runtime.md#timer-and-achieved-period
    prov = doc["provenance"]
    assert prov["verification"] == SUMMARY and prov["spec_sha256"] == SUMMARY["spec_sha256"]
    assert len(prov["tuning_sha256"]) == 64 and prov["rig"]["name"] == "pc-dual-servo"


def test_table_crc_is_zlib_crc32_of_the_documented_bytes() -> None:
    q = np.array([[0, 1, -2], [32767, -32768, 5], [6, 7, -8]])
    # docs/runtime.md#integrity-crcs-and-the-c-layout: little-endian int16 n, int16 f, then the
    # entries row-major
    raw = struct.pack("<hh", 1, 9) + struct.pack("<9h", *q.reshape(-1).tolist())
    assert table_crc32(q, 9) == zlib.crc32(raw)


FILTER_KEYS = ("b0", "b1", "b2", "a1", "a2", "frac_bits")
SLAVE_FILTERS = (  # two stable sections, integers chosen by hand
    SectionQ(b0=3835, b1=-6694, b2=3804, a1=-6695, a2=3544, frac_bits=12),
    SectionQ(b0=901, b1=1803, b2=901, a1=-1611, a2=1120, frac_bits=12),
)


@pytest.mark.parametrize("filtered", [False, True], ids=["unfiltered", "slave-filtered"])
def test_constants_crc_follows_the_documented_order(tuning: Tuning, filtered: bool) -> None:
    if filtered:
        slave = dataclasses.replace(tuning.controllers[1], filters=SLAVE_FILTERS)
        tuning = dataclasses.replace(tuning, controllers=(tuning.controllers[0], slave))
    doc = json.loads(tables_to_string(tuning, verification=SUMMARY))
    assert [len(ax["filters"]) for ax in doc["data"]["axes"]] == [0, 2 if filtered else 0]
    data = doc["data"]
    pairs = [(len(data["axes"]), 0), (data["timer_divisor"], 0)]
    for ax in data["axes"]:
        task = ax["task"] or {}

        def fx(key: str, task: dict = task) -> tuple[int, int]:
            c = task.get(key)
            return (c["q"], c["f"]) if c else (0, 0)

        pairs += [
            ({"none": 0, "pi": 1, "fuzzy_pid": 2}[ax["law"]], 0),
            (ax["lock_gain"]["q"], ax["lock_gain"]["f"]),
            fx("kp"),
            fx("ki_t"),
            (ax["following_error_limit_counts"], 0),
            (data["counter_bits"], 0),
            (data["dac"]["zero_code"], 0),
            (data["dac"]["code_max"], 0),
            fx("kd_t"),
            fx("k1_t"),
            fx("ke"),
            fx("kec"),
            (task.get("n", 0), 0),
            (ax["ref_source"], 0),
            (len(ax["filters"]), 0),  # docs/runtime.md#filters-in-the-law: 4 slots of 5 pairs
        ]
        for k in range(4):
            sec = ax["filters"][k] if k < len(ax["filters"]) else dict.fromkeys(FILTER_KEYS, 0)
            pairs += [(sec[w], sec["frac_bits"]) for w in ("b0", "b1", "b2", "a1", "a2")]
    raw = b"".join(struct.pack("<ih", q, f) for q, f in pairs)
    assert data["constants_crc32"] == zlib.crc32(raw) == constants_crc32(tuning)


# --- what load_tables rejects -----------------------------------------------------------------


def _doc(tuning: Tuning) -> dict:
    return json.loads(tables_to_string(tuning, verification=SUMMARY))


def _reject(doc: dict, *fragments: str) -> None:
    with pytest.raises(ExportError) as info:
        load_tables(json.dumps(doc))
    msg = str(info.value)
    assert "\n" not in msg
    for frag in fragments:
        assert frag in msg, msg


def test_a_changed_table_entry_is_rejected(tuning: Tuning) -> None:
    doc = _doc(tuning)
    doc["data"]["axes"][1]["task"]["tables"]["kd"]["q"][2][4] += 1
    _reject(doc, "axes[1] (slave) table kd", "CRC mismatch")


def test_a_changed_table_fraction_is_rejected(tuning: Tuning) -> None:
    doc = _doc(tuning)
    doc["data"]["axes"][1]["task"]["tables"]["ki"]["f"] -= 1
    _reject(doc, "table ki", "CRC mismatch")


def test_a_changed_constant_is_rejected(tuning: Tuning) -> None:
    doc = _doc(tuning)
    doc["data"]["axes"][0]["task"]["kp"]["q"] += 1
    _reject(doc, "constants_crc32", "CRC mismatch")
    doc = _doc(tuning)
    doc["data"]["axes"][1]["following_error_limit_counts"] = 99
    _reject(doc, "constants_crc32")


def test_an_entry_outside_int16_is_rejected(tuning: Tuning) -> None:
    doc = _doc(tuning)
    doc["data"]["axes"][1]["task"]["tables"]["kp"]["q"][0][1] = 40000
    _reject(doc, "table kp", "q[0][1] = 40000 is outside int16")


def test_wrong_schema_and_malformed_documents_are_rejected(tuning: Tuning, tmp_path) -> None:
    doc = _doc(tuning)
    doc["schema"] = "servotune.tables/5"
    _reject(doc, "schema must be 'servotune.tables/4'", "servotune.tables/5")
    # docs/decisions.md#17-file-versions
    for old in ("servotune.tables/1", "servotune.tables/2", "servotune.tables/3"):
        doc["schema"] = old
        _reject(doc, old, "written by an older servotune", "export the tuning again")
    doc = _doc(tuning)
    del doc["data"]["axes"][1]["task"]["tables"]["k1"]
    _reject(doc, "missing the field 'k1'")
    doc = _doc(tuning)
    doc["data"]["rig_nmae"] = "x"  # docs/decisions.md#1-unknown-keys
    _reject(doc, "unknown key data.rig_nmae", "did you mean 'rig_name'?")
    doc = _doc(tuning)
    doc["data"]["axes"][1]["task"]["tables"]["kp"]["q"][3].pop()
    _reject(doc, "table kp", "row 3 must have 7 entries")
    doc = _doc(tuning)
    doc["data"]["axes"][1]["ref_source"] = 1
    _reject(doc, "axes[1] (slave).ref_source must be -1 or another axis's index, got 1")
    with pytest.raises(ExportError, match="cannot write"):
        write_tables(tuning, tmp_path / "missing" / "t.json", verification=SUMMARY)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ExportError, match=r"bad\.json: not JSON"):
        load_tables(bad)
    with pytest.raises(ExportError, match="no such file"):
        load_tables(tmp_path / "missing.json")


def test_load_tables_reads_a_path(tuning: Tuning, tmp_path) -> None:
    path = tmp_path / "t.json"
    write_tables(tuning, path, verification=SUMMARY)
    assert load_tables(path) == load_tables(str(path)) == _doc(tuning)


# --- verification marker, rig checks, C files --------------------------------------------------


def test_export_needs_a_passing_verification_unless_marked_unverified(tuning: Tuning) -> None:
    with pytest.raises(ExportError, match="no verification summary"):
        tables_to_string(tuning)
    with pytest.raises(ExportError, match="verification failed"):
        tables_to_string(tuning, verification={"passed": False})
    with pytest.raises(ExportError, match="verification failed"):
        tables_to_string(tuning, verification={"passed": np.False_})
    doc = load_tables(tables_to_string(tuning, unverified=True))
    assert doc["verified"] is False and doc["provenance"]["verification"] is None
    # the data and its CRCs do not depend on the marker or the provenance
    assert doc["data"] == _doc(tuning)["data"]
    header = c_header_to_string(tuning, unverified=True)
    assert "#define ST_TABLES_VERIFIED 0" in header and "verified: NO" in header


def test_a_verification_object_and_the_spec_hash(tuning: Tuning) -> None:
    class Result:  # like servotune.verify.Verification: a to_dict() with the spec inside
        def to_dict(self) -> dict:
            return {"passed": True, "spec": {"name": "sync", "max_sync_err_counts": 50}}

    doc = json.loads(tables_to_string(tuning, verification=Result()))
    prov = doc["provenance"]
    assert prov["verification"] == Result().to_dict()
    canon = json.dumps(Result().to_dict()["spec"], sort_keys=True, separators=(",", ":"))
    assert prov["spec_sha256"] == hashlib.sha256(canon.encode()).hexdigest()
    header = c_header_to_string(tuning, verification=Result())
    assert f" * verification: passed (spec sha256 {prov['spec_sha256']})" in header


def test_the_rig_is_checked_and_gives_the_hardware(tuning: Tuning) -> None:
    rig = load_rig(EXAMPLE_RIG_PATH)
    doc = json.loads(tables_to_string(tuning, rig=rig, verification=SUMMARY))
    assert doc["data"]["counter_bits"] == 24
    assert doc["data"]["dac"] == {
        "bits": 12,
        "code_max": 4095,
        "range_v": [-10.0, 10.0],
        "zero_code": 2048,
    }
    other = dataclasses.replace(rig, axes=rig.axes[:1])
    with pytest.raises(ExportError, match="tuning is for axes"):
        tables_to_string(tuning, rig=other, verification=SUMMARY)


def test_write_c_writes_header_and_runtime(tuning: Tuning, tmp_path) -> None:
    files = write_c(tuning, tmp_path, verification=SUMMARY)
    assert sorted(p.name for p in files) == sorted(["servotune_tables.h", *RUNTIME_FILES])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in files)
    assert (tmp_path / "servotune_tables.h").read_text() == c_header_to_string(
        tuning, verification=SUMMARY
    )
    for name in RUNTIME_FILES:
        assert (tmp_path / name).read_text() == runtime_source(name)
    header = (tmp_path / "servotune_tables.h").read_text()
    doc = _doc(tuning)
    assert f"#define ST_CONSTS_CRC32 UINT32_C(0x{doc['data']['constants_crc32']:08x})" in header
    kd = doc["data"]["axes"][1]["task"]["tables"]["kd"]
    assert f"#define ST_SLAVE_TAB_KD_CRC32 UINT32_C(0x{kd['crc32']:08x})" in header


def test_write_c_writes_nothing_when_the_export_fails(tuning: Tuning, tmp_path) -> None:
    with pytest.raises(ExportError, match="no verification summary"):
        write_c(tuning, tmp_path)
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "a-file").write_text("x\n")
    with pytest.raises(ExportError, match="not a directory"):
        write_c(tuning, tmp_path / "a-file", verification=SUMMARY)
    # a missing directory is created with the files in it (written as a whole,
    # tests/io/test_whole_outputs.py), its missing parents too
    written = write_c(tuning, tmp_path / "new" / "c", verification=SUMMARY)
    assert sorted(p.name for p in (tmp_path / "new" / "c").iterdir()) == sorted(
        p.name for p in written
    )


# --- tampering: the document's digest -------------------------------------------------------


def _redigest(doc: dict) -> dict:
    """The document's digest recomputed independently (docs/decisions.md#3-digests: canonical JSON,
    sorted keys, no whitespace, UTF-8, the digest field left out), as a careful tamperer would."""
    body = {k: v for k, v in doc.items() if k != "sha256"}
    canon = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return {**body, "sha256": hashlib.sha256(canon.encode("utf-8")).hexdigest()}


def _table_crc(q: list, f: int) -> int:
    """The table CRC (docs/runtime.md#integrity-crcs-and-the-c-layout), built here with struct and
    zlib (not the exporter's function)."""
    n = (len(q) - 1) // 2
    raw = struct.pack("<hh", n, f) + b"".join(struct.pack("<h", v) for row in q for v in row)
    return zlib.crc32(raw)


def _leaves(x: object, path: tuple = ()) -> list[tuple]:
    """Every scalar leaf of a JSON document, with its path."""
    if isinstance(x, dict):
        return [leaf for k, v in x.items() for leaf in _leaves(v, (*path, k))]
    if isinstance(x, list):
        return [leaf for i, v in enumerate(x) for leaf in _leaves(v, (*path, i))]
    return [path]


def _changed(v: object) -> object:
    if isinstance(v, bool):
        return not v
    if isinstance(v, int):
        return v + 1
    if isinstance(v, float):
        return v * 1.001 + 1e-9
    if isinstance(v, str):
        return v + "x"
    return 0


def test_the_digest_matches_canonical_json_computed_independently(tuning: Tuning) -> None:
    doc = _doc(tuning)
    assert doc["schema"] == "servotune.tables/4"
    assert _redigest(doc)["sha256"] == doc["sha256"]


def test_every_edited_field_is_refused(tuning: Tuning, tmp_path) -> None:
    """Each scalar of the document changed alone (the verified flag, period_s, range_v, rig_name,
    provenance …, and every table entry): load_tables and check-table refuse it."""
    from servotune.cli import main

    base = _doc(tuning)
    leaves = [p for p in _leaves(base) if p != ("sha256",)]
    entries = sum(
        (2 * a["task"]["n"] + 1) ** 2 * 4 for a in base["data"]["axes"] if a["law"] == "fuzzy_pid"
    )
    assert entries > 0 and len(leaves) > entries + 20  # every table entry is among the leaves
    named = {
        ("verified",),
        ("data", "period_s"),
        ("data", "dac", "range_v", 0),
        ("data", "rig_name"),
        ("provenance", "tool_version"),
    }
    assert named <= set(leaves)
    for path in leaves:
        doc = copy.deepcopy(base)
        node = doc
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = _changed(node[path[-1]])
        with pytest.raises(ExportError):  # malformed (exit 3) or a digest mismatch (exit 1)
            load_tables(json.dumps(doc))
    # through the CLI, for the fields above: exit 1 (not the verified bytes: a
    # DigestError is a TrustError), one line, the digest named
    for path in sorted(named, key=str):
        doc = copy.deepcopy(base)
        node = doc
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = _changed(node[path[-1]])
        f = tmp_path / "edited.json"
        f.write_text(json.dumps(doc, indent=2))
        assert main(["check-table", str(f)]) == 1, path
    f.write_text(json.dumps(base, indent=2))
    assert main(["check-table", str(f)]) == 0


def test_a_table_with_its_own_crc_recomputed_is_refused(tuning: Tuning) -> None:
    base = _doc(tuning)
    for axis in base["data"]["axes"]:
        if axis["law"] != "fuzzy_pid":
            continue
        for name in ("kp", "ki", "kd", "k1"):
            doc = copy.deepcopy(base)
            tab = next(a for a in doc["data"]["axes"] if a["index"] == axis["index"])["task"][
                "tables"
            ][name]
            tab["q"][0][0] += 1 if tab["q"][0][0] < 32767 else -1
            tab["crc32"] = _table_crc(tab["q"], tab["f"])
            with pytest.raises(DigestError, match="sha256 does not match"):
                load_tables(json.dumps(doc))
            # and with the document digest recomputed too, the C-layout digest still refuses
            with pytest.raises(DigestError, match="c_layout_sha256 does not match"):
                load_tables(json.dumps(_redigest(doc)))


def test_an_edit_with_every_digest_recomputed_is_a_new_document(tuning: Tuning) -> None:
    """Threat model (docs/decisions.md#3-digests): accidents, not a tamperer holding the tool. A
    document whose every CRC and digest is recomputed is self-consistent; it is still not the
    verified one: its provenance digest no longer names the verification's tuning bytes."""
    doc = _doc(tuning)
    doc["verified"] = False
    assert load_tables(json.dumps(_redigest(doc)))["verified"] is False
