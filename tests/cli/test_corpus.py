"""Every file of the malformed-input corpus (tests/corpus) through the command line.

Each case runs as a user would, in a fresh working directory holding the file, the example
rig and spec (``plants/``, and ``pc-dual-servo.toml`` next to the file for gantry and linkage
configs) and a valid tuning (for the spec cases). A malformed file must give the manifest's
exit code (3 bad input; 1 for a tables export edited after export), exactly one non-empty line
on stderr naming the file or the field, no traceback, and leave the directory as it was.

Speed: the file's reader runs in-process first (milliseconds). When it refuses the file, the
CLI runs in-process too (``servotune.cli.main``). When it accepts the file, the CLI runs in a
subprocess with a time and memory limit, since an accepted bad file may start a run of hours
(a spec asking for 10^9 Monte Carlo sets, a 10^-9 s bus cycle). A few cases always run in a
subprocess, ``python -m servotune.cli``, exactly as from a shell.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import json
import os
import resource
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import guard
import pytest
from guard import GuardTimeout

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / "tests" / "corpus"
PLANTS = ROOT / "plants"
RIG = "plants/pc-dual-servo.toml"
SPEC = "plants/pc-dual-servo.spec.toml"
MANIFEST: list[dict[str, Any]] = json.loads((CORPUS / "manifest.json").read_text())
KINDS = ("rig", "spec", "log", "excitation", "tuning", "tables", "gantry", "linkage")

TIMEOUT_S = 90  # an accepted file's whole CLI run (verify of the base tuning takes ~12 s)
MEMORY_LIMIT = 8 << 30  # address space of the subprocess [bytes]
MAX_LINE = 1000  # characters of the error line (a huge value must be shortened, not echoed)
# run through `python -m servotune.cli` whatever the reader says
ALWAYS_SUBPROCESS = {
    ("rig", "bits-float.toml"),
    ("log", "empty.csv"),
    ("tuning", "n-string.json"),
    ("tables", "truncated.json"),
    ("excitation", "code-plus-minus.csv"),
    ("spec", "empty.toml"),
    ("gantry", "latency-float.toml"),
    ("linkage", "empty.toml"),
}


def _load_make_corpus() -> Any:
    spec = importlib.util.spec_from_file_location("make_corpus", CORPUS / "make_corpus.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("make_corpus", mod)  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def argv_for(kind: str, file: str) -> list[str]:
    """The command line a user would type for a file of this kind (cwd: the work directory)."""
    return {
        "rig": ["rig", file],
        "log": ["fit", file, "--axis", "master"],
        "spec": ["verify", "tuning.json", "--spec", file, "--rig", RIG],
        "tuning": ["verify", file, "--spec", SPEC],
        "tables": ["check-table", file],
        "excitation": ["simulate", RIG, "--input", file, "-o", "out.csv"],
        "gantry": ["sync", file],
        "linkage": ["linkage", file],
    }[kind]


def read_with_reader(kind: str, path: Path) -> None:
    """The library reader of this kind on ``path`` (what the CLI verb reads first)."""
    if kind == "rig":
        from servotune.rig import load_rig

        load_rig(path)
    elif kind == "spec":
        from servotune.verify import load_spec

        load_spec(path)
    elif kind == "log":
        from servotune.logs import read_log

        read_log(path)
    elif kind == "excitation":
        from servotune.excite import read_excitation
        from servotune.rig import load_rig

        read_excitation(path, load_rig(PLANTS / "pc-dual-servo.toml"))
    elif kind == "tuning":
        from servotune.tuning import read_tuning

        read_tuning(path)
    elif kind == "tables":
        from servotune.export.json import load_tables

        load_tables(path)
    elif kind == "gantry":
        from servotune.arch.gantry.load import load_gantry

        load_gantry(path)
    elif kind == "linkage":
        from servotune.arch.linkage import load_linkage

        load_linkage(path)
    else:  # pragma: no cover
        raise AssertionError(kind)


def make_workdir(d: Path, case: dict[str, Any]) -> Path:
    """A working directory as a user would have it; returns the case's file in it."""
    (d / "plants").mkdir()
    for name in ("pc-dual-servo.toml", "pc-dual-servo.spec.toml"):
        shutil.copy(PLANTS / name, d / "plants" / name)
    shutil.copy(PLANTS / "pc-dual-servo.toml", d / "pc-dual-servo.toml")  # gantry, linkage
    if case["kind"] == "spec":
        shutil.copy(CORPUS / "base" / "tuning.json", d / "tuning.json")
    target = d / case["file"]
    if case["generated"]:
        target.write_bytes(_load_make_corpus().build(case["kind"], case["file"]))
    else:
        shutil.copy(CORPUS / case["kind"] / case["file"], target)
    return target


def snapshot(d: Path) -> dict[str, str]:
    """Every file under ``d`` (hidden ones too) with its SHA-256."""
    return {
        str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(d.rglob("*"))
        if p.is_file()
    }


def guarded(
    seconds: int = TIMEOUT_S, memory: int = MEMORY_LIMIT
) -> contextlib.AbstractContextManager[None]:
    """:func:`guard.guarded` with this module's limits."""
    return guard.guarded(seconds, memory)


def run_in_process(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    from servotune.cli import main

    capsys.readouterr()
    try:
        with guarded():
            rc = main(argv)
    except SystemExit as exc:  # argparse
        rc = exc.code if isinstance(exc.code, int) else 2
    except BaseException as exc:  # any escape is the finding
        msg = str(exc).splitlines()[0][:200] if str(exc) else ""
        pytest.fail(
            f"`servotune {' '.join(argv)}` raised {type(exc).__module__}.{type(exc).__name__}: "
            f"{msg}",
            pytrace=False,
        )
    return rc, capsys.readouterr().err


def _limits() -> None:  # pragma: no cover - runs in the child
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def run_subprocess(argv: list[str], cwd: Path) -> tuple[int, str]:
    env = dict(os.environ, PYTHONWARNINGS="default")
    env.pop("SERVOTUNE_WORKBENCH", None)
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "servotune.cli", *argv],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
            preexec_fn=_limits,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(
            f"`servotune {' '.join(argv)}` accepted the file and was still running after "
            f"{TIMEOUT_S} s",
            pytrace=False,
        )
    return proc.returncode, proc.stderr


def _short(text: str, n: int = 300) -> str:
    text = text.strip()
    if "Traceback" in text:  # the exception line is the last one
        return "... " + text.splitlines()[-1][:n]
    return text[:n] + ("…" if len(text) > n else "")


@pytest.mark.parametrize("case", MANIFEST, ids=[f"{c['kind']}/{c['file']}" for c in MANIFEST])
def test_corpus_file(
    case: dict[str, Any],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    kind, file, expected = case["kind"], case["file"], case["exit"]
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("SERVOTUNE_WORKBENCH", raising=False)
    path = make_workdir(tmp_path, case)
    before = snapshot(tmp_path)
    argv = argv_for(kind, file)

    refused = hung = False
    try:
        with guarded(30):
            read_with_reader(kind, Path(file))
    except GuardTimeout:
        hung = True
    except Exception:  # a non-servotune error shows again in the CLI run
        refused = True
    if hung:
        pytest.fail(f"the {kind} reader was still reading {file} after 30 s", pytrace=False)
    if refused and (kind, file) not in ALWAYS_SUBPROCESS:
        rc, err = run_in_process(argv, capsys)
    else:
        rc, err = run_subprocess(argv, tmp_path)

    cmd = f"servotune {' '.join(argv)}"
    assert "Traceback" not in err, f"`{cmd}` printed a traceback: {_short(err)}"
    if expected == 0:
        assert rc == 0, f"`{cmd}` must accept this valid file; exit {rc}: {_short(err)}"
        return
    assert rc == expected, f"`{cmd}`: exit {rc}, expected {expected}; stderr: {_short(err)}"
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].strip(), (
        f"`{cmd}`: stderr must be one non-empty line, got {len(lines)}: {_short(err)}"
    )
    line = lines[0]
    assert len(line) <= MAX_LINE, f"`{cmd}`: error line of {len(line)} characters"
    hint = case["hint"]
    assert file in line or (hint and hint in line), (
        f"`{cmd}`: the message names neither the file nor {hint!r}: {line[:300]}"
    )
    after = snapshot(tmp_path)
    assert after == before, (
        f"`{cmd}` changed the working directory: new "
        f"{sorted(set(after) - set(before))}, changed "
        f"{sorted(k for k in before if k in after and after[k] != before[k])}"
    )
    assert path.exists()


def test_manifest_matches_the_files() -> None:
    listed = {(c["kind"], c["file"]) for c in MANIFEST if not c["generated"]}
    on_disk = {(k, p.name) for k in KINDS for p in (CORPUS / k).iterdir()}
    assert on_disk == listed, (
        f"run tests/corpus/make_corpus.py: not listed {sorted(on_disk - listed)}, missing "
        f"{sorted(listed - on_disk)}"
    )
    malformed = [c for c in MANIFEST if c["exit"] != 0]
    assert len(malformed) >= 60
    assert {c["kind"] for c in malformed} == set(KINDS)
    readme = (CORPUS / "README.md").read_text()
    assert all(f"`{c['file']}`" in readme for c in MANIFEST)


@pytest.mark.parametrize("kind", KINDS)
def test_the_bases_are_valid(kind: str, tmp_path: Path) -> None:
    """The corpus is made from valid files: each base reads (else remake the bases)."""
    mc = _load_make_corpus()
    src = mc.base_path(kind)
    shutil.copy(src, tmp_path / src.name)
    shutil.copy(PLANTS / "pc-dual-servo.toml", tmp_path / "pc-dual-servo.toml")
    read_with_reader(kind, tmp_path / src.name)
