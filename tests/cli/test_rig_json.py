"""`servotune rig --json` prints strict JSON (it once printed ``Infinity``)."""

from __future__ import annotations

import json
from pathlib import Path

import servotune.rig
from servotune.cli import main

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "plants" / "pc-dual-servo.toml"


def _strict(text: str) -> dict:
    def refuse(name: str) -> None:
        raise AssertionError(f"{name} is not JSON (RFC 8259)")

    return json.loads(text, parse_constant=refuse)


def test_rig_json_never_prints_infinity(capsys, monkeypatch) -> None:
    # a fact that is infinite (no rig file can make one any more: the speed limit's lower bound
    # keeps the time to wrap finite) goes out as null, never as Infinity
    real = servotune.rig.describe_rig

    def with_inf(rig):
        facts = real(rig)
        facts["axes"]["master"]["time_to_wrap_at_speed_limit_s"] = float("inf")
        return facts

    monkeypatch.setattr(servotune.rig, "describe_rig", with_inf)
    assert main(["rig", str(RIG), "--json"]) == 0
    facts = _strict(capsys.readouterr().out)
    assert facts["axes"]["master"]["time_to_wrap_at_speed_limit_s"] is None
    monkeypatch.undo()
    assert main(["rig", str(RIG), "--json"]) == 0
    facts = _strict(capsys.readouterr().out)
    # docs/runtime.md#timer-and-achieved-period: round(1,193,180 Hz × 4 ms)
    assert facts["timer_divisor"] == 4773
