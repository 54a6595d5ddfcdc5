"""The trust chain: what ``verify`` verified, and the check ``export-table`` makes against it.

``verify`` reads each input file's bytes **once**: the tuning, the rig and the spec are parsed
from those bytes and hashed from those same bytes, so a file replaced while verification runs
cannot be recorded as verified. The record (``<tuning>.verify.json``, ``servotune.verify/3``)
binds the SHA-256 of the three files and the tool version to the verdict, and carries its own
digest over its canonical JSON (:mod:`servotune.digest`), so an edited record is refused too.

Which rig: a tuning records its rig's name, path and SHA-256. ``verify`` and ``export-table``
use that rig: the given ``--rig`` file, else the recorded path, else ``plants/<rig name>.toml``
(in the working directory), else the example rig shipped in the package
(:data:`~servotune.rig.EXAMPLE_RIG_PATH`); a file is used only if its SHA-256 is the tuning's (a
moved copy is fine, another rig is refused). The other places are searched only when the
recorded file is gone: a recorded file that exists with other bytes (the rig edited since) is
refused, naming both hashes, even if a copy of the recorded bytes lies elsewhere. A file found
elsewhere says so (:attr:`SourceFile.instead_of`, :func:`fallback_notice`), for the command line
to tell the user.

``export-table`` (:func:`load_for_export`) refuses, with :class:`~servotune.errors.TrustError`
naming what differs, when there is no record, the record fails its own digest, did not pass,
was made by another servotune version, or holds another tuning, rig or spec than the ones given.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Generic, NamedTuple, TypedDict, TypeVar, Unpack

from servotune._version import __version__
from servotune.analysis.filter_effect import filter_effects
from servotune.analysis.frf import Frf
from servotune.analysis.frf_margins import frf_loops
from servotune.analysis.margins import DEFAULT_LIMITS, MarginLimits, Margins, tuning_margins
from servotune.digest import DIGEST_FIELD, document_sha256
from servotune.errors import RigError, SpecError, TrustError, TuningError
from servotune.executor import open_executor
from servotune.io.files import (
    atomic_write_text,
    json_float,
    json_text,
    parse_json,
    parse_toml,
    read_bytes,
)
from servotune.provenance import FileDigest, SourceFile
from servotune.rig import EXAMPLE_RIG_PATH, Rig, rig_from_dict
from servotune.tuning import Tuning, current_tuning_path, file_sha256, read_tuning_bytes
from servotune.verify.montecarlo import PlantDistribution
from servotune.verify.result import Verification
from servotune.verify.run import verify
from servotune.verify.spec import spec_from_bytes

__all__ = [
    "RECORD_SCHEMA",
    "RecordedVerification",
    "Verified",
    "VerifyRunOptions",
    "candidate_paths",
    "check_record",
    "default_rig_path",
    "fallback_notice",
    "load_for_export",
    "margins_files",
    "matching_file",
    "read_record",
    "record_path",
    "recorded_paths",
    "recorded_verification",
    "rig_for_tuning",
    "trust_record",
    "verification_record",
    "verify_files",
    "write_record",
]

RECORD_SCHEMA = "servotune.verify/3"
"""/3: the Monte-Carlo summary holds the worst plant sets and the sensitivity table, and a
run of more than ``LISTED_VARIANTS`` plant sets lists only the ones it names."""
_OLD_RECORD_SCHEMAS = ("servotune.verify/1", "servotune.verify/2")

_V = TypeVar("_V")


@dataclass(frozen=True, slots=True)
class Verified:
    """A tuning with the rig it is for and its verification record, checked against each other.

    ``record`` is None for an export the user asked to mark unverified.
    """

    tuning: Tuning
    tuning_file: SourceFile
    rig: Rig
    rig_file: SourceFile
    record: dict[str, Any] | None


class VerifyRunOptions(TypedDict, total=False):
    """How a verification of files runs (:func:`verify_files`,
    :func:`servotune.arch.gantry.verify_gantry_files`): ``seed`` (default: the spec's),
    ``montecarlo`` (overrides the spec's count), ``progress`` (one line per step), ``write``
    (the record next to the tuning; default True), ``scheduler`` and ``workers`` (the executor,
    :func:`servotune.executor.open_executor`)."""

    seed: int | None
    montecarlo: int | None
    progress: Callable[[str], None] | None
    write: bool
    scheduler: str | None
    workers: int | None


class RecordedVerification(NamedTuple, Generic[_V]):
    """What a ``verify`` run gives (:func:`verify_files`, and each architecture's): the
    verification, its record and where that was written; it unpacks as
    ``verification, record, path``.

    Attributes
    ----------
    verification
        The verdict (:class:`~servotune.verify.result.Verification`, or the architecture's).
    record : dict
        Its record (:func:`trust_record`).
    path : Path or None
        Where the record was written (None if ``write`` is false).
    """

    verification: _V
    record: dict[str, Any]
    path: Path | None


def record_path(tuning_path: str | Path) -> Path:
    """Where the verification record of a tuning file lives: ``<tuning name>.verify.json``."""
    p = Path(tuning_path)
    return p.with_name(p.name + ".verify.json")


def _rig_from(src: SourceFile) -> Rig:
    data = parse_toml(src.raw, src.path, RigError, "rig file")
    return rig_from_dict(data, default_name=Path(src.path).stem)


def _tuning_and_rig(
    tuning_path: str | Path, rig_path: str | Path | None
) -> tuple[Tuning, SourceFile, Rig, SourceFile]:
    """The tuning and its rig, each parsed from the bytes read once (see the module docstring)."""
    tuning_file = SourceFile.read(tuning_path, TuningError, "tuning file")
    tuning = read_tuning_bytes(tuning_file.raw, tuning_file.path)
    rig_file = rig_for_tuning(tuning, tuning_path, rig_path)
    return tuning, tuning_file, _rig_from(rig_file), rig_file


def _short(sha: str) -> str:
    return sha[:12] + "…"


def recorded_paths(recorded: str, tuning_path: str | Path) -> list[Path]:
    """Where a tuning's ``recorded`` file is: that path and, if relative, the same relative to
    the tuning's directory (none if nothing was recorded)."""
    if not recorded:
        return []
    p = Path(recorded)
    return [p] if p.is_absolute() else list(dict.fromkeys([p, Path(tuning_path).parent / p]))


def candidate_paths(
    recorded: str, tuning_path: str | Path, name: str, extra: Sequence[Path] = ()
) -> list[Path]:
    """Where a tuning's ``recorded`` file may be: that path, the same relative to the tuning's
    directory (:func:`recorded_paths`), ``plants/<name>.toml``, then ``extra`` (duplicates
    dropped)."""
    out: list[Path] = recorded_paths(recorded, tuning_path)
    out.append(Path("plants") / f"{name}.toml")
    out.extend(extra)
    seen: list[Path] = []
    for p in out:
        if p not in seen:
            seen.append(p)
    return seen


def _rig_candidates(tuning: Tuning, tuning_path: str | Path) -> list[Path]:
    example = [EXAMPLE_RIG_PATH] if EXAMPLE_RIG_PATH.stem == tuning.rig_name else []
    return candidate_paths(tuning.rig_path, tuning_path, tuning.rig_name, example)


def rig_for_tuning(
    tuning: Tuning, tuning_path: str | Path, rig_path: str | Path | None = None
) -> SourceFile:
    """The rig file a tuning is used with, read once; its SHA-256 must be the tuning's.

    Parameters
    ----------
    tuning : Tuning
    tuning_path : str or Path
        Where the tuning was read from (a relative recorded rig path is also tried there).
    rig_path : str or Path, optional
        The rig file the user gave (``--rig``): it may be a moved copy, not another rig.

    Raises
    ------
    TrustError
        The given rig, or every rig file found, differs from the tuning's (names both hashes).
    TuningError
        No rig file found (give ``--rig``).
    RigError
        The given rig file cannot be read.
    """
    return matching_file(
        tuning.rig_sha256,
        rig_path,
        _rig_candidates(tuning, tuning_path),
        kind="rig",
        name=tuning.rig_name,
        recorded=tuning.rig_path,
        error=RigError,
        recorded_at=recorded_paths(tuning.rig_path, tuning_path),
    )


def matching_file(
    want: str,
    given: str | Path | None,
    candidates: Sequence[Path],
    *,
    kind: str,
    name: str,
    recorded: str,
    error: type[Exception],
    owner: str = "tuning",
    flag: str = "",
    recorded_at: Sequence[Path] = (),
) -> SourceFile:
    """The ``kind`` file (``rig``, ``gantry`` …) a tuning (or another ``owner``: a plan) is
    used with, read once: the given one (``--<kind>``), else the recorded file (``recorded_at``:
    the recorded path, as read from each place it may mean), else, only if none of those
    exists, the first of the other ``candidates`` that exists; its SHA-256 must be ``want`` (a
    moved copy is fine, another file is refused, and so is a recorded file that changed, even
    if a copy of the recorded bytes lies elsewhere). A file found elsewhere than recorded has
    :attr:`SourceFile.instead_of` set (:func:`fallback_notice`). ``flag``: the option that gives
    the file (default ``--<kind>``).

    Raises
    ------
    TrustError
        The given file, the recorded file, or every candidate found, differs (names both
        hashes).
    TuningError
        No candidate exists (give ``--<kind>``).
    error
        The given file cannot be read.
    """
    flag = flag or f"--{kind}"
    if given is not None:
        src = SourceFile.read(given, error, f"{kind} file")
        if src.sha256 != want:
            raise TrustError(
                f"{kind} file {str(given)!r} (sha256 {_short(src.sha256)}) is not the {kind} the "
                f"{owner} was made for ({name!r}, sha256 {_short(want)}"
                + (f", {recorded}" if recorded else "")
                + f"): make the {owner} again for this {kind}, or give that {kind} file"
            )
        return src
    at = [SourceFile.read(p, error, f"{kind} file") for p in recorded_at if p.is_file()]
    for src in at:
        if src.sha256 == want:
            return src
    if at:  # the recorded file is there with other bytes: changed since, not to be replaced
        src = at[0]
        raise TrustError(
            f"{kind} file {src.path} changed since the {owner} recorded it: sha256 "
            f"{_short(src.sha256)} found, sha256 {_short(want)} recorded ({kind} {name!r}); if the "
            f"change is meant, make the {owner} for it and verify again, or give the verified "
            f"file with {flag}"
        )
    found = []
    for p in candidates:
        if p in recorded_at:
            continue
        if p.is_file():
            src = SourceFile.read(p, error, f"{kind} file")
            if src.sha256 == want:
                return replace(src, instead_of=recorded)
            found.append(f"{p} (sha256 {_short(src.sha256)})")
    if found:
        raise TrustError(
            f"no {kind} file matches the {owner}'s {kind} {name!r} (sha256 {_short(want)}): "
            f"found {', '.join(found)}; give the {kind} file the {owner} was made for ({flag})"
        )
    where = recorded or f"plants/{name}.toml"
    raise TuningError(
        f"no {kind} file {where} for the {owner}'s {kind} {name!r}; give the {kind} file ({flag})"
    )


def fallback_notice(src: SourceFile, kind: str = "rig", owner: str = "tuning") -> str | None:
    """The line telling the user which ``kind`` file was used when it was found elsewhere than
    the ``owner`` recorded (:attr:`SourceFile.instead_of`); None for the recorded or given
    file."""
    if src.instead_of is None:
        return None
    why = (
        f"the recorded {src.instead_of} is gone"
        if src.instead_of
        else f"the {owner} records no path"
    )
    return f"using {kind} file {src.path} ({why}; it has the recorded sha256 {_short(src.sha256)})"


def default_rig_path(tuning: Tuning, tuning_path: str | Path = ".") -> Path:
    """The path of the rig file :func:`rig_for_tuning` picks when none is given."""
    return Path(rig_for_tuning(tuning, tuning_path).path)


def verification_record(
    verification: Verification,
    *,
    tuning: SourceFile,
    rig: SourceFile,
    spec: SourceFile,
    sources: Sequence[tuple[str, str, str]] = (),
) -> dict[str, Any]:
    """The record of a verification: which exact bytes were verified, and the verdict.

    ``sources``: further files the verification read, as ``(kind, name, sha256)`` (the
    Monte-Carlo distribution's :attr:`~servotune.verify.montecarlo.PlantDistribution.source_files`,
    e.g. the fleet table of ``--plants-from``).

    Returns
    -------
    dict
        ``schema``, ``passed``, ``tool``/``tool_version``, ``files`` (name and SHA-256 of the
        tuning, rig and spec as read, and of each of ``sources``), ``seed``, ``summary``
        (counts, failures, the smallest relative margin), the full ``verification``, and
        ``sha256``: the record's own digest (:func:`servotune.digest.document_sha256`). No
        timestamps: the same inputs give the same bytes.
    """
    v = verification
    rels = [(r.relative_margin, r) for r in v.rows if r.relative_margin is not None]
    tight = min(rels, key=lambda x: x[0]) if rels else None
    summary = {
        "checks": len(v.checks),
        "checks_failed": sum(not c.passed for c in v.checks),
        "failures": v.failures,
        "limits": len(v.rows),
        "limits_failed": sum(not r.passed for r in v.rows),
        "plant_sets": v.plant_sets,
        "tightest": None
        if tight is None
        else {
            "axis": tight[1].axis,
            "quantity": tight[1].quantity,
            "relative_margin": json_float(tight[0]),
            "scenario": tight[1].scenario,
        },
    }
    files: dict[str, SourceFile | FileDigest] = {"rig": rig, "spec": spec, "tuning": tuning}
    for kind, name, sha in sources:
        if kind in files:
            raise ValueError(f"a distribution's source file kind {kind!r} is taken")
        files[kind] = FileDigest(name, sha)
    return trust_record(
        RECORD_SCHEMA,
        passed=v.passed,
        seed=v.seed,
        summary=summary,
        files=files,
        result={"verification": v.to_dict()},
    )


def trust_record(
    schema: str,
    *,
    passed: bool,
    files: Mapping[str, SourceFile | FileDigest],
    seed: int | None,
    summary: Mapping[str, Any],
    result: Mapping[str, Any],
) -> dict[str, Any]:
    """A verification record of any architecture: the schema, the verdict, which exact bytes
    were verified (``files``: name and SHA-256 per kind), the seed, a summary, the full result
    (``result``'s keys), the tool and its version, and the record's own digest
    (:func:`servotune.digest.document_sha256`). No timestamps."""
    record: dict[str, Any] = {
        "files": {kind: src.entry() for kind, src in files.items()},
        "passed": bool(passed),
        "schema": schema,
        "seed": seed,
        "summary": dict(summary),
        "tool": "servotune",
        "tool_version": __version__,
        **result,
    }
    record[DIGEST_FIELD] = document_sha256(record)
    return record


def _record_text(record: Mapping[str, Any]) -> str:
    return json_text(record)


def write_record(
    record: Mapping[str, Any], tuning_path: str | Path, tuning_sha256: str | None = None
) -> Path:
    """Write a record next to its tuning as ``<tuning name>.verify.json`` (atomically).

    With ``tuning_sha256`` (the bytes verified), the record is also written next to the
    workbench's current tuning (:func:`servotune.tuning.current_tuning_path`) when that file
    holds the same bytes: ``tune -o tuning.json`` records a copy there, and ``export-table``
    without a file exports that copy, which is then the verified tuning too.

    Returns
    -------
    Path
        The record's path (next to ``tuning_path``).
    """
    path = record_path(tuning_path)
    text = _record_text(record)
    atomic_write_text(path, text)
    current = current_tuning_path()
    if (
        tuning_sha256 is not None
        and current.is_file()
        and current.resolve() != Path(tuning_path).resolve()
        and file_sha256(current) == tuning_sha256
    ):
        atomic_write_text(record_path(current), text)
    return path


def recorded_verification(
    verification: _V,
    record: dict[str, Any],
    path: str | Path,
    sha256: str | None = None,
    *,
    write: bool = True,
) -> RecordedVerification[_V]:
    """``verification`` with its ``record``, which (``write``) is written next to the verified
    file ``path`` (:func:`write_record`; ``sha256``: that file's, as verified)."""
    written = write_record(record, path, sha256) if write else None
    return RecordedVerification(verification, record, written)


def verify_files(
    tuning_path: str | Path,
    spec_path: str | Path,
    rig_path: str | Path | None = None,
    *,
    distribution: Callable[[Rig], PlantDistribution] | None = None,
    **options: Unpack[VerifyRunOptions],
) -> RecordedVerification[Verification]:
    """What ``servotune verify TUNING --spec SPEC [--rig RIG]`` runs.

    Reads each file's bytes once, parses and hashes those bytes, verifies, builds the record
    and (``write``) writes it next to the tuning. ``montecarlo`` overrides the spec's variant
    count (the record then holds the spec as run). The plant sets run on the executor
    :func:`servotune.executor.open_executor` chooses for their number (``scheduler``: a Dask
    scheduler's address; ``workers``: processes of an embedded cluster, 1 for in-process); the
    result does not depend on it. ``distribution``, given the tuning's rig, gives the Monte-Carlo
    plant distribution (default: the spec's spread; e.g. ``--plants-from``'s
    :func:`servotune.fleet.fleet_spread`); the record's ``montecarlo.distribution`` names it.

    Returns
    -------
    RecordedVerification
        The :class:`~servotune.verify.result.Verification`, its record and its path.

    Raises
    ------
    TrustError
        The rig is not the one the tuning was made for (:func:`rig_for_tuning`).
    TuningError, RigError, SpecError
        A file is missing or malformed.
    SchedulerError
        ``scheduler`` does not answer.
    """
    tuning, tuning_file, rig, rig_file = _tuning_and_rig(tuning_path, rig_path)
    if (note := fallback_notice(rig_file)) is not None and options.get("progress") is not None:
        options["progress"](note)
    spec_file = SourceFile.read(spec_path, SpecError, "spec file")
    spec = spec_from_bytes(spec_file.raw, spec_path)
    if (count := options.get("montecarlo")) is not None:  # validated as the spec's count is
        spec = replace(spec, montecarlo=replace(spec.montecarlo, count=count))
    dist = None if distribution is None else distribution(rig)  # a bad one fails before a run
    with open_executor(
        spec.montecarlo.count + 1,
        scheduler=options.get("scheduler"),
        workers=options.get("workers"),
    ) as ex:
        result = verify(
            tuning,
            rig,
            spec,
            seed=options.get("seed"),
            executor=ex,
            progress=options.get("progress"),
            distribution=dist,
        )
    record = verification_record(
        result,
        tuning=tuning_file,
        rig=rig_file,
        spec=spec_file,
        sources=() if dist is None else dist.source_files,
    )
    return recorded_verification(
        result, record, tuning_path, tuning_file.sha256, write=options.get("write", True)
    )


def margins_files(
    tuning_path: str | Path,
    rig_path: str | Path | None = None,
    *,
    limits: MarginLimits | None = None,
    frf: Mapping[str, Frf] | None = None,
    extra_ticks: int = 1,
) -> Margins:
    """What ``servotune margins TUNING [--rig RIG] [--frf AXIS=FILE]`` computes: the margins of
    every loop of the tuning on the nominal plants of the rig it was made for
    (:func:`rig_for_tuning`); for an axis with output filters, what they do and the loops
    without them (:func:`~servotune.analysis.filter_effect.filter_effects`); for an axis with a
    measured response, every loop on it with its filters and without, with 0 and
    ``extra_ticks`` more ticks (:func:`~servotune.analysis.frf_margins.frf_loops`).

    Raises
    ------
    TrustError
        The rig is not the one the tuning was made for.
    TuningError, RigError
        A file is missing or malformed.
    """
    tuning, _, rig, _ = _tuning_and_rig(tuning_path, rig_path)
    m = tuning_margins(tuning, rig, limits=DEFAULT_LIMITS if limits is None else limits)
    measured = []
    for name, response in (frf or {}).items():
        ctl = tuning.controllers[rig.axis_names.index(rig.axis(name).name)]
        for with_filters in (True, False) if ctl.filters else (True,):
            measured += frf_loops(
                response,
                ctl,
                lsb_v=rig.dac.lsb_v,
                axis=name,
                extra_ticks=extra_ticks,
                filters=with_filters,
            )
    return replace(m, filters=filter_effects(tuning, rig), measured=tuple(measured))


def read_record(tuning_path: str | Path, schema: str = RECORD_SCHEMA) -> dict[str, Any]:
    """The verification record of a tuning file (of ``schema``), checked against its own
    digest.

    Raises
    ------
    TrustError
        No record, an unreadable one, one of an older schema, or one whose digest does not
        match its content (it was edited).
    """
    path = record_path(tuning_path)
    if not path.is_file():
        raise TrustError(
            f"{tuning_path} has no verification record ({path.name}): run `servotune verify` "
            "on it first, or export it marked --unverified"
        )
    raw = read_bytes(path, TrustError, "verification record")
    try:
        record = parse_json(raw.decode("utf-8"), str(path), TrustError)
    except UnicodeDecodeError:
        raise TrustError(f"{path}: not UTF-8 text; run `servotune verify` again") from None
    if not isinstance(record, dict):
        raise TrustError(f"{path}: not a verification record; run `servotune verify` again")
    got = record.get("schema")
    if got in _OLD_RECORD_SCHEMAS:
        raise TrustError(f"{path}: written by an older servotune ({got}); verify again")
    if got != schema:
        raise TrustError(f"{path}: schema must be {schema!r}; run `servotune verify` again")
    try:
        digest_ok = record.get(DIGEST_FIELD) == document_sha256(record)
    except (TypeError, ValueError):
        digest_ok = False
    if not digest_ok:
        raise TrustError(f"{path}: the record's digest does not match its content (it was edited)")
    return record


def check_record(
    record: Mapping[str, Any],
    *,
    tuning: SourceFile | None = None,
    rig: SourceFile | None = None,
    spec: SourceFile | None = None,
    **others: SourceFile | None,
) -> None:
    """Raise :class:`TrustError` unless ``record`` passed, was made by this servotune version,
    and holds exactly these files' hashes (each kind only when given; ``others``: the kinds of
    another architecture's record, e.g. ``gantry``, ``plan``); the message names what differs.
    The first file given (the tuning, else the first of ``others``) is the one the messages
    name as verified."""
    given = {"tuning": tuning, "rig": rig, "spec": spec, **others}
    order = (("tuning", tuning), *others.items(), ("rig", rig), ("spec", spec))
    kind, subject = next((k, src) for k, src in order if src is not None)
    if record.get("passed") is not True:
        summary = record.get("summary")
        why = summary.get("failures") if isinstance(summary, dict) else None
        first = f" ({why[0]})" if isinstance(why, list) and why and isinstance(why[0], str) else ""
        raise TrustError(
            f"{subject.path} failed its verification{first}: fix the {kind} and verify again"
        )
    if record.get("tool_version") != __version__:
        raise TrustError(
            f"{subject.path} was verified by servotune {record.get('tool_version')}, this is "
            f"{__version__}: verify it again with this version"
        )
    files = record.get("files")
    for kind, src in given.items():
        if src is None:
            continue
        entry = files.get(kind) if isinstance(files, dict) else None
        recorded = entry.get("sha256") if isinstance(entry, dict) else None
        if recorded != src.sha256:
            name = entry.get("name") if isinstance(entry, dict) else "?"
            raise TrustError(
                f"the {kind} differs from the verified one: {src.path} has sha256 "
                f"{_short(src.sha256)}, the record holds {name} with sha256 "
                f"{_short(str(recorded))}; verify again"
            )


def load_for_export(
    tuning_path: str | Path,
    rig_path: str | Path | None = None,
    spec_path: str | Path | None = None,
    *,
    unverified: bool = False,
) -> Verified:
    """What ``export-table`` exports: the tuning, its rig and its checked record.

    Each file is read once; the tuning and rig are parsed from the bytes that are checked.

    Parameters
    ----------
    tuning_path : str or Path
    rig_path : str or Path, optional
        The rig (``--rig``): must be the tuning's (:func:`rig_for_tuning`).
    spec_path : str or Path, optional
        If given (``--spec``), the record must hold this spec.
    unverified : bool
        Skip the record (the export is marked ``"verified": false``).

    Returns
    -------
    Verified
        Its ``rig_file.instead_of`` says whether the rig was found elsewhere than recorded
        (:func:`fallback_notice` gives the line to tell the user).

    Raises
    ------
    TrustError
        Anything of :func:`rig_for_tuning`, :func:`read_record` or :func:`check_record`.
    TuningError, RigError, SpecError
        A file is missing or malformed.
    SchedulerError
        ``scheduler`` does not answer.
    """
    tuning, tuning_file, rig, rig_file = _tuning_and_rig(tuning_path, rig_path)
    record = None
    if not unverified:
        spec = None if spec_path is None else SourceFile.read(spec_path, SpecError, "spec file")
        record = read_record(tuning_path)
        check_record(record, tuning=tuning_file, rig=rig_file, spec=spec)
    return Verified(
        tuning=tuning, tuning_file=tuning_file, rig=rig, rig_file=rig_file, record=record
    )
