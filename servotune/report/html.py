"""The HTML report: one self-contained page (plots embedded as PNG data URIs).

Sections: the verification table (with margins and checks), Bode plots of each task loop with
its margins (python-control, the discrete loop as the engine runs it), step and tracking
responses of the tuning in the bit-true loop, the query-table heat maps, and — when the output
directory holds them (``make demo`` writes them first) — the identification plots and the
Figure-4 comparison. The only other module that imports matplotlib is :mod:`servotune.plot`.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import control
import matplotlib.pyplot as plt
import numpy as np

from servotune._version import __version__
from servotune.io.files import atomic_write_text
from servotune.laws.fuzzy_pid import TABLE_NAMES, FuzzyPIDConstants
from servotune.plant import discretize
from servotune.plot import plot_bode, plot_query_tables, plot_tracking
from servotune.rig import Rig, load_rig
from servotune.scenarios import step_inputs, sync_move
from servotune.sim.engine import simulate
from servotune.tuning import Tuning, read_tuning
from servotune.verify.margins import tuning_margins

__all__ = ["loop_response", "write_report"]


def loop_response(rig: Rig, tuning: Tuning, axis: str, omega_rad_s: np.ndarray) -> Any:
    """Frequency response of one axis's task loop at the table centre (E = EC = 0).

    ``L(z) = C(z) · lsb_v · P(z)``, ``C(z) = Kp + Ki·T·z/(z−1) (+ Kd/T·(1 − z⁻¹))`` from the
    tuning's quantised constants, ``P`` the axis model discretised with ZOH and the lag
    ``compute_s + delay_s`` (:func:`servotune.plant.discretize`).

    Returns
    -------
    control.FrequencyResponseData
    """

    c = tuning.controller(axis)
    if c.task is None:
        raise ValueError(f"axis {axis!r} has no task law")
    t = rig.period_s
    kp, kit = c.task.kp.value, c.task.ki_t.value
    kdt = 0.0
    if isinstance(c.task, FuzzyPIDConstants):
        n = c.task.n
        kp = float(c.task.scheduled("kp")[n, n])
        kit = float(c.task.scheduled("ki")[n, n])
        kdt = float(c.task.scheduled("kd")[n, n])
    # C(z) = [(Kp + Ki·T + Kd/T) z² − (Kp + 2·Kd/T) z + Kd/T] / (z² − z)
    ctrl = control.tf([kp + kit + kdt, -(kp + 2 * kdt), kdt], [1.0, -1.0, 0.0], dt=t)
    ax = rig.axis(axis)
    plant = discretize(ax.plant, t, rig.timer.compute_s + ax.plant.delay_s) * rig.dac.lsb_v
    return control.frequency_response(control.series(ctrl, plant), omega_rad_s)


def _png(fig: Any) -> str:

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, metadata={"Software": None})
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _img(uri: str, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="{uri}">'


def _table(head: Sequence[str], rows: Sequence[Sequence[Any]], bad: Sequence[bool] = ()) -> str:
    out = ["<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for i, r in enumerate(rows):
        cls = ' class="fail"' if (i < len(bad) and bad[i]) else ""
        out.append(f"<tr{cls}>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>")
    return "\n".join(out) + "</table>"


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return "n/a" if not math.isfinite(x) else f"{x:.4g}"
    return "—" if x is None else str(x)


def _verification_section(v: Any) -> str:
    rows, bad = [], []
    for r in v.rows:
        rows.append([r.scenario, r.axis, r.quantity, _fmt(r.limit), _fmt(r.worst), _fmt(r.margin),
                     "pass" if r.passed else "FAIL"])  # fmt: skip
        bad.append(not r.passed)
    checks = [[c.name, "pass" if c.passed else "FAIL", c.detail] for c in v.checks]
    verdict = "PASSED" if v.passed else "FAILED"
    return (
        f"<h2>Verification: {verdict}</h2>"
        + _table(["scenario", "axis", "quantity", "limit", "worst", "margin", ""], rows, bad)
        + "<h3>Checks</h3>"
        + _table(["check", "", "detail"], checks, [row[1] == "FAIL" for row in checks])
    )


def _bode_section(rig: Rig, tuning: Tuning) -> str:

    w = np.logspace(-1, math.log10(math.pi / rig.period_s) - 1e-3, 600)
    responses, rows = {}, []
    for name, c in zip(tuning.axis_names, tuning.controllers, strict=True):
        if c.task is None:
            continue
        fr = loop_response(rig, tuning, name, w)
        gm, pm, _sm, wpc, wgc, _ws = control.stability_margins(fr)
        responses[name] = (w, np.asarray(fr.complex).ravel())
        gm_db = 20 * math.log10(gm) if gm and math.isfinite(gm) else math.inf
        rows.append([name, _fmt(float(wgc)), _fmt(float(pm)), _fmt(gm_db), _fmt(float(wpc))])
    return (
        "<h2>Loops (Bode, margins by python-control; slave at the table centre)</h2>"
        + _img(_png(plot_bode(responses)), "Bode plots")
        + _table(
            ["axis", "crossover [rad/s]", "PM [deg]", "GM [dB]", "phase crossover [rad/s]"], rows
        )
    )


def _response_section(rig: Rig, tuning: Tuning, seed: int) -> str:

    loop = tuning.loop(rig)
    step = simulate(loop, step_inputs(rig, step_counts=rig.counts_per_rev, seconds=2.0), seed=seed)
    track = simulate(loop, sync_move(rig).inputs, seed=seed)
    return (
        "<h2>Step and tracking responses (bit-true loop)</h2>"
        + _img(_png(plot_tracking(step, "master step of one revolution, slave following")), "step")
        + _img(
            _png(plot_tracking(track, "start, constant speed, load step on the slave, stop")),
            "tracking",
        )
    )


def _tables_section(tuning: Tuning) -> str:

    parts = []
    for name, c in zip(tuning.axis_names, tuning.controllers, strict=True):
        if isinstance(c.task, FuzzyPIDConstants):
            tabs = {t: c.task.scheduled(t) for t in TABLE_NAMES}
            fig = plot_query_tables(tabs, c.task.n, f"{name}: scheduled Kp, Ki·T, Kd/T, K1/T")
            parts.append(_img(_png(fig), f"{name} query tables"))
    return "<h2>Query tables (as the runtime holds them)</h2>" + "".join(parts) if parts else ""


def _margins_section(rig: Rig, tuning: Tuning) -> str:
    """Heat maps of each scheduled axis's phase margin and Ms over the query table (frozen
    gains, nominal plant; python-control), the worst loop of each axis named."""
    m = tuning_margins(tuning, rig)
    parts = ["<h2>Margins of every loop the runtime can run (nominal plants)</h2>",
             "<p>" + "; ".join(html.escape(f"{a}: worst {m.worst(a).name}, PM "
                                           f"{m.worst(a).phase_margin_deg:.1f}°, Ms "
                                           f"{m.worst(a).max_sensitivity:.2f}")
                               for a in tuning.axis_names)
             + ". The feedforward acts on the reference only: it changes no margin. "
             "Over the plant set, see <code>servotune margins</code> and the verification's "
             "margins checks.</p>"]  # fmt: skip
    for name, c in zip(tuning.axis_names, tuning.controllers, strict=True):
        if isinstance(c.task, FuzzyPIDConstants):
            grids = {"PM [deg]": m.cell_grid(name, "phase_margin_deg"),
                     "Ms": m.cell_grid(name, "max_sensitivity")}  # fmt: skip
            fig = plot_query_tables(grids, c.task.n, f"{name}: margins per query-table cell")
            parts.append(_img(_png(fig), f"{name} margins per cell"))
    return "".join(parts)


def _figure4_text(data: dict) -> str:
    """The Figure-4 statement, its numbers (mean and range over the seeds) and the constraints
    each structure's optima sit on."""
    parts = [f"<p>{html.escape(s)}</p>" for s in data.get("statement", [])]
    table, spread = data.get("table", {}), data.get("spread", {})
    if table:
        keys = list(next(iter(table.values())))
        head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
        rows = []
        for s, row in table.items():
            cells = []
            for k in keys:
                v, r = row.get(k), spread.get(s, {}).get(k)
                text = "n/a" if v is None else f"{v:.4g}"
                if r and r[0] is not None and r[0] != r[1]:
                    text += f" ({r[0]:.4g}–{r[1]:.4g})"
                cells.append(f"<td>{text}</td>")
            active = data.get("active_constraints", {}).get(s, {})
            sits = ", ".join(active.get("binding", []) + active.get("at_bounds", [])) or "none"
            rows.append(f"<tr><th>{html.escape(s)}</th>{''.join(cells)}"
                        f"<td>{html.escape(sits)}</td></tr>")  # fmt: skip
        seeds = ", ".join(str(x) for x in data.get("seeds", []))
        parts.append(f"<p>Seeds {html.escape(seeds)}; held-out scenarios: "
                     f"{html.escape(', '.join(data.get('heldout_scenarios', [])))}.</p>"
                     f"<table><tr><th>structure</th>{head}<th>active constraints</th></tr>"
                     f"{''.join(rows)}</table>")  # fmt: skip
    return "".join(parts)


def _existing_images(out: Path) -> str:
    parts = []
    for pattern, title in (("fit_*.png", "Identification"), ("figure4.png", "Figure 4"),
                           ("sync_*.png", "Gantry with a listening slave (seed 003)"),
                           ("linkage_*.png", "Multi-CPU linkage (seed 002)")):  # fmt: skip
        files = sorted(out.glob(pattern))
        if files:
            parts.append(f"<h2>{title}</h2>")
            if pattern == "figure4.png" and (out / "figure4.json").is_file():
                parts.append(_figure4_text(json.loads((out / "figure4.json").read_text())))
                files += sorted(out.glob("pareto.png"))
            for f in files:
                uri = "data:image/png;base64," + base64.b64encode(f.read_bytes()).decode("ascii")
                parts.append(_img(uri, f.name))
    return "".join(parts)


_STYLE = (
    "body{font-family:sans-serif;max-width:1000px;margin:auto}img{max-width:100%}"
    "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:2px 6px}"
    "tr.fail{background:#fdd}"
)


def write_report(
    out_dir: str | Path,
    *,
    tuning_path: str | Path,
    rig_path: str | Path,
    verification: Any = None,
    seed: int = 0,
) -> Path:
    """Write ``report.html`` into ``out_dir`` (atomically) and return its path."""
    out = Path(out_dir)
    tuning = read_tuning(tuning_path)
    rig = load_rig(rig_path)
    tuning.check_rig(rig)
    prov = tuning.provenance
    body = [
        f"<h1>servotune report: {html.escape(rig.name)}</h1>",
        f"<p>tool {__version__}; tuning seed {html.escape(str(prov.get('seed')))}, rule base "
        f"{html.escape(str(prov.get('rule_base')))}; period {rig.period_s:.9g} s "
        f"(divisor {tuning.timer_divisor}).</p>",
    ]
    if verification is not None:
        body.append(_verification_section(verification))
    body += [
        _bode_section(rig, tuning),
        _response_section(rig, tuning, seed),
        _tables_section(tuning),
        _margins_section(rig, tuning),
        _existing_images(out),
    ]
    page = (
        '<!DOCTYPE html>\n<html><head><meta charset="utf-8"><title>servotune report</title>'
        f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n"
    )
    path = out / "report.html"
    atomic_write_text(path, page)
    return path
