"""``servotune --help`` is fast: tested by what it imports, not by a timer.

After ``import servotune.cli`` and ``servotune --help`` (or ``servotune VERB --help``), none of
the heavy dependencies is in ``sys.modules``; the package ``__init__`` is lazy (PEP 562), and its
public names still resolve on first use.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

import servotune

HEAVY = ("numba", "scipy", "matplotlib", "control", "casadi", "dask", "distributed")


_PRELUDE = f"""
import contextlib, io, json, sys

HEAVY = {HEAVY!r}

def heavy():  # the heavy packages imported so far (top-level names)
    return sorted(set(HEAVY).intersection(m.partition(".")[0] for m in sys.modules))

def help_of(argv):
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        try:
            servotune.cli.main(argv)
        except SystemExit as exc:
            return exc.code, out.getvalue()
    return "returned", out.getvalue()
"""


def _run(code: str) -> dict:
    """Run ``code`` (after :data:`_PRELUDE`) in a fresh interpreter; it prints one JSON document
    as its last line."""
    proc = subprocess.run(
        [sys.executable, "-c", _PRELUDE + textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def test_import_cli_and_help_import_no_heavy_module() -> None:
    got = _run(
        """
        import servotune.cli
        import servotune.cli.parser
        after_import = heavy()
        code, text = help_of(["--help"])
        print(json.dumps({"after_import": after_import, "after_help": heavy(), "code": code,
                          "usage": text.startswith("usage: servotune")}))
        """
    )
    assert got["after_import"] == [], f"import servotune.cli imported {got['after_import']}"
    assert got["after_help"] == [], f"servotune --help imported {got['after_help']}"
    assert got["code"] == 0
    assert got["usage"]


def test_every_verbs_help_exits_0_without_numba() -> None:
    got = _run(
        """
        import argparse
        import servotune.cli
        import servotune.cli.parser
        (sub,) = (a for a in servotune.cli.parser.build_parser()._actions
                  if isinstance(a, argparse._SubParsersAction))
        verbs = {}
        for verb in sub.choices:
            code, text = help_of([verb, "--help"])
            verbs[verb] = {"code": code, "usage": text.startswith(f"usage: servotune {verb}")}
        print(json.dumps({"verbs": verbs, "heavy": heavy()}))
        """
    )
    verbs = got["verbs"]
    assert {"rig", "simulate", "fit", "tune", "verify", "export-table", "demo"} <= set(verbs)
    bad = {v: r for v, r in verbs.items() if r != {"code": 0, "usage": True}}
    assert not bad, f"servotune VERB --help did not exit 0 with its usage: {bad}"
    assert got["heavy"] == [], f"servotune VERB --help imported {got['heavy']}"


def test_import_servotune_imports_no_heavy_module_until_a_name_is_used() -> None:
    got = _run(
        """
        import servotune
        before = heavy()
        servotune.ServotuneError  # errors.py is light
        light = heavy()
        servotune.Rig
        print(json.dumps({"before": before, "light": light, "rig": "Rig" in vars(servotune)}))
        """
    )
    assert got["before"] == [], f"import servotune imported {got['before']}"
    assert got["light"] == [], f"servotune.ServotuneError imported {got['light']}"
    assert got["rig"]  # resolved, and kept in the module's namespace


def test_every_public_name_resolves_to_its_defining_object() -> None:
    import importlib

    assert servotune.__version__
    assert set(servotune.__all__) == set(servotune._LAZY) | {"__version__"}
    for name in servotune.__all__:
        value = getattr(servotune, name)
        if name != "__version__":
            assert value is getattr(importlib.import_module(servotune._LAZY[name]), name), name
    assert servotune.Rig is importlib.import_module("servotune.rig").Rig
    namespace: dict[str, object] = {}
    exec("from servotune import *", namespace)
    assert set(servotune.__all__) <= set(namespace)


def test_dir_lists_every_public_name() -> None:
    listed = dir(servotune)
    assert set(servotune.__all__) <= set(listed)
    assert listed == sorted(listed)


def test_an_unknown_name_raises_attribute_error() -> None:
    with pytest.raises(AttributeError, match=r"module 'servotune' has no attribute 'nope'"):
        servotune.nope  # noqa: B018
    assert not hasattr(servotune, "nope")
    with pytest.raises(ImportError):
        exec("from servotune import nope", {})
