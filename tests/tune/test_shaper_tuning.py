"""``tune --shaper`` on the resonant example rig (plants/belt-scale.toml), through to the
exported tables and to verify (docs/runtime.md#shapers-in-the-tables).

A study (marker ``study``: ``make test-study``, run by ``.ci/run``): one quick tune of the
resonant rig with its filter choice (about 35 s) and two nominal verifications.

- The tune designs the master's shaper for its closed-loop mode (15 Hz with its notch) and
  stores the Q15 amplitudes in its controller; the slave gets none; ``design.shapers`` says
  what and why. The tables export carries the same amplitudes.
- ``verify`` runs the master's moves shaped: the settling times move by the shaper's
  centroid delay ``Σ i·a_i / 2^15`` ticks (computed here from the amplitudes), within two
  ticks and 20 %, against the same tuning without the shaper. On this rig the notch has
  already taken the mode out of the closed loop: the residual vibration is the noise floor
  either way (measured 1.08 against 1.22 counts in ``track``), so the benefit of a shaper on a
  ringing loop is shown in the engine (tests/sim/test_shaped_moves.py) and the gantry
  (tests/sim/test_gantry_shaped_moves.py), not here.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from servotune.examples import example_path
from servotune.export.json import load_tables
from servotune.export.json import to_string as tables_to_string
from servotune.rig import load_rig
from servotune.tune.slave import SlaveTuneSpec
from servotune.tune.workflow import tune_rig
from servotune.verify.run import verify
from servotune.verify.spec import load_spec

pytestmark = pytest.mark.study


@pytest.fixture(scope="module")
def tuned():
    path = example_path("belt-scale.toml")
    spec = SlaveTuneSpec(generations=2, population=6, max_overshoot_pct=300.0)
    lines: list[str] = []
    tuning = tune_rig(path, seed=0, spec=spec, shaper="auto", progress=lines.append)
    return tuning, load_rig(path), lines


def test_the_tune_designs_the_masters_shaper_for_its_closed_loop_mode(tuned) -> None:
    tuning, _, lines = tuned
    master, slave = tuning.controllers
    taps = np.array(master.shaper)
    assert taps.size > 5 and taps.sum() == 1 << 15 and np.all(taps >= 0)
    assert slave.shaper == ()
    rec = tuning.design["shapers"]["master"]
    assert rec["amplitudes_q"] == list(master.shaper)
    (mode,) = rec["modes"]
    assert 14.0 < mode["freq_hz"] < 16.0 and 0.0 < mode["damping"] < 0.1  # the 15 Hz mode
    assert any("shaper for master" in line and "later" in line for line in lines)
    assert master.filters  # the notch chosen with it is kept


def test_the_tables_export_carries_the_amplitudes(tuned) -> None:
    tuning, rig, _ = tuned
    doc = load_tables(tables_to_string(tuning, rig=rig, unverified=True))
    assert [ax["shaper"] for ax in doc["data"]["axes"]] == [list(tuning.controllers[0].shaper), []]


def _settling(v) -> dict[tuple[str, str], float]:
    return {
        (r.scenario, r.axis): r.worst
        for r in v.rows
        if r.quantity == "settling_time_s" and r.variant == "nominal"
    }


def test_verify_runs_the_moves_shaped(tuned) -> None:
    tuning, rig, _ = tuned
    spec = load_spec(example_path("belt-scale.spec.toml"))
    spec = dataclasses.replace(spec, montecarlo=dataclasses.replace(spec.montecarlo, count=0))
    lines: list[str] = []
    shaped = verify(tuning, rig, spec, progress=lines.append)
    plain_ctl = dataclasses.replace(tuning.controllers[0], shaper=())
    plain_tuning = dataclasses.replace(tuning, controllers=(plain_ctl, tuning.controllers[1]))
    plain = verify(plain_tuning, rig, spec)
    assert any("moves shaped by its" in line for line in lines)
    taps = np.array(tuning.controllers[0].shaper, dtype=float)
    centroid_s = float(np.arange(taps.size) @ taps) / (1 << 15) * rig.period_s
    a, b = _settling(shaped), _settling(plain)
    assert a.keys() == b.keys() and len(a) >= 4
    for key in a:
        shift = a[key] - b[key]
        assert abs(shift - centroid_s) <= 2 * rig.period_s + 0.2 * centroid_s, (key, shift)
