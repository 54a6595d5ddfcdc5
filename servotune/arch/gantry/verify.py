"""Verification of a gantry tuning against a gantry spec, and the trust chain to its export.

:func:`verify_gantry` runs the tuning's integers (:func:`~servotune.arch.gantry.tuning.
apply_tuning`) on the gantry under the spec's bus and checks, each as a row with its value,
limit and unit:

- **sync error** in each case (:data:`~servotune.arch.gantry.config.CASES`) of the deployed
  topology: largest and RMS |sync error| within the spec's limits, and no trip;
- **trip thresholds**: the monitor has a trip threshold, below the beam's skew limit; in the
  fault case (a load step of ``fault_volts`` on the slave's side at ``fault_time_s``) the
  monitor trips, both drives are latched at 0 V within the stop bound (latency + 1 cycles), and
  the true skew at that cycle is within the skew limit;
- **margins** of each loop (each drive's PI, the sync loop through the compensator with the
  bus latency) over the spec's plant set, each also ``extra_cycles`` late
  (:func:`~servotune.arch.gantry.margins.gantry_margins`): a failure names the loop, the plant
  case and the limit;
- **Monte Carlo**: no drawn plant pair trips in any case
  (:func:`~servotune.arch.gantry.run.gantry_montecarlo`), with the pass fraction's exact 95 %
  interval.

:func:`verify_gantry_files` is ``servotune verify GANTRY-TUNING --spec SPEC``: each file read
once, the gantry config found by the hash the tuning records (``--config``, else the recorded
path, else, only if that is gone, ``plants/<name>.toml``: a recorded config edited since is
refused, :func:`servotune.verify.record.matching_file`), the record
(``servotune.gantry-verify/1``) written next to the tuning. :func:`load_gantry_for_export` is
what ``export-table`` checks before exporting.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Unpack

import numpy as np

from servotune.analysis.margins import LoopMargins, MarginLimits
from servotune.arch.gantry.config import CASES, GantryConfig, GantryMargins
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.margins import LOOP_NAMES, gantry_margins, margin_failures
from servotune.arch.gantry.result import GantryMonteCarlo
from servotune.arch.gantry.run import (
    MC_CLUSTER_MIN_PAIRS,
    gantry_command,
    gantry_montecarlo,
    run_gantry,
    simulate_gantry,
)
from servotune.arch.gantry.tuning import (
    GantryTuning,
    apply_tuning,
    gantry_rig_path,
    read_gantry_tuning_bytes,
)
from servotune.errors import ConfigError, SpecError, TrustError, TuningError
from servotune.executor import Executor, open_executor
from servotune.io.files import json_float, parse_toml_as
from servotune.io.sections import build_section
from servotune.kernels import warm_up
from servotune.laws.axis import FLAG_SYNC_TRIP
from servotune.provenance import SourceFile
from servotune.validate import check_integer, check_keys, check_number, show_share
from servotune.verify import record as rec
from servotune.verify.record import RecordedVerification, VerifyRunOptions

__all__ = [
    "GANTRY_RECORD_SCHEMA",
    "GantryCheck",
    "GantrySpec",
    "GantryVerification",
    "GantryVerified",
    "gantry_spec_from_bytes",
    "load_gantry_for_export",
    "verify_gantry",
    "verify_gantry_files",
]

GANTRY_RECORD_SCHEMA = "servotune.gantry-verify/1"
_MAX_MC = 10_000


@dataclass(frozen=True, slots=True, kw_only=True)
class SpecBus:
    """The bus to verify on (``[bus]``); None: the gantry config's."""

    latency_cycles: int | None = None
    jitter_s: float | None = None

    def __post_init__(self) -> None:
        if self.latency_cycles is not None:
            check_integer("latency_cycles", self.latency_cycles, "cycles", hi=1000, error=SpecError)
        if self.jitter_s is not None:
            check_number("jitter_s", self.jitter_s, "s", hi=0.01, error=SpecError)


@dataclass(frozen=True, slots=True, kw_only=True)
class SyncLimits:
    """The sync error and trip limits (``[sync]``)."""

    max_sync_error_counts: float
    max_rms_sync_error_counts: float
    max_skew_counts: float
    fault_volts: float = -5.0
    fault_time_s: float = 0.8

    def __post_init__(self) -> None:
        for name in ("max_sync_error_counts", "max_rms_sync_error_counts", "max_skew_counts"):
            check_number(
                name, getattr(self, name), "counts", strict=True, hi=2**31, error=SpecError
            )
        check_number("fault_volts", self.fault_volts, "V", lo=-1000.0, hi=1000.0, error=SpecError)
        if self.fault_volts == 0:
            raise SpecError("fault_volts must not be 0 [V]: the fault case needs a load")
        check_number("fault_time_s", self.fault_time_s, "s", hi=3600.0, error=SpecError)


@dataclass(frozen=True, slots=True, kw_only=True)
class MonteCarloSpec:
    """Plant pairs drawn inside the spreads (``[montecarlo]``)."""

    count: int = 32
    seed: int = 0

    def __post_init__(self) -> None:
        check_integer("count", self.count, "plant pairs", hi=_MAX_MC, error=SpecError)
        check_integer("seed", self.seed, "-", hi=2**63 - 1, error=SpecError)


@dataclass(frozen=True, slots=True, kw_only=True)
class GantrySpec:
    """What a gantry tuning must do (a ``*.spec.toml`` with ``[sync]``, optional ``[bus]``,
    ``[margins]`` (the gantry config's keys) and ``[montecarlo]``)."""

    bus: SpecBus = field(default_factory=SpecBus)
    sync: SyncLimits
    margins: GantryMargins = field(default_factory=GantryMargins)
    montecarlo: MonteCarloSpec = field(default_factory=MonteCarloSpec)


def gantry_spec_from_bytes(raw: bytes, src: str | Path) -> GantrySpec:
    """Parse a gantry spec from its bytes.

    Raises
    ------
    SpecError
        Not TOML, an unknown or missing table or key, a value out of range (named).
    """
    return parse_toml_as(raw, str(src), SpecError, "gantry spec", _gantry_spec_from_dict)


def _gantry_spec_from_dict(data: Mapping[str, Any]) -> GantrySpec:
    check_keys(data, "", ("sync",), ("bus", "margins", "montecarlo"), error=SpecError, noun="table")
    parts = {}
    for key, cls in (
        ("bus", SpecBus),
        ("sync", SyncLimits),
        ("margins", GantryMargins),
        ("montecarlo", MonteCarloSpec),
    ):
        t = data.get(key, {})
        if not isinstance(t, dict):
            raise SpecError(f"[{key}] must be a table")
        parts[key] = build_section(cls, t, key, SpecError)
    return GantrySpec(**parts)


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryCheck:
    """One row of a gantry verification: ``value`` against ``limit`` (``kind`` ``"<="``,
    ``">="`` or ``"=="``), in ``unit``; ``subject`` names the case or loop."""

    check: str
    subject: str
    value: float
    limit: float
    unit: str
    kind: str = "<="
    detail: str = ""

    @property
    def passed(self) -> bool:
        """The value keeps its limit."""
        if not np.isfinite(self.value):
            return False
        if self.kind == "==":
            return self.value == self.limit
        return self.value <= self.limit if self.kind == "<=" else self.value >= self.limit

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {
            "check": self.check,
            "detail": self.detail,
            "kind": self.kind,
            "limit": json_float(self.limit),
            "passed": self.passed,
            "subject": self.subject,
            "unit": self.unit,
            "value": json_float(self.value),
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryVerification:
    """The result of :func:`verify_gantry`."""

    gantry: str
    latency_cycles: int
    seed: int
    rows: tuple[GantryCheck, ...]
    failures: tuple[str, ...]
    montecarlo: GantryMonteCarlo | None = None

    @property
    def passed(self) -> bool:
        """Every row keeps its limit."""
        return not self.failures

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (the record's ``verification``)."""
        return {
            "failures": list(self.failures),
            "gantry": self.gantry,
            "latency_cycles": self.latency_cycles,
            "montecarlo": None if self.montecarlo is None else self.montecarlo.to_dict(),
            "passed": self.passed,
            "rows": [r.to_dict() for r in self.rows],
            "seed": self.seed,
        }


def _spec_config(cfg: GantryConfig, spec: GantrySpec) -> GantryConfig:
    """``cfg`` under the spec's bus and plant set."""
    bus = cfg.bus
    if spec.bus.latency_cycles is not None:
        bus = replace(bus, latency_cycles=spec.bus.latency_cycles)
    if spec.bus.jitter_s is not None:
        bus = replace(bus, jitter_s=spec.bus.jitter_s)
    return replace(cfg, bus=bus, margins=spec.margins)


def _fault_rows(run: GantryConfig, spec: GantrySpec, seed: int) -> list[GantryCheck]:
    """The trip threshold rows and the fault case (see the module docstring)."""
    lim = spec.sync
    trip = run.sync.trip_counts
    rows = [
        GantryCheck(
            check="trip threshold",
            subject="set",
            value=float(trip),
            limit=1.0,
            unit="counts",
            kind=">=",
            detail="0 means the monitor never trips",
        ),
        GantryCheck(
            check="trip threshold",
            subject="below the skew limit",
            value=float(trip),
            limit=lim.max_skew_counts,
            unit="counts",
        ),
    ]
    n = run.n_cycles
    load = np.zeros((n, 2))
    load[min(n, round(lim.fault_time_s / run.bus.cycle_s)) :, 1] = lim.fault_volts
    tr = run_gantry(run, gantry_command(run, n), load, seed=seed, case="fault")
    k = tr.trip_cycle
    stop = k + run.stop_bound_cycles
    if k < 0 or stop >= n:
        rows.append(
            GantryCheck(
                check="fault case",
                subject="monitor trips",
                value=0.0,
                limit=1.0,
                unit="trips",
                kind=">=",
                detail=f"{lim.fault_volts:g} V on the slave's side at {lim.fault_time_s:g} s",
            )
        )
        return rows
    latched = np.flatnonzero(np.all(tr.flags[k:] & FLAG_SYNC_TRIP, axis=1))
    stopped = float(latched[0]) if latched.size else float("inf")
    skew = float(abs(tr.position[stop, 0] - tr.position[stop, 1]))
    rows += [
        GantryCheck(
            check="fault case",
            subject="both drives stopped",
            value=stopped,
            limit=float(run.stop_bound_cycles),
            unit="cycles after the trip",
            detail=f"tripped at {k * run.bus.cycle_s:.4f} s",
        ),
        GantryCheck(
            check="fault case",
            subject="skew when stopped",
            value=skew,
            limit=lim.max_skew_counts,
            unit="counts",
            detail="true position difference at the stop bound",
        ),
    ]
    return rows


def _latency_row(run: GantryConfig, tuning: GantryTuning) -> GantryCheck:
    """The bus's latency against the tuning's: the runtime aligns the master's feedback with
    its own position by a constant delay line (the tuning's latency), so a bus of another
    latency is another machine."""
    return GantryCheck(
        check="bus latency",
        subject="the bus's = the runtime's delay line",
        value=float(run.bus.latency_cycles),
        limit=float(tuning.latency_cycles),
        unit="cycles",
        kind="==",
        detail="tune the gantry for this bus"
        if run.bus.latency_cycles != tuning.latency_cycles
        else "",
    )


def _sync_rows(run: GantryConfig, spec: GantrySpec, seed: int) -> list[GantryCheck]:
    """Largest and RMS |sync error| and the trips in each case of the deployed topology."""
    lim = spec.sync
    rows: list[GantryCheck] = []
    for case in CASES:
        m = simulate_gantry(run, case=case, seed=seed).metrics()
        rows += [
            GantryCheck(
                check="sync error",
                subject=f"{case} case, largest",
                value=m.max_sync_error_counts,
                limit=lim.max_sync_error_counts,
                unit="counts",
            ),
            GantryCheck(
                check="sync error",
                subject=f"{case} case, RMS",
                value=m.rms_sync_error_counts,
                limit=lim.max_rms_sync_error_counts,
                unit="counts",
            ),
            GantryCheck(
                check="sync error",
                subject=f"{case} case, trips",
                value=float(m.tripped),
                limit=0.0,
                unit="trips",
                detail="" if not m.tripped else f"at {m.trip_time_s:.4f} s",
            ),
        ]
    return rows


def _failure(r: GantryCheck) -> str:
    """A failed row in words."""
    return (
        f"{r.check}: {r.subject} {r.value:g} {r.unit} (limit {r.kind} "
        f"{r.limit:g}){'; ' + r.detail if r.detail else ''}"
    )


def _margin_rows(margins: Sequence[LoopMargins], limits: MarginLimits) -> list[GantryCheck]:
    """Each loop's worst phase margin, gain margin and Ms over the plant set (an unstable
    case first)."""
    rows: list[GantryCheck] = []
    for loop, name in LOOP_NAMES.items():
        ms = [m for m in margins if m.axis == loop]
        if not ms:
            continue
        w = min(ms, key=lambda m: (m.stable, m.phase_margin_deg))
        g = min(ms, key=lambda m: (m.stable, m.gain_margin_db))
        s = max(ms, key=lambda m: (not m.stable, m.max_sensitivity))
        rows += [
            GantryCheck(
                check="margins",
                subject=f"{name}, phase margin",
                value=w.phase_margin_deg if w.stable else -np.inf,
                limit=limits.min_phase_margin_deg,
                unit="deg",
                kind=">=",
                detail=f"plant {w.plant}",
            ),
            GantryCheck(
                check="margins",
                subject=f"{name}, gain margin",
                value=g.gain_margin_db if g.stable else -np.inf,
                limit=limits.min_gain_margin_db,
                unit="dB",
                kind=">=",
                detail=f"plant {g.plant}",
            ),
            GantryCheck(
                check="margins",
                subject=f"{name}, Ms",
                value=s.max_sensitivity if s.stable else np.inf,
                limit=limits.max_sensitivity,
                unit="-",
                detail=f"plant {s.plant}",
            ),
        ]
    return rows


def _montecarlo_row(mc: GantryMonteCarlo) -> GantryCheck:
    """The plant pairs that trip, with the pass fraction's exact 95 % interval."""
    k, n, _, lo, hi = mc.pass_fraction
    return GantryCheck(
        check="Monte Carlo",
        subject="plant pairs that trip",
        value=float(n - k),
        limit=0.0,
        unit="pairs",
        detail=f"pass {k}/{n}, 95 % interval {show_share(lo)}–{show_share(hi)} %",
    )


def _montecarlo_failure(mc: GantryMonteCarlo) -> str:
    """A failed Monte Carlo in words, with the first tripping pair's draws."""
    k, n, *_ = mc.pass_fraction
    w = mc.worst
    drawn = ", ".join(f"{key.replace('_', ' ')} x{v:.3f}" for key, v in w.factors.items())
    return f"Monte Carlo: {n - k} of {n} plant pairs trip (first by size: {drawn})"


def verify_gantry(
    cfg: GantryConfig,
    tuning: GantryTuning,
    spec: GantrySpec,
    *,
    seed: int | None = None,
    progress: Callable[[str], None] | None = None,
    executor: Executor | None = None,
) -> GantryVerification:
    """Verify ``tuning``'s integers on the gantry ``cfg`` against ``spec`` (see the module
    docstring).

    Parameters
    ----------
    cfg : GantryConfig
        The gantry (its gains are replaced by the tuning's).
    tuning : GantryTuning
    spec : GantrySpec
    seed : int, optional
        Noise, jitter and Monte-Carlo seed (default: the spec's).
    progress : callable, optional
        Called with a line per stage.
    executor : Executor, optional
        Runs the Monte-Carlo plant pairs (default in-process); the result does not depend on
        it.
    """
    say = progress or (lambda _msg: None)
    seed = spec.montecarlo.seed if seed is None else seed
    run = _spec_config(apply_tuning(cfg, tuning), spec)
    rows: list[GantryCheck] = [_latency_row(run, tuning)]
    say("verify gantry: sync error in each case")
    warm_up(("gantry",), progress=progress)  # a cold cache compiles here, saying so (once)
    rows += _sync_rows(run, spec, seed)
    say("verify gantry: trip thresholds and the fault case")
    rows += _fault_rows(run, spec, seed)
    failures = [_failure(r) for r in rows if not r.passed]
    say("verify gantry: margins of every loop over the plant set")
    margins = gantry_margins(run)
    limits = run.margins.limits
    rows += _margin_rows(margins, limits)
    failures += margin_failures(margins, limits)
    mc = None
    if spec.montecarlo.count:
        say(f"verify gantry: Monte Carlo over {spec.montecarlo.count} plant pairs")
        mc = gantry_montecarlo(
            run, spec.montecarlo.count, seed=seed, progress=progress, executor=executor
        )
        rows.append(_montecarlo_row(mc))
        if not mc.passed:
            failures.append(_montecarlo_failure(mc))
    return GantryVerification(
        gantry=cfg.name,
        latency_cycles=run.bus.latency_cycles,
        seed=seed,
        rows=tuple(rows),
        failures=tuple(failures),
        montecarlo=mc,
    )


@dataclass(frozen=True, slots=True)
class GantryVerified:
    """A gantry tuning with its gantry config and its checked record (None: exported
    unverified)."""

    tuning: GantryTuning
    tuning_file: SourceFile
    config: GantryConfig
    gantry_file: SourceFile
    record: dict[str, Any] | None


def _tuning_and_gantry(
    tuning_path: str | Path, gantry_path: str | Path | None
) -> tuple[GantryTuning, SourceFile, GantryConfig, SourceFile, SourceFile]:
    """The tuning, the gantry config it was made for (found by its hash) and that config's
    rig, each parsed from the bytes read once; the config runs the tuning's integers."""
    tuning_file = SourceFile.read(tuning_path, TuningError, "tuning file")
    tuning = read_gantry_tuning_bytes(tuning_file.raw, tuning_file.path)
    candidates = rec.candidate_paths(tuning.gantry_path, tuning_path, tuning.gantry_name)
    gantry_file = rec.matching_file(
        tuning.gantry_sha256,
        gantry_path,
        candidates,
        kind="gantry",
        name=tuning.gantry_name,
        recorded=tuning.gantry_path,
        error=ConfigError,
        flag="--config",
        recorded_at=rec.recorded_paths(tuning.gantry_path, tuning_path),
    )
    # the config's gains are not designed again: the tuning holds every one
    cfg = load_gantry(gantry_file.path, raw=gantry_file.raw)
    rig_file = SourceFile.read(
        gantry_rig_path(gantry_file.raw, gantry_file.path), ConfigError, "rig file"
    )
    if rig_file.sha256 != tuning.rig_sha256:
        raise TrustError(
            f"the rig file {rig_file.path} (sha256 {rig_file.sha256[:12]}…) of gantry "
            f"{tuning.gantry_name!r} is not the one the tuning was made for (sha256 "
            f"{tuning.rig_sha256[:12]}…): tune the gantry again"
        )
    return tuning, tuning_file, apply_tuning(cfg, tuning), gantry_file, rig_file


def verify_gantry_files(
    tuning_path: str | Path,
    spec_path: str | Path,
    gantry_path: str | Path | None = None,
    **options: Unpack[VerifyRunOptions],
) -> RecordedVerification[GantryVerification]:
    """What ``servotune verify GANTRY-TUNING --spec SPEC [--config CONFIG]`` runs (see the
    module docstring); ``montecarlo`` overrides the spec's count. The plant pairs run on the
    executor :func:`servotune.executor.open_executor` chooses for their number (from
    :data:`~servotune.arch.gantry.run.MC_CLUSTER_MIN_PAIRS` an embedded ``LocalCluster``;
    ``scheduler``: a Dask scheduler's address; ``workers``: processes of an embedded cluster, 1
    for in-process); the result does not depend on it. Returns the
    :class:`GantryVerification`, its record and where that was written.

    Raises
    ------
    TrustError
        The gantry config is not the one the tuning was made for.
    TuningError, ConfigError, SpecError
        A file is missing or malformed.
    SchedulerError
        ``scheduler`` does not answer.
    """
    tuning, tuning_file, cfg, gantry_file, rig_file = _tuning_and_gantry(tuning_path, gantry_path)
    note = rec.fallback_notice(gantry_file, "gantry")
    if note is not None and options.get("progress") is not None:
        options["progress"](note)
    spec_file = SourceFile.read(spec_path, SpecError, "spec file")
    spec = gantry_spec_from_bytes(spec_file.raw, spec_path)
    if (count := options.get("montecarlo")) is not None:
        spec = replace(spec, montecarlo=replace(spec.montecarlo, count=count))
    where = {"scheduler": options.get("scheduler"), "workers": options.get("workers")}
    with open_executor(spec.montecarlo.count, min_items=MC_CLUSTER_MIN_PAIRS, **where) as ex:
        result = verify_gantry(
            cfg,
            tuning,
            spec,
            seed=options.get("seed"),
            progress=options.get("progress"),
            executor=ex,
        )
    summary = {
        "checks": len(result.rows),
        "checks_failed": sum(not r.passed for r in result.rows),
        "failures": list(result.failures),
    }
    record = rec.trust_record(
        GANTRY_RECORD_SCHEMA,
        passed=result.passed,
        seed=result.seed,
        summary=summary,
        result={"verification": result.to_dict()},
        files={"gantry": gantry_file, "rig": rig_file, "spec": spec_file, "tuning": tuning_file},
    )
    return rec.recorded_verification(
        result, record, tuning_path, tuning_file.sha256, write=options.get("write", True)
    )


def load_gantry_for_export(
    tuning_path: str | Path,
    gantry_path: str | Path | None = None,
    spec_path: str | Path | None = None,
    *,
    unverified: bool = False,
) -> GantryVerified:
    """What ``export-table`` exports for a gantry: the tuning, its gantry config and its checked
    record (passed, this version, exactly these tuning, gantry and spec bytes). Its
    ``gantry_file.instead_of`` says whether the config was found elsewhere than recorded
    (:func:`servotune.verify.record.fallback_notice` gives the line to tell the user).

    Raises
    ------
    TrustError
        No record, a failed, edited or stale one, or other files than the verified ones.
    """
    tuning, tuning_file, cfg, gantry_file, rig_file = _tuning_and_gantry(tuning_path, gantry_path)
    record = None
    if not unverified:
        spec = None if spec_path is None else SourceFile.read(spec_path, SpecError, "spec file")
        record = rec.read_record(tuning_path, schema=GANTRY_RECORD_SCHEMA)
        rec.check_record(record, tuning=tuning_file, rig=rig_file, spec=spec, gantry=gantry_file)
    elif spec_path is not None:
        raise TrustError("--spec checks a verification record; --unverified exports without one")
    return GantryVerified(
        tuning=tuning, tuning_file=tuning_file, config=cfg, gantry_file=gantry_file, record=record
    )
