"""Loaders load, runners run: the linkage's gains are resolved by the caller
(servotune.arch.linkage.synthesis), never inside a loader or a runner.

An axis without gains is refused by ``run_linkage`` by name; ``resolve_gains`` tunes it with
exactly the ``tune_pi`` call the run made before (the same numbers, checked against a direct
call); and neither the linkage's runner nor the gantry's loader and runner import the tuners
(read from their sources, imports at any depth included).
"""

from __future__ import annotations

import ast
import copy
import tomllib
from pathlib import Path
from typing import Any

import pytest
from conftest import ROOT

from servotune.arch.linkage import (
    TUNE_TARGETS,
    LinkageConfig,
    axis_gains,
    linkage_from_dict,
    load_linkage,
    resolve_gains,
    run_linkage,
)
from servotune.errors import ConfigError
from servotune.laws.pi import PIGains
from servotune.tune.pi import tune_pi

EXAMPLE = ROOT / "plants" / "linkage-6axis.toml"
_DATA = tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))

RUNNERS_AND_LOADERS = (
    "servotune/arch/linkage/run.py",
    "servotune/arch/linkage/config.py",
    "servotune/arch/gantry/load.py",
    "servotune/arch/gantry/run.py",
)
"""Modules that must not tune: the linkage's runner and loader, the gantry's loader and runner."""

FORBIDDEN = (
    "servotune.tune",
    "servotune.arch.linkage.synthesis",
    "servotune.arch.gantry.synthesis",
)
"""What they must not import: the tuners, and the modules that resolve gains with them."""


def without_gains(*axes: str) -> dict[str, Any]:
    """The example's parsed TOML with ``kp`` and ``ki`` taken out of ``axes``."""
    d = copy.deepcopy(_DATA)
    for name in axes:
        del d["axis"][name]["kp"], d["axis"][name]["ki"]
    return d


@pytest.fixture(scope="module")
def bare() -> LinkageConfig:
    """The example with axis x's gains left out (as a file that leaves them to be tuned)."""
    return linkage_from_dict(without_gains("x"), EXAMPLE.parent)


@pytest.fixture(scope="module")
def resolved(bare: LinkageConfig) -> LinkageConfig:
    return resolve_gains(bare)


# --- (a) the runner refuses an axis without gains -------------------------------------------


def test_run_refuses_an_axis_without_gains_naming_it_and_resolve_gains(
    bare: LinkageConfig,
) -> None:
    with pytest.raises(ConfigError) as exc:
        run_linkage(bare, seconds=0.1)
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg == (
        "axis 'x' has no PI gains: give them in the linkage file or resolve them first "
        "(servotune.arch.linkage.resolve_gains)"
    )


def test_the_loader_leaves_absent_gains_unset() -> None:
    p = EXAMPLE.parent / "linkage-6axis.toml"
    assert all(a.gains is not None and not a.gains_tuned for a in load_linkage(p).axes)
    cfg = linkage_from_dict(without_gains("x", "b"), EXAMPLE.parent)
    assert [a.name for a in cfg.axes if a.gains is None] == ["x", "b"]
    assert not any(a.gains_tuned for a in cfg.axes)


def refusal(key: str, value: Any) -> str:
    """The loader's message for the example with ``key = value`` added to ``[axis.x]``."""
    d = copy.deepcopy(_DATA)
    d["axis"]["x"][key] = value
    with pytest.raises(ConfigError) as exc:
        linkage_from_dict(d, EXAMPLE.parent)
    return str(exc.value)


@pytest.mark.parametrize("value", [True, False])
def test_gains_tuned_is_not_a_file_key(value: bool) -> None:
    # refused as any unknown key is, and not listed among the allowed ones
    msg = refusal("gains_tuned", value)
    assert msg.startswith("unknown key axis.x.gains_tuned")
    assert msg == refusal("gainz", value).replace("gainz", "gains_tuned")
    assert msg.count("gains_tuned") == 1 and "counter_init" in msg


# --- (b) resolve_gains tunes, as the run did ------------------------------------------------


def test_resolve_gains_tunes_a_missing_axis_with_tune_pi(
    bare: LinkageConfig, resolved: LinkageConfig
) -> None:
    x = resolved.axis("x")
    assert x.gains_tuned and x.gains is not None
    # the tuner's call written out here, not read from the code under test
    assert TUNE_TARGETS == {"phase_margin_deg": 50.0, "gain_margin_db": 8.0, "max_sensitivity": 1.6}
    ref = tune_pi(
        bare.axis("x").plant,
        period_s=0.002,
        compute_s=bare.rig.timer.compute_s,
        lsb_v=bare.rig.dac.lsb_v,
        phase_margin_deg=50.0,
        gain_margin_db=8.0,
        max_sensitivity=1.6,
    )
    assert (x.kp, x.ki) == (ref.kp, ref.ki)
    # every other axis keeps the file's gains, not marked tuned
    for a, b in zip(bare.axes[1:], resolved.axes[1:], strict=True):
        assert (b.kp, b.ki, b.gains_tuned) == (a.kp, a.ki, False)
    # the rest of the config is untouched
    assert resolved.axis_names == bare.axis_names and resolved.path == bare.path
    assert resolved.cpus == bare.cpus and resolved.bus == bare.bus


def test_a_resolved_config_runs_and_shows_the_tuned_axis(resolved: LinkageConfig) -> None:
    r = run_linkage(resolved, seconds=0.2)
    shown = {a.name: (a.kp, a.ki, a.tuned) for a in r.axes}
    x = resolved.axis("x")
    assert shown["x"] == (x.kp, x.ki, True)
    assert shown["y"] == (0.3168, 1.051, False)
    assert axis_gains(resolved)["x"].to_dict() == {"ki": x.ki, "kp": x.kp, "tuned": True}


def test_resolving_again_changes_nothing(resolved: LinkageConfig) -> None:
    assert resolve_gains(resolved) == resolved


def test_given_gains_override_and_are_not_tuned(bare: LinkageConfig) -> None:
    cfg = resolve_gains(bare, {"x": PIGains(kp=0.25, ki=1.0), "y": PIGains(kp=0.5, ki=2.0)})
    assert [(a.kp, a.ki, a.gains_tuned) for a in cfg.axes[:2]] == [
        (0.25, 1.0, False),
        (0.5, 2.0, False),
    ]
    with pytest.raises(ConfigError, match=r"gains for unknown axis 'q'"):
        resolve_gains(bare, {"q": PIGains(kp=0.25, ki=1.0)})


# --- (c) no runner or loader imports a tuner ------------------------------------------------


def imported_modules(source: str, module: str) -> set[str]:
    """Every module ``source`` (the module ``module``) imports, at any depth: in functions,
    under ``if TYPE_CHECKING:``, relative imports resolved, ``from a import b`` as both ``a``
    and ``a.b``, and ``importlib.import_module`` / ``__import__`` of a constant name."""
    out: set[str] = set()
    package = module.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.add(mod)
            out.update(f"{mod}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Call) and node.args:
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            arg = node.args[0]
            if name in ("import_module", "__import__") and isinstance(arg, ast.Constant):
                out.add(str(arg.value))
    return out


def forbidden_imports(source: str, module: str) -> list[str]:
    return sorted(
        m
        for m in imported_modules(source, module)
        if any(m == f or m.startswith(f + ".") for f in FORBIDDEN)
    )


@pytest.mark.parametrize("path", RUNNERS_AND_LOADERS)
def test_runners_and_loaders_do_not_import_the_tuners(path: str) -> None:
    module = path.removesuffix(".py").replace("/", ".")
    source = (ROOT / path).read_text(encoding="utf-8")
    assert forbidden_imports(source, module) == []


PLANTED = {
    "top level": "from servotune.tune.pi import tune_pi\n",
    "in a function": "def f():\n    from servotune.tune.pi import tune_pi\n    return tune_pi\n",
    "type checking": (
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import servotune.tune.pi\n"
    ),
    "the package": "from servotune import tune\n",
    "relative": "from ...tune import pi\n",
    "the resolver": "from servotune.arch.linkage.synthesis import resolve_gains\n",
    "sibling": "from . import synthesis\n",
    "by name": "import importlib\nimportlib.import_module('servotune.tune.pi')\n",
}


@pytest.mark.parametrize("case", sorted(PLANTED))
def test_a_planted_import_of_a_tuner_is_found(case: str) -> None:
    assert forbidden_imports(PLANTED[case], "servotune.arch.linkage.run"), case


def test_the_checked_files_exist() -> None:
    assert all(Path(ROOT / p).is_file() for p in RUNNERS_AND_LOADERS)
