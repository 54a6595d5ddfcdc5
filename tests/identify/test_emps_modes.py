"""No mode from the real drive's logs: ``servotune fit --modes auto`` and ``servotune frf
--modes auto`` on the EMPS benchmark's two experiments (docs/decisions.md#7-real-data-emps),
read where tests/identify/test_emps.py reads them, skipped with its reason without them.

Neither log carries a periodic excitation made for a frequency response: the EMPS experiment has
no excitation column at all, and the PULSES experiment's force pulses (its ``exc_code``) repeat
every second but excite 5 lines, 1 … 9 Hz, on which the response hardly shows them (median
coherence 0.012, measured 2026-11-29). Modes cannot be measured from either, and both verbs say
so in one line and exit 3 — before the time-domain fit runs, so nothing is written.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from test_emps import FILES, _data_dir

from servotune.cli import main
from servotune.identify.emps import read_emps
from servotune.logs import write_log

WHY = {
    "EMPS": "the log has no exc_code column for axis 'emps'",
    "PULSES": "the log's excitation cannot measure modes: its response has 5 lines not flagged "
    "aliased (1 … 9 Hz, median coherence 0.012), 6 needed for choosing the order",
}


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Both experiments as servotune logs (the columns :meth:`EmpsLog.to_log` makes)."""
    d = _data_dir()
    out = tmp_path_factory.mktemp("emps")
    paths = {}
    for name, file in FILES.items():
        log = read_emps(d / file).to_log()
        ax = log.axis(None)
        cols = {"emps.cmd_v": ax.cmd_v, "emps.pos_counts": ax.pos_counts}
        if ax.exc_code is not None:
            cols["emps.exc_code"] = ax.exc_code
        meta = {"dac_bits": log.dac_bits, "dac_range_v": "-10,10", "counter_bits": 32}
        assert log.dac_range_v == (-10.0, 10.0)
        paths[name] = out / f"{name}.csv"
        write_log(paths[name], period_s=log.period_s, columns=cols, metadata=meta)
    return paths


@pytest.mark.parametrize("verb", ["fit", "frf"])
@pytest.mark.parametrize("name", sorted(FILES))
def test_modes_are_refused_with_the_reason_in_one_line(
    logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], verb: str, name: str
) -> None:
    out = tmp_path / ("fitted.toml" if verb == "fit" else "frf.json")
    argv = [verb, str(logs[name]), "--axis", "emps", "--modes", "auto", "-o", str(out)]
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and WHY[name] in err and "Traceback" not in err, err
    assert not out.exists()
