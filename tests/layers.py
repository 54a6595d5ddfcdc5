"""The house rules of the package, measured on its sources (docs/contributing.md#house-rules):
the layer order of its imports, import cycles, private names imported from another module,
functions over 100 code lines outside compiled kernels, modules over 800 lines.

``python tests/layers.py`` prints every finding; ``tests/test_layers.py`` fails on any finding
not in ``tests/layers_known.txt`` (the findings of the day the check was written, each one a
piece of work left) and on an entry there that no longer occurs (the list only shrinks)."""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "servotune"

LAYERS: tuple[tuple[str, ...], ...] = (
    ("_version", "errors", "progress"),
    ("validate", "budget", "digest", "fixed", "_control", "_numba_cache", "kernels", "executor"),
    ("hw", "io", "examples", "provenance"),
    ("plant", "modal", "resonance", "laws", "fuzzy"),
    (
        "rig",
        "logs",
        "metrics",
        "scenarios",
        "excite",
        "excite_design",
        "excitation_file",
    ),
    ("sim", "tuning"),
    ("analysis",),
    ("identify", "tune"),
    ("verify",),
    ("arch", "export", "fleet", "compare"),
    ("report", "plot", "pipeline", "testing", "autotune", "autotune_component", "autotune_live"),
    ("warmup", "cli", "__init__"),
)
"""The layers, lowest first: a module may import from its own layer and those below it
(``servotune.X``: ``X`` is the first name after ``servotune``; the package's own
``__init__``, the public API, is on top)."""

MAX_FUNCTION_LINES = 100
"""Code lines of a function (its docstring, blank lines and comment lines not counted) above
which it is a finding, unless it is a compiled kernel (decorated with ``jit``)."""
MAX_MODULE_LINES = 800
"""Lines of a module above which it is a finding."""


@dataclass(frozen=True, order=True)
class Finding:
    """One breach of a rule: ``kind`` (``layer``, ``cycle``, ``private``, ``function``,
    ``module``) and what, in words stable across edits (no line numbers)."""

    kind: str
    what: str

    def __str__(self) -> str:
        return f"{self.kind}: {self.what}"


def modules() -> dict[str, Path]:
    """Every module of the package: dotted name → file."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _resolve(node: ast.ImportFrom, name: str, is_package: bool) -> str:
    """The absolute module an ``from … import`` names (relative imports resolved)."""
    if node.level == 0:
        return node.module or ""
    base = name.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports(name: str, path: Path, known: set[str]) -> Iterator[tuple[str, str | None]]:
    """``(module imported, name imported from it or None)`` for every import in the module,
    at any depth (in functions and ``TYPE_CHECKING`` blocks too), servotune's only."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_package = path.name == "__init__.py"
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "servotune":
                    yield alias.name, None
        elif isinstance(node, ast.ImportFrom):
            mod = _resolve(node, name, is_package)
            if mod.split(".")[0] != "servotune":
                continue
            for alias in node.names:
                sub = f"{mod}.{alias.name}"
                if sub in known:  # a module imported from its package
                    yield sub, None
                else:
                    yield mod, alias.name


def unit(module: str) -> str:
    """The first name after ``servotune`` (``__init__`` for the package itself)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def layer(module: str) -> int:
    u = unit(module)
    for i, names in enumerate(LAYERS):
        if u in names:
            return i
    raise KeyError(f"{module}: {u!r} is in no layer of tests/layers.py LAYERS")


def _code_lines(fn: ast.FunctionDef | ast.AsyncFunctionDef, source: list[str]) -> int:
    body = fn.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        start = body[0].end_lineno or fn.lineno  # after the docstring
        body_start = body[1].lineno if len(body) > 1 else (fn.end_lineno or start)
    else:
        body_start = body[0].lineno
    end = fn.end_lineno or body_start
    lines = source[body_start - 1 : end]
    return sum(1 for ln in lines if ln.strip() and not ln.strip().startswith("#"))


def _is_kernel(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    for d in fn.decorator_list:
        target = d.func if isinstance(d, ast.Call) else d
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in ("jit", "njit"):
            return True
    return False


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]
    sys.setrecursionlimit(10_000)

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def findings() -> list[Finding]:
    """Every finding of the package today."""
    mods = modules()
    known = set(mods)
    found: set[Finding] = set()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, path in mods.items():
        for target, imported in imports(name, path, known):
            if target not in known:
                continue
            if target != name:
                graph[name].add(target)
            if layer(target) > layer(name):
                found.add(Finding("layer", f"{name} imports {target}"))
            private = imported is not None and imported.startswith("_")
            if private and not imported.startswith("__") and target != name:
                found.add(Finding("private", f"{name} imports {target}.{imported}"))
        source = path.read_text(encoding="utf-8").split("\n")
        if len(source) > MAX_MODULE_LINES:
            found.add(Finding("module", f"{name} ({len(source) // 100 * 100}+ lines)"))
        for node in ast.walk(ast.parse("\n".join(source))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not _is_kernel(node):
                n = _code_lines(node, source)
                if n > MAX_FUNCTION_LINES:
                    found.add(Finding("function", f"{name}.{node.name}"))
    for comp in _cycles(graph):
        found.add(Finding("cycle", " <-> ".join(comp)))
    return sorted(found)


if __name__ == "__main__":
    for f in findings():
        print(f)
