"""The house rules (docs/contributing.md#house-rules), measured by tests/layers.py: imports run
down the layers, no import cycle (through functions and TYPE_CHECKING too), no private name
imported from another module, no function over 100 code lines outside compiled kernels, no
module over 800 lines, at most 40 ``# fmt: skip``.

The findings of the day the check was written are listed in tests/layers_known.txt, each a
piece of work left: a new finding fails, and so does a listed one that no longer occurs (take
it off the list: it only shrinks). The rules themselves are checked on small made-up modules,
so a check that stopped finding anything would fail here too."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import layers
import pytest

ROOT = Path(__file__).resolve().parents[1]
KNOWN = ROOT / "tests" / "layers_known.txt"


def _known() -> set[str]:
    lines = KNOWN.read_text(encoding="utf-8").splitlines()
    return {ln for ln in lines if ln.strip() and not ln.startswith("#")}


def test_no_new_finding_and_none_fixed_but_listed() -> None:
    found = {str(f) for f in layers.findings()}
    known = _known()
    new = sorted(found - known)
    gone = sorted(known - found)
    assert not new, "breaks the house rules (docs/contributing.md#house-rules):\n" + "\n".join(new)
    assert not gone, "fixed: take these off tests/layers_known.txt:\n" + "\n".join(gone)


def test_fmt_skip_only_on_tables_of_constants() -> None:
    count = 0
    paths = [*ROOT.glob("servotune/**/*.py"), *ROOT.glob("tests/**/*.py")]
    for path in [*paths, *ROOT.glob("bench/*.py")]:
        lines = path.read_text(encoding="utf-8").splitlines()
        count += sum(1 for ln in lines if ln.rstrip().endswith("# fmt: skip"))
    assert count <= 40, f"{count} '# fmt: skip' (at most 40, on tables of constants)"


def test_every_module_is_in_a_layer() -> None:
    for name in layers.modules():
        layers.layer(name)  # KeyError names the module otherwise


@pytest.fixture
def toy(tmp_path, monkeypatch):
    """A made-up package ``servotune`` under ``tmp_path`` the rules are measured on."""
    pkg = tmp_path / "servotune"

    def write(rel: str, text: str) -> None:
        p = pkg / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(textwrap.dedent(text), encoding="utf-8")

    write("__init__.py", "")
    monkeypatch.setattr(layers, "ROOT", tmp_path)
    monkeypatch.setattr(layers, "PACKAGE", pkg)
    return write


def _kinds(findings) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for f in findings:
        out.setdefault(f.kind, []).append(f.what)
    return out


def test_the_rules_find_what_they_are_for(toy) -> None:
    toy("errors.py", "class E(Exception): ...\n")
    toy("plant.py", "from servotune.verify import run\n")  # layer 3 importing layer 8
    toy("verify/__init__.py", "")
    toy("verify/run.py", "from servotune.plant import _private\nimport servotune.plant\n")
    toy("sim/__init__.py", "")
    toy("sim/a.py", "def f():\n    from servotune.sim import b\n")
    tc = "import typing\nif typing.TYPE_CHECKING:\n    from servotune.sim import a\n"
    toy("sim/b.py", tc)
    long_body = "\n".join(f"    x{i} = {i}" for i in range(101))
    toy("laws/__init__.py", "")
    kernel = f"@jit\ndef kernel():\n{long_body}\n"
    toy("laws/big.py", f"def long():\n    '''doc'''\n{long_body}\n\n\n{kernel}")
    toy("fuzzy/__init__.py", "")
    toy("fuzzy/huge.py", "x = 1\n" * 801)
    kinds = _kinds(layers.findings())
    assert kinds["layer"] == ["servotune.plant imports servotune.verify.run"]
    assert kinds["private"] == ["servotune.verify.run imports servotune.plant._private"]
    assert "servotune.sim.a <-> servotune.sim.b" in kinds["cycle"]
    assert kinds["function"] == ["servotune.laws.big.long"]  # the jit kernel is exempt
    assert kinds["module"] == ["servotune.fuzzy.huge (800+ lines)"]


def test_a_function_of_100_code_lines_is_not_a_finding(toy) -> None:
    body = "\n".join(f"    x{i} = {i}  # a comment" for i in range(100))
    toy("laws/__init__.py", "")
    toy("laws/ok.py", f"def ok():\n    '''doc\n\n    more doc'''\n\n    # why\n{body}\n")
    assert _kinds(layers.findings()).get("function") is None


def test_the_known_list_names_real_modules() -> None:
    names = set(layers.modules())
    for entry in _known():
        for dotted in re.findall(r"servotune(?:\.\w+)+", entry):
            parts = dotted.split(".")
            assert any(".".join(parts[:k]) in names for k in range(len(parts), 1, -1)), entry
