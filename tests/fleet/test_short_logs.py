"""Short closed-loop logs (4 s = 1,000 ticks): a fit either answers honestly or refuses in one line.

Before, about one 4 s log in five stopped the fit with a bare ``ValueError`` (``math domain
error`` / ``invalid number of data points (0)``): the noise model chosen for the residual had its
moving-average root at the stability clamp, so its whitening filter needed ~920 samples to
settle, and the log had none left after them. Now such a log is refused with an
:class:`~servotune.errors.IdentificationError` naming it and saying why (CLI: one line, exit 3),
and the fits that are given keep their 95 % intervals honest: for every fit that passes its own
diagnostics the truth lies within 4 interval half-widths / 1.96 (|z| < 4) of the estimate.
The logs and their true plants come from the fleet generator of ``tests/fleet/test_fleet.py`` (15
machines of the example rig's master with drawn gain, tau, delay, offset and friction).
"""

from __future__ import annotations

import warnings

import pytest
from test_fleet import write_fleet_logs

from servotune.cli import main
from servotune.errors import IdentificationError
from servotune.identify import fit_log

N_LOGS = 16  # seed 5: 6 of them are too short for their disturbance (checked below)


@pytest.fixture(scope="module")
def short_logs(tmp_path_factory: pytest.TempPathFactory):
    d = tmp_path_factory.mktemp("short")
    return write_fleet_logs(d, N_LOGS, seconds=4.0, dates=("2025-01-01",), seed=5)


def test_a_short_log_is_fitted_honestly_or_refused_in_one_line(short_logs) -> None:
    paths, truth = short_logs
    refused, fitted = [], []
    for p in paths:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # inadequacy warnings: counted through .adequate
            try:
                r, _, _ = fit_log(p)
            except IdentificationError as exc:  # anything else fails the test
                assert str(p) in str(exc) and "too short" in str(exc), exc
                refused.append(p.name)
                continue
        fitted.append(p.name)
        if not r.adequate:
            continue  # it says so
        t = truth[p.name.split("_")[0]]
        for k in ("gain_cps_per_v", "tau_s"):
            lo, hi = r.ci95[k]
            z = (r.params[k] - t[k]) / ((hi - lo) / 3.92)
            assert abs(z) < 4.0, (p.name, k, r.params[k], t[k], (lo, hi))
    # the refusals are the exception, and both outcomes occur in this set
    assert 0 < len(refused) <= N_LOGS // 2 and len(fitted) >= N_LOGS // 2, (refused, fitted)


def test_the_cli_refuses_a_too_short_log_in_one_line(short_logs, capsys) -> None:
    paths, _ = short_logs
    bad = next(p for p in paths if p.name.startswith("m004"))  # refused in the test above
    assert main(["fit", str(bad)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("servotune fit: error: ") and "too short" in err[0]
    assert "Traceback" not in err[0]
