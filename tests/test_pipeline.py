"""The demo job (`make demo`): what it writes and that it is deterministic."""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from pathlib import Path

import pytest
from conftest import EXAMPLE_RIG
from products import DIGESTS, FLOATS, PEAKS, Rule, column_differences, differences, read_product

import servotune as st
import servotune.export
from servotune._version import __version__
from servotune.export.json import load_tables
from servotune.pipeline import run_demo


def test_demo_writes_its_products(tmp_path: Path) -> None:
    summary = run_demo(EXAMPLE_RIG, tmp_path, seed=0)
    for name in (
        "demo_summary.json",
        "lock_hold.png",
        "track.png",
        "track_log.csv",
        "fit_master.png",
        "fit_slave.png",
        "fitted-rig.toml",
        "tuning.json",
        "tuning.json.verify.json",
        "figure4.png",
        "figure4.json",
        "fuzzy.json",
        "c/servotune_tables.h",
        "c/servotune_rt.c",
        "report.html",
        "sync.json",
        "sync_load.png",
        "sync_mismatch.png",
        "linkage.json",
        "linkage_queues.png",
        "linkage_circle.png",
    ):
        assert (tmp_path / name).stat().st_size > 0, name
    # the whole chain: tuned on the fitted rig, verified on the example rig, exported
    assert summary["verification"]["passed"], summary["verification"]["failures"]
    assert load_tables(tmp_path / "fuzzy.json")["verified"] is True
    page = (tmp_path / "report.html").read_text()
    for section in (
        "Verification: PASSED",
        "Loops (Bode",
        "Query tables",
        "Margins of every loop",
        "(the tuning objective)",
        "Identification",
        "Figure 4",
        "Gantry with a listening slave",
        "Multi-CPU linkage",
    ):
        assert section in page, section
    assert summary["architectures"]["gantry"]["passed"]
    assert summary["architectures"]["linkage"]["passed"]
    assert json.loads((tmp_path / "sync.json").read_text())["schema"] == "servotune.sync/2"
    table = summary["comparison"]
    assert set(table) == {"pid", "pid_ff", "composite"}
    on_disk = json.loads((tmp_path / "demo_summary.json").read_text())
    assert on_disk["schema"] == "servotune.demo/2" and on_disk["preset"] == "quick"
    # Figure 4 on the quick preset (docs/decisions.md#9-the-demo-preset: one seed), judged on the
    # held-out scenarios
    fig4 = json.loads((tmp_path / "figure4.json").read_text())
    assert fig4["seeds"] == [0] and fig4["heldout_scenarios"] == ["track", "lock", "heldout"]
    assert fig4["budget"]["generations"] == 12 and fig4["pareto"] == []
    assert summary["figure4_statement"] == fig4["statement"]
    for name, hold in summary["lock_hold"].items():
        lo, hi = hold["observed_counts"]
        # ±1 pulse (docs/runtime.md#position-lock-and-its-holding-band)
        assert -4 <= lo <= hi <= 4, name
    for name, ident in summary["identification"].items():
        for key, err in ident["relative_error"].items():
            assert abs(err) < 0.02, (name, key, err)
    fitted = st.load_rig(tmp_path / "fitted-rig.toml")
    assert fitted.axis("slave").plant.tau_s == pytest.approx(
        summary["identification"]["slave"]["params"]["tau_s"], rel=1e-6
    )
    first = (tmp_path / "demo_summary.json").read_bytes()
    first_tables = (tmp_path / "fuzzy.json").read_bytes()
    run_demo(EXAMPLE_RIG, tmp_path, seed=0)
    # same input + seed -> same bytes, on one machine and lock
    assert (tmp_path / "demo_summary.json").read_bytes() == first
    assert (tmp_path / "fuzzy.json").read_bytes() == first_tables
    # across machines: the reference products within their tolerances (tests/products.py)
    found = demo_differences(tmp_path)
    assert not found, "the single-rig demo products changed:\n" + "\n".join(found[:20])


REFERENCE = Path(__file__).resolve().parent / "golden" / "demo"
"""The single-rig products of ``run_demo(EXAMPLE_RIG, out, seed=0)``, with the output folder
written as ``<out>`` and the package version as ``<version>``. Regenerate only on purpose, with
``python tests/test_pipeline.py`` (it runs the demo and rewrites this folder), and say in the
commit what changed and why."""

COMPARED = ("demo_summary.json", "tuning.json", "figure4.json", "fuzzy.json", "fitted-rig.toml",
            "track_log.csv")  # fmt: skip
"""Floating-point products: compared field by field with the rules below."""

RUNTIME = Path(servotune.export.__file__).resolve().parent / "runtime"
PINNED = {
    "c/servotune_rt.c": RUNTIME / "servotune_rt.c",
    "c/servotune_rt.h": RUNTIME / "servotune_rt.h",
    "c/servotune_filter.h": RUNTIME / "servotune_filter.h",
}
"""Machine-independent products (the runtime's C sources: text, no arithmetic): byte for byte
the package's runtime sources, which the C export copies unchanged."""

TABLE_CODES = Rule(
    pattern="/data/*",
    int_abs=1,
    reason="the tables' integers are the tuning's float gains quantised (q·2^-f, rounded half "
    "away from zero): a gain within 1e-13 of a rounding edge may land on the neighbouring "
    "integer on another machine; the export of a given tuning is pinned bit for bit in "
    "tests/export/test_json_export.py",
)
TABLE_CRC = Rule(pattern="*crc32", skip=True, reason="a CRC of the table codes above")
RULES = {
    "fuzzy.json": (DIGESTS, TABLE_CRC, TABLE_CODES, PEAKS, FLOATS),
    "default": (DIGESTS, PEAKS, FLOATS),
}
LOG_CODES = {"int_abs": 1, "max_fraction": 1e-3}
"""A simulated log's counters and D/A codes: the plant's float state crossing an encoder edge
within a few ulps latches a count one off on a machine whose libm rounds its last bit
otherwise; the loop answers it with at most one D/A code for a tick, so a sample within 1 and
at most 0.1 % of the samples different at all."""


def _products(out: Path, names: tuple[str, ...]) -> dict[str, object]:
    replace = {str(out): "<out>", __version__: "<version>"}
    return {name: read_product(out / name, replace) for name in names}


def demo_differences(out: Path) -> list[str]:
    """Every difference of the demo's products in ``out`` from the reference beyond the rules."""
    found = []
    want, got = _products(REFERENCE, COMPARED), _products(out, COMPARED)
    for name in COMPARED:
        if name.endswith(".csv"):
            rows = column_differences(want[name], got[name], **LOG_CODES)
            rows += differences(want[name]["meta"], got[name]["meta"], ())
        else:
            rows = differences(want[name], got[name], RULES.get(name, RULES["default"]))
        found += [f"{name}: {row}" for row in rows]
    for name, source in PINNED.items():
        if (out / name).read_bytes() != source.read_bytes():
            found.append(f"{name}: its bytes differ from the reference")
    # the header compiles in the tables of exactly this tuning
    tuning_sha = hashlib.sha256((out / "tuning.json").read_bytes()).hexdigest()
    if f"tuning sha256: {tuning_sha}" not in (out / "c" / "servotune_tables.h").read_text():
        found.append("c/servotune_tables.h: does not name the tuning's sha256")
    return found


def _reference_copy(tmp_path: Path) -> Path:
    out = tmp_path / "out"
    shutil.copytree(REFERENCE, out)
    (out / "c").mkdir()
    for name, source in PINNED.items():
        shutil.copyfile(source, out / name)
    for path in out.rglob("*"):
        if path.is_file():
            text = path.read_text(encoding="utf-8")
            path.write_text(text.replace("<out>", str(out)).replace("<version>", __version__))
    _bind_header(out)
    return out


def _bind_header(out: Path) -> None:
    """The header of the reference's tuning, as export-table would name it."""
    (out / "c" / "servotune_tables.h").write_text(
        "tuning sha256: " + hashlib.sha256((out / "tuning.json").read_bytes()).hexdigest()
    )


def _edit_json(path: Path, edit) -> None:
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    _bind_header(path.parent)


def test_the_demo_comparison_passes_the_reference_and_fails_a_changed_product(tmp_path) -> None:
    # the check the demo test runs, on the reference itself: nothing differs
    out = _reference_copy(tmp_path)
    assert demo_differences(out) == []
    kp = json.loads((out / "tuning.json").read_text())["design"]["master"]["pi"]["kp"]

    def set_kp(value: float) -> None:
        _edit_json(out / "tuning.json", lambda d: d["design"]["master"]["pi"].update(kp=value))

    set_kp(kp * (1 + 1e-9))  # within 1e-6 relative: another machine's last bits
    assert demo_differences(out) == []
    set_kp(kp * (1 + 1e-4))  # beyond: a changed tuner
    found = demo_differences(out)
    assert len(found) == 1 and found[0].startswith("tuning.json: /design/master/pi/kp: "), found
    set_kp(kp)

    def shift_code(by: int) -> None:
        _edit_json(
            out / "fuzzy.json",
            lambda d: d["data"]["axes"][0]["lock_gain"].update(
                q=d["data"]["axes"][0]["lock_gain"]["q"] + by
            ),
        )

    shift_code(1)  # one integer off: a gain rounded the other way
    assert demo_differences(out) == []
    shift_code(1)  # two off: not a rounding edge
    assert [f for f in demo_differences(out) if "lock_gain/q" in f], demo_differences(out)
    shift_code(-2)
    # a statement read from the numbers: its text is compared exactly
    _edit_json(out / "figure4.json", lambda d: d["statement"].__setitem__(0, "PID is lowest"))
    assert [f for f in demo_differences(out) if f.startswith("figure4.json: /statement[0]")]


def test_the_demo_comparison_fails_a_changed_log_or_runtime(tmp_path) -> None:
    out = _reference_copy(tmp_path)
    log = out / "track_log.csv"
    lines = log.read_text().splitlines()
    body = [i for i, ln in enumerate(lines) if ln and ln[0].isdigit()]
    header = next(ln for ln in lines if ln.startswith("tick,")).split(",")
    col = header.index("master.dac_code")

    def set_code(row: int, delta: int) -> None:
        cells = lines[body[row]].split(",")
        cells[col] = str(int(cells[col]) + delta)
        lines[body[row]] = ",".join(cells)
        log.write_text("\n".join(lines) + "\n")

    set_code(100, 1)  # one sample one code off: a count latched the other way
    assert demo_differences(out) == []
    set_code(100, 2)  # three codes off
    assert [f for f in demo_differences(out) if "master.dac_code" in f]
    set_code(100, -3)
    for row in range(0, 40, 2):  # 20 samples (more than 0.1 %) one code off
        set_code(row, 1)
    assert [f for f in demo_differences(out) if "samples differ" in f]
    _ = [set_code(row, -1) for row in range(0, 40, 2)]
    assert demo_differences(out) == []
    with (out / "c" / "servotune_rt.c").open("a") as f:
        f.write("\n")
    assert demo_differences(out) == ["c/servotune_rt.c: its bytes differ from the reference"]


def test_demo_needs_an_existing_directory(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        run_demo(EXAMPLE_RIG, tmp_path / "missing")


OTHER_MACHINE = {
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",  # numpy 2.4's AVX-512 groups
    "NUMBA_CPU_NAME": "haswell",
    "OPENBLAS_CORETYPE": "Haswell",
}
"""What a machine chooses by its processor, chosen otherwise: numpy's SIMD kernels without
AVX-512, numba's code for an AVX2 processor, another OpenBLAS kernel (docs/reproducibility.md)."""


@pytest.mark.slow
def test_demo_on_an_emulated_other_machine(tmp_path: Path) -> None:
    """The demo where numpy, numba and OpenBLAS round otherwise: the reference's tolerances hold
    (about 7 minutes: numba compiles every kernel for the other processor)."""
    import os
    import subprocess

    from numpy._core._multiarray_umath import __cpu_features__

    if not __cpu_features__.get("AVX512F"):
        pytest.skip("this machine has no AVX-512 to turn off: it is already the other machine")
    out = tmp_path / "out"
    out.mkdir()
    env = {**os.environ, **OTHER_MACHINE, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    code = (
        "import sys; from pathlib import Path; from servotune.pipeline import run_demo; "
        "run_demo(Path(sys.argv[1]), Path(sys.argv[2]), seed=0)"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, str(EXAMPLE_RIG), str(out)],
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    found = demo_differences(out)
    assert not found, "\n".join(found[:20])


def _regenerate(reference: Path = REFERENCE) -> None:
    """Run the demo and store its products as the reference (see :data:`REFERENCE`)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        run_demo(EXAMPLE_RIG, out, seed=0)
        for name in COMPARED:
            text = (out / name).read_text(encoding="utf-8")
            text = text.replace(str(out), "<out>").replace(__version__, "<version>")
            (reference / name).parent.mkdir(parents=True, exist_ok=True)
            (reference / name).write_text(text, encoding="utf-8")


if __name__ == "__main__":
    _regenerate()
    print(f"wrote the demo reference to {REFERENCE}", file=sys.stderr)
