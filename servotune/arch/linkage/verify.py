"""Verification of a linkage plan against a linkage spec, and its trust chain.

:func:`verify_plan_files` runs the simulation on exactly a plan's integers
(:func:`~servotune.arch.linkage.run_plan`) under a linkage spec's conditions
(:mod:`~servotune.arch.linkage.spec`) and judges it (:func:`verify_plan`); the record it
writes binds the verdict to the bytes of the plan, the config, the rig and the spec, and
:func:`load_plan_for_export` refuses a plan without a passing, matching record.

Clock cases: the nominal clocks (each CPU at its plan's ``clock_ppm``), and with a tolerance
``t``: every CPU at ``+t``, every CPU at ``−t``, and for each bit ``b`` of the CPU's index the
CPUs whose bit is set at ``+t``, the others at ``−t``, and the reverse (so every pair of CPUs
runs once apart both ways: the worst skew between any two; for two CPUs, the four corners).
Every limit is judged at its worst over the cases. Always checked besides the spec's limits:
the checks before motion (bus, prefill, queue, speed), no axis fault in any case, and, at the
nominal clocks, the plan's watermarks (the lowest level before a pop >= ``low_watermark``, the
highest after a block <= ``high_watermark``).

The record (``<plan>.verify.json``, ``"schema": "servotune.linkage-verify/1"``,
:func:`servotune.verify.record.trust_record`) holds the SHA-256 of the plan, config, rig and
spec as read (each read once, parsed from those bytes), the verdict and the rows.

Which config: the one given (``--config``), else the first found of its recorded path, the
same path relative to the plan's directory and, only if those are gone, its file name beside
the plan; it is used only if its SHA-256 is the plan's (:func:`servotune.verify.record.
matching_file`: a recorded config edited since is refused, not replaced by a copy elsewhere),
and its rig (the config's ``rig``) only if its SHA-256 is the one the plan holds. An export
checks the record against the plan (and the spec, if given) with
:func:`servotune.verify.record.check_record`, and the config the same way (when none is found
the plan's recorded hashes stand for it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from servotune.analysis.margins import (
    GRID_DECADES_BELOW,
    GRID_POINTS,
    GainSet,
    MarginLimits,
    loop_margins,
    loop_model,
)
from servotune.arch.linkage.bus import MAX_CLOCK_PPM
from servotune.arch.linkage.checks import Check, check_linkage
from servotune.arch.linkage.config import LinkageConfig
from servotune.arch.linkage.plan import (
    LinkagePlan,
    PlanCpu,
    plan_config,
    read_config,
    read_plan_bytes,
    run_plan,
)
from servotune.arch.linkage.result import CpuResult, LinkageResult
from servotune.arch.linkage.spec import LinkageSpec, linkage_spec_from_bytes
from servotune.errors import ConfigError, SpecError, TrustError, TuningError
from servotune.io.files import json_float
from servotune.kernels import warm_up
from servotune.laws.pi import PIConstants
from servotune.provenance import SourceFile
from servotune.verify.record import (
    RecordedVerification,
    check_record,
    fallback_notice,
    matching_file,
    read_record,
    recorded_paths,
    recorded_verification,
    trust_record,
)

__all__ = [
    "RECORD_SCHEMA",
    "LinkageRow",
    "LinkageVerification",
    "clock_cases",
    "load_plan_for_export",
    "verify_plan",
    "verify_plan_files",
]

RECORD_SCHEMA = "servotune.linkage-verify/1"
"""Version tag of a plan's verification record (``<plan>.verify.json``)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkageRow:
    """One judged figure of a verification.

    Attributes
    ----------
    check : str
        ``contour_error``, ``bus_utilisation``, ``phase_drift:<cpu>``, ``underruns:<cpu>``,
        ``overruns:<cpu>``, ``min_level:<cpu>``, ``skipped:<cpu>``, ``low_watermark:<cpu>``,
        ``high_watermark:<cpu>``, ``fault:<axis>``, ``phase_margin:<axis>``,
        ``gain_margin:<axis>``, ``sensitivity:<axis>``, ``stable:<axis>``, or
        ``before_motion:<check>`` (a check of :func:`~servotune.arch.linkage.check_linkage`).
    case : str
        The clock case giving the worst value (or ``"plan"``, ``"nominal plant"``).
    value, limit : float
        The worst value and the bound [unit].
    unit : str
    bound : str
        ``"<="`` (an upper bound), ``">="`` (a lower bound) or ``"<"``.
    passed : bool
    detail : str
        For a failure, the reason in one line.
    """

    check: str
    case: str
    value: float
    limit: float
    unit: str
    bound: str
    passed: bool
    detail: str = ""

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (integers stay integers, inf as null)."""
        d: dict[str, Any] = {
            k: getattr(self, k) for k in ("bound", "case", "check", "detail", "passed", "unit")
        }
        for k in ("value", "limit"):
            v = getattr(self, k)
            d[k] = v if isinstance(v, int) else json_float(float(v))
        return d


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkageVerification:
    """A plan judged against a spec (:func:`verify_plan`).

    Attributes
    ----------
    config : str
        The config's name.
    spec : LinkageSpec
    cases : tuple of (str, tuple of float)
        The clock cases run: label and ppm per CPU.
    rows : tuple of LinkageRow
    """

    config: str
    spec: LinkageSpec
    cases: tuple[tuple[str, tuple[float, ...]], ...]
    rows: tuple[LinkageRow, ...]

    @property
    def passed(self) -> bool:
        """True if every row passed."""
        return all(r.passed for r in self.rows)

    @property
    def failures(self) -> tuple[str, ...]:
        """One line per failed row: what, the value against its limit, the case."""
        return tuple(r.detail for r in self.rows if not r.passed)

    def row(self, check: str) -> LinkageRow:
        """The row called ``check``."""
        for r in self.rows:
            if r.check == check:
                return r
        raise KeyError(check)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {
            "cases": [{"clock_ppm": list(p), "label": label} for label, p in self.cases],
            "config": self.config,
            "failures": list(self.failures),
            "passed": self.passed,
            "rows": [r.to_dict() for r in self.rows],
            "spec": self.spec.to_dict(),
        }


def clock_cases(
    plan: LinkagePlan, tolerance_ppm: float
) -> tuple[tuple[str, tuple[float, ...]], ...]:
    """The clock cases a spec's tolerance asks for (module docstring): label, ppm per CPU.

    Raises
    ------
    SpecError
        A case takes a CPU beyond ±10,000 ppm.
    """
    base = tuple(c.clock_ppm for c in plan.cpus)
    names = [c.name for c in plan.cpus]
    out = [("nominal clocks", base)]
    if tolerance_ppm > 0:
        n = len(base)
        patterns = [(1,) * n, (-1,) * n]
        for b in range(max(1, (n - 1).bit_length())):
            p = tuple(1 if (i >> b) & 1 else -1 for i in range(n))
            patterns += [p, tuple(-x for x in p)]
        for p in dict.fromkeys(patterns):
            ppm = tuple(float(v + s * tolerance_ppm) for v, s in zip(base, p, strict=True))
            if max(abs(v) for v in ppm) > MAX_CLOCK_PPM:
                raise SpecError(
                    f"clock.tolerance_ppm {tolerance_ppm:g} takes a CPU to {ppm} ppm, beyond "
                    f"±{MAX_CLOCK_PPM:g} ppm"
                )
            out.append((", ".join(f"{c} {v:+g} ppm" for c, v in zip(names, ppm, strict=True)), ppm))
    return tuple(out)


def _row(
    check: str, case: str, value: float, limit: float, unit: str, bound: str, what: str
) -> LinkageRow:
    """A row judged by its bound; ``what`` says what the value is, for the failure line."""
    passed = {"<=": value <= limit, ">=": value >= limit, "<": value < limit}[bound]
    worse = {"<=": ">", ">=": "<", "<": ">="}[bound]
    u = "" if unit == "1" else f" {unit}"
    detail = (
        ""
        if passed
        else (f"{check}: {what} {_num(value)}{u} {worse} limit {_num(limit)}{u} ({case})")
    )
    return LinkageRow(
        check=check,
        case=case,
        value=value,
        limit=limit,
        unit=unit,
        bound=bound,
        passed=bool(passed),
        detail=detail,
    )


def _num(v: float) -> str:
    return str(v) if isinstance(v, int) else f"{v:.4g}"


def _worst(values: list[tuple[float, str]], high: bool) -> tuple[float, str]:
    """The worst (largest if ``high``) value and its case; the first case on a tie."""
    best = values[0]
    for v in values[1:]:
        if (v[0] > best[0]) if high else (v[0] < best[0]):
            best = v
    return best


def _margin_rows(
    plan: LinkagePlan, config: LinkageConfig, limits: MarginLimits
) -> list[LinkageRow]:
    rows = []
    rig = config.rig
    nyq = math.pi / plan.period_s
    for name, ctl in zip(plan.axis_names, plan.controllers, strict=True):
        plant = config.axis(name).plant
        task = ctl.task
        assert isinstance(task, PIConstants)  # LinkagePlan holds PI controllers only
        g = GainSet(kp=task.kp.value, ki_t=task.ki_t.value)
        lag = rig.timer.compute_s + plant.delay_s
        loop = loop_model(
            plant,
            g,
            period_s=plan.period_s,
            lag_s=lag,
            lsb_volts=rig.dac.lsb_v,
            filters=ctl.filters,
        )
        lo = min(1.0 / plant.tau_s, nyq) * 10.0**-GRID_DECADES_BELOW
        w = np.logspace(math.log10(lo), math.log10(nyq * (1.0 - 1e-9)), GRID_POINTS)
        m = loop_margins(loop, w)
        case = "nominal plant"
        rows.append(
            _row(
                f"stable:{name}",
                case,
                float(m.spectral_radius),
                1.0,
                "1",
                "<",
                "closed-loop pole radius",
            )
        )
        rows.append(
            _row(
                f"phase_margin:{name}",
                case,
                float(m.phase_margin_deg),
                limits.min_phase_margin_deg,
                "deg",
                ">=",
                "phase margin",
            )
        )
        rows.append(
            _row(
                f"gain_margin:{name}",
                case,
                float(m.gain_margin_db),
                limits.min_gain_margin_db,
                "dB",
                ">=",
                "gain margin",
            )
        )
        rows.append(
            _row(
                f"sensitivity:{name}",
                case,
                float(m.max_sensitivity),
                limits.max_sensitivity,
                "1",
                "<=",
                "peak sensitivity Ms",
            )
        )
    return rows


def verify_plan(plan: LinkagePlan, config: LinkageConfig, spec: LinkageSpec) -> LinkageVerification:
    """Run a plan under a spec's clock cases and judge every limit (module docstring).

    Parameters
    ----------
    plan : LinkagePlan
    config : LinkageConfig
        The config the plan was made from (its rig, plants and path).
    spec : LinkageSpec

    Returns
    -------
    LinkageVerification

    Raises
    ------
    ConfigError
        The plan restates a config field differently (it was edited).
    SpecError
        The spec is for another config, or its tolerance takes a clock out of range.
    """
    if spec.config is not None and spec.config != plan.config_name:
        raise SpecError(
            f"the spec is for config {spec.config!r}, the plan for {plan.config_name!r}"
        )
    cases = clock_cases(plan, spec.clock_tolerance_ppm)
    nominal = plan_config(plan, config)
    rows: list[LinkageRow] = []
    if spec.max_utilisation_pct is not None:
        rows.append(
            _row(
                "bus_utilisation",
                "plan",
                plan.utilisation * 100.0,
                spec.max_utilisation_pct,
                "%",
                "<=",
                "bus utilisation (frame time / broadcast period)",
            )
        )
    if spec.margins is not None:
        rows += _margin_rows(plan, config, spec.margins)
    before = [c for c in check_linkage(nominal) if not c.passed]
    if before:  # nothing to simulate: every case would be refused before motion
        rows += _before_motion_rows(before)
        return LinkageVerification(
            config=plan.config_name, spec=spec, cases=cases, rows=tuple(rows)
        )
    results = [
        (label, run_plan(plan, config, clock_ppm=ppm, seconds=spec.seconds, seed=spec.seed))
        for label, ppm in cases
    ]
    if spec.max_contour_error_counts is not None:
        v, case = _worst([(r.contour_max_counts, lb) for lb, r in results], high=True)
        rows.append(
            _row(
                "contour_error",
                case,
                v,
                spec.max_contour_error_counts,
                "counts",
                "<=",
                "largest distance from the programmed path",
            )
        )
    for s, c in enumerate(plan.cpus):
        rows += _queue_limit_rows(plan, spec, s, [(r.cpus[s], lb) for lb, r in results])
        rows += _watermark_rows(c, results[0][1].cpus[s], results[0][0])
    rows += _fault_rows(plan, results)
    return LinkageVerification(config=plan.config_name, spec=spec, cases=cases, rows=tuple(rows))


def _before_motion_rows(before: list[Check]) -> list[LinkageRow]:
    """One failed row per check before motion that fails (nothing is simulated then)."""
    return [
        LinkageRow(
            check=f"before_motion:{c.name}",
            case="plan",
            value=1,
            limit=0,
            unit="checks",
            bound="<=",
            passed=False,
            detail=f"before_motion:{c.name}: {c.detail}",
        )
        for c in before
    ]


def _queue_limit_rows(
    plan: LinkagePlan, spec: LinkageSpec, s: int, per: list[tuple[CpuResult, str]]
) -> list[LinkageRow]:
    """The spec's limits on CPU ``s``'s clock and queue, each at its worst over the cases
    (``per``: the CPU's result and label of each case); a limit the spec leaves out, no row."""
    t = plan.period_s
    c = plan.cpus[s]
    checks = (
        (
            "phase_drift",
            spec.max_phase_drift_ticks,
            "ticks",
            True,
            lambda x: (
                float(np.max(np.abs(x.tick_time_s - x.tick_index * t)) / t)
                if x.tick_index.size
                else 0.0
            ),
            "largest |tick time − index·T| of a tick",
        ),
        (
            "underruns",
            spec.max_underrun_ticks,
            "ticks",
            True,
            lambda x: x.underruns,
            "ticks that found no command",
        ),
        (
            "overruns",
            spec.max_overrun_blocks,
            "blocks",
            True,
            lambda x: x.overruns,
            "blocks that did not fit the queue",
        ),
        (
            "skipped",
            spec.max_skipped_setpoints,
            "setpoints",
            True,
            lambda x: x.skipped,
            "commands discarded at syncs",
        ),
        (
            "min_level",
            spec.min_level_setpoints,
            "setpoints",
            False,
            lambda x: x.min_level,
            "lowest queue level before a pop",
        ),
    )
    rows = []
    for name, limit, unit, high, get, what in checks:
        if limit is None:
            continue
        v, case = _worst([(get(x), lb) for x, lb in per], high=high)
        rows.append(_row(f"{name}:{c.name}", case, v, limit, unit, "<=" if high else ">=", what))
    return rows


def _watermark_rows(c: PlanCpu, nom: CpuResult, case: str) -> list[LinkageRow]:
    """CPU ``c``'s queue levels in the nominal case ``nom`` against the plan's watermarks."""
    return [
        _row(
            f"low_watermark:{c.name}",
            case,
            nom.min_level,
            c.low_watermark,
            "setpoints",
            ">=",
            "lowest queue level before a pop",
        ),
        _row(
            f"high_watermark:{c.name}",
            case,
            nom.max_level,
            c.high_watermark,
            "setpoints",
            "<=",
            "highest queue level after a block",
        ),
    ]


def _fault_rows(plan: LinkagePlan, results: list[tuple[str, LinkageResult]]) -> list[LinkageRow]:
    """Per axis: the clock cases with a fault latched (none allowed), the first one named."""
    rows = []
    for i, name in enumerate(plan.axis_names):
        faulted = [lb for lb, r in results if r.axes[i].fault is not None]
        case = faulted[0] if faulted else "every case"
        rows.append(
            _row(
                f"fault:{name}",
                case,
                len(faulted),
                0,
                "cases",
                "<=",
                "clock cases with a fault latched (following-error trip, counter fault):",
            )
        )
    return rows


def _config_file(plan: LinkagePlan, plan_path: str | Path, given: str | Path | None) -> SourceFile:
    """The plan's config file, read once; its SHA-256 must be the plan's (module docstring).

    Not :func:`~servotune.verify.record.candidate_paths`: its ``plants/<name>.toml`` would let
    a copy of the planned bytes elsewhere stand in for a config edited after planning, which
    is refused instead.
    """
    recorded = Path(plan.config_path)
    beside = Path(plan_path).parent
    at = recorded_paths(plan.config_path, plan_path)
    candidates = list(dict.fromkeys([*at, beside / recorded.name]))
    return matching_file(
        plan.config_sha256,
        given,
        candidates,
        kind="config",
        name=plan.config_name,
        recorded=plan.config_path,
        error=ConfigError,
        owner="plan",
        recorded_at=at,
    )


def verify_plan_files(
    plan_path: str | Path,
    spec_path: str | Path,
    *,
    write: bool = True,
    config_path: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
) -> RecordedVerification[LinkageVerification]:
    """What ``servotune verify PLAN --spec SPEC`` runs for a linkage plan.

    Reads the plan, its config (``config_path``, else as the module docstring says), the
    config's rig and the spec once each, parses and hashes those bytes, checks the config and
    rig are the ones the plan was made from, verifies (:func:`verify_plan`), builds the record
    and (``write``) writes it next to the plan (``<plan>.verify.json``). ``progress`` gets the
    lines of the linkage kernels' compiling, if the cache lacks them
    (:func:`servotune.kernels.warm_up`).

    Returns
    -------
    RecordedVerification
        The :class:`LinkageVerification`, its record and its path.

    Raises
    ------
    TrustError
        The config or its rig is not the one the plan was made from (names both hashes).
    ConfigError, SpecError
        A file is malformed or cannot be read, or the plan restates its config differently.
    TuningError
        No config file found where the plan says (give ``config_path``).
    """
    plan_file = SourceFile.read(plan_path, ConfigError, "linkage plan")
    plan = read_plan_bytes(plan_file.raw, plan_file.path)
    spec_file = SourceFile.read(spec_path, SpecError, "linkage spec")
    spec = linkage_spec_from_bytes(spec_file.raw, spec_file.path)
    config_file = _config_file(plan, plan_path, config_path)
    note = fallback_notice(config_file, "config", "plan")
    if note is not None and progress is not None:
        progress(note)
    config, rig_file, _ = read_config(config_file)
    if rig_file.sha256 != plan.rig_sha256:
        raise TrustError(
            f"rig file {rig_file.path} (sha256 {rig_file.sha256[:12]}…) is not the rig the "
            f"plan was made with ({plan.rig_name!r}, sha256 {plan.rig_sha256[:12]}…): plan "
            f"the config again"
        )
    warm_up(("linkage",), progress=progress)
    try:
        result = verify_plan(plan, config, spec)
    except ConfigError as exc:
        raise ConfigError(f"linkage plan {plan_file.path!r}: {exc}") from None
    except SpecError as exc:
        raise SpecError(f"linkage spec {spec_file.path!r}: {exc}") from None
    contour = [r.value for r in result.rows if r.check == "contour_error"]
    summary = {
        "cases": len(result.cases),
        "checks": len(result.rows),
        "checks_failed": sum(not r.passed for r in result.rows),
        "contour_max_counts": json_float(contour[0]) if contour else None,
        "failures": list(result.failures),
    }
    record = trust_record(
        RECORD_SCHEMA,
        passed=result.passed,
        seed=spec.seed,
        summary=summary,
        files={"config": config_file, "plan": plan_file, "rig": rig_file, "spec": spec_file},
        result={"verification": result.to_dict()},
    )
    return recorded_verification(result, record, plan_path, write=write)


def load_plan_for_export(
    plan_path: str | Path,
    spec_path: str | Path | None = None,
    *,
    unverified: bool = False,
    config_path: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[LinkagePlan, dict[str, Any] | None]:
    """What ``export-table`` exports for a linkage: the plan and its checked record.

    The plan is read once and parsed from the bytes whose hash is checked.

    Parameters
    ----------
    plan_path : str or Path
    spec_path : str or Path, optional
        If given, the record must hold this spec.
    unverified : bool
        Skip the record (the export is marked unverified); the record returned is None.
    config_path : str or Path, optional
        The plan's config (``--config``), else found as the module docstring says; it must be
        the verified one (none found: the plan's recorded hashes stand for it).
    progress : callable, optional
        Told which config file was used when it was found elsewhere than the plan records.

    Raises
    ------
    TrustError
        No record, an edited one (its digest), one of another tool version, a failed
        verification, a record of other plan or spec bytes (names which;
        :func:`~servotune.verify.record.check_record`), or a config that is not the plan's
        (the recorded one edited since, or the one given).
    ConfigError, SpecError
        A file is missing or malformed.
    """
    plan_file = SourceFile.read(plan_path, ConfigError, "linkage plan")
    plan = read_plan_bytes(plan_file.raw, plan_file.path)
    if unverified:
        return plan, None
    record = read_record(plan_path, schema=RECORD_SCHEMA)
    spec_file = None if spec_path is None else SourceFile.read(spec_path, SpecError, "linkage spec")
    # the plan and the spec bind the rest: the config and the rig are bound through the plan's
    # own recorded hashes (verify_plan_files checked both files against them), and the record's
    # hash of the plan file covers those hashes. A config found is still checked: one edited
    # since verification describes another machine than the one verified
    try:
        config_file = _config_file(plan, plan_path, config_path)
    except TuningError:  # no config anywhere: the plan's hashes stand for it
        config_file = None
    if config_file is not None:
        note = fallback_notice(config_file, "config", "plan")
        if note is not None and progress is not None:
            progress(note)
    check_record(record, plan=plan_file, spec=spec_file, config=config_file)
    return plan, record
