"""pytest for users: check a tuning's step responses in the bit-true loop, in three lines.

Registered as a pytest plugin (entry point ``servotune``), so in a user's repository::

    # pytest.ini / pyproject [tool.pytest.ini_options]
    servotune_rig = plants/my-rig.toml
    servotune_tuning = tuning.json

    # test_servo.py
    from servotune.testing import assert_step_response

    def test_master_step(servotune_rig, servotune_tuning):
        assert_step_response(servotune_tuning, servotune_rig, axis="master", step_counts=3072,
                             max_overshoot_pct=5, max_settling_s=1.2)

The fixtures ``servotune_rig`` and ``servotune_tuning`` load the files named by the ini options
(paths relative to the rootdir) or the command-line options ``--servotune-rig`` and
``--servotune-tuning``. A test that asks for one of them while its option is not set is an
error that says how to set it, never a skip: a CI that checked nothing must not be green.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from servotune.errors import SpecError
from servotune.laws.axis import MODE_TASK
from servotune.metrics import StepInfo, step_info
from servotune.rig import Rig, load_rig
from servotune.scenarios import step_inputs
from servotune.sim.engine import simulate
from servotune.tuning import Tuning, read_tuning

__all__ = ["StepResponse", "assert_step_response", "step_response"]


@dataclass(frozen=True, slots=True, kw_only=True)
class StepResponse:
    """A step of the master's reference and one axis's response, in the bit-true loop.

    Attributes
    ----------
    axis : str
    step_counts : int
    info : StepInfo
        MATLAB ``stepinfo`` characteristics of the axis position (from the step).
    final_error_counts : int
        Reference − position at the end [counts].
    faults : int
        Fault flags seen on the axis.
    """

    axis: str
    step_counts: int
    info: StepInfo
    final_error_counts: int
    faults: int


def step_response(
    tuning: Tuning,
    rig: Rig,
    *,
    axis: str,
    step_counts: int,
    seconds: float = 2.0,
    seed: int = 0,
) -> StepResponse:
    """Step the master's reference by ``step_counts`` (all axes in task mode); measure ``axis``.

    A slave's response is to the master's move (its reference is the master's position).
    """
    loop = tuning.loop(rig)
    names = rig.axis_names
    if axis not in names:
        raise SpecError(f"no axis {axis!r}; axes: {list(names)}")
    inp = step_inputs(rig, step_counts=step_counts, seconds=seconds)
    lead = int(np.argmax(inp.mode[:, 0] == MODE_TASK))
    tr = simulate(loop, inp, seed=seed)
    i = names.index(axis)
    t = tr.time_s[lead:] - tr.time_s[lead]
    y = tr.pos_counts[lead:, i].astype(float)
    info = step_info(t, y, y_init=float(y[0]), y_final=float(step_counts))
    return StepResponse(
        axis=axis,
        step_counts=int(step_counts),
        info=info,
        final_error_counts=int(step_counts - tr.pos_counts[-1, i]),
        faults=int(np.bitwise_or.reduce(tr.flags[:, i] & 3)),
    )


def assert_step_response(
    tuning: Tuning,
    rig: Rig,
    *,
    axis: str,
    step_counts: int,
    max_overshoot_pct: float | None = None,
    max_settling_s: float | None = None,
    max_rise_s: float | None = None,
    max_final_error_counts: int | None = None,
    seconds: float = 2.0,
    seed: int = 0,
) -> StepResponse:
    """Assert step-response limits of one axis (MATLAB ``stepinfo`` definitions, 2 % band).

    Raises
    ------
    AssertionError
        Naming every limit the response breaks, with the measured value.
    """
    r = step_response(tuning, rig, axis=axis, step_counts=step_counts, seconds=seconds, seed=seed)
    broken = []
    if r.faults:
        broken.append(f"fault flags {r.faults} (counter fault 1, following-error trip 2)")
    checks = (
        ("overshoot", r.info.overshoot_pct, max_overshoot_pct, "%"),
        ("settling time", r.info.settling_time_s, max_settling_s, "s"),
        ("rise time", r.info.rise_time_s, max_rise_s, "s"),
        ("final error", abs(r.final_error_counts), max_final_error_counts, "counts"),
    )
    for name, value, limit, unit in checks:
        if limit is not None and not (value <= limit):  # NaN (never reached) breaks the limit
            broken.append(f"{name} {value:.4g} {unit} > {limit:g} {unit}")
    if broken:
        raise AssertionError(f"{axis} step of {step_counts} counts: " + "; ".join(broken))
    return r


# --- the pytest plugin ----------------------------------------------------------------------


def pytest_addoption(parser: Any) -> None:
    """Ini and command-line options naming the rig and tuning files."""
    parser.addini("servotune_rig", "rig file (TOML) for the servotune_rig fixture", default="")
    parser.addini("servotune_tuning", "tuning file for the servotune_tuning fixture", default="")
    group = parser.getgroup("servotune")
    group.addoption("--servotune-rig", default=None, help="rig file for servotune_rig")
    group.addoption("--servotune-tuning", default=None, help="tuning file for servotune_tuning")


def _configured(request: Any, name: str) -> Path:
    import pytest

    value = request.config.getoption(f"--{name.replace('_', '-')}") or request.config.getini(name)
    if not value:
        flag = f"--{name.replace('_', '-')}"
        pytest.fail(
            f"the {name} fixture has no file to load: set `{name} = path/to/file` under "
            f"[tool.pytest.ini_options] in pyproject.toml (or [pytest] in pytest.ini), or pass "
            f"{flag} FILE",
            pytrace=False,
        )
    p = Path(value)
    return p if p.is_absolute() else Path(request.config.rootpath) / p


def _fixture(func: Any) -> Any:
    import pytest

    return pytest.fixture(scope="session")(func)


@_fixture
def servotune_rig(request: Any) -> Rig:
    """The rig named by the ``servotune_rig`` option."""
    return load_rig(_configured(request, "servotune_rig"))


@_fixture
def servotune_tuning(request: Any) -> Tuning:
    """The tuning named by the ``servotune_tuning`` option."""
    return read_tuning(_configured(request, "servotune_tuning"))
