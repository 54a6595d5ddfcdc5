"""The verbs on the deliverable: ``export-table`` (any format of the registry
:data:`servotune.export.formats.FORMATS`: JSON, C, LinuxCNC HAL or component) and
``check-table`` (every CRC and digest of any of those exports but the C files: the tables,
gantry and linkage JSON by their loaders, the HAL file and component by their digest line)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from servotune.cli.output import EXIT_OK, check_dirs, check_outputs, deliver_product, progress_line
from servotune.errors import ServotuneError
from servotune.export.formats import FORMATS, KINDS, formats_for

# The library is imported inside each handler, not here, so that ``servotune --help`` (and any
# verb) pays only for what it uses: numba, scipy, matplotlib and python-control stay unloaded
# until a handler needs them (tests/cli/test_help_imports.py); the export formats' registry is
# the exception, as it imports a format's module only when that format renders. That is the
# only reason for an import inside a function in this module; none of them works around an
# import cycle.


def _rig_export(args: argparse.Namespace, path: Path) -> tuple[Any, dict[str, Any]]:
    """A rig's tuning to export (checked against its verification record, unless
    ``--unverified``) and the keywords every format takes for it."""
    from servotune.verify import fallback_notice, load_for_export

    if args.config is not None:
        raise ServotuneError(f"--config is for a gantry tuning; {path} is a rig's tuning")
    v = load_for_export(path, args.rig, args.spec, unverified=args.unverified)
    if (note := fallback_notice(v.rig_file)) is not None:
        progress_line(note)
    return v.tuning, {"rig": v.rig, "verification": v.record, "unverified": v.record is None}


def _gantry_export(args: argparse.Namespace, path: Path) -> tuple[Any, dict[str, Any]]:
    """A gantry tuning to export, as :func:`_rig_export`."""
    from servotune.arch.gantry.verify import load_gantry_for_export
    from servotune.verify.record import fallback_notice

    if args.rig is not None:
        raise ServotuneError(
            f"--rig is for a single rig's tuning; {path} is a gantry tuning "
            "(give its gantry config with --config)"
        )
    v = load_gantry_for_export(path, args.config, args.spec, unverified=args.unverified)
    if (note := fallback_notice(v.gantry_file, "gantry")) is not None:
        progress_line(note)
    return v.tuning, {"rig": v.config.rig, "verification": v.record, "unverified": args.unverified}


def _linkage_export(args: argparse.Namespace, path: Path) -> tuple[Any, dict[str, Any]]:
    """A linkage plan to export, as :func:`_rig_export`."""
    from servotune.arch.linkage import load_plan_for_export

    if args.rig is not None:
        raise ServotuneError(
            f"--rig does not apply to a linkage plan ({path}): the plan binds "
            "its config and rig by their hashes (a moved config: "
            "--config)"
        )
    plan, record = load_plan_for_export(
        path, args.spec, unverified=args.unverified, config_path=args.config, progress=progress_line
    )
    return plan, {"verification": record, "unverified": args.unverified}


_LOADERS: dict[str, Callable[[argparse.Namespace, Path], tuple[Any, dict[str, Any]]]] = {
    "rig": _rig_export,
    "gantry": _gantry_export,
    "linkage": _linkage_export,
}
"""What ``export-table`` loads for each document kind (servotune.export.formats.KINDS)."""


def cmd_export_table(args: argparse.Namespace) -> int:
    """``export-table``: the format is the registry's (servotune.export.formats.FORMATS), the
    document's kind read from its schema; the format's ``to_file`` writes ``-o``, else its
    ``to_string`` goes to stdout."""
    from servotune.arch.kind import document_kind
    from servotune.tuning import current_tuning_path

    fmt = FORMATS[args.format]
    path = Path(args.tuning) if args.tuning else current_tuning_path()
    kind = document_kind(path)
    if fmt.directory and not args.output:
        what = fmt.kinds.get(kind, "the files")
        raise ServotuneError(
            f"--format {fmt.name} needs -o DIR (the directory to write {what} into)"
        )
    check_outputs(None if fmt.directory else args.output, inputs=(path, args.rig, args.spec))
    check_dirs(args.output if fmt.directory else None)
    if kind not in fmt.kinds:
        raise ServotuneError(
            f"--format {fmt.name} exports {' or '.join(KINDS[k] for k in fmt.kinds)}; {path} is "
            f"{KINDS[kind]}: export it with --format {' or '.join(formats_for(kind))}"
        )
    obj, kw = _LOADERS[kind](args, path)
    kw.update({option: getattr(args, option) for option in fmt.options})
    if fmt.directory:
        written = fmt.to_file(obj, args.output, **kw)
        print(f"wrote {', '.join(p.name for p in written)} to {args.output}", file=sys.stderr)
    else:
        deliver_product(
            args.output,
            lambda p: fmt.to_file(obj, p, **kw),
            lambda: fmt.to_string(obj, **kw),
            fmt.kinds[kind],
        )
    return EXIT_OK


def _check_gantry_table(args: argparse.Namespace) -> int:
    from servotune.errors import ExportError
    from servotune.export.gantry import check_gantry_tables
    from servotune.io.files import read_bytes

    raw = read_bytes(args.file, ExportError, "gantry tables export")
    doc = check_gantry_tables(raw.decode("utf-8", errors="replace"), args.file)
    data = doc["data"]
    if args.json:
        print(
            json.dumps(
                {
                    "c_layout_sha256": data["c_layout_sha256"],
                    "file": args.file,
                    "gantry": data["gantry_name"],
                    "ok": True,
                    "schema": doc["schema"],
                    "sha256": doc["sha256"],
                    "verified": doc["verified"],
                },
                indent=2,
                sort_keys=True,
            )
        )
    verified = "verified" if doc["verified"] else "NOT verified (exported --unverified)"
    print(
        f"{args.file}: ok: {doc['schema']}, gantry {data['gantry_name']} "
        f"({data['topology']}), {verified}; both digests match (sha256 "
        f"{doc['sha256'][:12]}…)",
        file=sys.stderr,
    )
    return EXIT_OK


_CHECKED_SCHEMAS = ("servotune.tables/4", "servotune.gantry-tables/2",
                    "servotune.linkage-export/1")  # fmt: skip
"""The JSON exports ``check-table`` checks (besides the HAL file and the HAL component)."""


def _check_text_export(args: argparse.Namespace, text: str) -> int | None:
    """``check-table`` on a LinuxCNC HAL file or HAL component (their digest line), or
    ``None`` when ``text`` is neither."""
    from servotune.export.hal_component import check_component_source
    from servotune.export.linuxcnc import HAL_FILE_FIRST_LINE, check_hal_file

    first = text.split("\n", 1)[0]
    if text.startswith(HAL_FILE_FIRST_LINE):
        check_hal_file(text, args.file)
        what = "LinuxCNC HAL file (export-table --format linuxcnc-hal)"
    elif first.startswith("// ") and ".comp -- generated by servotune" in first:
        check_component_source(text, args.file)
        what = "LinuxCNC HAL component (export-table --format linuxcnc-comp)"
    else:
        return None
    if args.json:
        print(
            json.dumps(
                {"file": args.file, "kind": what.split(" (")[0], "ok": True},
                indent=2,
                sort_keys=True,
            )
        )
    print(f"{args.file}: ok: {what}; its sha256 line matches its content", file=sys.stderr)
    return EXIT_OK


def _check_linkage_export(args: argparse.Namespace, text: str) -> int:
    from servotune.export.linkage import check_linkage_export

    doc = check_linkage_export(text, args.file)
    config = doc["data"].get("config")
    name = config.get("name", "?") if isinstance(config, dict) else "?"
    if args.json:
        print(
            json.dumps(
                {
                    "file": args.file,
                    "ok": True,
                    "schema": doc["schema"],
                    "sha256": doc["sha256"],
                    "verified": doc["verified"],
                },
                indent=2,
                sort_keys=True,
            )
        )
    verified = "verified" if doc["verified"] else "NOT verified (exported --unverified)"
    print(
        f"{args.file}: ok: {doc['schema']}, linkage {name}, "
        f"{verified}; the digest matches (sha256 {doc['sha256'][:12]}…)",
        file=sys.stderr,
    )
    return EXIT_OK


def cmd_check_table(args: argparse.Namespace) -> int:
    from servotune.errors import ExportError
    from servotune.export.json import load_tables
    from servotune.io.files import read_bytes

    raw = read_bytes(args.file, ExportError, "export")
    text = raw.decode("utf-8", errors="replace")
    if not text.lstrip().startswith("{"):
        if (code := _check_text_export(args, text)) is not None:
            return code
    else:
        try:
            schema = json.loads(text).get("schema")
        except (ValueError, AttributeError, RecursionError):
            schema = None  # load_tables names what is wrong
        if isinstance(schema, str) and schema.startswith("servotune.gantry-tables/"):
            return _check_gantry_table(args)
        if schema == "servotune.linkage-export/1":
            return _check_linkage_export(args, text)
        if isinstance(schema, str) and not schema.startswith("servotune.tables/"):
            raise ExportError(
                f"{args.file}: schema {schema[:60]!r} is not an export check-table knows: "
                f"{', '.join(_CHECKED_SCHEMAS)}, a LinuxCNC HAL file or HAL component"
            )
    doc = load_tables(args.file)
    data = doc["data"]
    summary = {
        "axes": [a["name"] for a in data["axes"]],
        "c_layout_sha256": data["c_layout_sha256"],
        "file": args.file,
        "ok": True,
        "rig": data["rig_name"],
        "schema": doc["schema"],
        "sha256": doc["sha256"],
        "verified": doc["verified"],
    }
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    verified = "verified" if doc["verified"] else "NOT verified (exported --unverified)"
    print(
        f"{args.file}: ok: {doc['schema']}, rig {data['rig_name']}, axes "
        f"{', '.join(summary['axes'])}, {verified}; every CRC and digest matches "
        f"(sha256 {doc['sha256'][:12]}…)",
        file=sys.stderr,
    )
    return EXIT_OK
