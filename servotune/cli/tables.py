"""The verbs on the deliverable: ``export-table`` (JSON, C, LinuxCNC HAL or component) and
``check-table`` (every CRC and digest of any of those exports but the C files: the tables,
gantry and linkage JSON by their loaders, the HAL file and component by their digest line)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from servotune.cli.output import EXIT_OK, check_dirs, check_outputs, deliver_product, progress_line
from servotune.errors import ServotuneError

# The library is imported inside each handler, not here, so that ``servotune --help`` (and any
# verb) pays only for what it uses: numba, scipy, matplotlib and python-control stay unloaded
# until a handler needs them (tests/cli/test_help_imports.py). That is the only reason for an
# import inside a function in this module; none of them works around an import cycle.


def _export_gantry(args: argparse.Namespace, path: Path) -> int:
    from servotune.arch.gantry.verify import load_gantry_for_export
    from servotune.export.gantry import (
        gantry_document,
        gantry_tables_to_string,
        write_gantry_c,
        write_gantry_tables,
    )
    from servotune.verify.record import fallback_notice

    if args.rig is not None:
        raise ServotuneError(
            f"--rig is for a single rig's tuning; {path} is a gantry tuning "
            "(give its gantry config with --config)"
        )
    v = load_gantry_for_export(path, args.config, args.spec, unverified=args.unverified)
    if (note := fallback_notice(v.gantry_file, "gantry")) is not None:
        progress_line(note)
    doc = gantry_document(v.tuning, v.config.rig, record=v.record, unverified=args.unverified)
    if args.format == "c":
        written = write_gantry_c(doc, args.output)
        print(f"wrote {', '.join(p.name for p in written)} to {args.output}", file=sys.stderr)
    elif args.output and args.output != "-":
        write_gantry_tables(doc, args.output)
        print(f"wrote the gantry tables to {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(gantry_tables_to_string(doc))
    return EXIT_OK


def _export_linkage(args: argparse.Namespace, path: Path) -> int:
    from servotune.arch.linkage import load_plan_for_export
    from servotune.export.linkage import linkage_plan_json, write_linkage_c

    if args.rig is not None:
        raise ServotuneError(
            f"--rig does not apply to a linkage plan ({path}): the plan binds "
            "its config and rig by their hashes (a moved config: "
            "--config)"
        )
    plan, record = load_plan_for_export(
        path, args.spec, unverified=args.unverified, config_path=args.config, progress=progress_line
    )
    if args.format == "c":
        written = write_linkage_c(plan, args.output, record=record, unverified=args.unverified)
        print(f"wrote {', '.join(p.name for p in written)} to {args.output}", file=sys.stderr)
        return EXIT_OK
    text = linkage_plan_json(plan, record, unverified=args.unverified)
    if args.output and args.output != "-":
        from servotune.io.files import atomic_write_text

        atomic_write_text(args.output, text)
        print(f"wrote the linkage export to {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return EXIT_OK


def cmd_export_table(args: argparse.Namespace) -> int:
    from servotune.arch.kind import document_kind
    from servotune.export import tables_to_string, write_c, write_tables
    from servotune.io.files import atomic_write_text
    from servotune.tuning import current_tuning_path
    from servotune.verify import fallback_notice, load_for_export

    path = Path(args.tuning) if args.tuning else current_tuning_path()
    if args.format == "c" and not args.output:
        raise ServotuneError("--format c needs -o DIR (the directory to write the C files into)")
    check_outputs(args.output if args.format != "c" else None, inputs=(path, args.rig, args.spec))
    check_dirs(args.output if args.format == "c" else None)
    kind = document_kind(path)
    if args.format.startswith("linuxcnc-") and kind in ("gantry", "linkage"):
        raise ServotuneError(
            f"--format {args.format} exports a rig's tuning (one runtime, its master and slave "
            f"axes); {path} is a {kind} {'plan' if kind == 'linkage' else 'tuning'}: export it "
            "with --format json or c"
        )
    if kind == "gantry":
        return _export_gantry(args, path)
    if kind == "linkage":
        return _export_linkage(args, path)
    if args.config is not None:
        raise ServotuneError(f"--config is for a gantry tuning; {path} is a rig's tuning")
    v = load_for_export(path, args.rig, args.spec, unverified=args.unverified)
    if (note := fallback_notice(v.rig_file)) is not None:
        progress_line(note)
    kw = {"rig": v.rig, "verification": v.record, "unverified": v.record is None}
    if args.format.startswith("linuxcnc-"):
        text = _linuxcnc_text(args, v.tuning, kw)
        what = "HAL file" if args.format == "linuxcnc-hal" else "HAL component"
        deliver_product(
            args.output, lambda p: atomic_write_text(p, text), lambda: text, f"the {what}"
        )
    elif args.format == "c":
        written = write_c(v.tuning, args.output, **kw)
        print(f"wrote {', '.join(p.name for p in written)} to {args.output}", file=sys.stderr)
    elif args.output and args.output != "-":
        write_tables(v.tuning, args.output, **kw)
        print(f"wrote the tables to {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(tables_to_string(v.tuning, **kw))
    return EXIT_OK


def _linuxcnc_text(args: argparse.Namespace, tuning: object, kw: dict) -> str:
    """The text of a LinuxCNC export of ``tuning`` (``--format linuxcnc-*``)."""
    if args.format == "linuxcnc-comp":
        from servotune.export.hal_component import component_source

        return component_source(tuning, name=args.name, **kw)
    from servotune.export.linuxcnc import pid_hal_text

    if args.position_scale is None:
        raise ServotuneError(
            "--format linuxcnc-hal needs --position-scale (encoder counts per machine unit, "
            "the encoder's position-scale parameter)"
        )
    return pid_hal_text(
        tuning,
        position_scale=args.position_scale,
        output_scale=args.output_scale,
        pid_name=args.pid,
        velocity_feedforward=not args.no_feedforward,
        **kw,
    )


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


_CHECKED_SCHEMAS = ("servotune.tables/2", "servotune.gantry-tables/1",
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
        if schema == "servotune.gantry-tables/1":
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
