"""Repeatability of ``servotune autotune`` live (docs/autotune.md#the-live-run), in real HAL:
five runs on one stand-in machine (tests/hal/autotune_machine.py) whose plant component has the
example rig's encoder noise (0.3 counts), each run with its own noise stream (the component's
``seed``), one after the other in one HAL session as a user would repeat the run.

- every run loads validated gains, from captures that differ (the noise is in);
- the loaded gains are within ±5 % of each other (the spread is printed);
- the fitted gain and time constant of any two runs are within their 95 % intervals of each
  other (the intervals overlap).
"""

from __future__ import annotations

import json
import sys
import tomllib
from itertools import combinations
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared HAL harness
import autotune_machine as m
import halrun

from servotune.cli import main
from servotune.io.halcmd import Halcmd

pytestmark = pytest.mark.study  # make test-study (.ci/run): it holds HAL's session 2.5 minutes

PLANT = "statplantn"  # names no other test's components use
GUARD = "servotune_guard_rep"
SEEDS = (1, 2, 3, 4, 5)
GAINS = ("Pgain", "Igain", "FF1")  # the parameters the run sets away from 0
GAIN_SPREAD = 0.05
"""Largest (max − min) / min of each loaded gain over the runs (the acceptance's ±5 %)."""


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> list[dict]:
    """The five runs' records, each with its fitted plant's values and 95 % intervals."""
    halrun.hal_available()
    build = tmp_path_factory.mktemp("repeat_build")
    plant_so, guard_so = m.build(build, PLANT, noise=True, guard=GUARD)
    work = tmp_path_factory.mktemp("repeat")
    m.workspace(work, m.config_text(8.0))
    halrun.share(work)
    hal = Halcmd(user=halrun.HAL_USER if m.hal_user_args() else None)
    records = []
    with halrun.installed_component(plant_so), halrun.installed_component(guard_so):
        with m.machine(work, PLANT, guard=GUARD):
            for seed in SEEDS:
                hal("setp", f"{PLANT}.seed", str(seed))
                out = work / f"run{seed}"
                argv = ["autotune", str(work / "at.toml"), "-o", str(out), "--guard-name", GUARD]
                rc = main([*argv, *m.hal_user_args()])
                rec = json.loads((out / "autotune.json").read_text())
                assert rc == 0, rec["stopped"]
                plant = tomllib.loads((out / "fitted-rig.toml").read_text())["axis"]["master"]
                rec["plant"] = plant["plant"]
                rec["capture"] = (out / "capture.txt").read_text()
                records.append(rec)
    return records


def test_every_run_loads_validated_gains_from_its_own_noise(runs) -> None:
    assert [r["status"] for r in runs] == ["loaded"] * len(SEEDS)
    assert all(r["validation"]["passed"] for r in runs)
    # the noise is in: five different captures, five different fits
    assert len({r["capture"] for r in runs}) == len(SEEDS)
    assert len({r["fit"]["params"]["gain_cps_per_v"] for r in runs}) == len(SEEDS)


def test_the_loaded_gains_are_within_five_percent_of_each_other(runs) -> None:
    spread = {}
    for k in GAINS:
        values = [r["loaded"][k] for r in runs]
        assert min(values) > 0, (k, values)
        spread[k] = (max(values) - min(values)) / min(values)
    print("autotune repeatability, spread of the loaded gains over 5 noise seeds:", spread)
    assert all(s <= GAIN_SPREAD for s in spread.values()), spread


@pytest.mark.parametrize("param", ["gain_cps_per_v", "tau_s"])
def test_the_fitted_plants_are_within_their_intervals_of_each_other(runs, param) -> None:
    est = [(r["plant"][param], *r["plant"]["fit"]["ci95"][param]) for r in runs]
    print(f"autotune repeatability, {param} (estimate, 95 % interval):", est)
    for (x, lo, hi), (y, lo2, hi2) in combinations(est, 2):
        assert lo <= x <= hi and lo2 <= y <= hi2
        assert abs(x - y) <= (hi - lo) / 2 + (hi2 - lo2) / 2, ((x, lo, hi), (y, lo2, hi2))
