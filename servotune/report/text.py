"""Results as text for the terminal: one function per result, each returning lines (no newline
at the end). The CLI prints them; the library never prints.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from servotune.arch.gantry.config import CASES, TOPOLOGIES
from servotune.report.summary import pass_fraction_text, search_notes
from servotune.validate import show_number, show_value
from servotune.verify.montecarlo import BEYOND_CHANCE

if TYPE_CHECKING:
    from servotune.analysis.margins import LoopMargins, Margins
    from servotune.arch.gantry.result import SyncComparison
    from servotune.arch.gantry.tuning import GantryTuning
    from servotune.arch.gantry.verify import GantryVerification
    from servotune.arch.linkage import LinkagePlan, LinkageVerification
    from servotune.arch.linkage.result import LinkageResult
    from servotune.verify.result import MonteCarloSummary, Verification

__all__ = [
    "figure4_statement",
    "format_comparison",
    "format_gantry_tuning",
    "format_gantry_verification",
    "format_linkage_plan",
    "format_linkage_summary",
    "format_linkage_verification",
    "format_margins",
    "format_montecarlo",
    "format_rig_facts",
    "format_table",
    "format_tuning_summary",
]


def format_table(verification: Verification) -> str:
    """A pass/fail table with margins, then the checks and the verdict (for the terminal)."""
    v = verification
    head = ("scenario", "quantity", "axis", "limit", "worst", "margin", "margin %", "variant", "")
    lines = [head]
    for r in v.rows:
        rel = r.relative_margin
        lines.append(
            (
                r.scenario,
                r.quantity,
                r.axis,
                f"{show_number(r.limit)} {r.unit}",
                f"{show_number(r.worst)} {r.unit}",
                show_number(r.margin),
                "n/a" if rel is None or not math.isfinite(rel) else f"{100.0 * rel:.0f}",
                r.variant,
                "ok" if r.passed else "FAIL",
            )
        )
    widths = [max(len(row[i]) for row in lines) for i in range(len(head))]
    right = {3, 4, 5, 6}
    out = [
        f"verify: spec {show_value(v.spec.name)} on rig {show_value(v.rig_name)}, seed {v.seed}, "
        f"{v.plant_sets} plant sets (nominal + {v.plant_sets - 1} Monte Carlo)"
    ]
    for row in lines:
        cells = [
            c.rjust(w) if i in right else c.ljust(w)
            for i, (c, w) in enumerate(zip(row, widths, strict=True))
        ]
        out.append("  ".join(cells).rstrip())
    if not v.rows:
        out.append("(closed-loop runs skipped)")
    out.append("checks")
    for c in v.checks:
        out.append(f"  {'ok  ' if c.passed else 'FAIL'}  {c.name}: {c.detail}")
    if v.pass_fraction[1]:
        out.append(pass_fraction_text(v.pass_fraction))
    if v.montecarlo is not None:
        out.append(format_montecarlo(v.montecarlo))
    n_fail = sum(not r.passed for r in v.rows) + sum(not c.passed for c in v.checks)
    out.append("PASSED" if v.passed else f"FAILED ({n_fail} of {len(v.rows) + len(v.checks)})")
    return "\n".join(out)


def format_montecarlo(summary: MonteCarloSummary, parameters: int = 3) -> str:
    """The Monte-Carlo plant sets with the least margin (each with the ``parameters`` drawn
    values the sensitivity table ranks first) and the sensitivity table."""
    s = summary
    if not s.count:
        return "Monte Carlo: no plant sets drawn"
    top = [x.parameter for x in s.sensitivity[:parameters]]
    out = [
        f"worst plant sets of {s.count:,} from the {s.distribution} (least relative margin "
        "over every limit):"
    ]
    for w in s.worst:
        if w.quantity == "fault_runs":
            fig = f"{w.scenario}: a fault latched on {w.axis}"
        else:
            fig = (
                f"{w.scenario}: {w.quantity} of {w.axis} = {show_number(w.value)} {w.unit} "
                f"(limit {show_number(w.limit)})"
            )
        rel = w.relative_margin
        pct = f"{100.0 * rel:+.0f} %" if math.isfinite(rel) else "fault"
        params = ", ".join(f"{p} {show_number(w.parameters[p])}" for p in top)
        out.append(
            f"  {w.label:<10} {pct:>7}  {'ok  ' if w.passed else 'FAIL'}  {fig}"
            + (f"; {params}" if params else "")
        )
    if s.sensitivity:
        tested = any(math.isfinite(x.fail_p_value) for x in s.sensitivity)
        out.append(
            "sensitivity: failure rate of the plant sets in each parameter's lowest and "
            "highest quarter of the draws; "
            + (
                "p = rank-sum test of the failing against the passing plant sets' values "
                "(two-sided); "
                if tested
                else ""
            )
            + "ρ = Spearman correlation with the least margin (< 0: larger values leave "
            "less margin)"
        )
        head = (
            "parameter",
            "lowest quarter",
            "fail %",
            "highest quarter",
            "fail %",
            *(("p",) if tested else ()),
            "ρ",
        )
        rows = [head]
        for x in s.sensitivity:
            rho = x.rank_correlation
            rows.append(
                (
                    x.parameter,
                    f"<= {show_number(x.low_edge)}",
                    f"{x.low_fail_pct:.3g}",
                    f">= {show_number(x.high_edge)}",
                    f"{x.high_fail_pct:.3g}",
                    *((show_number(x.fail_p_value),) if tested else ()),
                    f"{rho:+.2f}" if math.isfinite(rho) else "n/a",
                )
            )
        widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
        for r in rows:
            cells = [
                c.ljust(w) if i == 0 else c.rjust(w)
                for i, (c, w) in enumerate(zip(r, widths, strict=True))
            ]
            out.append("  " + "  ".join(cells).rstrip())
        if tested:
            n_fail = s.count - s.passed
            rule = f"p < {BEYOND_CHANCE:g}/{len(s.sensitivity)}, Bonferroni"
            apart = [x.parameter for x in s.sensitivity if x.beyond_chance]
            out.append(
                f"the {n_fail} failing plant sets differ beyond chance ({rule}) in: "
                + ", ".join(apart)
                if apart
                else f"no parameter sets the {n_fail} failing plant sets apart beyond chance "
                f"({rule}): the table's failure rates may be chance"
            )
    return "\n".join(out)


def format_comparison(cmp: SyncComparison) -> str:
    """The comparison as a text table (one row per topology, max/RMS per case)."""
    c = cmp.config
    head = f"{'topology':<11}" + "".join(
        f"{case + ' max':>13}{case + ' RMS':>13}" for case in CASES
    )
    lines = [
        f"gantry {c.name}: sync error [counts], bus cycle {c.bus.cycle_s * 1e3:g} ms, "
        f"latency {c.bus.latency_cycles} cycle(s), deployed: {c.topology}",
        head,
    ]
    for topo in TOPOLOGIES:
        cells = ""
        for case in CASES:
            r = cmp.row(topo, case)
            mark = " TRIP" if r.tripped else ""
            cells += f"{r.max_sync_error_counts:>13.1f}{r.rms_sync_error_counts:>13.1f}{mark}"
        lines.append(f"{topo:<11}{cells}")
    lines += [f"move shaping: {line}" for line in cmp.shaper]
    for side in ("master", "slave"):
        filters = getattr(c, side).filters
        if filters:
            lines.append(
                f"{side} drive's output filters: {'; '.join(f.describe() for f in filters)}"
            )
    if cmp.predicted is not None:
        p = cmp.predicted
        lines.append(
            f"predicted (linear) load-case max: parallel {p.parallel_max_counts:.1f}, "
            f"listening {p.listening_max_counts:.1f} (x{p.ratio:.3f})"
        )
    lim = c.margins
    lines.append(
        f"margins over the plant set (gain ±{lim.gain_spread:.0%}, tau "
        f"±{lim.tau_spread:.0%}, +{lim.extra_cycles} cycle; limits PM >= "
        f"{lim.min_phase_margin_deg:g}°, GM >= {lim.min_gain_margin_db:g} dB, Ms <= "
        f"{lim.max_sensitivity:g}), the least phase margin of each loop:"
    )
    for loop, m in cmp.worst_margins().items():
        lines.append(
            f"  {loop:<7}PM {show_number(m.phase_margin_deg)}°, GM "
            f"{show_number(m.gain_margin_db)} dB, Ms {show_number(m.max_sensitivity)} "
            f"(plant {m.plant})"
        )
    if cmp.montecarlo is not None:
        w = cmp.montecarlo.worst
        lines.append(
            pass_fraction_text(cmp.montecarlo.pass_fraction, "plant pairs never trip")
            + f"; largest sync error {w.max_sync_error_counts:.0f} counts "
            f"({w.label})"
        )
    lines.append("PASS" if cmp.passed else "FAIL: " + "; ".join(cmp.failed))
    return "\n".join(lines)


def format_linkage_summary(result: LinkageResult) -> str:
    """A short text summary of a run (what ``servotune linkage`` prints).

    Returns
    -------
    str
        Several lines, no trailing newline.
    """
    b = result.bus
    rec = result.recommended_resync_interval_s
    lines = [
        f"linkage {result.name}: {len(result.axes)} axes on {len(result.cpus)} slave CPUs, "
        f"{result.time_s.size * result.period_s:.3f} s at {result.period_s * 1e3:g} ms, "
        f"seed {result.seed}",
        f"  bus        frame {b.frame_bytes} bytes = {b.frame_s * 1e3:.3f} ms every "
        f"{b.broadcast_period_s * 1e3:.3f} ms (utilisation {b.utilisation * 100:.1f} %), "
        f"lead {b.lead_s * 1e3:.2f} ms",
        f"  clock      resync every {result.resync_interval_s:g} s"
        + (" (start only)" if not result.resync_interval_s else "")
        + (f"; recommended {rec:g} s" if rec is not None else ""),
    ]
    for c in result.cpus:
        first = f" (first {c.first_underrun_s:.3f} s)" if c.first_underrun_s is not None else ""
        firsto = f" (first {c.first_overrun_s:.3f} s)" if c.first_overrun_s is not None else ""
        lines.append(
            f"  cpu {c.name:<6} {c.clock_ppm:+8.1f} ppm  axes {','.join(c.axes):<10} queue "
            f"{c.min_level}..{c.max_level} of {c.queue_depth}  underruns {c.underruns}{first}  "
            f"overruns {c.overruns}{firsto}  skipped {c.skipped}"
        )
    for a in result.axes:
        fault = f"  FAULT {a.fault} at {a.first_fault_s:.3f} s" if a.fault else ""
        lines.append(
            f"  axis {a.name:<5} on {a.cpu:<6} kp {a.kp:.4g} ki {a.ki:.4g}"
            f"{' (tuned)' if a.tuned else ''}  tracking error max {a.max_abs_err_counts:.1f} "
            f"rms {a.rms_err_counts:.1f} counts{fault}"
        )
    lines.append(
        f"  contour    max {result.contour_max_counts:.2f} counts, rms "
        f"{result.contour_rms_counts:.2f} counts"
    )
    for arc in result.arcs:
        lines.append(
            f"  circle     move {arc.move} in {'/'.join(arc.plane)}, R {arc.radius_counts:g}: "
            f"radial deviation {arc.min_dev_counts:+.2f} … {arc.max_dev_counts:+.2f}, "
            f"circularity {arc.circularity_counts:.2f} counts at constant feed "
            f"({arc.circularity_whole_counts:.2f} with the ramps)"
        )
    failed = result.failed_checks
    lines.append("  PASSED" if not failed else "  FAILED: " + "; ".join(c.detail for c in failed))
    return "\n".join(lines)


def format_rig_facts(f: Mapping[str, Any]) -> str:
    """What ``servotune rig`` prints: the facts of :func:`servotune.rig.describe_rig`."""
    lines = [
        f"rig {f['rig']}",
        f"  timer divisor            {f['timer_divisor']}",
        f"  achieved period          {f['achieved_period_s'] * 1e3:.6f} ms "
        f"({f['period_error_ppm']:+.1f} ppm vs {f['requested_period_s'] * 1e3:g} ms)",
        f"  counts per revolution    {f['counts_per_rev']:g}",
        f"  D/A LSB                  {f['dac_lsb_mv']:.4f} mV",
        f"  unwrap speed limit       {f['unwrap_speed_limit_rpm']:.0f} r/min "
        f"({f['unwrap_max_counts_per_tick']} counts/tick)",
        f"  input-frequency limit    {f['input_frequency_speed_limit_rpm']:.0f} r/min "
        f"(binds first: {f['binding_speed_limit']})",
    ]
    for name, a in f["axes"].items():
        lo, hi = a["lock_band_counts"]
        lines += [
            f"  axis {name} ({a['role']})",
            f"    speed limit            {a['speed_limit_rpm']:g} r/min "
            f"({a['counts_per_tick_at_speed_limit']:.1f} counts/tick; "
            f"{'within' if a['speed_limit_ok'] else 'EXCEEDS'} the counter limits)",
            f"    counter wraps every    {a['time_to_wrap_at_speed_limit_s']:.1f} s at that speed",
            f"    lock holding band      [{lo}, {hi}] counts "
            f"({'within' if a['lock_band_within_one_pulse'] else 'outside'} ±1 pulse)",
        ]
    return "\n".join(lines)


def _margin_row(m: LoopMargins, what: str, broken: tuple[str, ...]) -> str:
    def num(x: float, digits: int) -> str:
        return f"{x:.{digits}f}" if math.isfinite(x) else "inf"

    verdict = "ok" if not broken else "FAIL: " + "; ".join(broken)
    return (
        f"{m.axis:<8} {what:<26} {m.plant:<10} {num(m.phase_margin_deg, 1):>7} "
        f"{num(m.gain_margin_db, 1):>7} {num(m.delay_margin_ticks, 2):>9} "
        f"{num(m.max_sensitivity, 2):>6} {num(m.max_complementary_sensitivity, 2):>6} "
        f"{num(m.bandwidth_rad_s, 1):>9}  {verdict}"
    )


def _filter_lines(fx: Any, lim: Any) -> list[str]:
    """A filtered axis: its sections, their response at the modes and crossovers, and the
    nominal loops with the filters taken out."""
    out = [f"{fx.axis} output filters ({len(fx.sections)}, in series before the D/A):"]
    for i, s in enumerate(fx.sections):
        out.append(
            f"  {i + 1}: b = [{s.b0}, {s.b1}, {s.b2}], a = [{1 << s.frac_bits}, {s.a1}, {s.a2}] "
            f"(÷ 2^{s.frac_bits})"
        )
    for f_hz, g_db, ph in fx.at_modes:
        out.append(f"  at the mode {f_hz:g} Hz: {g_db:+.1f} dB, {ph:+.1f}°")
    for loop, wc, g_db, ph in fx.at_crossover:
        out.append(f"  at the {loop} loop's crossover {wc:.3g} rad/s: {g_db:+.2f} dB, {ph:+.1f}°")
    for m in fx.without:
        name = "task centre cell" if m.cell is not None else m.loop
        out.append(_margin_row(m, f"{name}, no filter", lim.broken(m)))
    return out


def _measured_lines(loops: Sequence[Any], lim: Any) -> list[str]:
    """The loops on measured responses: per axis, loop and latency the worst over the response
    and its 95 % bounds (the nominal in brackets), with the filters and without."""
    lo, hi = loops[0].band_hz
    out = [
        f"on the measured response ({lo:.3g} … {hi:.3g} Hz; worst over its 95 % bounds, on the "
        "response itself in brackets):",
        f"{'axis':<8} {'loop':<26} {'latency':<10} {'PM[deg]':>13} {'GM[dB]':>13} {'Ms':>11}",
    ]
    groups: dict[tuple[str, bool, str, int], list[Any]] = {}
    for m in loops:
        groups.setdefault((m.axis, not m.filtered, m.loop, m.extra_ticks), []).append(m)
    for key in sorted(groups):
        w = max(groups[key], key=lambda x: x.max_sensitivity)
        broken = w.broken(lim)
        name = w.loop + ("" if w.filtered else ", no filter")
        out.append(
            f"{w.axis:<8} {name:<26} {f'+{w.extra_ticks} tick':<10} "
            f"{w.phase_margin_deg:>5.1f} ({w.nominal_phase_margin_deg:5.1f}) "
            f"{w.gain_margin_db:>5.1f} ({w.nominal_gain_margin_db:5.1f}) "
            f"{w.max_sensitivity:>4.2f} ({w.nominal_max_sensitivity:4.2f})  "
            + ("ok" if not broken else "FAIL: " + "; ".join(broken))
        )
    return out


def format_margins(margins: Margins) -> str:
    """What ``servotune margins`` prints: per axis and loop the worst case, the scheduled
    axes' worst and centre cells, and the verdict naming the worst loop."""
    lim = margins.limits
    lines = [
        f"loop margins (limits: PM >= {lim.min_phase_margin_deg:g}°, GM >= "
        f"{lim.min_gain_margin_db:g} dB, Ms <= {lim.max_sensitivity:g})",
        f"{'axis':<8} {'loop':<26} {'plant':<10} {'PM[deg]':>7} {'GM[dB]':>7} "
        f"{'DM[ticks]':>9} {'Ms':>6} {'Mt':>6} {'BW[rad/s]':>9}",
    ]
    axes = list(dict.fromkeys(m.axis for m in margins.loops))
    scheduled = False
    for a in axes:
        for loop in ("lock", "task"):
            ms = list(margins.select(a, loop))
            if not ms:
                continue
            worst = margins.worst(a, loop)
            if worst.cell is None:
                lines.append(_margin_row(worst, loop, lim.broken(worst)))
                continue
            scheduled = True
            n_bad = sum(bool(lim.broken(m)) for m in ms)
            cells = len({m.cell for m in ms})
            lines.append(_margin_row(worst, f"task worst of {cells} cells", lim.broken(worst)))
            lines.append(
                f"{'':<8}   at E={worst.cell[0]:+d} EC={worst.cell[1]:+d}; "
                f"{n_bad} of {len(ms)} cell loops break a limit"
            )
            centre = [m for m in ms if m.cell == (0, 0) and m.plant == worst.plant]
            if centre:
                lines.append(_margin_row(centre[0], "task centre cell", lim.broken(centre[0])))
    if scheduled:
        lines.append("the feedforward (K1) acts on the reference only: it changes no margin")
    for fx in margins.filters:
        lines += _filter_lines(fx, lim)
    if margins.measured:
        lines += _measured_lines(margins.measured, lim)
    bad = margins.failures()
    if not bad:
        lines.append(f"margins: PASS ({len(margins.loops)} loops)")
    else:
        m, b = bad[0]
        lines.append(
            f"margins: FAIL ({len(bad)} of {len(margins.loops)} loops break a limit; "
            f"worst {m.name} on {m.plant}: {'; '.join(b)})"
        )
    return "\n".join(lines)


def format_tuning_summary(summary: Mapping[str, Any]) -> str:
    """What ``servotune tune`` prints on stderr (:func:`servotune.tune.workflow.tuning_summary`):
    per axis its gains and its worst loop's margins over the plant set."""
    lines = ["tuned gains [codes/count; Ki·T per tick, Kd/T and K1/T per count of change]"]
    for name, ax in summary["axes"].items():
        g = ax["gains"]
        parts = [f"lock {ax['lock_gain']:.4g}"]
        if g:
            parts.append(f"{ax['law']}: Kp {g['kp']:.4g}, Ki·T {g['ki_t']:.4g}")
        if "kd_t" in g:
            parts[-1] += f", Kd/T {g['kd_t']:.4g}, K1/T {g['k1_t']:.4g}"
            parts.append("table Kp " + "–".join(f"{x:.4g}" for x in g["kp_range"]))
        lines.append(f"  {name}: " + "; ".join(parts))
        w = ax.get("worst_loop")
        if w:
            cell = "" if w["cell"] is None else f" cell E={w['cell'][0]:+d} EC={w['cell'][1]:+d}"
            lines.append(
                f"    worst loop ({w['loop']}{cell}, plant {w['plant']}): PM "
                f"{show_number(w['phase_margin_deg'])}°, GM {show_number(w['gain_margin_db'])} dB, "
                f"Ms {show_number(w['max_sensitivity'])}"
            )
    s = summary.get("slave") or {}
    if s.get("objective") is not None:
        lines.append(
            f"  slave objective (mean ITAE of the sync error over the variants): "
            f"{s['objective']:.4g} counts·s²"
        )
    w = s.get("worst") or {}
    if "max_sync_counts" in w:
        run = summary.get("run") or {}
        lines.append(
            f"  tuning run ({show_number(run.get('speed_fraction'))} of the speed limit, load "
            f"{show_number(run.get('load_step_v'))} V), worst plant variant: sync error max "
            f"{w['max_sync_counts']:.0f} counts, RMS {w['rms_sync_counts']:.0f} counts; "
            f"saturation {w['saturation_pct']:.1f} %; slave lead {w['overshoot_pct']:.0f} % of "
            f"its lag; {'a fault' if w['fault'] else 'no fault'}"
        )
    lines += [f"  {n}" for n in search_notes(s)]
    return "\n".join(lines)


_FIGURE4_METRICS = (
    ("itae", "ITAE of the sync error (the tuning objective)", "counts·s²", 1.0, "{:.4g}"),
    ("max_sync_counts", "max sync error", "counts", 1.0, "{:.0f}"),
    ("rms_sync_counts", "RMS sync error", "counts", 1.0, "{:.1f}"),
    ("rise_s", "rise time", "ms", 1e3, "{:.0f}"),
    ("settling_s", "settling time", "ms", 1e3, "{:.0f}"),
    ("heldout_max_sync_counts", "held out: worst max sync error", "counts", 1.0, "{:.0f}"),
    ("heldout_rms_sync_counts", "held out: worst RMS sync error", "counts", 1.0, "{:.1f}"),
    ("heldout_pass_pct", "held out: plant sets keeping every limit", "%", 1.0, "{:.1f}"),
    ("worst_ms", "worst peak sensitivity Ms over the plant set", "", 1.0, "{:.2f}"),
)
_HIGHER_IS_BETTER = frozenset({"heldout_pass_pct"})
_STRUCTURE_NAMES = {"pid": "PID", "pid_ff": "PID + feedforward", "composite": "composite"}


def _structure(s: str) -> str:
    return _STRUCTURE_NAMES.get(s, s)


def _finite(row: Mapping[str, Any], key: str) -> bool:
    v = row.get(key)
    return v is not None and math.isfinite(v)


def figure4_statement(
    table: Mapping[str, Mapping[str, float]],
    spread: Mapping[str, Mapping[str, Sequence[float]]] | None = None,
) -> str:
    """What the Figure-4 comparison measured, in words derived from its numbers: the best
    structure of each metric with every structure's value (and its range over the seeds, where
    ``spread`` gives one), and whether the composite law wins on the tuning objective and on the
    held-out scenarios' worst sync error, as the seed claims. A win whose ranges over the seeds
    overlap the rival's is called not clear."""

    def shown(key: str, s: str, fmt: str, scale: float) -> str:
        text = fmt.format(table[s][key] * scale)
        lo_hi = (spread or {}).get(s, {}).get(key)
        if lo_hi is not None and lo_hi[0] != lo_hi[1]:
            text += f" ({fmt.format(lo_hi[0] * scale)}–{fmt.format(lo_hi[1] * scale)})"
        return text

    lines = []
    for key, what, unit, scale, fmt in _FIGURE4_METRICS:
        vals = {s: row[key] for s, row in table.items() if _finite(row, key)}
        if not vals:
            continue
        sign = -1.0 if key in _HIGHER_IS_BETTER else 1.0
        top = min(sign * v for v in vals.values())
        best = [_structure(s) for s, v in vals.items() if sign * v <= top + 1e-9 * abs(top)]
        values = ", ".join(f"{_structure(s)} {shown(key, s, fmt, scale)}" for s in vals)
        verb = "highest" if sign < 0 else "lowest"
        who = f"{best[0]} is {verb}" if len(best) == 1 else f"{' and '.join(best)} tie"
        lines.append(f"{what}: {who} ({values}{' ' + unit if unit else ''})")
    if spread:
        lines.append("Values are means over the seeds, ranges over the seeds in brackets.")
    failed = [_structure(s) for s, row in table.items() if not _finite(row, "itae")]
    if failed:
        lines.append(
            f"No tuning within the constraints and budget for {', '.join(failed)} "
            "(on some seed): its figures are its closest candidate's, and it takes "
            "no part in the objective's verdict."
        )
    for key, what, fmt in (
        ("itae", "on the objective", "{:.4g} counts·s²"),
        (
            "heldout_max_sync_counts",
            "on the held-out scenarios' worst max sync error",
            "{:.0f} counts",
        ),
    ):
        vals = {s: row[key] for s, row in table.items() if _finite(row, key)}
        if "composite" not in vals or len(vals) < 2:
            continue
        rival = min((s for s in vals if s != "composite"), key=lambda s: vals[s])
        c, r = vals["composite"], vals[rival]
        versus = f"{fmt.format(c)} against {_structure(rival)}'s {fmt.format(r)}"
        ranges = (
            (spread or {}).get("composite", {}).get(key),
            (spread or {}).get(rival, {}).get(key),
        )
        overlap = (
            None not in ranges and ranges[0][0] <= ranges[1][1] and ranges[1][0] <= ranges[0][1]
        )
        if c < r and not overlap:
            lines.append(f"The composite law wins {what}: {versus}, as the seed's Figure 4 claims.")
        elif c < r:
            lines.append(
                f"The composite law is ahead {what} on average ({versus}), but not "
                "clearly: the ranges over the seeds overlap."
            )
        else:
            lines.append(
                f"The composite law does not win {what}: {versus} (same optimiser, "
                "budget and margin limits), contrary to the seed's Figure 4."
            )
    return "\n".join(lines)


def format_gantry_tuning(tuning: GantryTuning) -> str:
    """What ``servotune tune GANTRY.toml`` prints: the gains, each loop's least margin over
    the plant set and each case's sync error on the nominal drives."""
    d = tuning.design
    g = d.get("gains", {})
    lines = [
        f"gantry {tuning.gantry_name}: {tuning.topology}, bus cycle "
        f"{tuning.cycle_s * 1e3:g} ms, latency {tuning.latency_cycles} cycle(s)"
    ]
    for name in ("master", "slave"):
        if name in g:
            lines.append(
                f"  {name} drive PI: Kp {show_number(g[name]['kp'])} codes/count, Ki "
                f"{show_number(g[name]['ki'])} codes/(count·s)"
            )
    if "sync" in g:
        s = g["sync"]
        lines.append(
            f"  sync compensator ({tuning.sync_law}): Kp {show_number(s['kp'])}, Ki "
            f"{show_number(s['ki'])} 1/s, Kd {show_number(s['kd'])} s; dead zone "
            f"{tuning.sync.dead_zone_counts}, limit {tuning.sync.limit_counts}, warn "
            f"{tuning.warn_counts}, trip {tuning.trip_counts} counts"
        )
    for loop, m in d.get("worst_margins", {}).items():
        lines.append(
            f"  least margin, {loop:<6} PM {show_number(m['phase_margin_deg'])}°, GM "
            f"{show_number(m['gain_margin_db'])} dB, Ms "
            f"{show_number(m['max_sensitivity'])} (plant {m['plant']})"
        )
    for case, c in d.get("cases", {}).items():
        trip = ", TRIPS" if c["tripped"] else ""
        lines.append(
            f"  {case} case: sync error max {c['max_sync_error_counts']:.0f}, RMS "
            f"{c['rms_sync_error_counts']:.1f} counts{trip}"
        )
    return "\n".join(lines)


def format_gantry_verification(v: GantryVerification) -> str:
    """What ``servotune verify GANTRY-TUNING`` prints: one row per check, then the verdict."""
    lines = [
        f"gantry {v.gantry}: verified at a bus latency of {v.latency_cycles} cycle(s)",
        f"{'check':<15}{'what':<42}{'value':>9}  {'limit':<10}{'unit':<8}result",
    ]
    for r in v.rows:
        value = show_number(r.value)
        limit = f"{r.kind} {show_number(r.limit)}"
        unit = r.unit if len(r.unit) <= 7 else ""
        note = "; ".join(x for x in (r.unit if not unit else "", r.detail) if x)
        lines.append(
            f"{r.check:<15}{r.subject:<42}{value:>9}  {limit:<10}{unit:<8}"
            f"{'ok' if r.passed else 'FAIL'}{'  ' + note if note else ''}"
        )
    lines.append("PASS" if v.passed else "FAIL: " + "; ".join(v.failures))
    return "\n".join(lines)


def format_linkage_plan(plan: LinkagePlan) -> str:
    """What ``servotune plan`` prints: the bus budget, the clock sync, each CPU's queue."""
    b = plan.bus
    lines = [
        f"linkage {plan.config_name}: {len(plan.axis_names)} axes on {len(plan.cpus)} slave "
        f"CPUs, tick {plan.period_s * 1e3:g} ms",
        f"  bus: {plan.frame_bytes}-byte frames ({b.block_size} setpoints per axis), "
        f"{plan.frame_s * 1e3:.2f} ms every {plan.broadcast_period_s * 1e3:g} ms: utilisation "
        f"{100 * plan.utilisation:.1f} %, {b.prefill_blocks} blocks prefilled",
        f"  clock sync every {plan.resync_ticks} ticks"
        if plan.resync_ticks
        else "  clock sync at motion start only",
    ]
    for c in plan.cpus:
        lines.append(
            f"  cpu {c.name} ({', '.join(c.axes)}, {c.clock_ppm:+g} ppm): queue "
            f"{c.queue_depth}, watermarks low {c.low_watermark} / high "
            f"{c.high_watermark} setpoints"
        )
    return "\n".join(lines)


def format_linkage_verification(v: LinkageVerification) -> str:
    """What ``servotune verify PLAN`` prints: one row per check, then the verdict."""
    head = f"{'check':<30}{'worst case':<18}{'value':>10}  {'limit':<12}{'unit':<12}result"
    lines = [
        f"linkage {v.config}: {len(v.cases)} clock case(s): "
        + ", ".join(label for label, _ in v.cases),
        head,
    ]
    for r in v.rows:
        limit = f"{r.bound} {show_number(float(r.limit))}"
        lines.append(
            f"{r.check:<30}{r.case:<18}{show_number(float(r.value)):>10}  {limit:<12}"
            f"{r.unit:<12}{'ok' if r.passed else 'FAIL'}"
        )
    lines.append("PASS" if v.passed else "FAIL: " + "; ".join(v.failures))
    return "\n".join(lines)
