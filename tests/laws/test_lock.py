"""The lock file: ``make`` installs exact versions with their hashes (requirements.lock), while
``pyproject.toml`` keeps ranges for library users. The lock must cover every dependency the
project declares (runtime and dev), within its range, each pin with its files' hashes; ``make``
and CI must install from it."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[2]
LOCK = ROOT / "requirements.lock"


def _pins(text: str) -> dict[str, tuple[str, list[str]]]:
    """name -> (version, hashes) of every ``name==version \\ --hash=...`` entry."""
    pins = {}
    for block in re.split(r"\n(?=[A-Za-z0-9])", text):
        m = re.match(r"([A-Za-z0-9_.\-\[\],]+)==([^\s\\;]+)", block)
        if m:
            name = canonicalize_name(m.group(1).split("[")[0])
            pins[name] = (m.group(2), re.findall(r"--hash=sha256:([0-9a-f]{64})", block))
    return pins


def _declared() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    return [
        Requirement(r) for r in project["dependencies"] + project["optional-dependencies"]["dev"]
    ]


def test_the_lock_pins_every_declared_dependency_within_its_range_with_hashes() -> None:
    pins = _pins(LOCK.read_text())
    assert len(pins) > 50  # the whole tree, not only the direct dependencies
    for req in _declared():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is declared in pyproject.toml but not locked"
        version, hashes = pins[name]
        assert req.specifier.contains(version, prereleases=True), (req, version)
    for name, (version, hashes) in pins.items():
        assert hashes, f"{name}=={version} has no hash"


def test_the_pin_reader_sees_a_stale_lock() -> None:
    # the check above, on a lock whose numpy is below pyproject's floor: found
    text = "numpy==1.20.0 \\\n    --hash=sha256:" + "0" * 64 + "\n"
    version, hashes = _pins(text)["numpy"]
    floor = next(r for r in _declared() if r.name == "numpy")
    assert version == "1.20.0" and hashes == ["0" * 64]
    assert not floor.specifier.contains(version)


def test_make_and_ci_install_from_the_lock() -> None:
    makefile = (ROOT / "Makefile").read_text()
    assert "--require-hashes -r $(LOCK)" in makefile and "LOCK := requirements.lock" in makefile
    assert re.search(r"^lock:", makefile, re.M)  # make lock refreshes it
    ci = (ROOT / ".ci" / "run").read_text()
    assert "make test" in ci and "UNLOCKED" not in ci
