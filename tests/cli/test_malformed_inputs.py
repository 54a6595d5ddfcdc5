"""The reliability contract: malformed inputs end in one line on stderr naming the
file, the field and the expected form or unit, exit code 3, no traceback, no file written.

Every case goes through the command line (``servotune.cli.main``), as a user meets it.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import EXAMPLE_RIG, ROOT

from servotune.budget import set_memory_budget
from servotune.cli import main
from servotune.logs import LogMetadataWarning

PLANTS = ROOT / "plants"


@pytest.fixture(autouse=True)
def _default_budget() -> None:
    set_memory_budget(None)


def refused(
    capsys: pytest.CaptureFixture[str],
    args: list[str],
    *mentions: str,
    not_written: Path | None = None,
) -> str:
    """Run the CLI; assert exit 3, exactly one non-empty stderr line holding every mention,
    no traceback and (if given) no output file. Returns the line."""
    code = main(args)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 3, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for m in mentions:
        assert m in lines[0], (m, lines[0])
    if not_written is not None:
        assert not not_written.exists()
        assert not list(not_written.parent.glob(f".{not_written.name}.*.tmp"))
    return lines[0]


def variant(tmp_path: Path, source: Path, old: str, new: str, name: str = "") -> Path:
    """``source`` with ``old`` replaced by ``new`` (once), next to a copy of the example rig."""
    text = source.read_text(encoding="utf-8")
    assert old in text, old
    (tmp_path / EXAMPLE_RIG.name).write_text(EXAMPLE_RIG.read_text())
    out = tmp_path / (name or source.name)
    out.write_text(text.replace(old, new, 1), encoding="utf-8")
    return out


# --- rig files ---------------------------------------------------------------------------------

RIG_CASES = {
    "counter_bits_float": ("bits = 24", "bits = 24.0", "counter.bits", "[bits]", "24.0"),
    "counter_bits_string": ("bits = 24", 'bits = "24"', "counter.bits", "integer", "'24'"),
    "dac_bits_float": ("bits = 12", "bits = 12.0", "dac.bits", "integer in 8..16"),
    "lock_gain_huge": ("lock_gain_codes_per_count = 0.4 ", "lock_gain_codes_per_count = 1e10 ",
                       "axis.master.lock_gain_codes_per_count", "[codes/count]"),
    "offset_1000_v": ("offset_v = 0.005", "offset_v = 1000.0", "axis.master.plant.offset_v",
                      "[-10, 10] [V]"),
    "huge_integer": ("speed_limit_rpm = 600", "speed_limit_rpm = 1" + "0" * 400,
                     "axis.master.speed_limit_rpm", "401 digits"),
    "bool_for_number": ("pulses_per_rev = 3072", "pulses_per_rev = true",
                        "encoder.pulses_per_rev", "[pulses/rev]", "True"),
    "string_for_number": ("period_s = 0.004 ", 'period_s = "4ms" ', "timer.period_s", "[s]"),
    "negative_period": ("period_s = 0.004 ", "period_s = -0.004 ", "timer.period_s", "> 0"),
    "zero_period": ("period_s = 0.004 ", "period_s = 0.0 ", "timer.period_s", "> 0"),
    "nan": ("tau_s = 0.025", "tau_s = nan", "axis.master.plant.tau_s", "[s]"),
    "empty_timer": ("period_s = 0.004 ", "# nothing ", "missing key timer.period_s"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(RIG_CASES))
def test_rig_file(case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old, new, *mentions = RIG_CASES[case]
    rig = variant(tmp_path, EXAMPLE_RIG, old, new, "rig.toml")
    refused(capsys, ["rig", str(rig)], str(rig), *mentions)


def test_rig_file_with_bom_is_accepted(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = tmp_path / "bom.toml"
    rig.write_bytes(b"\xef\xbb\xbf" + EXAMPLE_RIG.read_bytes())
    assert main(["rig", str(rig)]) == 0
    assert "timer divisor" in capsys.readouterr().out


def test_rig_file_nested_too_deep(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = tmp_path / "deep.toml"
    rig.write_text(EXAMPLE_RIG.read_text() + "\n[x]\ny = " + "[" * 200_000 + "]" * 200_000)
    refused(capsys, ["rig", str(rig)], str(rig), "nested too deeply")


# --- logs (servotune fit) ----------------------------------------------------------------------


def _log_text(dt: float = 0.004, n: int = 300, meta: str = "", first: str = "") -> str:
    rows = [f"{i * dt!r},{2148 if (i // 5) % 2 else 1948},{i * 3}" for i in range(n)]
    if first:
        rows[0] = first
    return meta + "time_s,dac_code,counter\n" + "\n".join(rows) + "\n"


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("log") / "log.csv"
    assert (
        main(["simulate", str(EXAMPLE_RIG), "--scenario", "prbs", "--seconds", "4", "-o", str(out)])
        == 0
    )
    return out


@pytest.mark.parametrize("value", ["nan", "-1", "inf", "1"])
def test_fit_compute_s_option(
    value: str, sim_log: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    refused(
        capsys, ["fit", str(sim_log), "--axis", "master", "--compute-s", value], "option compute_s"
    )


LOG_CASES: dict[str, tuple[Callable[[], str], tuple[str, ...]]] = {
    "step_1e304": (lambda: _log_text(dt=1e304), ("period", "1e-06 … 60 s")),
    "step_1e-300": (lambda: _log_text(dt=1e-300), ("period", "1e-06 … 60 s")),
    "int_of_5e6_digits": (
        lambda: _log_text(first="0.0,2048," + "1" * 5_000_000),
        ("row 2", "'counter'", "5000000 characters", "at most 64"),
    ),
    "float_of_5e6_digits": (
        lambda: _log_text(first="0." + "1" * 5_000_000 + ",2048,0"),
        ("row 2", "'time_s'", "at most 64"),
    ),
    "metadata_of_5e6_chars": (
        lambda: _log_text(meta="# period_s: 0.004" + "0" * 5_000_000 + "\n"),
        ("line 1", "'period_s'", "at most 1024"),
    ),
    "metadata_period_out_of_range": (
        lambda: _log_text(meta="# period_s: 1e-300\n"),
        ("line 1", "'period_s'", "seconds > 0"),
    ),
    "nan_time": (lambda: _log_text(first="nan,2048,0"), ("row 2", "'time_s'", "not finite")),
    "superscript_digit": (lambda: _log_text(first="0.0,2²,0"), ("row 2", "'dac_code'")),
}


@pytest.mark.parametrize("case", sorted(LOG_CASES))
def test_fit_log(case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    make, mentions = LOG_CASES[case]
    log = tmp_path / "log.csv"
    log.write_text(make(), encoding="utf-8")
    out = tmp_path / "fitted.toml"
    refused(
        capsys,
        ["fit", str(log), "-o", str(out), "--axis", "x"],
        str(log),
        *mentions,
        not_written=out,
    )


def test_unknown_metadata_warns_and_bom_is_accepted(
    sim_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "noted.csv"
    text = sim_log.read_text(encoding="utf-8")
    log.write_bytes(
        b"\xef\xbb\xbf" + ("# machine_id: m7\n# date: 2024-05-01\n# colour: blue\n" + text).encode()
    )
    with pytest.warns(LogMetadataWarning, match="'colour'") as rec:
        assert main(["fit", str(log), "--axis", "master"]) == 0
    assert not any("machine_id" in str(w.message) for w in rec)


def test_a_metadata_typo_is_one_warning_line_with_a_suggestion(
    sim_log: Path, tmp_path: Path
) -> None:
    """docs/decisions.md#1-unknown-keys: an unknown metadata key warns (not an error), in one line
    on stderr naming the closest declared key; the fit still runs."""
    log = tmp_path / "typo.csv"
    log.write_text("# counter_bitz: 24\n" + sim_log.read_text())
    run = subprocess.run(
        [sys.executable, "-m", "servotune.cli", "fit", str(log), "--axis", "master"],
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    warned = [ln for ln in run.stderr.splitlines() if "warning" in ln]
    assert warned == [
        f"servotune fit: warning: log {str(log)!r}: unknown metadata 'counter_bitz' (line 1, "
        "did you mean 'counter_bits'?), kept but not used (a typo? see "
        "servotune.logs.METADATA_KEYS)"
    ]


def test_declared_metadata_does_not_warn(
    sim_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "declared.csv"
    log.write_text("# machine_id: m7\n# date: 2024-05-01\n" + sim_log.read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("error", LogMetadataWarning)
        assert main(["fit", str(log), "--axis", "master"]) == 0


# --- excitation files (servotune simulate --input) --------------------------------------------


@pytest.fixture(scope="module")
def excitation(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("exc") / "exc.csv"
    assert (
        main(
            [
                "excite",
                "--rig",
                str(EXAMPLE_RIG),
                "--kind",
                "steps",
                "--seconds",
                "1",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    return out


@pytest.mark.parametrize("code", ["2²", "+-5", "1e3", "0x10", "9" * 70])
def test_simulate_input_bad_code(
    code: str, excitation: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    lines = excitation.read_text(encoding="utf-8").splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("tick,"))
    cells = lines[head + 4].split(",")
    cells[-1] = code
    lines[head + 4] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n", encoding="utf-8")
    out = tmp_path / "log.csv"
    refused(
        capsys,
        ["simulate", str(EXAMPLE_RIG), "--input", str(bad), "-o", str(out)],
        str(bad),
        f"row {head + 5}",
        "'master.dac_code'",
        not_written=out,
    )


# --- resource bounds ---------------------------------------------------------------------------


def test_simulate_seconds_1e12(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x.csv"
    line = refused(
        capsys,
        ["simulate", str(EXAMPLE_RIG), "--scenario", "prbs", "--seconds", "1e12", "-o", str(out)],
        "simulate 1e+12 s",
        "ticks × 2 axes",
        "over the memory budget of 2 GiB",
        not_written=out,
    )
    assert "PiB" in line


def test_excite_seconds_1e12(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x.csv"
    refused(
        capsys,
        [
            "excite",
            "--rig",
            str(EXAMPLE_RIG),
            "--kind",
            "multisine",
            "--seconds",
            "1e12",
            "-o",
            str(out),
        ],
        "excitation of 1e+12 s",
        "memory budget",
        not_written=out,
    )


def test_budget_from_environment(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SERVOTUNE_MAX_MEMORY", "64K")
    out = tmp_path / "x.csv"
    refused(
        capsys,
        ["simulate", str(EXAMPLE_RIG), "--scenario", "steps", "--seconds", "10", "-o", str(out)],
        "memory budget of 64 KiB",
        not_written=out,
    )
    monkeypatch.setenv("SERVOTUNE_MAX_MEMORY", "lots")
    args = ["simulate", str(EXAMPLE_RIG), "--scenario", "steps", "--seconds", "10", "-o", str(out)]
    refused(capsys, args, "SERVOTUNE_MAX_MEMORY", "'lots'", not_written=out)


# --- gantry (servotune sync) and linkage configs ----------------------------------------------

SYNC_CASES = {
    "cycle_10_s": ("cycle_s = 0.001", "cycle_s = 10", "bus.cycle_s", "[s]"),
    "latency_1e9_float": ("latency_cycles = 1", "latency_cycles = 1e9", "bus.latency_cycles",
                          "integer in 1..1000 [cycles]"),
    "latency_1e9_int": ("latency_cycles = 1", "latency_cycles = 1000000000",
                        "bus.latency_cycles", "integer in 1..1000"),
    "seconds_negative": ("seconds = 2.0", "seconds = -2.0", "gantry.seconds", "[s]"),
    "distance_float": ("distance_counts = 150000", "distance_counts = 1.5e5",
                       "move.distance_counts", "integer"),
    "empty_sync_law": ('law = "pi"', 'law = ""', "sync.law", "pi, pd"),
    # found by a bad-input sweep (2026-11-26): these three ended in a ZeroDivisionError traceback
    "distance_zero": ("distance_counts = 150000", "distance_counts = 0", "move.distance_counts",
                      "needs a move"),
    "load_after_the_run": ("time_s = 0.8", "time_s = 50", "load.time_s", "gantry.seconds (2 s)",
                           "inside the run"),
    "load_zero_volts": ("volts = -0.3", "volts = 0.0", "load.volts", "needs a load step"),
    "move_after_the_run": ("start_s = 0.05", "start_s = 2.0", "move.start_s", "inside the run"),
    "montecarlo_negative": ("[gantry]", "[gantry]", "Monte-Carlo count", "1..1,000,000"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(SYNC_CASES))
def test_sync_config(case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old, new, *mentions = SYNC_CASES[case]
    cfg = variant(tmp_path, PLANTS / "gantry.toml", old, new)
    if case == "montecarlo_negative":  # an option, not the file
        refused(capsys, ["sync", str(cfg), "--montecarlo", "-1"], *mentions)
    elif case == "load_after_the_run":  # refused where the load case runs, without the file
        refused(capsys, ["sync", str(cfg)], *mentions)
    else:
        refused(capsys, ["sync", str(cfg)], str(cfg), *mentions)


LINKAGE_CASES = {
    "length_1e300": ("to = { x = 40000,", "to = { x = 1e300,", "path.move[0].to.x", "[counts]"),
    "dwell_1e12": ("dwell_s = 0.5", "dwell_s = 1e12", "path.move[1].dwell_s", "[s]"),
    "feed_bool": ("feed_cps = 40000", "feed_cps = true", "path.move[0].feed_cps", "True"),
    "queue_float": ("queue_depth = 20 ", "queue_depth = 20.0 ", "cpu[0].queue_depth",
                    "integer"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(LINKAGE_CASES))
def test_linkage_config(case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old, new, *mentions = LINKAGE_CASES[case]
    cfg = variant(tmp_path, PLANTS / "linkage-6axis.toml", old, new)
    refused(capsys, ["linkage", str(cfg)], str(cfg), *mentions)


def test_linkage_crawling_feed_is_over_budget(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = variant(tmp_path, PLANTS / "linkage-6axis.toml", "feed_cps = 40000", "feed_cps = 1e-6")
    refused(capsys, ["linkage", str(cfg)], "linkage-6axis", "path.move[0]", "memory budget")


# --- JSON (tuning files) -----------------------------------------------------------------------

JSON_CASES = {
    "nested_200000": ("[" * 200_000 + "]" * 200_000, "nested 200000 levels"),
    "nan": ('{"schema": "servotune.tuning/1", "period_s": NaN}', "NaN"),
    "infinity": ('{"schema": "servotune.tuning/1", "period_s": Infinity}', "Infinity"),
    "minus_infinity": ('{"period_s": -Infinity}', "-Infinity"),
    "long_number": ('{"period_s": 1' + "0" * 5000 + "}", "5001 characters"),
}


@pytest.mark.parametrize("case", sorted(JSON_CASES))
def test_tuning_json(case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text, mention = JSON_CASES[case]
    path = tmp_path / "tuning.json"
    path.write_text(text, encoding="utf-8")
    out = tmp_path / "tables.json"
    # reading the tuning is the first thing export-table does
    refused(
        capsys,
        ["export-table", str(path), "--unverified", "-o", str(out)],
        str(path),
        mention,
        not_written=out,
    )


# --- writing -----------------------------------------------------------------------------------


def test_unwritable_directory_names_the_target(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import servotune.io.files as files

    real_open = os.open

    def no_temp_files(path: object, *args: object, **kwargs: object) -> int:
        if str(path).endswith(".tmp"):  # the directory refuses new files (root ignores modes)
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(files.os, "open", no_temp_files)
    out = tmp_path / "log.csv"
    line = refused(
        capsys,
        ["simulate", str(EXAMPLE_RIG), "--scenario", "steps", "--seconds", "1", "-o", str(out)],
        str(out),
        "Permission denied",
        not_written=out,
    )
    assert ".tmp" not in line


@pytest.mark.parametrize(
    ("args", "mentions"),
    [
        (
            ["simulate", str(EXAMPLE_RIG), "--seconds", "abc", "-o", "x.csv"],
            ("servotune simulate: error:", "--seconds", "'abc'", "servotune simulate --help"),
        ),
        (["verify", "tuning.json"], ("servotune verify: error:", "--spec", "verify --help")),
        (
            ["verify", "t.json", "--spec", "s.toml", "--montecarlo", "1e6"],
            ("--montecarlo", "'1e6'"),
        ),
        (["frobnicate"], ("servotune: error:", "'frobnicate'", "servotune --help")),
    ],
)
def test_a_usage_error_is_one_line(
    args: list[str], mentions: tuple[str, ...], capsys: pytest.CaptureFixture[str]
) -> None:
    """A wrong option value or a missing argument: one line naming it and where the usage is
    (argparse would print its whole usage block first), exit 2, as argparse exits."""
    with pytest.raises(SystemExit) as stop:
        main(args)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    for m in mentions:
        assert m in lines[0], (m, lines[0])


@pytest.mark.parametrize("seed", ["-1", str(2**64), "1.5", "0x10"])
@pytest.mark.parametrize(
    "verb",
    [
        ["simulate", str(EXAMPLE_RIG), "--scenario", "prbs", "-o", "x.csv"],
        ["tune", str(EXAMPLE_RIG)],
        ["verify", "tuning.json", "--spec", "spec.toml"],
        ["demo", str(EXAMPLE_RIG)],
        ["compare", str(EXAMPLE_RIG), "--spec", "spec.toml"],
        ["sync", str(PLANTS / "gantry.toml")],
    ],
    ids=lambda v: v[0],
)
def test_a_seed_outside_64_bits_is_a_usage_error(
    verb: list[str], seed: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every verb's ``--seed`` is an integer in 0..2**64 - 1 (what the random streams take;
    ``demo``, ``compare``, ``verify``, ``simulate`` and ``sync`` ended in numpy's OverflowError or
    ValueError traceback on -1); 2**64 - 1 itself runs (the linkage config's bound)."""
    with pytest.raises(SystemExit) as stop:
        main([*verb, "--seed", seed])
    assert stop.value.code == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--seed" in lines[0] and repr(seed) in lines[0], lines


def test_the_largest_seed_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "log.csv"
    code = main(
        [
            "simulate",
            str(EXAMPLE_RIG),
            "--scenario",
            "prbs",
            "--seconds",
            "0.1",
            "-o",
            str(out),
            "--seed",
            str(2**64 - 1),
        ]
    )
    assert code == 0 and out.stat().st_size > 0, capsys.readouterr().err


@pytest.mark.parametrize(
    "verb",
    [
        ["simulate", str(EXAMPLE_RIG), "--scenario", "prbs", "--seconds", "0.1", "-o"],
        ["tune", str(EXAMPLE_RIG), "-o"],
        ["fit", str(ROOT / "tests" / "data" / "missing.csv"), "-o"],
    ],
    ids=lambda v: v[0],
)
def test_an_output_that_is_a_directory_is_refused_first(
    verb: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``-o DIR``: one line before any work (``fit`` used to fit the whole log, print its
    summary, then fail on reading the directory as a rig file)."""
    line = refused(capsys, [*verb, str(tmp_path)], str(tmp_path), "is a directory")
    assert "file to write" in line
    assert list(tmp_path.iterdir()) == []


def test_a_population_over_the_memory_budget_is_refused_first(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``tune --population 100000000`` grew past 6 GB within 25 s and ran on (found by a
    bad-input sweep); a generation is one batch of population × plant variants runs, so its
    memory is estimated and held to the budget before any candidate is drawn."""
    out = tmp_path / "t.json"
    refused(
        capsys,
        [
            "tune",
            str(EXAMPLE_RIG),
            "-q",
            "--no-current",
            "--generations",
            "2",
            "--population",
            "100000000",
            "-o",
            str(out),
        ],
        "population of 100,000,000",
        "memory budget",
        not_written=out,
    )


def test_an_output_that_is_an_input_is_refused_first(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], default_tuning
) -> None:
    """``export-table T.json -o T.json`` replaced the tuning with the tables, ``tune R.toml -o
    R.toml`` the rig with a tuning (found by a bad-input sweep): the output may not be a file the
    command reads, named by any path (here through a symbolic link too)."""
    from servotune.tuning import write_tuning

    rig = tmp_path / EXAMPLE_RIG.name
    rig.write_bytes(EXAMPLE_RIG.read_bytes())
    tuning = tmp_path / "tuning.json"
    write_tuning(default_tuning, tuning)
    link = tmp_path / "same.json"
    link.symlink_to(tuning)
    before = {p: p.read_bytes() for p in (rig, tuning)}
    cases = [
        (["export-table", str(tuning), "--unverified", "-o", str(tuning)], str(tuning)),
        (["export-table", str(tuning), "--unverified", "-o", str(link)], str(link)),
        (["tune", str(rig), "-q", "--no-current", "-o", str(rig)], str(rig)),
    ]
    for args, named in cases:
        line = refused(capsys, args, named, "is also an input")
        assert "give another output file" in line
    assert {p: p.read_bytes() for p in (rig, tuning)} == before


def test_messages_read_as_written(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Three messages a bad-input sweep found garbled: numpy's repr of the times of a log whose
    time goes back, "starting at at line" of a cut JSON string, "excitation file file"."""
    log = tmp_path / "log.csv"
    assert (
        main(
            [
                "simulate",
                str(EXAMPLE_RIG),
                "--scenario",
                "prbs",
                "--seconds",
                "0.2",
                "-q",
                "-o",
                str(log),
            ]
        )
        == 0
    )
    rows = log.read_text(encoding="utf-8").splitlines()
    header = next(i for i, r in enumerate(rows) if r.startswith("tick,"))
    col = rows[header].split(",").index("time_s")
    cells = rows[header + 5].split(",")
    cells[col] = "1e+308"
    rows[header + 5] = ",".join(cells)
    log.write_text("\n".join(rows) + "\n", encoding="utf-8")
    capsys.readouterr()
    line = refused(capsys, ["fit", str(log), "--axis", "master", "-q"], "time goes back")
    assert "np.float64" not in line
    cut = tmp_path / "cut.json"
    cut.write_text('{"a": "abc', encoding="utf-8")
    line = refused(capsys, ["check-table", str(cut)], "Unterminated string starting at line 1")
    assert "at at" not in line
    missing = tmp_path / "missing.csv"
    args = ["simulate", str(EXAMPLE_RIG), "--input", str(missing), "-o", str(tmp_path / "o.csv")]
    line = refused(capsys, args, "excitation file", "does not exist")
    assert "file file" not in line


CORPUS = ROOT / "tests" / "corpus" / "base"


@pytest.mark.parametrize(
    "verb",
    [
        ["demo", str(EXAMPLE_RIG), "--out"],
        ["compare", str(EXAMPLE_RIG), "--spec", str(PLANTS / "pc-dual-servo.spec.toml"), "--out"],
        ["sync", str(PLANTS / "gantry.toml"), "--plot"],
        ["linkage", str(PLANTS / "linkage-6axis.toml"), "--plot"],
        [
            "verify",
            str(CORPUS / "tuning.json"),
            "--spec",
            str(PLANTS / "pc-dual-servo.spec.toml"),
            "--report",
        ],
        ["export-table", str(CORPUS / "tuning.json"), "--unverified", "--format", "c", "-o"],
    ],
    ids=lambda v: v[0],
)
def test_a_directory_output_that_is_a_file_is_refused_first(
    verb: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An output directory given as an existing file (or below one): one line before any work
    (``sync --plot FILE`` ran its 9 s comparison, then failed with 'File exists'; ``compare
    --out FILE`` tried to make the directory; ``export-table --format c -o FILE`` loaded and
    checked the tuning first); the file is left as it was."""
    f = tmp_path / "a-file"
    f.write_text("keep\n", encoding="utf-8")
    refused(capsys, [*verb, str(f), "-q"], str(f), "is a file, not a directory")
    refused(capsys, [*verb, str(f / "sub"), "-q"], "cannot create the directory", "is a file")
    assert f.read_text(encoding="utf-8") == "keep\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]


def test_bad_inputs_leave_no_output_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``demo`` with a bad rig and ``compare`` with a sweep ceiling the tuner refuses (``--pareto
    0.5``: it ran the whole comparison and wrote figure4.png first) fail before the output
    directory is made."""
    out = tmp_path / "out"
    refused(capsys, ["demo", str(tmp_path / "missing.toml"), "--out", str(out)], "missing.toml")
    assert not out.exists()
    refused(
        capsys,
        [
            "compare",
            str(EXAMPLE_RIG),
            "--spec",
            str(PLANTS / "pc-dual-servo.spec.toml"),
            "--out",
            str(out),
            "--pareto",
            "1.5,0.5",
            "-q",
        ],
        "pareto: max_sensitivity",
        "got 0.5",
    )
    assert not out.exists()


def test_fit_into_a_file_that_is_not_a_rig_is_refused_before_the_fit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``fit LOG -o FILE`` with FILE an existing file that is no rig (or lacks the axis) fitted
    the whole log, printed its summary, then failed on writing: now one line, before the fit."""
    not_rig = tmp_path / "notes.toml"
    not_rig.write_text("x = 1\n", encoding="utf-8")
    log = str(CORPUS / "log.csv")
    refused(
        capsys,
        ["fit", log, "--axis", "master", "-o", str(not_rig)],
        str(not_rig),
        "is not a rig to write the fit into",
    )
    assert not_rig.read_text(encoding="utf-8") == "x = 1\n"
    rig = tmp_path / "rig.toml"
    rig.write_bytes(EXAMPLE_RIG.read_bytes())
    refused(
        capsys,
        ["fit", log, "--axis", "nope", "-o", str(rig)],
        "has no axis 'nope'",
        "master, slave",
    )
    assert rig.read_bytes() == EXAMPLE_RIG.read_bytes()


def test_a_huge_period_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``period_s = 1e308`` printed numpy's 'overflow encountered in multiply' as a warning line
    before the error (found by a bad-input sweep)."""
    rig = variant(tmp_path, EXAMPLE_RIG, "period_s = 0.004 ", "period_s = 1e308 ")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        line = refused(capsys, ["rig", str(rig)], "period_s 1e+308", "divisor outside 2..65536")
    assert "overflow" not in line
    assert not [w for w in seen if "overflow" in str(w.message)]
