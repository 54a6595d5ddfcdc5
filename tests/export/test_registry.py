"""The export formats' registry (servotune.export.formats): every format is one module with
``to_string`` and ``to_file``, ``to_file`` writes what ``to_string`` gives, and a format added
by :func:`~servotune.export.formats.register` is offered and written by ``export-table
--format`` with no change to the CLI (docs/contributing.md#adding-an-export-format).

This module is the toy format's module too: its ``to_string`` and ``to_file`` below, a CSV
of the first fuzzy-PID axis's Kp query table, are what the toy registers.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import servotune as st
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.tuning import tune_gantry
from servotune.arch.linkage import plan_linkage
from servotune.cli import main
from servotune.cli.parser import build_parser
from servotune.errors import ExportError
from servotune.export import FORMATS, KINDS, ExportFormat, register
from servotune.export.c import runtime_source
from servotune.export.document import write_export
from servotune.export.json import tables_document
from servotune.laws.fuzzy_pid import TABLE_NAMES, FuzzyPIDConstants
from servotune.tuning import write_tuning

ROOT = Path(__file__).resolve().parents[2]
GANTRY = ROOT / "plants" / "gantry.toml"
LINKAGE = ROOT / "plants" / "linkage-6axis.toml"

SAMPLE_OPTIONS: dict[str, dict[str, Any]] = {"linuxcnc-hal": {"position_scale": 2000.0}}
"""The options a format cannot render without (a new format with one adds its sample here)."""


# --- the toy format: this module's to_string and to_file ---------------------------------------


def to_string(
    tuning: st.Tuning,
    *,
    rig: st.Rig | None = None,
    verification: Any = None,
    unverified: bool = False,
    name: str = "servotune",
) -> str:
    """The toy export: ``# <name>``, then the first fuzzy-PID axis's Kp query table as CSV
    (a header row ``E\\EC`` and the levels, then one row per ``E``: the level, the entries
    ``q``). Refused, as every export, without a passing verification unless ``unverified``."""
    doc = tables_document(tuning, rig=rig, verification=verification, unverified=unverified)
    axis = next(a for a in doc["data"]["axes"] if a["law"] == "fuzzy_pid")
    table = axis["task"]["tables"]["kp"]
    levels = range(-table["n"], table["n"] + 1)
    out = io.StringIO()
    out.write(f"# {name}: {axis['name']} kp, q * 2^-{table['f']}\n")
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["E\\EC", *levels])
    for e, row in zip(levels, table["q"], strict=True):
        writer.writerow([e, *row])
    return out.getvalue()


def to_file(tuning: st.Tuning, path: str | Path, **options: Any) -> None:
    """Write :func:`to_string` atomically."""
    write_export(path, to_string(tuning, **options))


TOY = ExportFormat(
    name="toy",
    help="the first fuzzy-PID axis's Kp table as CSV (a test's format)",
    module=__name__,
    kinds={"rig": "the toy table"},
    options=("name",),
)


@pytest.fixture
def toy() -> Iterator[ExportFormat]:
    """The toy format, registered for one test."""
    fmt = register(TOY)
    try:
        yield fmt
    finally:
        del FORMATS[fmt.name]


@pytest.fixture(scope="module")
def tuning_file(quick_tuning: st.Tuning, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("registry") / "tuning.json"
    write_tuning(quick_tuning, path)
    return path


def _export_table_dests() -> set[str]:
    """The ``dest`` of every option of ``export-table``."""
    (sub,) = (a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest for a in sub.choices["export-table"]._actions}


# --- every registered format -------------------------------------------------------------------


def test_the_builtin_formats_are_registered_in_the_cli_order() -> None:
    assert list(FORMATS)[:4] == ["json", "c", "linuxcnc-hal", "linuxcnc-comp"]
    assert set(FORMATS["json"].kinds) == set(FORMATS["c"].kinds) == set(KINDS)
    assert [f.name for f in FORMATS.values() if f.directory] == ["c"]


@pytest.mark.parametrize("name", list(FORMATS))
def test_every_format_is_one_module_of_two_functions(name: str) -> None:
    fmt = FORMATS[name]
    module = fmt.load()
    assert module.__name__ == fmt.module
    assert callable(module.to_string) and callable(module.to_file)
    assert set(fmt.kinds) <= set(KINDS) and all(fmt.kinds.values())
    assert set(fmt.options) <= _export_table_dests(), "an option the CLI does not have"


def _objects(quick_tuning: st.Tuning, rig: st.Rig) -> dict[str, tuple[Any, dict[str, Any]]]:
    """One thing to export of each kind, unverified, and its keywords."""
    return {
        "rig": (quick_tuning, {"rig": rig, "unverified": True}),
        "gantry": (tune_gantry(GANTRY), {"rig": load_gantry(GANTRY).rig, "unverified": True}),
        "linkage": (plan_linkage(LINKAGE), {"unverified": True}),
    }


def test_to_file_writes_what_to_string_gives(
    quick_tuning: st.Tuning, rig: st.Rig, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    objects = _objects(quick_tuning, rig)
    checked = []
    for fmt in FORMATS.values():
        for kind in fmt.kinds:
            obj, kw = objects[kind]
            kw = {**kw, **SAMPLE_OPTIONS.get(fmt.name, {})}
            text = fmt.to_string(obj, **kw)
            assert fmt.to_string(obj, **kw) == text  # deterministic
            out = tmp_path / f"{fmt.name}-{kind}"
            if fmt.directory:
                written = fmt.to_file(obj, out, **kw)
                assert written[0].read_text(encoding="utf-8") == text  # the generated file
                assert all(p.parent == out for p in written)
                assert {p.name for p in written} == {p.name for p in out.iterdir()}
                for p in written[1:]:  # the rest is the runtime's sources, as shipped
                    assert p.read_text(encoding="utf-8") == runtime_source(p.name)
                assert text.startswith(f"/* {written[0].name} -- generated by servotune")
            else:
                assert fmt.to_file(obj, out, **kw) is None
                assert out.read_text(encoding="utf-8") == text
                # real content: check-table reads it back and its digests hold
                assert main(["check-table", str(out)]) == 0, capsys.readouterr().err
            checked.append((fmt.name, kind))
    assert ("json", "linkage") in checked and ("linuxcnc-comp", "rig") in checked
    # each JSON document is the kind's own
    schemas = {
        kind: json.loads(FORMATS["json"].to_string(obj, **kw))["schema"]
        for kind, (obj, kw) in objects.items()
    }
    assert schemas == {
        "rig": "servotune.tables/4",
        "gantry": "servotune.gantry-tables/2",
        "linkage": "servotune.linkage-export/1",
    }


def test_a_format_is_checked_when_made_and_registered_once() -> None:
    with pytest.raises(ExportError, match="kinds"):
        ExportFormat(name="x", help="", module=__name__, kinds={"robot": "it"})
    with pytest.raises(ExportError, match="one word"):
        ExportFormat(name="two words", help="", module=__name__, kinds={"rig": "it"})
    with pytest.raises(ExportError, match="registered already"):
        register(ExportFormat(name="json", help="", module=__name__, kinds={"rig": "it"}))
    with pytest.raises(ExportError, match="has no to_string and no to_file"):
        ExportFormat(name="x", help="", module="servotune.errors", kinds={"rig": "it"}).load()


# --- a format added through the registry -------------------------------------------------------


def test_a_registered_format_is_offered_by_export_table(
    toy: ExportFormat, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["export-table", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "--format {json,c,linuxcnc-hal,linuxcnc-comp,toy}" in text
    assert f"toy: {toy.help}" in " ".join(text.split())  # its help, as argparse wraps it
    (sub,) = (a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    (action,) = (a for a in sub.choices["export-table"]._actions if a.dest == "format")
    assert list(action.choices) == [*FORMATS]


def test_export_table_writes_what_the_toy_renders(
    toy: ExportFormat,
    quick_tuning: st.Tuning,
    rig: st.Rig,
    tuning_file: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = ["export-table", str(tuning_file), "--format", "toy", "--unverified"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert out == to_string(quick_tuning, rig=rig, unverified=True)
    # the content: the tuning's Kp table of its fuzzy-PID axis, level by level
    first, *rows = out.splitlines()
    task, axis = next(
        (c.task, n)
        for c, n in zip(quick_tuning.controllers, quick_tuning.axis_names, strict=True)
        if isinstance(c.task, FuzzyPIDConstants)
    )
    q, f = task.tables[TABLE_NAMES.index("kp")]
    assert first == f"# servotune: {axis} kp, q * 2^-{f}"
    table = list(csv.reader(rows))
    n = task.n
    assert table[0] == ["E\\EC", *map(str, range(-n, n + 1))]
    assert [int(r[0]) for r in table[1:]] == list(range(-n, n + 1))
    assert [[int(v) for v in r[1:]] for r in table[1:]] == q.tolist()
    assert (q != 0).any()  # a real table, not zeros
    # -o writes the file (its option from the CLI's --name), and says so
    path = tmp_path / "kp.csv"
    assert main([*argv, "--name", "bench_7", "-o", str(path)]) == 0
    assert path.read_text() == to_string(quick_tuning, rig=rig, unverified=True, name="bench_7")
    assert path.read_text().startswith("# bench_7: ")
    assert capsys.readouterr().err.endswith(f"wrote the toy table to {path}\n")
    # refused unverified, as every export
    assert main(argv[:-1]) == 1
    assert "verif" in capsys.readouterr().err


def test_a_kind_the_format_does_not_export_is_refused_naming_those_that_do(
    toy: ExportFormat, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "gantry.json"
    path.write_text(json.dumps({"schema": "servotune.gantry-tuning/1"}))
    code = main(["export-table", str(path), "--format", "toy", "--unverified"])
    cap = capsys.readouterr()
    assert code == 3 and cap.out == ""
    assert cap.err == (
        f"servotune export-table: error: --format toy exports a rig's tuning (one runtime, its "
        f"master and slave axes); {path} is a gantry tuning: export it with --format json or c\n"
    )
