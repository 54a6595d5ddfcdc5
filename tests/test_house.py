"""The repository stands alone: it cites only documents it contains.

**(a) No reference to a document outside the repository.** The requirements servotune was built
from are written down in ``docs/`` in the project's own words
(docs/decisions.md#19-docs-in-the-repository); code, tests, comments, notebooks and build files cite
those pages. A scanned file must not match any of these patterns (:data:`OUTSIDE`):

- ``SPEC`` (upper case, a whole word) followed by ``§``, a section number (``SPEC 6``),
  ``section N``, ``.md``, ``:`` or ``parameter(s)`` / ``name(s)`` (also after ``'s``): a section
  of an outside specification. ``SPEC`` alone is fine: it is the ``--spec SPEC`` metavar and the
  name of test variables holding a spec file's path;
- ``DECISIONS`` followed by a number (``DECISIONS 8``, ``DECISIONS §8``, ``DECISIONS #8``,
  ``DECISIONS point 8``), or ``DECISIONS.md``;
- ``../shared``, or ``shared/`` followed by ``SPEC``, ``DECISIONS`` or ``seeds``: the folder
  those documents live in. A data set read from beside the checkout (the EMPS benchmark's
  ``shared/data/real``, cited by its public reference) is data, not a document, and is allowed;
- ``issue`` or ``issues`` followed by a number, with or without ``#`` (any case: ``issue 17``,
  ``Issue #17``, ``issues 17``): a ticket of this project, which a reader does not have; say what
  is required instead. The word alone (``the issue's target``) is not a reference. Tickets of
  other projects are cited as ``python-control #550`` or by URL (``…/issues/550``), which do not
  match;
- ``seed`` followed by a three-digit number starting ``00`` (``seed 000``, ``Seed 003's``): the
  numbering of the source documents; name the system instead (docs/systems.md). Random seeds
  (``seed 0``, ``--seed 1``) do not match.

**(b) Every reference to the docs resolves.** ``docs/<name>.md`` and ``docs/<name>.md#anchor``
anywhere (not inside a URL), and relative links ``[text](<name>.md#anchor)`` inside ``docs/``,
name an existing file and, with an anchor, one of its headings, slugged as GitHub does
(:func:`slug`: lower case, punctuation dropped, spaces to ``-``, repeats numbered ``-1``, ``-2``).

Scanned: ``git ls-files --cached --others --exclude-standard`` (tracked files, and new files not
ignored, so a check before the first commit sees them too), except binary files (a NUL byte, or
not UTF-8), the data under ``tests/golden/``, ``tests/export/golden/`` and ``tests/corpus/``
(pinned products and generated malformed inputs: regenerated, not edited by hand), and this file,
which spells the patterns out. The self-tests below plant a bad reference of each kind and check
that the checkers flag it, so a broken pattern cannot pass silently.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
THIS = Path(__file__).resolve().relative_to(ROOT).as_posix()

SKIPPED_DIRS = ("tests/golden/", "tests/export/golden/", "tests/corpus/")
"""Data files: pinned products and generated inputs (regenerated, not edited)."""

OUTSIDE: tuple[tuple[str, re.Pattern[str]], ...] = (
    (
        "a section of an outside specification",
        re.compile(
            r"\bSPEC(?:\.md\b|\s*§|\s+section\s+\d|[ \t]+\d|:|(?:'s)?\s+(?:parameter|name)s?\b)"
        ),
    ),
    (
        "an outside decisions page",
        re.compile(r"\bDECISIONS(?:\.md\b|\s*(?:#\s*)?(?:§\s*|point\s+)?\d)"),
    ),
    ("the outside shared folder", re.compile(r"\.\./shared\b|\bshared/(?:SPEC|DECISIONS|seeds)\b")),
    ("a ticket number", re.compile(r"\bissues?\s*(?:#\s*)?\d+", re.IGNORECASE)),
    ("a source document by number", re.compile(r"\bseeds?\s+00\d\b", re.IGNORECASE)),
)

DOC_REF = re.compile(r"(?<![\w./-])docs/([\w.-]+\.md)(?:#([\w-]+))?")
"""``docs/<name>.md`` with an optional ``#anchor``; not part of a longer path or URL."""

RELATIVE_LINK = re.compile(r"\]\(([\w.-]+\.md)(?:#([\w-]+))?\)")
"""A markdown link to a sibling page inside ``docs/``: ``[text](name.md#anchor)``."""


def outside_references(text: str) -> list[tuple[int, str, str]]:
    """Every reference to an outside document in ``text``: (line number, what, the match).

    The whole text is searched, so a reference broken over two lines (``DECISIONS`` at the end
    of one, ``11`` on the next, even after a comment's ``#``) is found too."""
    found = []
    for what, pattern in OUTSIDE:
        for m in pattern.finditer(text):
            found.append((text.count("\n", 0, m.start()) + 1, what, " ".join(m.group(0).split())))
    return sorted(found)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading's text: lower case, every character that is not a letter,
    digit, space, ``-`` or ``_`` dropped, spaces to ``-``."""
    text = heading.strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(markdown: str) -> set[str]:
    """The anchors of a markdown page's headings (fenced code blocks skipped; a repeated slug
    numbered ``-1``, ``-2`` as GitHub does)."""
    seen: dict[str, int] = {}
    out: set[str] = set()
    fence = None
    for line in markdown.splitlines():
        stripped = line.lstrip()
        marker = stripped[:3]
        if marker in ("```", "~~~"):
            fence = None if fence == marker else (fence or marker)
            continue
        if fence:
            continue
        m = re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        s = slug(m.group(1))
        if s in seen:
            seen[s] += 1
            out.add(f"{s}-{seen[s]}")
        else:
            seen[s] = 0
            out.add(s)
    return out


def broken_doc_references(
    text: str, docs: dict[str, set[str]], *, in_docs: bool = False
) -> list[tuple[int, str]]:
    """Every ``docs/…`` reference (and, ``in_docs``, every relative ``…md`` link) in ``text``
    whose file is not in ``docs`` (name → its anchors) or whose anchor is not among its
    headings: (line number, the reference)."""
    patterns = (DOC_REF, RELATIVE_LINK) if in_docs else (DOC_REF,)
    found = []
    for n, line in enumerate(text.splitlines(), 1):
        for pattern in patterns:
            for m in pattern.finditer(line):
                name, anchor = m.group(1), m.group(2)
                if name not in docs or (anchor is not None and anchor not in docs[name]):
                    found.append((n, m.group(0)))
    return found


def _docs() -> dict[str, set[str]]:
    return {p.name: anchors(p.read_text(encoding="utf-8")) for p in (ROOT / "docs").glob("*.md")}


def _text_files() -> list[tuple[str, str]]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the scanned files are git's list")
    out = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout
    files = []
    for rel in sorted({p for p in out.decode("utf-8").split("\0") if p}):
        path = ROOT / rel
        if rel == THIS or rel.startswith(SKIPPED_DIRS) or not path.is_file():
            continue
        raw = path.read_bytes()
        if b"\0" in raw:
            continue
        try:
            files.append((rel, raw.decode("utf-8")))
        except UnicodeDecodeError:
            continue
    return files


# --- the checks --------------------------------------------------------------------------------


def test_no_file_cites_a_document_outside_the_repository() -> None:
    files = _text_files()
    assert any(rel == "README.md" for rel, _ in files) and len(files) > 100
    found = [
        f"{rel}:{n}: {what}: {match!r}"
        for rel, text in files
        for n, what, match in outside_references(text)
    ]
    assert not found, (
        "cite docs/<page>.md#<section> (or say what is required) instead of:\n" + "\n".join(found)
    )


def test_every_docs_reference_names_an_existing_page_and_heading() -> None:
    docs = _docs()
    assert {"runtime.md", "formats.md", "systems.md", "decisions.md"} <= set(docs)
    found = [
        f"{rel}:{n}: {ref}"
        for rel, text in _text_files()
        for n, ref in broken_doc_references(
            text, docs, in_docs=rel.startswith("docs/") and rel.endswith(".md")
        )
    ]
    assert not found, "no such page or heading:\n" + "\n".join(found)


# --- the checkers flag what they must (so the checks above can fail) -------------------------


@pytest.mark.parametrize(
    "text",
    [
        "# the high-byte rule (SPEC §1a)",
        "the arithmetic of SPEC section 6",
        "runtime (SPEC 6 fixed point)",
        "the D/A (SPEC: 12 bits over ±10 V)",
        "Every SPEC parameter (0 when left out)",
        "see ../shared/SPEC.md",
        "the shared/seeds folder",
        "a marker (DECISIONS 8)",
        "keyed by seed and index (DECISIONS\n    # 11)",
        "the sync chain (issue\n19, point 1)",
        "as DECISIONS.md says",
        "the reliability contract (issue 15)",
        "Issue #20: a bare word is not a unit",
        "asked by issues 17 and 18",
        "the lock of seed 000",
        "Seed 003's gantry",
    ],
)
def test_a_planted_outside_reference_is_flagged(text: str) -> None:
    assert outside_references(text), text


@pytest.mark.parametrize(
    "text",
    [
        "servotune verify TUNING --spec SPEC",
        "SPEC = ROOT / 'plants' / 'pc-dual-servo.spec.toml'",
        "_SPEC_TABLES and SPEC_PATH",
        "the issue's 5e7 target, and the issue it found",
        "python-control #550 (https://github.com/python-control/python-control/issues/550)",
        "--seed 1, seed 0, seeds 0-2",
        "the EMPS data in shared/data/real beside the repository",
        "see docs/decisions.md#8-test-time",
    ],
)
def test_ordinary_words_are_not_flagged(text: str) -> None:
    assert outside_references(text) == [], text


def test_slugs_are_githubs() -> None:
    assert slug("Counter overflow (high-byte rule)") == "counter-overflow-high-byte-rule"
    assert slug("1. Unknown keys") == "1-unknown-keys"
    assert slug("D/A quantisation") == "da-quantisation"
    assert slug("Integrity: CRCs and the C layout") == "integrity-crcs-and-the-c-layout"
    page = "# A\n## Same\n```sh\n# not a heading\n```\n## Same\n"
    assert anchors(page) == {"a", "same", "same-1"}


def test_a_broken_docs_reference_is_flagged() -> None:
    docs = {"runtime.md": {"one-tick", "rounding"}}
    assert broken_doc_references("see docs/runtime.md#one-tick and docs/runtime.md", docs) == []
    assert broken_doc_references("(docs/runtime.md#no-such-heading)", docs) == [
        (1, "docs/runtime.md#no-such-heading")
    ]
    assert broken_doc_references("x\ndocs/nosuch.md", docs) == [(2, "docs/nosuch.md")]
    # a URL that happens to hold docs/… is not a reference to this repository's docs
    assert broken_doc_references("https://example.org/docs/nosuch.md", docs) == []
    # inside docs/, relative links are checked too
    assert broken_doc_references("[x](runtime.md#nope)", docs, in_docs=True) == [
        (1, "](runtime.md#nope)")
    ]
    assert broken_doc_references("[x](runtime.md#rounding)", docs, in_docs=True) == []
