"""The report of a live autotune run (docs/autotune.md#the-live-run): ``autotune.html``.

One self-contained page (:mod:`.page`) from what the run wrote into its directory: the record
``autotune.json`` (status, each step's numbers, the files' SHA-256, the capture's channels), and
the phases' captures (``wiring-check.txt``, ``experiment.txt``: halsampler rows, the sample
number first, then the channels the record names) and ``validation.csv`` (the validation move:
measured against predicted). A step the run did not reach is said to be missing, not drawn.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from servotune.io.files import atomic_write_text
from servotune.report.page import (
    escape_html,
    figure_html,
    fmt_value,
    page_html,
    paragraph_html,
    png_uri,
    table_html,
)

__all__ = ["autotune_report_html", "write_autotune_report"]


def _capture(path: Path) -> np.ndarray | None:
    if not path.exists():
        return None
    rows = np.loadtxt(path, ndmin=2)
    return rows if rows.size else None


def _phase_figure(
    rec: np.ndarray, col: dict[str, int], period_s: float, scale: float, title: str
) -> str:
    """A phase's capture drawn; ``col``: each channel's column."""
    t = np.arange(rec.shape[0]) * period_s
    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 4.6), sharex=True)
    pos = (rec[:, col["feedback"]] - rec[0, col["command"]]) * scale
    a.plot(t, pos, lw=1, label="position − start command [counts]")
    a.set_ylabel("counts")
    a.legend(loc="upper right", fontsize=8)
    b.plot(t, rec[:, col["volts"]], lw=1, label="output to the drive [V]")
    b.plot(t, rec[:, col["excitation"]], lw=1, label="excitation [V]")
    trip = np.flatnonzero(rec[:, col["fault"]] > 0.5)
    if trip.size:
        for ax in (a, b):
            ax.axvline(t[trip[0]], color="r", lw=1)
        b.text(t[trip[0]], b.get_ylim()[1], " guard tripped", color="r", va="top", fontsize=8)
    b.set_xlabel("time [s]")
    b.set_ylabel("V")
    b.legend(loc="upper right", fontsize=8)
    a.set_title(title)
    fig.tight_layout()
    return figure_html(png_uri(fig), title)


def _validation_figure(path: Path) -> str:
    d = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    t, cmd, meas, pred = d.T
    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 4.6), sharex=True)
    a.plot(t, cmd, lw=1, label="command")
    a.plot(t, meas, lw=1, label="measured")
    a.plot(t, pred, lw=1, ls="--", label="predicted (verified model)")
    a.set_ylabel("counts")
    a.legend(loc="upper right", fontsize=8)
    b.plot(t, cmd - meas, lw=1, label="measured")
    b.plot(t, cmd - pred, lw=1, ls="--", label="predicted")
    b.set_ylabel("following error [counts]")
    b.set_xlabel("time [s]")
    b.legend(loc="upper right", fontsize=8)
    a.set_title("validation move")
    fig.tight_layout()
    return figure_html(png_uri(fig), "validation move", "measured against the prediction")


def autotune_report_html(out_dir: str | Path) -> str:
    """The page for the run whose files are in ``out_dir`` (module docstring)."""
    out = Path(out_dir)
    doc = json.loads((out / "autotune.json").read_text())
    period_s = float(doc.get("period_s", 0.004))
    scale = float(doc.get("position_scale", 1.0))
    col = {name: k + 1 for k, name in enumerate(doc["capture_channels"])}
    status = (
        "loaded and validated"
        if doc["status"] == "loaded"
        else f"stopped: {doc['stopped']} (the previous parameters are back)"
    )
    parts = [f"<h1>servotune autotune: {escape_html(status)}</h1>"]
    w = doc.get("wiring_check") or {}
    parts.append("<h2>1. Wiring check (open loop)</h2>")
    if w:
        parts.append(
            table_html(
                ["pulse", "expected", "moved up", "moved down", "ratio"],
                [
                    [
                        fmt_value(w["volts"], "V"),
                        fmt_value(w["expected_counts"], "counts"),
                        fmt_value(w["up_counts"], "counts"),
                        fmt_value(w["down_counts"], "counts"),
                        fmt_value(w["ratio"]),
                    ]
                ],
            )
        )
    for name, title, step in (
        ("wiring-check.txt", "wiring check", None),
        ("experiment.txt", "experiment (closed loop, captured)", "2. Experiment"),
    ):
        if step:
            parts.append(f"<h2>{step}</h2>")
        rec = _capture(out / name)
        parts.append(
            _phase_figure(rec, col, period_s, scale, title)
            if rec is not None
            else paragraph_html(f"{title}: not reached")
        )
    parts.append("<h2>3. Fit, tune, verify, export</h2>")
    fit = doc.get("fit") or {}
    if fit:
        rows = [[k, fmt_value(v)] for k, v in sorted(fit["params"].items())]
        rows.append(["velocity fit", fmt_value(fit["velocity_fit_pct"], "%")])
        for k, mode in enumerate(fit.get("modes") or [], start=1):
            rows.append(
                [
                    f"mode {k}",
                    f"{fmt_value(mode['freq_hz'], 'Hz')}, damping {fmt_value(mode['damping'])}, "
                    f"gain {fmt_value(mode['gain'])}",
                ]
            )
        parts.append(table_html(["fitted", "value"], rows))
    else:
        parts.append(paragraph_html("not reached"))
    parts.append("<h2>4. Parameters</h2>")
    loaded = doc.get("loaded") or {}
    prev = {k.rsplit(".", 1)[1]: v for k, v in (doc.get("previous") or {}).items()}
    rows = [
        [n, prev.get(n, "—"), fmt_value(loaded[n]) if n in loaded else "—"]
        for n in sorted(set(prev) | set(loaded))
    ]
    parts.append(table_html(["pin", "before", "loaded"], rows))
    parts.append("<h2>5. Validation move</h2>")
    v = doc.get("validation") or {}
    if v:
        parts.append(
            table_html(
                ["", "measured [counts]", "predicted [counts]", "allowed"],
                [
                    [
                        k.replace("_", " "),
                        fmt_value(v["measured"][k]),
                        fmt_value(v["predicted"][k]),
                        f"±({rel:g}·|predicted| + {ab:g})",
                    ]
                    for k, (rel, ab) in v["tolerance"].items()
                ],
                bad=[bool(v["problems"])] * len(v["tolerance"]),
            )
        )
    if (out / "validation.csv").exists():
        parts.append(_validation_figure(out / "validation.csv"))
    else:
        parts.append(paragraph_html("not reached"))
    parts.append("<h2>Record</h2>")
    parts.append(table_html(["file", "SHA-256"], sorted((doc.get("files_sha256") or {}).items())))
    secs = doc.get("seconds") or {}
    parts.append(
        paragraph_html(
            f"machine time {fmt_value(secs.get('machine_s'), 's')}, wall time "
            f"{fmt_value(secs.get('total_s'), 's')}; servotune {doc['servotune']}"
        )
    )
    return page_html("servotune autotune", "\n".join(parts), doc)


def write_autotune_report(out_dir: str | Path) -> Path:
    """Write ``autotune.html`` into ``out_dir`` (atomically); its path."""
    path = Path(out_dir) / "autotune.html"
    atomic_write_text(path, autotune_report_html(out_dir))
    return path
