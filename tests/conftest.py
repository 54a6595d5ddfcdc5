"""Shared fixtures: the example rig and simple variants of it."""

from __future__ import annotations

import dataclasses
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

import servotune as st

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_RIG = ROOT / "plants" / "pc-dual-servo.toml"


@pytest.fixture(scope="session")
def default_tuning() -> st.Tuning:
    """``tune_rig`` of the example rig, default budget, seed 0: a good tuning, made once for
    every test file that needs one (a frozen value: tests replace fields, never mutate it)."""
    from servotune.tune.workflow import tune_rig

    return tune_rig(EXAMPLE_RIG, seed=0)


@pytest.fixture(scope="session")
def quick_tuning() -> st.Tuning:
    """A two-generation tuning of the example rig (seed 0; overshoot bound relaxed so that it
    is feasible): a real tuning, too little tuned for the shipped spec's sync-error limit."""
    from servotune.tune.slave import SlaveTuneSpec
    from servotune.tune.workflow import tune_rig

    spec = SlaveTuneSpec(generations=2, population=6, max_overshoot_pct=300.0)
    return tune_rig(EXAMPLE_RIG, seed=0, spec=spec)


@pytest.fixture(scope="session")
def rig() -> st.Rig:
    """The example rig, the PC dual-servo rig (plants/pc-dual-servo.toml)."""
    return st.load_rig(EXAMPLE_RIG)


def one_axis(rig: st.Rig, name: str = "master", **plant_changes: object) -> st.Rig:
    """A single-axis rig from one axis of ``rig``, its plant changed as given."""
    ax = rig.axis(name)
    plant = dataclasses.replace(ax.plant, **plant_changes)
    return dataclasses.replace(rig, axes=(dataclasses.replace(ax, plant=plant, role="master"),))


def linear_one_axis(rig: st.Rig, compute_s: float = 0.0, **plant_changes: object) -> st.Rig:
    """Single-axis rig with only the linear dynamics: no drift, friction, noise or speed limit."""
    base = {
        "offset_v": 0.0,
        "coulomb_v": 0.0,
        "noise_counts": 0.0,
        "max_speed_rpm": None,
        "delay_s": 0.0,
    }
    base.update(plant_changes)
    r = one_axis(rig, **base)
    ax = dataclasses.replace(r.axes[0], following_error_limit_counts=0, travel_counts=None)
    return dataclasses.replace(
        r, axes=(ax,), timer=dataclasses.replace(r.timer, compute_s=compute_s)
    )


@pytest.fixture(scope="session")
def quick_workbench(tmp_path_factory):
    """Factory ``make(name, tuning)``: a new folder holding a copy of the example rig
    (``my-rig.toml``), ``tuning`` written for that copy's path (``t.json``, as ``tune
    my-rig.toml`` records it) and the example spec with a 2-plant Monte Carlo
    (``quick.spec.toml``); returns their paths under "dir", "rig", "tuning", "spec"."""
    import shutil

    from servotune.tuning import write_tuning

    def make(name: str, tuning: st.Tuning) -> dict[str, Path]:
        d = tmp_path_factory.mktemp(name)
        rig = d / "my-rig.toml"
        shutil.copyfile(EXAMPLE_RIG, rig)
        path = d / "t.json"
        write_tuning(dataclasses.replace(tuning, rig_path=rig.as_posix()), path)
        spec = d / "quick.spec.toml"
        text = EXAMPLE_RIG.with_name("pc-dual-servo.spec.toml").read_text()
        assert "count = 64" in text
        spec.write_text(text.replace("count = 64", "count = 2"))
        return {"dir": d, "rig": rig, "tuning": path, "spec": spec}

    return make


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C handled as in a foreground run: a shell that starts a command in the background
    (``make test &``, a job without job control) starts it with SIGINT ignored, which every
    process it starts inherits, so the signal tests (Ctrl-C ends a run with exit 130) would
    test the shell's choice instead of servotune's handling."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(autouse=True)
def _sigint_left_as_found() -> Iterator[None]:
    """Every test leaves the process's Ctrl-C handling as it found it: a test (or the code it
    runs) that leaves SIGINT ignored makes every later signal test of its worker fail, far
    from the cause; this names the test instead."""
    before = signal.getsignal(signal.SIGINT)
    yield
    after = signal.getsignal(signal.SIGINT)
    if after is not before:
        signal.signal(signal.SIGINT, before)
        pytest.fail(f"the test left SIGINT's handler {after!r} (it was {before!r})")
