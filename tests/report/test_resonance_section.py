"""The report's resonance section (servotune.report.resonance, docs/frf.md#in-the-report): absent
for a rigid rig without an FRF (the page keeps its bytes), present with the belt-driven axis
(plants/belt-axis.toml) with the rig's modes in its table, its sentence computed from the numbers,
and with a measured FRF (made by the commands: ``servotune excite`` → ``simulate --closed-loop``
→ ``frf -o``) the figure embedded and the in-bounds count equal to one counted here, from the
FRF file and a model sampled independently with python-control."""

from __future__ import annotations

import base64
import dataclasses
import html
import json
import math
import re
from pathlib import Path

import control
import numpy as np
import pytest

import servotune as st
from report.figures_check import axis_unit_problems
from servotune.analysis.frf import Frf
from servotune.cli import main
from servotune.errors import SpecError
from servotune.modal import modal_response
from servotune.report import write_report
from servotune.report.page import png_uri
from servotune.report.resonance import (
    check_model,
    read_frf,
    resonance_figure,
    resonance_section,
    resonance_statement,
)
from servotune.resonance import Mode
from servotune.rig import load_rig
from servotune.tuning import write_tuning

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_RIG = ROOT / "plants" / "pc-dual-servo.toml"
BELT_RIG = ROOT / "plants" / "belt-axis.toml"


# --- helpers ---------------------------------------------------------------------------------


def _section(page: str) -> str | None:
    m = re.search(r'<section id="resonance">.*?</section>', page, re.S)
    return None if m is None else m.group(0)


def _data(page: str) -> dict:
    m = re.search(r'<script type="application/json" id="servotune-data">(.*?)</script>', page)
    assert m is not None
    return json.loads(m.group(1))


def _rows(section: str) -> list[list[str]]:
    rows = re.findall(r"<tr>(.*?)</tr>", section, re.S)
    cells = [[html.unescape(c) for c in re.findall(r"<td>(.*?)</td>", r)] for r in rows]
    return [c for c in cells if c]


def _frf_file(tmp: Path, rig: Path, name: str) -> Path:
    """An FRF file as a user makes one: a periodic multisine (8 periods over 40 s), played in
    closed loop on ``rig`` by the engine, measured by ``servotune frf``."""
    exc, log, out = tmp / f"{name}-ms.csv", tmp / f"{name}-log.csv", tmp / f"{name}-frf.json"
    excite = ["excite", "--rig", str(rig), "--axis", "master", "--kind", "multisine"]
    assert main([*excite, "--periods", "8", "--seconds", "40", "-o", str(exc), "-q"]) == 0
    sim = ["simulate", str(rig), "--input", str(exc), "--closed-loop", "--seed", "1"]
    assert main([*sim, "-o", str(log), "-q"]) == 0
    assert main(["frf", str(log), "--axis", "master", "-o", str(out), "--json"]) == 0
    return out


def _independent_model(rig: st.Rig, freq_hz: np.ndarray) -> np.ndarray:
    """The master's velocity response as ``servotune frf`` measures it, sampled here with
    python-control by another route than servotune.modal's: the plant
    ``K / (s (τ s + 1)) · (1 + g s² / (s² + 2 ζ ω s + ω²))`` (docs/frf.md#modes) discretised by
    ZOH at the input's change instants (period T) and its output read ``T − d`` after them
    (``d`` the compute time and the delay, < T), so ``y_k = z⁻¹ (C Φ_{T−d} (zI − Φ)⁻¹ Γ +
    C Γ_{T−d}) u_k``; the velocity is its backward difference ``(1 − z⁻¹) / T``."""
    plant = rig.axis("master").plant
    t, d = rig.period_s, plant.delay_s + rig.timer.compute_s
    assert 0 < d < t
    s = control.tf("s")
    factor = 1
    for m in plant.modes:
        w = 2 * math.pi * m.freq_hz
        factor = factor + m.gain * s**2 / (s**2 + 2 * m.damping * w * s + w**2)
    cont = control.ss(plant.gain_cps_per_v / (s * (plant.tau_s * s + 1)) * factor)
    full = control.sample_system(cont, t, method="zoh")
    part = control.sample_system(cont, t - d, method="zoh")
    c, phi, gam = np.asarray(cont.C), np.asarray(full.A), np.asarray(full.B)
    out = []
    for z in np.exp(2j * np.pi * np.asarray(freq_hz) * t):
        x = np.linalg.solve(z * np.eye(phi.shape[0]) - phi, gam)
        y = (c @ np.asarray(part.A) @ x + c @ np.asarray(part.B))[0, 0] / z
        out.append(y * (1 - 1 / z) / t)
    return np.array(out)


def _count_inside(path: Path, rig: st.Rig) -> tuple[int, int]:
    """Lines of the FRF file (its ``re``, ``im``, ``radius95``, docs/frf.md#file) whose 95 %
    circle holds the independent model."""
    doc = json.loads(path.read_text(encoding="utf-8"))
    f = np.array([ln["freq_hz"] for ln in doc["lines"]])
    g = np.array([ln["re"] + 1j * ln["im"] for ln in doc["lines"]])
    r = np.array([ln["radius95"] for ln in doc["lines"]])
    return int(np.sum(np.abs(_independent_model(rig, f) - g) <= r)), f.size


def _said_count(sentence: str) -> tuple[int, int]:
    m = re.search(r"within the measured 95 % bounds on (\d+) of (\d+) lines", sentence)
    assert m is not None, sentence
    return int(m.group(1)), int(m.group(2))


@pytest.fixture(scope="module")
def tuning_path(tmp_path_factory: pytest.TempPathFactory, default_tuning: st.Tuning) -> Path:
    """The session's tuning of the example rig; the belt-axis rig has the same axes, roles and
    timer, so it is reported on with it."""
    path = tmp_path_factory.mktemp("resonance-tuning") / "tuning.json"
    write_tuning(default_tuning, path)
    return path


@pytest.fixture(scope="module")
def belt_frf(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _frf_file(tmp_path_factory.mktemp("belt-frf"), BELT_RIG, "belt")


# --- absent: a rigid rig without an FRF -------------------------------------------------------


def test_absent_for_the_example_rig_and_the_page_keeps_its_bytes(
    tmp_path: Path, tuning_path: Path
) -> None:
    assert resonance_section(load_rig(EXAMPLE_RIG)) == ("", None)
    pages = []
    for name, extra in (("without", {}), ("none", {"frf": None}), ("empty", {"frf": {}})):
        out = tmp_path / name
        out.mkdir()
        pages.append(
            write_report(out, tuning_path=tuning_path, rig_path=EXAMPLE_RIG, **extra).read_bytes()
        )
    # the page written without the new parameter is the reference
    assert pages[1] == pages[0] and pages[2] == pages[0]
    page = pages[0].decode("utf-8")
    assert _section(page) is None and 'href="#resonance"' not in page
    assert "resonance" not in _data(page)


# --- present: the belt-driven axis ------------------------------------------------------------


def test_the_belt_axis_rig_has_the_section_with_its_modes(tmp_path: Path) -> None:
    rig = load_rig(BELT_RIG)
    body, data = resonance_section(rig)
    assert body.startswith('<section id="resonance"><h2>Resonance</h2>') and data is not None
    mode = rig.axis("master").plant.modes[0]  # plants/belt-axis.toml: 35 Hz, 0.04, 0.5
    (row,) = _rows(body)
    assert row[0] == "master"
    assert [float(row[i]) for i in (1, 3, 5)] == [mode.freq_hz, mode.damping, mode.gain]
    assert row[2] == row[4] == row[6] == "—"  # the rig file gives no intervals
    # anti-resonance f / √(1 + g) (docs/frf.md#modes), shown to 4 digits
    assert float(row[7]) == pytest.approx(mode.freq_hz / math.sqrt(1 + mode.gain), rel=5e-4)
    assert data["master"]["modes"] == [mode.to_dict()] and data["slave"]["modes"] == []
    said = data["master"]["statement"]
    assert said == (
        "master: 1 mode at 35.0 Hz (damping 0.040) in the rig file; no frequency response measured."
    )
    assert html.escape(said) in body
    assert data["slave"]["statement"].startswith("slave: no mode in the rig file")


def test_fitted_intervals_are_shown(tmp_path: Path) -> None:
    text = BELT_RIG.read_text(encoding="utf-8").replace(
        "gain = 0.5                # J_load",
        "gain = 0.5\nfreq_hz_95 = [34.8, 35.2]\ndamping_95 = [0.035, 0.045]\n"
        "gain_95 = [0.45, 0.55]   # J_load",
    )
    path = tmp_path / "belt-fitted.toml"
    path.write_text(text, encoding="utf-8")
    (row,) = _rows(resonance_section(load_rig(path))[0])
    assert row[2] == "34.8 … 35.2" and row[4] == "0.035 … 0.045" and row[6] == "0.45 … 0.55"


def test_the_statement_follows_the_numbers(tmp_path: Path) -> None:
    before = resonance_section(load_rig(BELT_RIG))[1]["master"]["statement"]
    text = BELT_RIG.read_text(encoding="utf-8")
    text = text.replace("freq_hz = 35.0 ", "freq_hz = 42.5 ").replace(
        "damping = 0.04 ", "damping = 0.025 "
    )
    path = tmp_path / "belt-42.toml"
    path.write_text(text, encoding="utf-8")
    rig = load_rig(path)
    body, data = resonance_section(rig)
    after = data["master"]["statement"]
    assert after != before and "35.0" not in after
    assert after.startswith("master: 1 mode at 42.5 Hz (damping 0.025)")
    (row,) = _rows(body)
    assert [float(row[i]) for i in (1, 3)] == [42.5, 0.025]
    two = (
        Mode(freq_hz=35.0, damping=0.04, gain=0.5),
        Mode(freq_hz=80.5, damping=0.01, gain=0.1),
    )
    assert resonance_statement("x", two).startswith(
        "x: 2 modes at 35.0 Hz (damping 0.040) and 80.5 Hz (damping 0.010) in the rig file"
    )


# --- with a measured frequency response -------------------------------------------------------


def test_with_an_frf_file_the_figure_is_embedded_and_the_count_is_right(
    tmp_path: Path, tuning_path: Path, belt_frf: Path
) -> None:
    rig = load_rig(BELT_RIG)
    page_path = write_report(
        tmp_path, tuning_path=tuning_path, rig_path=BELT_RIG, frf={"master": belt_frf}
    )
    page = page_path.read_text(encoding="utf-8")
    body = _section(page)
    assert body is not None and '<a href="#resonance">Resonance</a>' in page
    # the figure: a PNG, the same bytes as the figure drawn again (deterministic)
    (src,) = re.findall(r'<img alt="[^"]*" src="data:image/png;base64,([^"]+)"', body)
    png = base64.b64decode(src)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    again = png_uri(resonance_figure(rig, "master", belt_frf))
    assert again == "data:image/png;base64," + src
    # the count, against one made here from the file and python-control
    inside, lines = _count_inside(belt_frf, rig)
    said = _data(page)["resonance"]["master"]
    assert _said_count(said["statement"]) == (inside, lines)
    assert (said["frf"]["lines_inside_95"], said["frf"]["lines"]) == (inside, lines)
    assert html.escape(said["statement"]) in body
    # Coulomb friction (plants/belt-axis.toml: coulomb_v 0.002) is not in the linear model: the
    # lines it bends lie outside, the rest inside
    assert 0.5 * lines < inside < lines
    (row,) = _rows(body)
    assert float(row[1]) == 35.0  # plants/belt-axis.toml


def test_a_right_model_lies_inside_on_about_95_percent_of_the_lines(tmp_path: Path) -> None:
    """Without Coulomb friction the rig's linear model is the simulated plant: its lines lie
    inside the 95 % bounds on about 95 % of them (a wrong compute time or delay in the model
    would put most outside)."""
    text = BELT_RIG.read_text(encoding="utf-8").replace("coulomb_v = 0.002", "coulomb_v = 0.0")
    rig_path = tmp_path / "belt-no-friction.toml"
    rig_path.write_text(text, encoding="utf-8")
    rig = load_rig(rig_path)
    frf_path = _frf_file(tmp_path, rig_path, "nofric")
    check = check_model(rig, "master", frf_path)
    inside, lines = _count_inside(frf_path, rig)
    assert (check.lines_inside, check.lines) == (inside, lines)
    assert inside >= 0.9 * lines
    said = resonance_section(rig, {"master": frf_path})[1]["master"]["statement"]
    assert _said_count(said) == (inside, lines)


def test_a_synthetic_frf_counts_exactly_the_lines_moved_outside() -> None:
    rig = load_rig(BELT_RIG)
    t = rig.period_s
    freq = (2 * np.arange(60) + 1) / (500 * t)  # odd lines of a 500-tick period, < 60 Hz
    model = _independent_model(rig, freq)
    radius = 1e-3 * np.abs(model)
    moved = np.zeros(freq.size, dtype=bool)
    moved[[3, 17, 29, 30, 44, 58]] = True
    measured = model + np.where(moved, 3.0, 0.2) * radius * np.exp(1j * np.arange(freq.size))
    empty = np.zeros(0)
    frf = Frf(
        freq_hz=freq,
        response=measured,
        std=radius / 2.45,
        radius95=radius,
        coherence=np.ones(freq.size),
        noise=radius,
        output_level=np.abs(measured),
        aliased=np.zeros(freq.size, dtype=bool),
        odd_hz=empty,
        odd_level=empty,
        odd_noise=empty,
        even_hz=empty,
        even_level=empty,
        even_noise=empty,
        output="velocity",
        period_s=t,
        period_ticks=500,
        periods=7,
        skipped=1,
    )
    data = resonance_section(rig, {"master": frf})[1]
    said = data["master"]["statement"]
    assert _said_count(said) == (54, 60)  # 60 lines, 6 moved out
    assert data["master"]["frf"]["outside_hz"] == pytest.approx(freq[moved].tolist())
    assert "farthest outside at" in said and "3 times its 95 % radius away" in said
    # the sentence follows the numbers: one more line out, one fewer in
    moved[10] = True
    frf2 = dataclasses.replace(frf, response=model + np.where(moved, 3.0, 0.2) * radius)
    said2 = resonance_section(rig, {"master": frf2})[1]["master"]["statement"]
    assert _said_count(said2) == (53, 60)
    fig = resonance_figure(rig, "master", frf)
    assert not axis_unit_problems(fig)


def test_the_frf_file_reads_back(belt_frf: Path) -> None:
    doc = json.loads(belt_frf.read_text(encoding="utf-8"))
    frf = read_frf(belt_frf)
    assert read_frf(doc).to_dict()["lines"] == doc["lines"] == frf.to_dict()["lines"]
    assert (frf.periods, frf.period_ticks, frf.output) == (
        doc["periods"],
        doc["period_ticks"],
        doc["output"],
    )


def test_bad_frf_inputs_are_refused(tmp_path: Path, belt_frf: Path) -> None:
    rig = load_rig(BELT_RIG)
    with pytest.raises(SpecError, match=r"FRF given for axes \['x'\]"):
        resonance_section(rig, {"x": belt_frf})
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema": "servotune.fleet/1"}', encoding="utf-8")
    with pytest.raises(SpecError, match=r"not a servotune\.frf/1 file"):
        resonance_section(rig, {"master": bad})
    doc = json.loads(belt_frf.read_text(encoding="utf-8"))
    doc["period_s"] = 0.001
    with pytest.raises(SpecError, match=r"measured at a tick period of 0\.001 s"):
        check_model(rig, "master", doc)


def test_modal_response_is_the_model_drawn(belt_frf: Path) -> None:
    """The report's model is servotune.modal's exact sampled response of the rig's plant,
    which agrees with the python-control route above to rounding."""
    rig = load_rig(BELT_RIG)
    check = check_model(rig, "master", belt_frf)
    plant = rig.axis("master").plant
    direct = modal_response(
        check.frf.freq_hz,
        gain_cps_per_v=plant.gain_cps_per_v,
        tau_s=plant.tau_s,
        delay_s=plant.delay_s,
        period_s=rig.period_s,
        modes=plant.modes,
        compute_s=rig.timer.compute_s,
    )
    np.testing.assert_array_equal(check.model, direct)
    np.testing.assert_allclose(direct, _independent_model(rig, check.frf.freq_hz), rtol=1e-9)


def test_doctests_of_the_resonance_module() -> None:
    import doctest

    import servotune.report.resonance

    result = doctest.testmod(servotune.report.resonance)
    assert result.failed == 0 and result.attempted > 0
