"""The phase lead the filter tuner adds behind a notch (``servotune.tune.filters.lead_section``),
checked against its definition on the realised integers with scipy's ``freqz``: gain 1 at DC,
``ratio²`` far above its centre, the most phase, ``2·asin((ratio − 1)/(ratio + 1))``, at its
centre (two equal first-order leads: the textbook lead's maximum phase, doubled)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import freqz

from servotune.laws.filters import realize
from servotune.tune.filters import lead_candidates, lead_section

PERIOD_S = 0.004


@pytest.mark.parametrize(("centre", "ratio"), [(15.4, 1.15), (20.1, 1.1), (40.0, 1.4)])
def test_lead_gain_and_phase(centre: float, ratio: float) -> None:
    q = realize(lead_section(centre, ratio), PERIOD_S)
    b, a = q.ba()
    w = np.geomspace(centre / 50, 0.9 * math.pi / PERIOD_S, 4000)
    h = freqz(b, a, worN=w * PERIOD_S)[1]
    assert abs(h[0]) == pytest.approx(1.0, rel=0.01)
    phase = np.degrees(np.angle(h))
    want = 2 * math.degrees(math.asin((ratio - 1) / (ratio + 1)))
    k = int(np.argmax(phase))
    assert phase[k] == pytest.approx(want, abs=0.5)
    assert w[k] == pytest.approx(centre, rel=0.05)  # pre-warped at the centre
    assert np.all(np.abs(h) <= ratio**2 * 1.01) and abs(h[-1]) > 1.0


def test_lead_candidates_leave_out_a_full_chain_and_a_lead_near_nyquist() -> None:
    one = (lead_section(10.0, 1.1),)
    got = lead_candidates("notch x1.5", one, 12.0, 125.0)
    assert len(got) == 4 and all(len(s) == 2 for _, s in got)
    assert got[0][0] == "notch x1.5+lead 1.1@15.6"
    assert lead_candidates("notch", one * 4, 12.0, 125.0) == []
    assert lead_candidates("notch", one, math.nan, 125.0) == []
    # a crossover so high that every lead's pole would pass half the Nyquist frequency
    assert lead_candidates("notch", one, 300.0, 125.0) == []
