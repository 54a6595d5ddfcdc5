"""The README is a tested tutorial: every block it shows is run as written, or says why not.

How README.md's fenced blocks are treated (the marks are visible in the README's source):

- A ```` ```console ```` block is a tutorial step and is run. Its ``$ `` lines are commands (a
  line ending in ``\\`` continues onto the next); each runs as a user's shell runs it,
  ``bash -e -o pipefail -c COMMAND`` in the workspace with the venv's ``bin`` first on PATH
  (so redirects, pipes and ``|| echo`` work as written). Every command must exit 0 and leave
  the files it names after ``-o``, ``--output`` or ``>`` non-empty. The block's other lines are
  output the command shows (stdout and stderr together, as a terminal shows them): each must
  match a whole line of that output, in the order shown, runs of blanks counting as one and
  ``…`` standing for any text; a line holding only ``…`` marks left-out lines.
- A block right after ``<!-- file: NAME -->`` is saved as ``NAME`` in the workspace (the
  README tells the reader to save it), for a later command to use.
- A ```` ```python ```` block with ``>>>`` prompts is a doctest (ELLIPSIS, NORMALIZE_WHITESPACE),
  run in the workspace; all of them share one namespace, in document order.
- Any other block must follow ``<!-- not run by tests/test_readme.py: WHY -->``;
  :func:`test_every_block_is_run_or_marked` fails on an unmarked one.

Blocks run in document order in one workspace: a temporary directory holding a copy of
``plants/`` and the two LinuxCNC example files ``servotune init`` adds to it.
``SERVOTUNE_WORKBENCH`` is removed from the environment, so the current tuning goes
where a user's goes by default, the working directory's ``.servotune/`` (and the messages name
it as the README shows). Pointing it at the workspace itself would make the current tuning and
``-o tuning.json`` one file and hide a workflow that once broke (``export-table`` of the
current tuning after ``verify tuning.json``).

The C steps need ``cc``: without one they are left out and the test is reported skipped after
the rest has run. Time: 55 s measured on this 2-core VM under a load of about 3 (numba's cache
warm, as after the rest of the suite), most of it the two ``tune`` runs (with the quick budget
the README explains), the two ``verify`` runs and the start-up of some twenty processes.
"""

from __future__ import annotations

import contextlib
import doctest
import itertools
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from servotune.examples import EXAMPLES_DIR

sys.path.insert(0, str(Path(__file__).resolve().parent / "hal"))  # the shared HAL harness
import halrun

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
VENV_BIN = Path(sys.executable).parent
SKIP_NOTE = re.compile(r"<!-- not run by tests/test_readme\.py: (?P<why>\S.*?) -->")
FILE_NOTE = re.compile(r"<!-- file: (?P<name>[\w.\-/]+) -->")
FENCE = re.compile(r"^(?P<fence>`{3,})(?P<info>[^`]*)$")
COMMAND_TIMEOUT_S = 300
DOCTEST_FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


@dataclass(frozen=True)
class Block:
    """One fenced block of the README: where it opens, its info string, text and mark."""

    line: int  # 1-based line of the opening fence
    info: str
    text: str
    note: str  # the line right before the fence

    @property
    def kind(self) -> str:
        """``console``, ``file``, ``doctest``, ``skip`` or ``unmarked``."""
        if FILE_NOTE.fullmatch(self.note.strip()):
            return "file"
        if SKIP_NOTE.fullmatch(self.note.strip()):
            return "skip"
        if self.info == "console":
            return "console"
        if self.info == "python" and ">>>" in self.text:
            return "doctest"
        return "unmarked"


@dataclass
class Command:
    """One ``$`` command of a console block and the output lines the README shows for it."""

    line: int
    text: str
    shown: list[str] = field(default_factory=list)


def readme_blocks(text: str) -> list[Block]:
    """The fenced blocks of ``text`` in order."""
    blocks: list[Block] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, start = m["fence"], i
        i += 1
        while i < len(lines) and lines[i].rstrip() != fence:
            i += 1
        assert i < len(lines), f"README.md:{start + 1}: the block opened here is never closed"
        note = lines[start - 1] if start else ""
        body = "\n".join(lines[start + 1 : i]) + "\n"
        blocks.append(Block(line=start + 1, info=m["info"].strip(), text=body, note=note))
        i += 1
    return blocks


def console_commands(block: Block) -> list[Command]:
    """The commands of a console block, each with the output lines shown after it."""
    commands: list[Command] = []
    lines = block.text.splitlines()
    i = 0
    while i < len(lines):
        line, n = lines[i], block.line + 1 + i
        i += 1
        if line.startswith("$ "):
            text = line[2:]
            while text.endswith("\\") and i < len(lines):
                text += "\n" + lines[i]
                i += 1
            commands.append(Command(line=n, text=text))
        elif line.strip() not in ("", "…"):
            assert commands, f"README.md:{n}: output shown before any `$ ` command"
            commands[-1].shown.append(line)
    return commands


def _squeeze(s: str) -> str:
    return " ".join(s.split())


def shown_pattern(shown: str) -> re.Pattern[str]:
    """A shown output line as a pattern for one whole (blank-squeezed) output line."""
    return re.compile(".*".join(re.escape(_squeeze(part)) for part in shown.split("…")))


def check_shown(cmd: Command, output: str) -> None:
    """Each line the README shows for ``cmd`` is in its output, in the order shown."""
    actual = [_squeeze(x) for x in output.splitlines()]
    at = 0
    for shown in cmd.shown:
        pattern = shown_pattern(shown)
        while at < len(actual) and not pattern.fullmatch(actual[at]):
            at += 1
        assert at < len(actual), (
            f"README.md:{cmd.line}: `{cmd.text}` does not show, in this order, the line\n"
            f"    {shown}\nIts output was:\n{output}"
        )
        at += 1


def named_outputs(command: str) -> list[str]:
    """The files or directories a command names after ``-o``, ``--output`` or ``>``."""
    try:
        words = shlex.split(command, comments=True)
    except ValueError:
        return []
    return [
        nxt
        for word, nxt in itertools.pairwise(words)
        if word in ("-o", "--output", ">") and nxt != "-"
    ]


def _needs_cc(command: str) -> bool:
    return command.startswith(("cc ", "./"))


def _env() -> dict[str, str]:
    drop = ("SERVOTUNE_WORKBENCH", "PYTEST_")  # a user's default workbench; no outer pytest's
    env = {k: v for k, v in os.environ.items() if not k.startswith(drop)}
    env["PATH"] = f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONUNBUFFERED"] = "1"  # stdout and stderr interleaved as on a terminal
    return env


def run_command(cmd: Command, workspace: Path, env: dict[str, str]) -> str:
    """Run one README command as the user's shell would; fail the test unless it does as shown.
    ``autotune`` reads a running HAL session where there is one: it runs while no real-HAL
    test of another worker holds one (their lock, tests/hal/halrun.py)."""
    hal = halrun.hal_lock() if "servotune autotune" in cmd.text else contextlib.nullcontext()
    with hal:
        res = subprocess.run(
            ["bash", "-e", "-o", "pipefail", "-c", cmd.text],
            cwd=workspace,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=COMMAND_TIMEOUT_S,
        )
    assert res.returncode == 0, (
        f"README.md:{cmd.line}: `{cmd.text}` exited {res.returncode}:\n{res.stdout}"
    )
    check_shown(cmd, res.stdout)
    for name in named_outputs(cmd.text):
        p = workspace / name
        made = (p.is_file() and p.stat().st_size > 0) or (p.is_dir() and any(p.iterdir()))
        assert made, f"README.md:{cmd.line}: `{cmd.text}` left {name} missing or empty"
    return res.stdout


def run_doctest(block: Block, globs: dict) -> None:
    """Run a python block as a doctest in ``globs`` (kept for the next block)."""
    name = f"README.md:{block.line}"
    test = doctest.DocTestParser().get_doctest(block.text, globs, name, str(README), block.line)
    report: list[str] = []
    runner = doctest.DocTestRunner(optionflags=DOCTEST_FLAGS)
    runner.run(test, out=report.append, clear_globs=False)
    globs.update(test.globs)  # a DocTest runs in a copy of the namespace it is given
    assert runner.failures == 0, "".join(report)


def test_every_block_is_run_or_marked() -> None:
    blocks = readme_blocks(README.read_text(encoding="utf-8"))
    unmarked = [f"README.md:{b.line} ```{b.info}" for b in blocks if b.kind == "unmarked"]
    assert not unmarked, (
        "blocks neither run (console, python with >>>, <!-- file: NAME -->) nor marked "
        "<!-- not run by tests/test_readme.py: WHY --> on the line before: " + ", ".join(unmarked)
    )
    kinds = {b.kind for b in blocks}
    assert {"console", "doctest", "file"} <= kinds, kinds


def test_the_tutorial_runs_the_whole_chain() -> None:
    """The quick start and the 'your own machine' path hold the commands a new user
    needs, in order (the quick start is a workflow that once broke), so a README edit cannot drop
    a step from what the test runs."""
    blocks = readme_blocks(README.read_text(encoding="utf-8"))
    commands = [c.text for b in blocks if b.kind == "console" for c in console_commands(b)]
    steps = [
        r"servotune tune plants/pc-dual-servo\.toml -o tuning\.json\b",
        r"servotune verify tuning\.json --spec plants/pc-dual-servo\.spec\.toml",
        r"servotune export-table -o fuzzy\.json",
        r"servotune excite .*-o exc\.csv",
        r"servotune simulate .*--input exc\.csv --closed-loop -o my\.csv",
        r"servotune fit my\.csv .*-o myrig\.toml",
        r"servotune tune myrig\.toml -o tuning\.json\b",
        r"servotune verify tuning\.json --spec ",
        r"servotune export-table > fuzzy\.json",
        r"servotune export-table tuning\.json --format c -o runtime/",
    ]
    at = 0
    for step in steps:
        while at < len(commands) and not re.fullmatch(step + r".*", commands[at]):
            at += 1
        assert at < len(commands), f"no console command matching {step!r} (in this order)"
        at += 1


def test_readme_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert (VENV_BIN / "servotune").exists(), f"servotune is not installed in {VENV_BIN}"
    workspace = tmp_path / "workspace"
    workspace.mkdir()
    shutil.copytree(ROOT / "plants", workspace / "plants")
    for name in ("linuxcnc-map.toml", "linuxcnc-autotune.toml"):  # what servotune init adds
        shutil.copy(EXAMPLES_DIR / name, workspace / "plants" / name)
    env = _env()
    monkeypatch.chdir(workspace)  # the doctests read and write where the commands did
    monkeypatch.delenv("SERVOTUNE_WORKBENCH", raising=False)
    have_cc = shutil.which("cc") is not None
    left_out: list[str] = []
    timings: list[tuple[float, str]] = []
    globs: dict = {"__name__": "README"}
    for block in readme_blocks(README.read_text(encoding="utf-8")):
        t0 = time.perf_counter()
        if block.kind == "file":
            target = workspace / FILE_NOTE.fullmatch(block.note.strip())["name"]
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(block.text, encoding="utf-8")
        elif block.kind == "doctest":
            run_doctest(block, globs)
            timings.append((time.perf_counter() - t0, f"README.md:{block.line} doctest"))
        elif block.kind == "console":
            for cmd in console_commands(block):
                if _needs_cc(cmd.text) and not have_cc:
                    left_out.append(cmd.text)
                    continue
                t0 = time.perf_counter()
                run_command(cmd, workspace, env)
                timings.append((time.perf_counter() - t0, f"README.md:{cmd.line} {cmd.text}"))
    for seconds, what in sorted(timings, reverse=True)[:8]:
        print(f"{seconds:6.1f} s  {what}")
    if left_out:
        pytest.skip(f"no C compiler (`cc` not on PATH): left out {left_out}; the rest ran")
