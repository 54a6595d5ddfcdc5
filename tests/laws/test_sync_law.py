"""The sync compensator law (laws/sync.py) in the runtime arithmetic."""

from __future__ import annotations

import numpy as np
import pytest

from servotune.fixed import F_U
from servotune.laws.sync import (
    SYNC_OK,
    SYNC_TRIP,
    SYNC_WARN,
    SyncGains,
    dead_zone,
    sync_enter,
    sync_monitor,
    sync_step,
)

T = 0.001


def _run(g: SyncGains, errors: list[int]) -> tuple[list[int], list[int]]:
    c = g.quantize(T)
    args = (
        c.kp.q,
        c.kp.f,
        c.ki_t.q,
        c.ki_t.f,
        c.kd_t.q,
        c.kd_t.f,
        c.dead_zone_counts,
        c.limit_counts,
    )
    integ, e_prev = sync_enter(c.kp.q, c.kp.f, c.dead_zone_counts, c.limit_counts, errors[0])
    comps, integs = [0], [integ]
    for e in errors[1:]:
        comp, integ, e_prev = sync_step(*args, integ, e_prev, e)
        comps.append(comp)
        integs.append(integ)
    return comps, integs


def test_dead_zone_moves_towards_zero_and_clamps() -> None:
    assert [dead_zone(e, 3) for e in (-5, -4, -3, 0, 3, 4, 5)] == [-2, -1, 0, 0, 0, 1, 2]
    assert dead_zone(0, 0) == 0 and dead_zone(-7, 0) == -7
    assert dead_zone(2**40, 0) == 2**31 - 1  # docs/runtime.md#saturation-and-clamps: errors clamped
    assert dead_zone(-(2**40), 10) == -(2**31 - 1) + 10


def test_entry_is_bumpless_and_pi_follows_the_float_law() -> None:
    g = SyncGains(law="pi", kp=0.6, ki=12.0, limit_counts=100_000)
    errs = [40] * 50 + [-25] * 50
    comps, _ = _run(g, errs)
    # float reference of u(k) = Kp·e(k) + I(k), I(k) = I(k−1) + Ki·T·e(k), I(0) = −Kp·e(0)
    integ = -g.kp * errs[0]
    ref = [0.0]
    for e in errs[1:]:
        integ += g.ki * T * e
        ref.append(g.kp * e + integ)
    assert comps[0] == 0 and comps[1] == round(g.kp * 40 - g.kp * 40 + g.ki * T * 40)
    np.testing.assert_allclose(comps, ref, atol=0.5 + 1e-9)  # one quantiser rounding


def test_limit_clamps_and_the_integrator_does_not_wind_up() -> None:
    g = SyncGains(law="pi", kp=1.0, ki=100.0, limit_counts=50)
    comps, integs = _run(g, [0] + [200] * 200 + [-10] * 3)
    assert max(comps) == 50
    # while saturated the integrator stops at the rail instead of growing
    assert max(integs) <= 50 * 2**F_U
    # once the error reverses the output leaves the rail at once (no wound-up integral)
    assert comps[-1] < 50 and comps[-3] < comps[-4]


def test_pd_reacts_to_the_error_change_and_dead_zone_mutes_noise() -> None:
    g = SyncGains(law="pd", kp=0.5, kd=0.004, dead_zone_counts=2, limit_counts=1000)
    comps, _ = _run(g, [0, 0, 10, 10, 10, 1, -2, 2])
    # e_d: 0 0 8 8 8 0 0 0; Kd/T = 4: step → 0.5·8 + 4·8 = 36, then 0.5·8 = 4, then 0 − 32
    assert comps == [0, 0, 36, 4, 4, -32, 0, 0]


def test_monitor_levels() -> None:
    assert [sync_monitor(e, 10, 20) for e in (0, 9, -10, 19, -20, 500)] == [
        SYNC_OK,
        SYNC_OK,
        SYNC_WARN,
        SYNC_WARN,
        SYNC_TRIP,
        SYNC_TRIP,
    ]
    assert sync_monitor(10**9, 0, 0) == SYNC_OK  # both thresholds off


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"law": "pid", "kp": 1.0}, "law must be one of pi, pd"),
        ({"kp": -1.0}, "kp must be a finite number >= 0"),
        ({"law": "pd", "kp": 1.0, "ki": 1.0}, "ki must be 0 for a PD"),
        ({"kp": 1.0, "limit_counts": 0}, "limit_counts must be an integer in 1.."),
        ({"kp": 1.0, "dead_zone_counts": 1.5}, "dead_zone_counts must be an integer"),
    ],
)
def test_gains_are_validated(kw: dict, msg: str) -> None:
    with pytest.raises(ValueError, match=msg):
        SyncGains(**kw)
