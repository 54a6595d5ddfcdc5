"""numba's cache follows every servotune source edit (servotune/_numba_cache.py).

numba alone re-checks a cached function against its own file only; a kernel that inlines a law
from another module would keep the old law after that module is edited.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numba

import servotune
from servotune import _numba_cache, fixed
from servotune.laws import pi
from servotune.sim import kernel, lean


def _tree(root: Path) -> Path:
    (root / "laws").mkdir(parents=True)
    (root / "engine.py").write_text("KERNEL = 1\n")
    (root / "laws" / "pi.py").write_text("GAIN = 1\n")
    return root


def test_digest_changes_with_any_source_edit_and_only_then(tmp_path: Path) -> None:
    root = _tree(tmp_path / "pkg")
    d0 = _numba_cache.source_digest(root)
    assert _numba_cache.source_digest(root) == d0
    (root / "notes.txt").write_text("not a source")
    assert _numba_cache.source_digest(root) == d0
    (root / "laws" / "pi.py").write_text("GAIN = 2\n")  # an inlined callee, not the kernel
    d1 = _numba_cache.source_digest(root)
    assert d1 != d0
    (root / "laws" / "pi.py").rename(root / "laws" / "pid.py")  # same bytes, other module
    assert _numba_cache.source_digest(root) not in (d0, d1)


def test_cache_dir_is_named_by_the_digest_and_replaces_the_old_one(tmp_path: Path) -> None:
    root = _tree(tmp_path / "pkg")
    first = _numba_cache.cache_dir(root)
    assert first == root / "__pycache__" / f"numba-{_numba_cache.source_digest(root)}"
    assert first.is_dir()
    (first / "kernel.nbi").write_text("old index")
    assert _numba_cache.cache_dir(root) == first  # unchanged sources: the same cache
    assert (first / "kernel.nbi").exists()
    (root / "laws" / "pi.py").write_text("GAIN = 2\n")
    second = _numba_cache.cache_dir(root)
    assert second != first
    assert second.is_dir()
    # a process of a moment ago may still write into the old cache: it stays for now
    assert first.exists()
    third_src = root / "laws" / "pi.py"
    third_src.write_text("GAIN = 3\n")
    idle = time.time() - _numba_cache._STALE_S - 1
    for d in (first, second):
        os.utime(d, (idle, idle))
    third = _numba_cache.cache_dir(root)
    assert third.is_dir() and not first.exists() and not second.exists()  # idle ones go


def test_servotune_functions_cache_under_the_digest_and_others_are_untouched() -> None:
    user_dir = os.environ.get("NUMBA_CACHE_DIR")
    expected = Path(user_dir) if user_dir else _numba_cache.cache_dir()
    assert expected is not None
    for fn in (lean.kernel_lean, kernel.batch_kernel, pi.pi_step, fixed.sat_add):
        assert Path(fn._cache._cache_path).is_relative_to(expected), fn
    # the setting is restored after servotune's imports: other packages keep numba's default
    assert numba.config.CACHE_DIR == os.environ.get("NUMBA_CACHE_DIR", "")
    assert servotune.__version__


def test_numba_cache_dir_set_by_the_user_rules(tmp_path: Path) -> None:
    code = "import servotune.sim.lean as e, sys; sys.stdout.write(e.kernel_lean._cache._cache_path)"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "mine")}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    ).stdout
    assert Path(out).is_relative_to(tmp_path / "mine")


def test_numba_is_used_through_its_public_api_only() -> None:
    # no private options or internals (``_nrt``, cgutils, arrayobj), and every compiled
    # function through the one decorator (_numba_cache.jit), so each caches under the digest
    package = Path(servotune.__file__).resolve().parent
    private = (
        "_nrt",
        "numba.core.cgutils",
        "from numba.core import cgutils",
        "numba.np.arrayobj",
        "make_array",
        "populate_array",
    )
    found = []
    for path in sorted(package.rglob("*.py")):
        text = path.read_text()
        rel = path.relative_to(package).as_posix()
        found += [f"{rel}: {word}" for word in private if word in text]
        if rel != "_numba_cache.py" and ("nb.njit" in text or "numba.njit" in text):
            found.append(f"{rel}: numba.njit outside _numba_cache.jit")
    assert not found, found
