"""`servotune fit` and `servotune excite` from the command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLE_RIG

import servotune as st
from servotune.cli import main
from servotune.identify import ClosedLoopBiasWarning


@pytest.fixture(scope="module")
def good_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fit") / "log.csv"
    assert (
        main(
            [
                "simulate",
                str(EXAMPLE_RIG),
                "--scenario",
                "steps",
                "--closed-loop",
                "--seconds",
                "30",
                "--seed",
                "3",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    return out


def test_fit_json_rig_file_and_plot(
    good_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig_out = tmp_path / "fitted.toml"
    png = tmp_path / "fit.png"
    args = [
        "fit",
        str(good_log),
        "--axis",
        "master",
        "--json",
        "-o",
        str(rig_out),
        "--plot",
        str(png),
    ]
    assert main(args) == 0
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert d["schema"] == "servotune.fit/2" and d["axis"] == "master"
    assert set(d) >= {
        "structure",
        "params",
        "std",
        "ci95",
        "fit_pct",
        "whiteness",
        "period_s",
        "method",
        "interval_method",
        "adequate",
        "cross_correlation",
        "parameters",
        "units",
        "friction",
    }
    # simulate logs the excitation (exc_code): the default is the consistent method
    assert d["method"] == "iv" and "exc_code" in d["instruments"]["signals"]
    assert "moving-block bootstrap" in d["interval_method"]
    for p in d["structure"]:  # every parameter with its interval and unit
        entry = d["parameters"][p]
        assert entry["ci95"][0] <= entry["value"] <= entry["ci95"][1] and entry["unit"]
    truth = st.load_rig(EXAMPLE_RIG).axis("master").plant
    assert d["params"]["gain_cps_per_v"] == pytest.approx(truth.gain_cps_per_v, rel=0.02)
    assert "structure:" in cap.err and "fit (MATLAB compare)" in cap.err
    assert "method: iv" in cap.err and "intervals: moving-block bootstrap" in cap.err
    assert "counts/s/V 95 %:" in cap.err
    # the rig file was created from the example rig, with the fitted plant, its provenance and
    # the fit record (docs/decisions.md#6-the-fit-record): intervals, method, structure, friction
    # form, adequacy
    ax = st.load_rig(rig_out).axis("master")
    assert ax.plant.tau_s == pytest.approx(d["params"]["tau_s"], rel=1e-6)
    assert "fitted by servotune" in rig_out.read_text()
    rec = ax.plant_fit
    assert rec is not None and rec.method == "iv" and rec.friction == d["friction"]
    assert list(rec.structure) == d["structure"] and rec.adequate == d["adequate"]
    for p, (lo, hi) in rec.ci95.items():
        assert lo == pytest.approx(d["ci95"][p][0], rel=1e-6, abs=1e-12)
        assert hi == pytest.approx(d["ci95"][p][1], rel=1e-6, abs=1e-12)
    assert png.read_bytes()[:4] == b"\x89PNG"
    # same input → same bytes
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out) == d


def test_excite_simulate_input_fit(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    exc = tmp_path / "exc.csv"
    log = tmp_path / "log.csv"
    assert (
        main(
            [
                "excite",
                "--rig",
                str(EXAMPLE_RIG),
                "--axis",
                "master",
                "--kind",
                "multisine",
                "--seconds",
                "30",
                "-o",
                str(exc),
            ]
        )
        == 0
    )
    assert (
        main(["simulate", str(EXAMPLE_RIG), "--input", str(exc), "--seed", "1", "-o", str(log)])
        == 0
    )
    assert main(["fit", str(log), "--axis", "master", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    truth = st.load_rig(EXAMPLE_RIG).axis("master").plant
    assert d["params"]["tau_s"] == pytest.approx(truth.tau_s, rel=0.02)


def _rows(n: int, cmd: np.ndarray, pos: np.ndarray) -> str:
    lines = ["time_s,cmd_v,pos_counts"]
    lines += [f"{k * 0.004:.9f},{c:.6f},{p}" for k, (c, p) in enumerate(zip(cmd, pos, strict=True))]
    return "\n".join(lines) + "\n"


def _bad_logs() -> dict[str, tuple[str, str]]:
    n = 400
    k = np.arange(n)
    u = np.where((k // 50) % 2 == 0, 1.0, -1.0)
    y = np.cumsum(np.round(u * 40)).astype(int)
    good = _rows(n, u, y)
    lines = good.splitlines()

    def with_line(i: int, field: int, value: str) -> str:
        cells = lines[i].split(",")
        cells[field] = value
        return "\n".join([*lines[:i], ",".join(cells), *lines[i + 1 :]]) + "\n"

    return {
        "empty": ("", "empty"),
        "header only": ("time_s,cmd_v,pos_counts\n", "no data rows"),
        "missing column": ("time_s,cmd_v\n0,1\n0.004,1\n0.008,1\n", "pos_counts"),
        "misspelt column": (good.replace("pos_counts", "pos_count", 1), "did you mean"),
        "nan": (with_line(5, 1, "nan"), "row 6"),
        "inf": (with_line(7, 1, "inf"), "row 8"),
        "text": (with_line(9, 2, "abc"), "row 10"),
        "time not increasing": ("\n".join([*lines[:4], lines[2], *lines[5:]]) + "\n", "row"),
        "duplicated time": ("\n".join([*lines[:4], lines[3], *lines[5:]]) + "\n", "row"),
        "irregular": ("\n".join([*lines[:10], *lines[11:]]) + "\n", "irregular"),
        "constant command": (_rows(n, np.full(n, 0.5), y), "constant"),
        "too short": (_rows(40, u[:40], y[:40]), "too short"),
        "never moved": (_rows(n, u, np.zeros(n, dtype=int)), "never moved"),
    }


@pytest.mark.parametrize("case", list(_bad_logs()))
def test_bad_logs_one_line_exit_3_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    text, words = _bad_logs()[case]
    log = tmp_path / "bad.csv"
    log.write_text(text)
    out = tmp_path / "rig.toml"
    assert main(["fit", str(log), "--axis", "x", "-o", str(out)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert words in err, err
    assert not out.exists()


def test_counter_column_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = "time_s,dac_code,counter\n" + "".join(
        f"{k * 0.004:.9f},{2048 + (k % 7)},{k * 3}\n" for k in range(300)
    )
    for bad, words in [("16777216", "outside"), ("12.5", "integer")]:
        p = tmp_path / "c.csv"
        p.write_text(base.replace(",600\n", f",{bad}\n", 1))
        assert main(["fit", str(p)]) == 3
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1


def test_output_into_missing_directory(
    good_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "nope" / "rig.toml"
    assert main(["fit", str(good_log), "--axis", "master", "-o", str(out)]) == 3
    err = capsys.readouterr().err
    assert "does not exist" in err and err.count("\n") == 1
    assert not out.parent.exists()


def test_multi_axis_log_needs_axis(good_log: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fit", str(good_log)]) == 3
    assert "--axis" in capsys.readouterr().err


def _reverse_counter(src: Path, dst: Path, axis: str = "master") -> None:
    """The log as an encoder counting the other way would have written it (24-bit register)."""
    lines = src.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    col = lines[head].split(",").index(f"{axis}.counter")
    out = lines[: head + 1]
    for ln in lines[head + 1 :]:
        cells = ln.split(",")
        cells[col] = str((2**24 - int(cells[col])) % 2**24)
        out.append(",".join(cells))
    dst.write_text("\n".join(out) + "\n")


def test_reversed_encoder_exit_3_and_invert_encoder(
    good_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rev = tmp_path / "reversed.csv"
    _reverse_counter(good_log, rev)
    out = tmp_path / "rig.toml"
    assert main(["fit", str(rev), "--axis", "master", "-o", str(out)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "reversed" in err and "--invert-encoder" in err, err
    assert not out.exists()
    assert main(["fit", str(rev), "--axis", "master", "--invert-encoder", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    truth = st.load_rig(EXAMPLE_RIG).axis("master").plant
    assert d["inverted_encoder"] is True
    assert d["params"]["gain_cps_per_v"] == pytest.approx(truth.gain_cps_per_v, rel=0.02)


def test_method_option(good_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fit", str(good_log), "--axis", "master", "--method", "oe", "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["method"] == "oe" and "warning" not in cap.err
    # a log with no external signal: least squares, and one line on stderr saying why
    n = 400
    k = np.arange(n)
    u = np.where((k // 50) % 2 == 0, 1.0, -1.0)
    y = np.cumsum(np.round(u * 40)).astype(int)
    plain = tmp_path / "plain.csv"
    plain.write_text(_rows(n, u, y))
    with pytest.warns(ClosedLoopBiasWarning, match=r"no external signal.*least squares \(oe\)"):
        assert (
            main(["fit", str(plain), "--structure", "offset", "--friction", "sym", "--json"]) == 0
        )
    assert json.loads(capsys.readouterr().out)["method"] == "oe"
    # iv asked for on that log: one line, exit 3
    assert main(["fit", str(plain), "--method", "iv"]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "method iv needs instruments" in err
    # choices are checked by argparse: exit 2
    with pytest.raises(SystemExit) as info:
        main(["fit", str(plain), "--method", "pem"])
    assert info.value.code == 2
