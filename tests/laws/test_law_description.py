"""A task law is described once (``servotune.laws.axis.TASK_LAWS``) and every reader of its
constants reads that description: the constants vector, the tables document, the C headers
and the C layout. A toy law, registered from this module, goes the whole path; the built-in
descriptions are checked against the C runtime's own header, read as text."""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytest

import servotune as st
from servotune.export import c as c_export
from servotune.export import json as json_export
from servotune.export.c_text import axis_lines, c_identifiers
from servotune.export.layout import constants_pairs
from servotune.fixed import Fixed
from servotune.laws.axis import (
    C_KIT_Q,
    C_KP_F,
    C_KP_Q,
    C_LAW,
    C_LOCK_Q,
    C_N,
    CONST_HEADER,
    N_CONST,
    TASK_LAWS,
    AxisController,
    LawWord,
    TaskLaw,
    law_names,
    task_law,
)
from servotune.laws.fuzzy_pid import FuzzyPIDConstants
from servotune.laws.pi import PIConstants
from servotune.validate import check_keys

RUNTIME_H = st.__path__[0] + "/export/runtime/servotune_rt.h"


@dataclass(frozen=True, slots=True)
class PConstants:
    """The toy law's constants: a proportional gain alone."""

    kp: Fixed

    def to_dict(self) -> dict[str, dict[str, int]]:
        return {"kp": self.kp.to_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, dict[str, int]]) -> PConstants:
        d = check_keys(d, "task", ("kp",))
        return cls(kp=Fixed.from_dict(d["kp"]))


TOY = TaskLaw(
    name="p_only",
    code=3,
    constants=PConstants,
    words=(LawWord("kp", C_KP_Q, "Kp [LSB/count]"),),
)


@pytest.fixture
def toy(monkeypatch: pytest.MonkeyPatch) -> Iterator[TaskLaw]:
    monkeypatch.setitem(TASK_LAWS, TOY.name, TOY)
    yield TOY


def _toy_controller() -> AxisController:
    return AxisController(
        lock_gain=Fixed(q=5, f=4),
        task=PConstants(kp=Fixed(q=7, f=3)),
        following_error_limit_counts=9,
    )


def test_the_toy_law_packs_its_words_into_the_constants_vector(toy: TaskLaw) -> None:
    ctl = _toy_controller()
    assert ctl.law == 3 and task_law(ctl.task) is toy
    c = ctl.consts(counter_bits=24, dac_bits=12, dac_zero=2048)
    assert len(c) == N_CONST  # no tables
    assert (c[C_LAW], c[C_LOCK_Q], c[C_KP_Q], c[C_KP_F]) == (3, 5, 7, 3)
    assert c[C_KIT_Q] == 0 and c[C_N] == 0  # words the toy does not have stay 0


def test_the_toy_law_round_trips_its_dict_and_is_refused_once_unregistered(
    toy: TaskLaw, monkeypatch: pytest.MonkeyPatch
) -> None:
    ctl = _toy_controller()
    d = ctl.to_dict()
    assert d["law"] == "p_only" and d["task"] == {"kp": {"f": 3, "q": 7}}
    assert AxisController.from_dict(d) == ctl
    assert "p_only" in law_names()
    monkeypatch.delitem(TASK_LAWS, "p_only")
    with pytest.raises(ValueError, match="law must be one of none, pi, fuzzy_pid"):
        AxisController.from_dict(d)


def test_the_toy_law_writes_its_c_macros_and_layout_pairs(toy: TaskLaw) -> None:
    ctl = _toy_controller()
    ax = {"index": 0, "name": "x", "role": "master", "ref_source": -1, **ctl.to_dict()}
    lines, init = axis_lines(ax, "x")
    assert "#define ST_X_KP_Q INT32_C(7) /* Kp [LSB/count] */" in lines
    assert "#define ST_X_KP_F 3" in lines
    assert ".law = ST_LAW_P_ONLY" in init and ".kp_q = ST_X_KP_Q" in init
    assert not any("KIT" in line or "_N " in line for line in lines)
    pairs = constants_pairs(
        [ctl], [-1], timer_divisor=1, counter_bits=24, dac_bits=12, dac_zero=2048
    )
    # part 1 of the C layout: (n_axes), (divisor), then the axis in CONST_HEADER order, its
    # ref_source, n_filters and 4 filter slots of 5 pairs (docs/runtime.md#filters-in-the-law)
    assert pairs[2:5] == [(3, 0), (5, 4), (7, 3)]
    assert len(pairs) == 2 + len(CONST_HEADER) + 1 + 1 + 4 * 5
    assert pairs[-21:] == [(0, 0)] * 21  # no filters


def test_the_toy_law_goes_through_the_tables_document_and_the_c_header(
    toy: TaskLaw, quick_tuning: st.Tuning, rig: st.Rig
) -> None:
    ctls = (_toy_controller(), *quick_tuning.controllers[1:])
    tuning = dataclasses.replace(quick_tuning, controllers=ctls)
    text = json_export.to_string(tuning, rig=rig, unverified=True)
    doc = json.loads(text)
    assert doc["data"]["axes"][0]["law"] == "p_only"
    assert json_export.check_tables(doc)[0] == ctls[0]
    header = c_export.to_string(tuning, rig=rig, unverified=True)
    assert ".law = ST_LAW_P_ONLY" in header
    master = c_identifiers(tuning.axis_names)[0].upper()
    assert f"#define ST_{master}_KP_Q INT32_C(7)" in header


def _header_struct(name: str) -> list[str]:
    """The field names of a struct typedef in the runtime header, in order."""
    text = open(RUNTIME_H).read()
    body = re.search(r"typedef struct " + name + r" \{(.*?)\} " + name + "_t;", text, re.S)
    assert body, name
    code = re.sub(r"/\*.*?\*/", "", body.group(1), flags=re.S)
    return re.findall(r"(\w+)(?:\[\w+\])?;", code)


def test_the_constants_header_is_the_c_struct_in_its_order() -> None:
    fields = _header_struct("st_axis_consts")
    expected = []
    for stem, _, pair in CONST_HEADER:
        expected += [f"{stem}_q", f"{stem}_f"] if pair else [stem]
    assert fields[: len(expected)] == expected
    slots = [slot for _, slot, _ in CONST_HEADER]
    assert slots == sorted(slots) and slots[0] == 0


def test_every_law_is_known_to_the_c_runtime_by_its_code() -> None:
    text = open(RUNTIME_H).read()
    defined = {m[0]: int(m[1]) for m in re.findall(r"#define (ST_LAW_\w+) (\d+)", text)}
    assert defined.pop("ST_LAW_NONE") == 0
    assert defined == {law.macro: law.code for law in TASK_LAWS.values()}
    stems = {stem for stem, _, pair in CONST_HEADER if pair}
    for law in TASK_LAWS.values():
        assert {w.stem for w in law.words} <= stems
        assert len(law.table_titles) == len(law.tables)


def test_the_built_in_descriptions_name_their_constants_fields() -> None:
    assert task_law(PIConstants(kp=Fixed(q=1, f=0), ki_t=Fixed(q=1, f=0))).name == "pi"
    for law in TASK_LAWS.values():
        names = {f.name for f in dataclasses.fields(law.constants)}
        assert {w.key for w in law.words} <= names
    assert TASK_LAWS["fuzzy_pid"].constants is FuzzyPIDConstants
    with pytest.raises(TypeError, match="no task law"):
        task_law(np.zeros(1))
