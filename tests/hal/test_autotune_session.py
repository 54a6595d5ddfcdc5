"""The autotune config checked against a real HAL session (servotune.io.halcmd,
servotune.autotune.check_session, docs/autotune.md#checking-the-session).

The session: LinuxCNC's stock ``pid`` and ``encoder`` on a ``servo-thread``, as the example
config names them; ``halcmd show pin`` and ``show thread`` printed by that session are what the
parser reads. Bad configs (a missing pin, a pin of the wrong type or direction, a thread not
there or at another period) are each one line naming the key.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from servotune.autotune import check_session, load_autotune_config
from servotune.errors import ConfigError
from servotune.examples import EXAMPLES_DIR
from servotune.io.halcmd import HalSession, parse_pins, parse_thread_functions, parse_threads

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared HAL harness
import halrun

CONFIG = EXAMPLES_DIR / "linuxcnc-autotune.toml"


def _session(tmp_path: Path, period_ns: int) -> HalSession:
    script = "\n".join(
        [
            f"loadrt threads name1=servo-thread period1={period_ns}",
            "loadrt pid num_chan=1",
            "loadrt encoder num_chan=1",
            "addf pid.0.do-pid-calcs servo-thread",
            "net x-pos encoder.0.position => pid.0.feedback",
            "show pin",
            "show thread",
        ]
    )
    res = halrun.run_hal(script + "\n", tmp_path, timeout=120.0)
    # each parser takes its own lines of the whole output
    return HalSession(pins=parse_pins(res.stdout), threads=parse_threads(res.stdout))


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> HalSession:
    halrun.hal_available()
    return _session(tmp_path_factory.mktemp("hal_session"), 4_000_000)


def test_the_parser_reads_what_halcmd_prints(session: HalSession) -> None:
    assert session.pins["pid.0.output"].type == "float"
    assert session.pins["pid.0.output"].dir == "OUT"
    assert session.pins["pid.0.enable"].type == "bit"
    assert session.pins["pid.0.feedback"].signal == "x-pos"
    assert session.pins["encoder.0.position"].dir == "OUT"
    assert session.threads == {"servo-thread": 4_000_000}


def test_the_example_config_fits_the_session(session: HalSession) -> None:
    check_session(load_autotune_config(CONFIG), session)


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ('"encoder.0.position"', '"encoder.9.position"', "hal.feedback_pin 'encoder.9.position'"),
        ('enable_pin = "pid.0.enable"', 'enable_pin = "pid.0.output"', "is a float OUT pin; it"),
        ('output_pin = "pid.0.output"', 'output_pin = "pid.0.command"', "must be a float OUT"),
        ('thread = "servo-thread"', 'thread = "base-thread"', "hal.thread 'base-thread'"),
        (
            '# counts_pin = "encoder.0.rawcounts"',
            'counts_pin = "encoder.0.position"',
            "hal.counts_pin 'encoder.0.position' (the raw encoder count) is a float OUT pin; it "
            "must be a s32 OUT pin",
        ),
        ('# counts_pin = "encoder.0.rawcounts"', 'counts_pin = "enc.9"', "not a pin of the"),
    ],
)
def test_a_config_that_does_not_fit_the_session_is_one_line(
    session: HalSession, tmp_path: Path, old: str, new: str, words: str
) -> None:
    text = CONFIG.read_text()
    assert old in text
    for name in ("pc-dual-servo.toml", "pc-dual-servo.spec.toml"):
        (tmp_path / name).write_bytes((EXAMPLES_DIR / name).read_bytes())
    p = tmp_path / "at.toml"
    p.write_text(text.replace(old, new))
    with pytest.raises(ConfigError) as e:
        check_session(load_autotune_config(p), session)
    msg = str(e.value)
    assert words in msg and "\n" not in msg, msg


def test_the_component_target_fits_the_session_with_the_raw_count(
    session: HalSession, tmp_path: Path
) -> None:
    text = CONFIG.read_text()
    for name in ("pc-dual-servo.toml", "pc-dual-servo.spec.toml"):
        (tmp_path / name).write_bytes((EXAMPLES_DIR / name).read_bytes())
    p = tmp_path / "at.toml"
    text = text.replace('target = "pid"', 'target = "component"')
    p.write_text(
        text.replace('# counts_pin = "encoder.0.rawcounts"', 'counts_pin = "encoder.0.rawcounts"')
    )
    cfg = load_autotune_config(p)
    assert cfg.target == "component" and cfg.hal.counts_pin == "encoder.0.rawcounts"
    check_session(cfg, session)


def test_the_thread_functions_are_read_in_their_order(tmp_path: Path) -> None:
    """Where the component target places the runtime (before the guard) is read from
    ``show thread``: the functions in the order a thread runs them, positions as ``addf``
    gives them (1 first)."""
    halrun.hal_available()
    script = "\n".join(
        [
            "loadrt threads name1=servo-thread period1=4000000 name2=slow period2=8000000",
            "loadrt pid num_chan=2",
            "loadrt encoder num_chan=1",
            "addf pid.1.do-pid-calcs servo-thread",
            "addf encoder.update-counters slow",
            "addf pid.0.do-pid-calcs servo-thread 1",  # inserted before the first
            "loadusr -w halcmd -s show thread",  # the form servotune's halcmd reads
            "show thread",
        ]
    )
    res = halrun.run_hal(script + "\n", tmp_path, timeout=120.0)
    expected = {
        "servo-thread": ["pid.0.do-pid-calcs", "pid.1.do-pid-calcs"],
        "slow": ["encoder.update-counters"],
    }
    one_line, plain = res.stdout.split("Realtime Threads", 1)
    assert parse_thread_functions(one_line) == expected, res.stdout
    assert parse_thread_functions(plain) == expected, res.stdout


def test_a_thread_at_another_period_is_refused(tmp_path: Path) -> None:
    halrun.hal_available()
    slow = _session(tmp_path, 8_000_000)
    with pytest.raises(ConfigError, match=r"runs every 8 ms, not hal\.period_s = 4 ms"):
        check_session(load_autotune_config(CONFIG), slow)
