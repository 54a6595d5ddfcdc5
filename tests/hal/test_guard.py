"""The safety envelope's HAL component (servotune.export.hal_component.guard_component,
docs/autotune.md#the-safety-envelope) in real HAL: each limit trips the output to zero in the
very period the streamed signals breach it, computed here from the streamed values alone.

Four guards run in one session on one thread (1 ms), each fed its own position, command and
controller output by ``streamer`` and read by ``sampler``: one breaches the travel window, one
the speed, one the following error, one the output amplitude; before its breach each passes
its input through unchanged.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from servotune.errors import ExportError
from servotune.export.hal_component import guard_component

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared HAL harness
import halrun

PERIOD_S = 0.001
N = 3000
SCALE = 4.0  # counts per feedback unit
LIMITS = {
    "travel_counts": (-3000.0, 2000.0),
    "speed_cps": 250_000.0,
    "following_error_counts": 400.0,
    "max_volts": 6.0,
}
REASONS = {"travel": 1, "speed": 2, "following": 3, "output": 4}


def _signals(kind: str, rng: np.random.Generator) -> np.ndarray:
    """(N, 3): position and command [feedback units], controller output [V]. Everything within
    the limits but the one the kind names, which is breached once, about two thirds in."""
    t = np.arange(N) * PERIOD_S
    pos_counts = 1500.0 * np.sin(2 * np.pi * 0.7 * t) + 100.0  # ≤ 6.6e3 counts/s
    cmd_counts = pos_counts + 200.0 * np.sin(2 * np.pi * 3.1 * t)
    volts = 4.0 * np.sin(2 * np.pi * 11.0 * t) + rng.uniform(-0.5, 0.5, N)
    k = 2 * N // 3 + int(rng.integers(0, 100))
    if kind == "travel":
        pos_counts[k:] = pos_counts[k:] + np.linspace(0, 4000.0, N - k)
        cmd_counts[k:] = pos_counts[k:]
    elif kind == "speed":
        pos_counts[k:] += 300.0  # one period's jump: 300 counts in 1 ms = 300,000 counts/s
        cmd_counts[k:] += 300.0
    elif kind == "following":
        cmd_counts[k:] += 250.0 * np.linspace(1.0, 3.0, N - k)
    else:
        volts[k] = 6.5
    return np.stack([pos_counts / SCALE, cmd_counts / SCALE, volts], axis=1)


def _first_breach(sig: np.ndarray) -> tuple[int, int]:
    """(period, reason) of the first breach, as the component's rules read the streamed values."""
    p = sig[:, 0] * SCALE
    rel = p - p[0]
    speed = np.concatenate([[0.0], np.diff(p) / PERIOD_S])
    fe = sig[:, 1] * SCALE - p
    lo, hi = LIMITS["travel_counts"]
    for k in range(N):
        for reason, hit in (
            (1, rel[k] < lo or rel[k] > hi),
            (2, abs(speed[k]) > LIMITS["speed_cps"]),
            (3, abs(fe[k]) > LIMITS["following_error_counts"]),
            (4, abs(sig[k, 2]) > LIMITS["max_volts"]),
        ):
            if hit:
                return k, reason
    return -1, 0


def test_each_limit_zeroes_the_output_in_the_period_of_the_breach(tmp_path: Path) -> None:
    halrun.hal_available()
    rng = np.random.default_rng(11)
    kinds = list(REASONS)
    names = [f"st_test_guard_{k}" for k in kinds]
    sos = []
    for name in names:
        (tmp_path / f"{name}.comp").write_text(
            guard_component(name=name, position_scale=SCALE, **LIMITS)
        )
        sos.append(halrun.halcompile(tmp_path / f"{name}.comp"))
    sigs = [_signals(k, rng) for k in kinds]
    stream = np.concatenate(sigs, axis=1)
    hal = [n.replace("_", "-") for n in names]
    wiring = []
    for i, h in enumerate(hal):
        for j, pin in enumerate(("position", "command", "volts-in")):
            wiring.append(f"net in{i}{j} streamer.0.pin.{3 * i + j} {h}.{pin}")
        for j, pin in enumerate(("volts-out", "fault", "reason", "trip-period")):
            wiring.append(f"net out{i}{j} {h}.{pin} sampler.0.pin.{4 * i + j}")
    got = halrun.run_streamed(
        tmp_path,
        load=names,
        functs=hal,
        stream=stream.tolist(),
        stream_cfg="fff" * len(names),
        sample_cfg="fbss" * len(names),
        wiring=wiring,
        n=N,
        period_ns=round(PERIOD_S * 1e9),
        modules=sos,
    )
    assert len(got) == N and all(len(r) == 16 for r in got), got[-3:]
    for i, kind in enumerate(kinds):
        period, reason = _first_breach(sigs[i])
        assert reason == REASONS[kind], (kind, period, reason)  # the signals breach that limit
        volts_out = np.array([float(r[4 * i]) for r in got])
        fault = np.array([int(r[4 * i + 1]) for r in got])
        assert np.flatnonzero(fault)[0] == period, kind  # in the period of the breach
        assert np.all(fault[period:] == 1) and np.all(volts_out[period:] == 0.0), kind
        assert int(got[period][4 * i + 2]) == reason and int(got[-1][4 * i + 3]) == period
        # before it the output passed unchanged (halsampler prints %f: 6 decimals)
        assert np.allclose(volts_out[:period], sigs[i][:period, 2], atol=6e-7), kind


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"travel_counts": (0.0, 10.0)}, "travel"),
        ({"speed_cps": 0.0}, "speed_cps"),
        ({"max_volts": float("inf")}, "max_volts"),
    ],
)
def test_a_bad_limit_is_refused(change: dict, words: str) -> None:
    with pytest.raises(ExportError, match=words):
        guard_component(name="st_guard", **(LIMITS | change))
