"""Running real LinuxCNC HAL (user-space, ``linuxcnc-uspace``) from the tests.

One home for what every real-HAL test needs:

- :data:`needs_hal`: skip with the reason where LinuxCNC's user-space packages are missing, but
  *fail* under CI (``CI=true``): ``.ci/run`` installs them, so a skip there would hide a broken
  install.
- ``halrun`` refuses to run as root: as root, the tests run it as :data:`HAL_USER`, an
  unprivileged system user created on first use (``useradd``); as any other user, as that user.
- Only one HAL session may exist per machine (its shared memory is global): :func:`run_hal`
  holds an exclusive file lock for the session, so pytest-xdist workers take turns.
- A component built with ``halcompile --compile`` loads only from LinuxCNC's module directory
  (``rtapi_app`` refuses a path): :func:`installed_component` copies the built ``.so`` there
  for the session and removes it afterwards (what ``halcompile --install`` does, undone).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import pwd
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import pytest

HAL_USER = "servotune-hal"
MODULE_DIR = Path("/usr/lib/linuxcnc/modules")
LOCK_FILE = Path("/tmp/servotune-hal.lock")
_TOOLS = ("halrun", "halcmd", "halcompile", "halsampler", "halstreamer")


def _missing() -> str | None:
    """Why real HAL cannot run here, or None."""
    absent = [t for t in _TOOLS if shutil.which(t) is None]
    if absent:
        return (
            f"LinuxCNC user-space HAL is not installed ({', '.join(absent)} not on PATH): "
            "install linuxcnc-uspace and linuxcnc-uspace-dev (.ci/run does)"
        )
    if not MODULE_DIR.is_dir():
        return f"LinuxCNC's module directory {MODULE_DIR} is missing"
    if os.geteuid() != 0 and not os.access(MODULE_DIR, os.W_OK):
        return (
            f"a component built by the test loads only from {MODULE_DIR}, which this user "
            "cannot write (run as root, as CI does)"
        )
    return None


def hal_available() -> None:
    """Skip (or under CI, fail) the calling test when real HAL cannot run."""
    why = _missing()
    if why is None:
        return
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(f"CI must run the real-HAL tests: {why}")
    pytest.skip(why)


@pytest.fixture
def needs_hal() -> None:
    """Fixture form of :func:`hal_available`."""
    hal_available()


def _ensure_user() -> None:
    try:
        pwd.getpwnam(HAL_USER)
    except KeyError:
        subprocess.run(
            ["useradd", "--system", "--no-create-home", "--shell", "/bin/sh", HAL_USER],
            check=True,
            capture_output=True,
            text=True,
        )


def _as_user(argv: list[str], workdir: Path) -> list[str]:
    """``argv`` run as the unprivileged HAL user when we are root."""
    env = ["env", f"HOME={workdir}", f"PATH={os.environ.get('PATH', '/usr/bin:/bin')}"]
    if os.geteuid() != 0:
        return [*env, *argv]
    _ensure_user()
    return ["runuser", "-u", HAL_USER, "--", *env, *argv]


def share(workdir: Path) -> None:
    """Let the HAL user read and write ``workdir`` (and everything in it)."""
    if os.geteuid() != 0:
        return
    _ensure_user()
    uid, gid = pwd.getpwnam(HAL_USER)[2:4]
    for p in [workdir, *workdir.rglob("*")]:
        os.chown(p, uid, gid)
    for parent in workdir.parents:  # the user must be able to reach the directory
        if parent == Path("/"):
            break
        mode = parent.stat().st_mode
        if not mode & 0o001:
            os.chmod(parent, mode | 0o001)


def run_as_hal_user(
    argv: list[str], workdir: Path, timeout: float = 120.0
) -> subprocess.CompletedProcess:
    """Run ``argv`` in ``workdir`` as the HAL user; the caller judges the result.

    Its output goes to temporary files, not pipes, and the run ends when ``argv`` exits:
    ``rtapi_app`` (setuid root, started by ``halrun``) inherits the session's output, and one
    that outlives its session (seen under load: ``halrun`` done, ``rtapi_app`` still running)
    would otherwise hold the pipes open, so that reading them waited until the timeout. What
    it leaves running is ended by the next :func:`_clean`. On a timeout every ``rtapi_app`` is
    killed before the session.
    """
    share(workdir)
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(
            _as_user(argv, workdir),
            cwd=workdir,
            stdout=out,
            stderr=err,
            text=True,
            stdin=subprocess.DEVNULL,
        )
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            if os.geteuid() == 0:
                subprocess.run(["pkill", "-KILL", "-x", "rtapi_app"], check=False)
            proc.kill()
            proc.wait()
            raise
        out.seek(0)
        err.seek(0)
        return subprocess.CompletedProcess(proc.args, proc.returncode, out.read(), err.read())


@contextlib.contextmanager
def hal_lock() -> Iterator[None]:
    """One HAL session at a time on this machine (across pytest-xdist workers)."""
    with open(LOCK_FILE, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _clean(workdir: Path) -> None:
    """No HAL session left over: ``halrun -U``, then the shared-memory segments of the HAL
    user that nothing holds (a session killed mid-run leaves its streamer's and sampler's
    FIFOs behind, and one of another size makes the next ``loadrt`` fail)."""
    run_as_hal_user(["halrun", "-U"], workdir, timeout=60.0)
    if os.geteuid() == 0:  # a session whose halrun was killed (a timeout) outlives it
        subprocess.run(["pkill", "-KILL", "-x", "rtapi_app"], capture_output=True, check=False)
    res = subprocess.run(["ipcs", "-m"], capture_output=True, text=True, check=False)
    owner = HAL_USER if os.geteuid() == 0 else pwd.getpwuid(os.geteuid()).pw_name
    for line in res.stdout.splitlines():
        f = line.split()
        # key shmid owner perms bytes nattch; ipcs cuts long owner names to 10 characters
        if len(f) >= 6 and f[0].startswith("0x") and owner.startswith(f[2]) and f[5] == "0":
            subprocess.run(["ipcrm", "-m", f[1]], capture_output=True, check=False)


def run_hal(script: str, workdir: Path, timeout: float = 180.0) -> subprocess.CompletedProcess:
    """Run the halcmd ``script`` with ``halrun -f`` in ``workdir`` as the HAL user.

    Fails the test with HAL's output if the session does not exit cleanly. Any session left
    over by an earlier failure is unloaded first (``halrun -U``).
    """
    path = workdir / "session.hal"
    path.write_text(script)
    with hal_lock():
        _clean(workdir)
        try:
            res = run_as_hal_user(["halrun", "-f", path.name], workdir, timeout=timeout)
        finally:
            _clean(workdir)
    assert res.returncode == 0, f"halrun failed ({res.returncode}):\n{res.stdout}\n{res.stderr}"
    return res


def halcompile(comp: Path) -> Path:
    """Build ``comp`` (a ``.comp`` or ``.c`` component) with ``halcompile --compile``, as the
    HAL user; returns the built module. Fails the test with the compiler's messages."""
    res = run_as_hal_user(["halcompile", "--compile", comp.name], comp.parent, timeout=300.0)
    so = comp.with_suffix(".so")
    assert res.returncode == 0 and so.exists(), f"halcompile failed:\n{res.stdout}\n{res.stderr}"
    return so


@contextlib.contextmanager
def installed_component(so: Path) -> Iterator[str]:
    """``so`` copied into LinuxCNC's module directory for the duration; yields its name."""
    target = MODULE_DIR / so.name
    assert not target.exists(), f"{target} exists already: not overwriting another module"
    shutil.copyfile(so, target)
    os.chmod(target, 0o644)
    try:
        yield so.stem
    finally:
        target.unlink(missing_ok=True)


def run_streamed(
    workdir: Path,
    *,
    load: Sequence[str],
    functs: Sequence[str],
    stream: Iterable[Sequence],
    stream_cfg: str,
    sample_cfg: str,
    wiring: Sequence[str],
    n: int,
    period_ns: int,
    modules: Sequence[Path] = (),
    after: Sequence[str] = (),
) -> list[list[str]]:
    """One thread of ``period_ns`` running ``n`` periods: a ``streamer`` (its ``stream_cfg``)
    feeds the rows of ``stream`` (written to ``stream.txt``, one per period), the functions
    ``functs`` run after it and a ``sampler`` (its ``sample_cfg``) after them records every
    period. ``load`` are the ``loadrt`` arguments of the components under test, ``wiring``
    the ``net`` and ``setp`` lines, ``after`` halcmd lines once the thread is stopped (their
    output after the samples); the built ``modules`` are installed for the session. Returns
    the sampled rows (one per period, as text fields); fails the test if the sampler
    overran."""
    (workdir / "stream.txt").write_text("".join(" ".join(map(str, r)) + "\n" for r in stream))
    script = [
        f"loadrt threads name1=servo period1={period_ns}",
        *(f"loadrt {x}" for x in load),
        f"loadrt streamer depth={n + 16} cfg={stream_cfg}",
        f"loadrt sampler depth={n + 16} cfg={sample_cfg}",
        "addf streamer.0 servo",
        *(f"addf {f} servo" for f in functs),
        "addf sampler.0 servo",
        *wiring,
        "loadusr -w halstreamer stream.txt",
        "start",
        f"loadusr -w halsampler -n {n}",
        "stop",
        *after,
        "getp sampler.0.overruns",
    ]
    with contextlib.ExitStack() as stack:
        for so in modules:
            stack.enter_context(installed_component(so))
        res = run_hal("\n".join(script) + "\n", workdir, timeout=300.0)
    lines = [ln.split() for ln in res.stdout.splitlines() if ln.strip()]
    assert lines[-1] == ["0"], res.stdout[-400:]  # no overrun
    return lines[:n]


def run_component(
    so: Path,
    workdir: Path,
    inputs: dict[str, tuple[str, list]],
    outputs: dict[str, str],
    period_ns: int = 1_000_000,
) -> list[list[str]]:
    """Run the built component ``so`` alone in a thread of ``period_ns``
    (:func:`run_streamed`): a ``streamer`` feeds its ``inputs`` (pin suffix → (streamer type
    letter, values per period)), a ``sampler`` records its ``outputs`` (pin suffix → sampler
    type letter) every period, in that order after the component. Returns the sampled rows
    (one per period, as text fields); fails the test if the sampler overran."""
    hal = so.stem.replace("_", "-")
    return run_streamed(
        workdir,
        load=[so.stem],
        functs=[hal],
        stream=zip(*(values for _, values in inputs.values()), strict=True),
        stream_cfg="".join(t for t, _ in inputs.values()),
        sample_cfg="".join(outputs.values()),
        wiring=[
            *(f"net in{k} streamer.0.pin.{k} {hal}.{pin}" for k, pin in enumerate(inputs)),
            *(f"net out{k} {hal}.{pin} sampler.0.pin.{k}" for k, pin in enumerate(outputs)),
        ],
        n=len(next(iter(inputs.values()))[1]),
        period_ns=period_ns,
        modules=[so],
    )
