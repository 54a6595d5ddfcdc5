"""Outputs of several files are written as a whole: the C exports of a rig, a gantry and a
linkage, ``sync --plot`` and ``linkage --plot``. A full disk at any of the writes leaves nothing
new at the output and an existing output exactly as it was; a finished write holds every file.

Two ways to fill the disk: a write that fails with ``ENOSPC`` at the N-th ``os.write`` (every
N up to the number of files), and, where the test runs as root and may mount, a real small
tmpfs filled so that the export runs out of space part way (docs/formats.md "Outputs")."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from full_disk import no_space_at

import servotune.io.files as files
from servotune.arch.gantry.tuning import tune_gantry, write_gantry_tuning
from servotune.arch.linkage import plan_linkage, write_plan
from servotune.cli import main

ROOT = Path(__file__).resolve().parents[2]
PLANTS = ROOT / "plants"
CORPUS = ROOT / "tests" / "corpus" / "base"


def _tree(d: Path) -> dict[str, bytes]:
    """Every file under ``d`` (relative name → bytes), hidden ones included."""
    if not d.exists():
        return {}
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def _entries(d: Path) -> set[str]:
    return {p.name for p in d.iterdir()}


@pytest.fixture(scope="module")
def sources(tmp_path_factory) -> dict[str, list[str]]:
    """The export-table arguments (before ``--format c -o DIR``) of each kind, unverified."""
    d = tmp_path_factory.mktemp("whole_sources")
    gantry = d / "gantry.json"
    write_gantry_tuning(tune_gantry(PLANTS / "gantry.toml"), gantry)
    plan = d / "plan.json"
    write_plan(plan_linkage(PLANTS / "linkage-6axis.toml"), plan)
    return {
        "rig": [str(CORPUS / "tuning.json"), "--unverified"],
        "gantry": [str(gantry), "--config", str(PLANTS / "gantry.toml"), "--unverified"],
        "linkage": [str(plan), "--unverified"],
    }


def _export(args: list[str], out: Path) -> int:
    return main(["export-table", *args, "--format", "c", "-o", str(out)])


def _count_files(sources, kind: str, tmp_path: Path) -> int:
    d = tmp_path / f"count-{kind}"
    assert _export(sources[kind], d) == 0
    return len(_tree(d))


@pytest.mark.parametrize("kind", ["rig", "gantry", "linkage"])
def test_a_c_export_on_a_full_disk_leaves_nothing_new(
    kind, sources, tmp_path, monkeypatch, capsys
) -> None:
    n_files = _count_files(sources, kind, tmp_path)
    assert n_files >= 3  # the header and the runtime's sources
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "servotune_rt.c").write_text("/* the user's previous runtime */\n")
    (existing / "notes.txt").write_text("the user's own file\n")
    before = _tree(existing)
    for n in range(1, n_files + 1):  # the disk fills at the first, second, ... file
        new = tmp_path / f"new-{n}"
        capsys.readouterr()
        with no_space_at(monkeypatch, n) as calls:
            rc_new = _export(sources[kind], new)
            rc_old = _export(sources[kind], existing)
        assert calls[0] >= n  # the failing write was reached
        assert rc_new != 0 and rc_old != 0
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 2 and all("No space left on device" in e for e in err), err
        assert not new.exists()  # no directory, not even an empty one
        assert _tree(existing) == before  # same files, same bytes, nothing hidden left
        assert not any(e.endswith(".stage") for e in _entries(tmp_path))
    assert _export(sources[kind], existing) == 0  # with space, every file is replaced/added
    after = _tree(existing)
    assert after["notes.txt"] == before["notes.txt"]
    assert after["servotune_rt.c"] != before["servotune_rt.c"]
    assert len(after) == n_files + 1


def test_a_signal_during_the_moves_waits_until_the_output_is_whole(tmp_path) -> None:
    """SIGTERM raised while the staged files are renamed into an existing directory is
    delivered after the last rename: the output holds every new file, none half-moved."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "a.txt").write_text("old a\n")
    seen: list[str] = []
    previous = signal.signal(signal.SIGTERM, lambda *_: seen.append(str(sorted(_entries(out)))))
    try:
        real_rename = os.rename
        sent = [False]

        def rename_then_signal(src, dst) -> None:
            real_rename(src, dst)
            if not sent[0] and Path(dst).parent == out:
                sent[0] = True
                os.kill(os.getpid(), signal.SIGTERM)

        with pytest.MonkeyPatch.context() as m:
            m.setattr(files.os, "rename", rename_then_signal)
            files.write_files(out, {"a.txt": "new a\n", "b.txt": "new b\n", "c.txt": "new c\n"})
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert sent[0]
    assert seen == [str(["a.txt", "b.txt", "c.txt"])]  # the handler ran once all were in place
    assert _tree(out) == {"a.txt": b"new a\n", "b.txt": b"new b\n", "c.txt": b"new c\n"}


def test_a_failed_move_puts_back_what_was_there(tmp_path, monkeypatch) -> None:
    """A rename that fails part way through the moves (which a full disk cannot cause, but a
    permission change could) undoes the renames done: the old files are back, unchanged."""
    out = tmp_path / "out"
    (out / "sub").mkdir(parents=True)
    (out / "a.txt").write_text("old a\n")
    (out / "sub" / "x.txt").write_text("old x\n")
    before = _tree(out)
    real_rename = os.rename
    count = [0]

    def rename_fails_at_the_fourth(src, dst) -> None:
        count[0] += 1
        if count[0] == 4:
            raise PermissionError(errno.EACCES, "Permission denied", str(dst))
        real_rename(src, dst)

    monkeypatch.setattr(files.os, "rename", rename_fails_at_the_fourth)
    with pytest.raises(PermissionError):
        files.write_files(out, {"a.txt": "new a\n", "b.txt": "b\n", "sub/x.txt": "new x\n"})
    monkeypatch.undo()
    assert count[0] >= 4
    assert _tree(out) == before
    assert _entries(tmp_path) == {"out"}


def test_an_error_inside_the_block_leaves_nothing(tmp_path) -> None:
    out = tmp_path / "deep" / "out"
    with pytest.raises(ValueError), files.staged_directory(out) as stage:
        (stage / "a.txt").write_text("a\n")
        raise ValueError("the work failed")
    assert _entries(tmp_path) == set()  # neither "deep" nor a stage
    with files.staged_directory(out) as stage:
        (stage / "a.txt").write_text("a\n")
    assert _tree(tmp_path) == {"deep/out/a.txt": b"a\n"}


def test_a_file_where_the_directory_should_be_is_refused(tmp_path) -> None:
    f = tmp_path / "out"
    f.write_text("a file\n")
    with pytest.raises(NotADirectoryError):
        files.write_files(f, {"a.txt": "a\n"})
    assert f.read_text() == "a file\n"


@pytest.mark.parametrize(
    ("verb", "config", "names"),
    [
        ("sync", "gantry.toml", {"sync_load.png", "sync_mismatch.png"}),
        ("linkage", "linkage-6axis.toml", {"linkage_queues.png", "linkage_circle.png"}),
    ],
)
def test_plots_on_a_full_disk_leave_nothing_new(
    verb, config, names, tmp_path, monkeypatch, capsys
) -> None:
    """The figures of ``sync --plot`` / ``linkage --plot`` as a whole: the second figure's
    write fails, the first is not left behind."""
    args = [verb, str(PLANTS / config), "--seed", "0"]
    if verb == "linkage":
        args += ["--seconds", "2"]
    out = tmp_path / "plots"
    with no_space_at(monkeypatch, 2):
        rc = main([*args, "--plot", str(out)])
    assert rc != 0
    assert "No space left on device" in capsys.readouterr().err
    assert _entries(tmp_path) == set()
    main([*args, "--plot", str(out)])
    assert names <= _entries(out)


def _can_mount() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


@pytest.fixture
def small_disk(tmp_path) -> Iterator[Path]:
    """A 256 KiB tmpfs (root only; skipped where mounting is not allowed)."""
    if not _can_mount():
        pytest.skip("mounting a tmpfs needs root (the injected ENOSPC tests cover the rest)")
    d = tmp_path / f"disk-{uuid.uuid4().hex[:6]}"
    d.mkdir()
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(d)],
        capture_output=True,
        text=True,
        check=False,
    )
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield d
    finally:
        subprocess.run(["umount", str(d)], check=False)


def _fill(disk: Path, leave: int) -> None:
    """Fill ``disk`` until about ``leave`` bytes are free."""
    st = os.statvfs(disk)
    free = st.f_bavail * st.f_frsize
    with open(disk / "filler", "wb") as f:
        f.write(b"\0" * max(free - leave, 0))


@pytest.mark.parametrize("kind", ["rig", "gantry", "linkage"])
def test_a_c_export_on_a_real_full_tmpfs(kind, sources, small_disk, tmp_path, capsys) -> None:
    probe = tmp_path / "probe"
    assert _export(sources[kind], probe) == 0
    total = sum(len(b) for b in _tree(probe).values())
    existing = small_disk / "existing"
    existing.mkdir()
    (existing / "servotune_rt.c").write_text("/* old */\n")
    before = _tree(existing)
    _fill(small_disk, total // 2)  # the first files fit, the rest does not
    capsys.readouterr()
    assert _export(sources[kind], small_disk / "new") != 0
    assert _export(sources[kind], existing) != 0
    err = capsys.readouterr().err
    assert "No space left on device" in err
    assert _entries(small_disk) == {"existing", "filler"}
    assert _tree(existing) == before
    (small_disk / "filler").unlink()
    assert _export(sources[kind], existing) == 0
    assert _tree(existing).keys() == _tree(probe).keys()
