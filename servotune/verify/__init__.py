"""Verification: a tuning against a spec on the bit-true closed loop (:mod:`.run`; the spec file
:mod:`.spec`, its plant variants :mod:`.variants`, the checks :mod:`.checks`, the result and its
table :mod:`.result`, the Monte-Carlo distribution and summary :mod:`.montecarlo`), and the
trust chain from the verified bytes to the export (:mod:`.record`). The pass/fail table for the
terminal is :func:`servotune.report.text.format_table`."""

from servotune.analysis.margins import (
    DEFAULT_LIMITS,
    GainSet,
    LoopMargins,
    MarginLimits,
    Margins,
    tuning_margins,
)
from servotune.provenance import SourceFile
from servotune.verify.checks import check_overflow, check_speed, check_timer, max_safe_gain_q
from servotune.verify.montecarlo import PlantDistribution, SpecSpread
from servotune.verify.record import (
    RECORD_SCHEMA,
    Verified,
    check_record,
    default_rig_path,
    fallback_notice,
    load_for_export,
    margins_files,
    read_record,
    record_path,
    rig_for_tuning,
    verification_record,
    verify_files,
    write_record,
)
from servotune.verify.result import (
    Check,
    MonteCarloSummary,
    Row,
    Sensitivity,
    Verification,
    WorstVariant,
)
from servotune.verify.run import verify
from servotune.verify.spec import (
    KINDS,
    LIMITS,
    MonteCarlo,
    ScenarioSpec,
    Spec,
    load_spec,
    spec_from_bytes,
    spec_from_dict,
)
from servotune.verify.variants import Variant, plant_variants

__all__ = [
    "DEFAULT_LIMITS",
    "KINDS",
    "LIMITS",
    "RECORD_SCHEMA",
    "Check",
    "GainSet",
    "LoopMargins",
    "MarginLimits",
    "Margins",
    "MonteCarlo",
    "MonteCarloSummary",
    "PlantDistribution",
    "Row",
    "ScenarioSpec",
    "Sensitivity",
    "SourceFile",
    "Spec",
    "SpecSpread",
    "Variant",
    "Verification",
    "Verified",
    "WorstVariant",
    "check_overflow",
    "check_record",
    "check_speed",
    "check_timer",
    "default_rig_path",
    "fallback_notice",
    "load_for_export",
    "load_spec",
    "margins_files",
    "max_safe_gain_q",
    "plant_variants",
    "read_record",
    "record_path",
    "rig_for_tuning",
    "spec_from_bytes",
    "spec_from_dict",
    "tuning_margins",
    "verification_record",
    "verify",
    "verify_files",
    "write_record",
]
