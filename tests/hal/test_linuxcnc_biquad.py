"""Filter sections run by LinuxCNC's own ``biquad`` component from servotune's export
(servotune.export.linuxcnc_biquad), in real HAL at 1 kHz:

- LinuxCNC's float output is scipy's ``lfilter`` of the same coefficients (an independent
  float implementation) to 1e-9 codes: the exported coefficients and their sign convention are
  right;
- the runtime's fixed-point cascade (servotune.laws.filters.filter_run, whole D/A codes out) on
  the same input differs from LinuxCNC's float by at most one code: the difference the export's
  docstring states, measured here (printed).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared HAL harness
import halrun

from servotune.digest import text_digest_problem
from servotune.errors import ExportError
from servotune.export.linuxcnc_biquad import biquad_hal_text
from servotune.laws.filters import (
    N_FILTER_STATE,
    choose_frac_bits,
    filter_run,
    lowpass2,
    notch,
    quantize_section,
)

PERIOD_S = 0.001
NAMES = ("stq-notch", "stq-lowpass")  # names no other test's instances use


def _sections():
    designs = (notch(35.0, 7.0, -30.0), lowpass2(120.0, 0.5))
    return [quantize_section(d, PERIOD_S, choose_frac_bits(d, PERIOD_S)) for d in designs]


def _input(n: int) -> np.ndarray:
    """D/A codes: steps and a 5–150 Hz chirp, whole codes within ±1500."""
    t = np.arange(n) * PERIOD_S
    steps = np.where((t > 0.2) & (t < 1.2), 900.0, 0.0) - np.where(t > 2.0, 600.0, 0.0)
    chirp = 600.0 * signal.chirp(t, 5.0, t[-1], 150.0) * (t > 0.5)
    return np.rint(steps + chirp).astype(np.int64)


def _fixed_point(sections, x: np.ndarray) -> np.ndarray:
    y = x
    for sec in sections:
        out = np.zeros_like(y)
        filter_run(*sec.step_args(), np.zeros(N_FILTER_STATE, dtype=np.int64), y, out)
        y = out
    return y


def test_linuxcnc_biquad_runs_the_exported_sections(tmp_path: Path) -> None:
    halrun.hal_available()
    sections = _sections()
    text = biquad_hal_text(sections, names=NAMES, period_s=PERIOD_S)
    assert text_digest_problem(text, "#") is None
    x = _input(3000)
    lines = halrun.run_streamed(
        tmp_path,
        load=[f"biquad names={','.join(NAMES)}"],
        functs=NAMES,
        stream=[[v] for v in x.tolist()],
        stream_cfg="f",
        sample_cfg="ff",
        wiring=[
            *(ln for ln in text.splitlines() if not ln.startswith("#")),  # the export, as written
            f"net in streamer.0.pin.0 {NAMES[0]}.in sampler.0.pin.0",
            f"net mid {NAMES[0]}.out {NAMES[1]}.in",
            f"net out {NAMES[1]}.out sampler.0.pin.1",
        ],
        n=x.size,
        period_ns=round(PERIOD_S * 1e9),
        after=[f"getp {NAMES[0]}.valid"],
    )
    rows = np.array([[float(v) for v in r] for r in lines])
    fed, linuxcnc = rows[:, 0], rows[:, 1]
    assert np.array_equal(fed, x)  # the sampler saw the stream from its first row
    # an independent float implementation of the same coefficients
    y = x.astype(float)
    for sec in sections:
        b, a = sec.ba()
        y = signal.lfilter(b, a, y)
    assert np.abs(linuxcnc - y).max() < 1e-9 * max(1.0, np.abs(y).max())
    # the runtime's fixed point: whole codes, within one code of LinuxCNC's float
    diff = np.abs(_fixed_point(sections, x) - linuxcnc)
    print(f"LinuxCNC biquad vs the runtime's fixed point: largest |difference| {diff.max():.3f}")
    assert diff.max() <= 1.0 and np.abs(linuxcnc).max() > 500  # and the filters passed signal


def test_a_name_per_section_is_required() -> None:
    with pytest.raises(ExportError, match="one name per section"):
        biquad_hal_text(_sections(), names=NAMES[:1], period_s=PERIOD_S)
    with pytest.raises(ExportError, match="is not a HAL name"):
        biquad_hal_text(_sections(), names=("a b", "c"), period_s=PERIOD_S)
