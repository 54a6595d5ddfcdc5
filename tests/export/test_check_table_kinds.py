"""``servotune check-table`` on every export kind ``export-table`` writes but the C files:
the single rig's tables (``servotune.tables/4``), the gantry tables
(``servotune.gantry-tables/2``), the linkage export (``servotune.linkage-export/1``), the
LinuxCNC HAL file and the HAL component. Each real export passes (exit 0); one number changed
in it is refused (exit 1, one ``refused:`` line); a schema check-table does not know is one line
naming the ones it knows (exit 3)."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import pytest

import servotune as st
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.tuning import tune_gantry
from servotune.arch.linkage import plan_linkage
from servotune.cli import main
from servotune.export import hal_component
from servotune.export.json import to_string as json_text
from servotune.export.linuxcnc import pid_hal_text

ROOT = Path(__file__).resolve().parents[2]


def _gantry() -> str:
    path = ROOT / "plants" / "gantry.toml"
    return json_text(tune_gantry(path), rig=load_gantry(path).rig, unverified=True)


def _linkage() -> str:
    return json_text(plan_linkage(ROOT / "plants" / "linkage-6axis.toml"), unverified=True)


KINDS: dict[str, tuple[str, Callable[..., str]]] = {
    "tables": ("json", lambda t, r: json_text(t, rig=r, unverified=True)),
    "gantry": ("json", lambda t, r: _gantry()),
    "linkage": ("json", lambda t, r: _linkage()),
    "hal": ("hal", lambda t, r: pid_hal_text(t, rig=r, unverified=True, position_scale=2000.0)),
    "comp": ("comp", lambda t, r: hal_component.to_string(t, rig=r, unverified=True)),
}


@pytest.fixture(scope="module")
def exports(quick_tuning: st.Tuning, rig: st.Rig, tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("check_kinds")
    out = {}
    for kind, (suffix, make) in KINDS.items():
        out[kind] = d / f"{kind}.{suffix}"
        out[kind].write_text(make(quick_tuning, rig), encoding="utf-8")
    return out


def _one_number_changed(text: str) -> str:
    """``text`` with the last digit of its last number outside a digest, CRC, schema, version
    or comment line changed."""
    lines = text.splitlines(keepends=True)
    for i in range(len(lines) - 1, -1, -1):
        line = lines[i]
        skip = ("sha256", "crc", "schema", "version")
        if any(w in line.lower() for w in skip) or line.lstrip().startswith(("#", "//")):
            continue
        m = list(re.finditer(r"(?<![\w.])\d+(?:\.\d+)?(?![\w.])", line))
        if m:
            end = m[-1].end() - 1  # its last digit, one up (9 to 0)
            lines[i] = line[:end] + str((int(line[end]) + 1) % 10) + line[end + 1 :]
            return "".join(lines)
    raise AssertionError("no number to change")


@pytest.mark.parametrize("kind", list(KINDS))
def test_each_export_passes_and_an_edit_is_refused(kind, exports, tmp_path, capsys) -> None:
    path = exports[kind]
    assert main(["check-table", str(path)]) == 0, capsys.readouterr().err
    err = capsys.readouterr().err
    assert err.startswith(f"{path}: ok: ") and err.count("\n") == 1, err
    edited = tmp_path / f"edited{path.suffix}"
    edited.write_text(_one_number_changed(path.read_text(encoding="utf-8")), encoding="utf-8")
    assert edited.read_text() != path.read_text()
    assert main(["check-table", str(edited)]) == 1
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err.count("\n") == 1, cap.err
    assert cap.err.startswith("servotune check-table: refused: "), cap.err


def test_an_unknown_schema_is_one_line_naming_the_known_ones(exports, tmp_path, capsys) -> None:
    doc = json.loads(exports["linkage"].read_text())
    doc["schema"] = "servotune.linkage-export/9"
    path = tmp_path / "future.json"
    path.write_text(json.dumps(doc))
    assert main(["check-table", str(path)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'servotune.linkage-export/9'" in err
    for known in (
        "servotune.tables/4",
        "servotune.gantry-tables/2",
        "servotune.linkage-export/1",
        "HAL file",
        "HAL component",
    ):
        assert known in err, err


def test_a_text_export_without_its_digest_line_is_bad_input(exports, tmp_path, capsys) -> None:
    text = exports["hal"].read_text()
    cut = tmp_path / "cut.hal"
    cut.write_text("".join(ln for ln in text.splitlines(keepends=True) if "sha256 of" not in ln))
    assert main(["check-table", str(cut)]) == 3
    assert "0 digest lines" in capsys.readouterr().err
