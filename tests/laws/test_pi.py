"""The integer PI tick against an exact model of its arithmetic
(docs/runtime.md#integrator-and-conditional-integration).

``pi_step`` adds its four terms with plain adds when each is below 2**60 in magnitude (the
common case, a speed path) and with saturating adds otherwise. The model below does every step
in Python's unbounded integers and saturates after each one, as docs/runtime.md defines the runtime
arithmetic; both paths must give its integers exactly, including at the switch between them.
"""

from __future__ import annotations

import numpy as np
import pytest

from servotune.fixed import E_MAX, F_U, INT64_MAX
from servotune.laws.pi import PIGains, pi_step

TWO_60 = 2**60


def _sat(x: int) -> int:
    return max(-int(INT64_MAX), min(int(INT64_MAX), x))


def _round_shift(x: int, f: int) -> int:
    """``x / 2**f`` rounded half away from zero, exactly."""
    m = (abs(x) + 2 ** (f - 1)) >> f
    return m if x >= 0 else -m


def _model(
    kp_q: int,
    kp_f: int,
    kit_q: int,
    kit_f: int,
    integ: int,
    e: int,
    u_add: int,
    zero: int,
    code_max: int,
) -> tuple[tuple[int, int], bool]:
    """``pi_step``'s ``(u_q, I)``, and whether its plain-add path applies."""
    ec = max(-int(E_MAX), min(int(E_MAX), e))
    p = _sat(kp_q * ec * 2 ** (F_U - kp_f))
    d = _sat(kit_q * ec * 2 ** (F_U - kit_f))
    u_pre = _sat(_sat(_sat(p + integ) + d) + u_add)
    fast = all(abs(v) < TWO_60 for v in (p, d, integ, u_add))  # pi_step's plain-add path
    raw = _round_shift(u_pre, F_U) + zero
    if not ((raw > code_max and d > 0) or (raw < 0 and d < 0)):
        integ = _sat(integ + d)
        integ = min(max(integ, -zero * 2**F_U), (code_max - zero) * 2**F_U)
    return (_sat(_sat(p + integ) + u_add), integ), fast


def _cases(rng: np.random.Generator, n: int) -> list[tuple[int, ...]]:
    """Constants and states from ordinary to extreme, around the 2**60 switch and the rails."""
    near = [TWO_60 - 1, TWO_60, TWO_60 + 1, 2**61, 3 * 2**60, 2**62 - 1, 2**62, int(INT64_MAX)]
    near += [-v for v in near]
    cases = []
    for _ in range(n):
        kind = rng.integers(4)
        if kind == 0:  # the example rig: 12-bit D/A, gains of the bench, errors of a move
            g = PIGains(kp=float(rng.uniform(0, 2)), ki=float(rng.uniform(0, 50))).quantize(0.004)
            kp_q, kp_f, kit_q, kit_f = g.kp.q, g.kp.f, g.ki_t.q, g.ki_t.f
            zero, code_max = 2048, 4095
            integ = int(rng.integers(-zero, code_max - zero + 1)) << F_U
            e = int(rng.integers(-20_000, 20_001))
            u_add = int(rng.integers(-100, 101)) << F_U
        else:  # the sync law's wide rails, large gains and errors, terms near the switch
            kp_f, kit_f = (int(f) for f in rng.integers(0, F_U + 1, 2))
            kp_q, kit_q = (int(q) for q in rng.integers(0, 2**31, 2))
            limit = int(rng.choice([2047, 2**20, 2**29, 2**30]))
            zero, code_max = limit, 2 * limit
            integ = int(rng.choice(near)) if kind == 1 else int(rng.integers(-(2**62), 2**62))
            integ = min(max(integ, -zero * 2**F_U), (code_max - zero) * 2**F_U)
            e = int(rng.choice([0, 1, -1, 2**20, -(2**20), 2**31, -(2**31), 2**40, -(2**40)]))
            e = e if kind != 3 else int(rng.integers(-(2**12), 2**12))
            u_add = int(rng.choice(near)) if kind < 3 else int(rng.integers(-(2**61), 2**61))
        cases.append((kp_q, kp_f, kit_q, kit_f, integ, e, u_add, zero, code_max))
    return cases


@pytest.mark.parametrize("seed", [1, 2])
def test_pi_step_equals_the_exact_model_on_both_paths(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_fast = n_slow = n_saturated = 0
    for case in _cases(rng, 3000):
        expected, fast = _model(*case)
        got = pi_step(*case)
        assert (int(got[0]), int(got[1])) == expected, case
        n_fast += fast
        n_slow += not fast
        n_saturated += abs(expected[0]) == INT64_MAX
    # both of pi_step's paths ran, and the saturating one did saturate
    assert n_fast > 500
    assert n_slow > 500
    assert n_saturated > 50


def test_pi_step_at_the_switch_between_its_paths() -> None:
    # Kp = Ki·T = 1 code/count (q = 2**30, f = 30): p_term = d_i = e · 2**32; the rails at
    # ±2**30 codes let I reach ±2**62; every term just below, at and above 2**60, and sums of
    # terms below 2**61 that would pass 2**63 unsaturated
    terms = [TWO_60 - 1, TWO_60, 2**61 - 1, 2**61, 3 * 2**60 - 1, 2**62 - 1, int(INT64_MAX)]
    terms = [0, *terms, *(-v for v in terms)]
    errors = [2**28 - 1, 2**28, 2**29 - 1, 2**29, 3 * 2**28 - 1, 2**31]
    errors = [0, *errors, *(-v for v in errors)]
    n_fast = 0
    for e in errors:
        for integ in terms:
            integ = min(max(integ, -(2**62)), 2**62)
            for u_add in terms:
                case = (2**30, 30, 2**30, 30, integ, e, u_add, 2**30, 2**31)
                expected, fast = _model(*case)
                assert tuple(int(v) for v in pi_step(*case)) == expected, case
                n_fast += fast
    assert n_fast == 27  # |e| < 2**28, |I| < 2**60 and |u_add| < 2**60: 3 values each
