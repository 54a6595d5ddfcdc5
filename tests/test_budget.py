"""The memory budget (servotune.budget): refused before allocating, one line with the numbers."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from conftest import EXAMPLE_RIG

import servotune as st
from servotune.budget import (
    DEFAULT_MEMORY_BUDGET,
    BudgetError,
    check_memory,
    format_bytes,
    format_count,
    memory_budget,
    parse_bytes,
    set_memory_budget,
)
from servotune.errors import ServotuneError, SimulationError


@pytest.fixture(autouse=True)
def _reset(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.delenv("SERVOTUNE_MAX_MEMORY", raising=False)
    set_memory_budget(None)
    yield
    set_memory_budget(None)


def test_default_is_2_gib() -> None:
    assert memory_budget() == DEFAULT_MEMORY_BUDGET == 2 * 1024**3
    check_memory(DEFAULT_MEMORY_BUDGET, "exactly the budget")


def test_error_is_a_servotune_simulation_error() -> None:
    assert issubclass(BudgetError, SimulationError)
    assert issubclass(BudgetError, ServotuneError) and issubclass(BudgetError, ValueError)


def test_message_names_request_estimate_and_budget() -> None:
    with pytest.raises(BudgetError) as exc:
        check_memory(160 * 1024**4, "simulate 1e+12 s", "250,000 ticks × 2 axes × 512 bytes")
    msg = str(exc.value)
    assert msg.startswith("simulate 1e+12 s needs about 160 TiB (250,000 ticks × 2 axes")
    assert "over the memory budget of 2 GiB (--max-memory" in msg and "\n" not in msg


def test_unbounded_estimates() -> None:
    with pytest.raises(BudgetError, match="needs unbounded memory"):
        check_memory(float("inf"), "a run")
    with pytest.raises(BudgetError, match="needs unbounded memory"):
        check_memory(float("nan"), "a run")
    with pytest.raises(BudgetError, match=r"about 1\.11e\+287 EiB"):
        check_memory(1.28e305, "a run")


@pytest.mark.parametrize(
    ("text", "nbytes"),
    [
        ("1048576", 1024**2),
        ("512M", 512 * 1024**2),
        ("8G", 8 * 1024**3),
        ("1.5g", 1536 * 1024**2),
        ("64K", 65536),
        ("1T", 1024**4),
        (" 2GiB ", 2 * 1024**3),
    ],
)
def test_parse_bytes(text: str, nbytes: int) -> None:
    assert parse_bytes(text) == nbytes


@pytest.mark.parametrize("text", ["", "lots", "-1G", "0", "1e9", "5X", "1" * 100, "nan"])
def test_parse_bytes_refuses(text: str) -> None:
    with pytest.raises(BudgetError, match="SERVOTUNE_MAX_MEMORY"):
        parse_bytes(text)


def test_environment_and_setter(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SERVOTUNE_MAX_MEMORY", "512M")
    assert memory_budget() == 512 * 1024**2
    set_memory_budget(1024)
    assert memory_budget() == 1024  # the setter (the command line) wins
    set_memory_budget("4G")
    assert memory_budget() == 4 * 1024**3
    set_memory_budget(None)
    assert memory_budget() == 512 * 1024**2
    monkeypatch.setenv("SERVOTUNE_MAX_MEMORY", "much")
    with pytest.raises(BudgetError, match="'much'"):
        memory_budget()


@pytest.mark.parametrize("bad", [0, -5, True, 1.5, 2**70, "0"])
def test_setter_refuses(bad: object) -> None:
    with pytest.raises(BudgetError):
        set_memory_budget(bad)  # type: ignore[arg-type]


def test_formatting() -> None:
    assert format_bytes(10) == "10 bytes"
    assert format_bytes(1536) == "1.5 KiB"
    assert format_bytes(2 * 1024**3) == "2 GiB"
    assert format_count(250_000_000) == "250,000,000"
    assert format_count(2.5e302) == "2.5e+302"


def test_run_paths_check_before_allocating(rig: st.Rig) -> None:
    from servotune.excite import design_excitation
    from servotune.pipeline import lock_hold
    from servotune.scenarios import build_scenario, step_inputs, sync_move

    with pytest.raises(BudgetError, match=r"simulate 1e\+12 s needs about .* PiB"):
        build_scenario(rig, "prbs", axis="master", seconds=1e12)
    with pytest.raises(BudgetError, match="sync move"):
        sync_move(rig, seconds=1e12)
    with pytest.raises(BudgetError, match="step run"):
        step_inputs(rig, step_counts=100, seconds=1e12)
    with pytest.raises(BudgetError, match="lock hold"):
        lock_hold(rig, seconds=1e12)
    with pytest.raises(BudgetError, match="excitation of 1e\\+12 s"):
        design_excitation(rig, "master", "prbs", 1e12)
    set_memory_budget(1024)  # a tiny budget refuses even a short simulated run
    with pytest.raises(BudgetError, match="over the memory budget of 1 KiB"):
        build_scenario(rig, "steps", axis="master", seconds=1.0)


def test_engine_checks_the_trace_arrays(rig: st.Rig) -> None:
    from servotune.scenarios import Inputs
    from servotune.sim.engine import Loop, simulate

    inputs = Inputs.hold(2000, len(rig.axes))
    set_memory_budget(2000 * 2 * 72 - 1)
    with pytest.raises(BudgetError, match=r"simulating 1 candidate over 2,000 ticks"):
        simulate(Loop.from_rig(rig), inputs)


def test_gantry_and_linkage_runs() -> None:
    from servotune.arch.gantry import compare_topologies
    from servotune.arch.gantry.load import load_gantry
    from servotune.arch.linkage import load_linkage, run_linkage

    plants = EXAMPLE_RIG.parent
    cfg = load_gantry(plants / "gantry.toml")
    set_memory_budget(1024**2)
    with pytest.raises(BudgetError, match="comparing the gantry topologies over 2 s"):
        compare_topologies(cfg)
    set_memory_budget(None)
    link = load_linkage(plants / "linkage-6axis.toml")
    with pytest.raises(BudgetError, match=r"simulating 100000 s needs about 23\.1 GiB"):
        run_linkage(link, seconds=1e5)
