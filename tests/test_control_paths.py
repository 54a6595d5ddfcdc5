"""servotune's numbers do not depend on whether slycot is installed (:mod:`servotune._control`).

python-control switches to SLICOT (the optional package ``slycot``) when it can import it; the
results then differ in the last bits, and servotune writes those bits (a tuning's margins, hence
its digest). Measured with the real slycot 0.7.1 on 2026-11-26: the example rig's demo wrote a
``tuning.json`` whose margins differed in the 14th-16th digit, so ``tests/test_pipeline.py``'s
pinned digests failed. Here a stand-in ``slycot`` module, whose every routine records its call
and raises, is put where python-control looks for it: the first test shows python-control then
calls it (the stand-in is seen), the others that servotune's results are the same bits with it
present and that it is never called.
"""

from __future__ import annotations

import json
import sys
import threading
import types
from pathlib import Path

import control
import control.exception
import numpy as np
import pytest

from servotune._control import scipy_paths

ROOT = Path(__file__).resolve().parents[1]
SLYCOT_ROUTINES = ("ab08nd", "ab13dd", "ab13md", "tb01pd", "tb04ad", "tb05ad", "td04ad")


def _install_stand_in(monkeypatch: pytest.MonkeyPatch) -> tuple[types.ModuleType, list[str]]:
    """A ``slycot`` whose routines record their name and raise, installed for python-control."""
    calls: list[str] = []
    mod = types.ModuleType("slycot")
    for name in SLYCOT_ROUTINES:

        def routine(*_args: object, _name: str = name, **_kw: object) -> None:
            calls.append(_name)
            raise RuntimeError(f"slycot.{_name} was called")

        setattr(mod, name, routine)
    monkeypatch.setitem(sys.modules, "slycot", mod)
    monkeypatch.setattr(control.exception, "slycot_installed", True)
    return mod, calls


def _importable() -> bool:
    try:
        import slycot  # noqa: F401
    except ImportError:
        return False
    return True


def test_python_control_takes_the_stand_in_when_unguarded(monkeypatch) -> None:
    """The stand-in is real to python-control: a transfer function's conversion to state space
    calls ``td04ad``, a state-space frequency response tries ``tb05ad`` first."""
    _, calls = _install_stand_in(monkeypatch)
    with pytest.raises(RuntimeError, match="td04ad"):
        control.ss(control.tf([1.0], [1.0, 1.0]))
    sys_ss = control.ss([[0.5, 0.1], [0.0, 0.2]], [[1.0], [1.0]], [[1.0, 0.0]], [[0.0]], dt=0.1)
    control.frequency_response(sys_ss, np.array([1.0, 2.0]))
    assert calls == ["td04ad", "tb05ad"]


def _results(rig, tuning) -> dict[str, str]:
    """Every servotune result that goes through python-control, as text holding every bit."""
    from servotune.analysis.margins import tuning_margins
    from servotune.arch.gantry.design import predicted_load_reduction
    from servotune.arch.gantry.load import load_gantry
    from servotune.arch.gantry.synthesis import resolve_gains
    from servotune.modal import discretize_lti
    from servotune.report.loops import loop_response
    from servotune.tune.pi import tune_pi

    out = {"margins": json.dumps(tuning_margins(tuning, rig).to_dict(), sort_keys=True)}
    w = np.geomspace(0.5, 700.0, 50)
    out["bode"] = repr(np.asarray(loop_response(rig, tuning, "slave", w).complex).tolist())
    d = discretize_lti(control.tf([1.0], [1.0, 1.0]), 0.1, 0.05)
    out["discretize_lti"] = repr([d.A.tolist(), d.B.tolist(), d.C.tolist(), d.D.tolist()])
    r = tune_pi(control.tf([1.0], [1.0, 3.0, 3.0, 1.0]), period_s=0.001, phase_margin_deg=60)
    out["tune_pi"] = repr((r.kp, r.ki))
    cfg = resolve_gains(load_gantry(ROOT / "plants" / "gantry.toml"))
    out["gantry_gains"] = repr(cfg)
    out["gantry_prediction"] = repr(predicted_load_reduction(cfg))
    return out


def test_results_are_the_same_bits_with_slycot_present(monkeypatch, rig, quick_tuning) -> None:
    without = _results(rig, quick_tuning)
    mod, calls = _install_stand_in(monkeypatch)
    with_it = _results(rig, quick_tuning)
    assert calls == []
    changed = sorted(k for k in without if with_it[k] != without[k])
    assert not changed, f"changed with slycot importable: {changed}"
    # the user's slycot is back once servotune's calls have returned
    assert sys.modules["slycot"] is mod
    assert control.exception.slycot_installed is True


def test_the_guard_nests_lifts_after_an_error_and_spans_threads(monkeypatch) -> None:
    mod, _ = _install_stand_in(monkeypatch)

    @scipy_paths
    def inner() -> bool:
        return _importable()

    @scipy_paths
    def outer() -> tuple[bool, bool]:
        return inner(), _importable()  # still guarded after the inner call left

    assert outer() == (False, False)
    assert _importable() and sys.modules["slycot"] is mod

    @scipy_paths
    def fails() -> None:
        raise ValueError("inside")

    with pytest.raises(ValueError, match="inside"):
        fails()
    assert sys.modules["slycot"] is mod and control.exception.slycot_installed is True

    # a call that leaves while another thread's call still runs does not lift the guard
    entered, release = threading.Event(), threading.Event()
    seen: list[bool] = []

    @scipy_paths
    def long_call() -> None:
        entered.set()
        release.wait(10.0)
        seen.append(_importable())

    t = threading.Thread(target=long_call)
    t.start()
    assert entered.wait(10.0)
    assert inner() is False
    release.set()
    t.join(10.0)
    assert seen == [False]
    assert sys.modules["slycot"] is mod


def test_without_slycot_the_guard_leaves_no_entry() -> None:
    """Where slycot is not installed, the guard leaves ``sys.modules`` as it found it."""
    if "slycot" in sys.modules:
        pytest.skip("slycot is imported in this process")

    @scipy_paths
    def probe() -> bool:
        return "slycot" in sys.modules and sys.modules["slycot"] is None

    assert probe() is True
    assert "slycot" not in sys.modules
