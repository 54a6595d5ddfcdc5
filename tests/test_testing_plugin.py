"""servotune.testing: the pytest plugin for users, run as a user's repository would run it."""

from __future__ import annotations

from pathlib import Path

import pytest

import servotune as st
from servotune.testing import assert_step_response, step_response
from servotune.tuning import write_tuning

pytest_plugins = ["pytester"]

RIG = Path(__file__).resolve().parents[1] / "plants" / "pc-dual-servo.toml"

# the README's example, verbatim
USER_TEST = """
from servotune.testing import assert_step_response

def test_master_step(servotune_rig, servotune_tuning):
    assert_step_response(servotune_tuning, servotune_rig, axis="master", step_counts=3072,
                         max_overshoot_pct=5, max_settling_s=LIMIT)
"""


@pytest.fixture(scope="module")
def tuning_file(tmp_path_factory, default_tuning) -> Path:
    # the default tuning: a step response is judged on a loop as `servotune tune` makes it
    p = tmp_path_factory.mktemp("tuning") / "tuning.json"
    write_tuning(default_tuning, p)
    return p


def test_readme_example_passes_and_fails(pytester, tuning_file: Path) -> None:
    pytester.makeini(f"[pytest]\nservotune_rig = {RIG}\nservotune_tuning = {tuning_file}\n")
    # the master's PI (largest Ki at 50° phase margin) settles a one-revolution step in ~0.9 s
    ok = pytester.makepyfile(test_servo_ok=USER_TEST.replace("LIMIT", "1.2"))
    pytester.runpytest().assert_outcomes(passed=1)
    ok.unlink()
    pytester.makepyfile(test_servo_tight=USER_TEST.replace("LIMIT", "0.5"))
    res = pytester.runpytest()
    res.assert_outcomes(failed=1)
    res.stdout.fnmatch_lines(["*master step of 3072 counts: settling time * s > 0.5 s*"])


def test_fixture_without_option_is_an_error_saying_how_to_configure(pytester) -> None:
    # a user's CI must not be green having checked nothing: no skip
    pytester.makepyfile("def test_x(servotune_rig):\n    pass\n")
    res = pytester.runpytest()
    res.assert_outcomes(errors=1)
    res.stdout.fnmatch_lines(["*servotune_rig = path/to/file*--servotune-rig FILE*"])
    assert res.ret != 0


def test_step_response_measures_the_loop(tuning_file: Path) -> None:
    from servotune.tuning import read_tuning

    rig = st.load_rig(RIG)
    t = read_tuning(tuning_file)
    r = step_response(t, rig, axis="master", step_counts=3072)
    assert r.faults == 0 and abs(r.final_error_counts) <= 4
    assert 0 < r.info.rise_time_s < r.info.settling_time_s < 2.0
    # the slave follows the master's move and arrives with it
    s = step_response(t, rig, axis="slave", step_counts=3072)
    assert s.faults == 0 and abs(s.final_error_counts) <= 8
    assert abs(s.info.settling_time_s - r.info.settling_time_s) < 0.2
    with pytest.raises(AssertionError, match="rise time"):
        assert_step_response(t, rig, axis="master", step_counts=3072, max_rise_s=0.001)
