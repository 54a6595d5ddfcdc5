"""The example files that ship inside the package, and ``servotune init``, which copies them out.

The example rig (``pc-dual-servo.toml``), its belt-driven variant (``belt-axis.toml``: the
master's plant with a 35 Hz mode) and that variant read by a linear scale on the carriage
(``belt-scale.toml``: a 15 Hz mode seen non-collocated, where the tuner places a notch), the
gantry and the six-axis linkage configs, a spec for each, a LinuxCNC capture's map
(``linuxcnc-map.toml``, read by ``servotune fit --map``) and an autotune config
(``linuxcnc-autotune.toml``, read by ``servotune autotune``).
The repository's ``plants/`` holds the same files, byte for byte, all but the two LinuxCNC
files (``tests/test_examples.py``); the library reads only these copies, so an installed wheel works
without a checkout. :func:`write_examples` writes them into a directory: ``servotune init DIR``
puts them into ``DIR/plants/``, where the README's and ``--help``'s commands look for them.

Examples
--------
>>> "pc-dual-servo.toml" in example_names()
True
>>> example_path("pc-dual-servo.toml").read_text().startswith("#")
True
"""

from __future__ import annotations

import errno
from pathlib import Path
from typing import Literal, NamedTuple

from servotune.io.files import atomic_write_bytes

__all__ = [
    "EXAMPLES_DIR",
    "ExampleFile",
    "ExamplesDifferError",
    "example_names",
    "example_path",
    "write_examples",
]

EXAMPLES_DIR = Path(__file__).resolve().parent
"""The package's folder of example files (the package is installed unzipped)."""


class ExamplesDifferError(FileExistsError):
    """Files where :func:`write_examples` would write hold other bytes than the examples
    (``paths``: every such file); nothing was written."""

    def __init__(self, paths: list[Path]) -> None:
        self.paths = tuple(paths)
        names = ", ".join(repr(str(p)) for p in paths)
        verbs = "exists and differs" if len(paths) == 1 else "exist and differ"
        super().__init__(
            errno.EEXIST,
            f"{names} {verbs} from servotune's example; nothing written",
            str(paths[0]),
        )


class ExampleFile(NamedTuple):
    """One example file :func:`write_examples` handled: where, and what it did with it."""

    path: Path
    """The file in the target directory."""
    action: Literal["wrote", "replaced", "unchanged"]
    """``wrote``: it was not there; ``replaced``: a different file was there (``force``);
    ``unchanged``: the same bytes were there already (left alone)."""


def example_names() -> tuple[str, ...]:
    """The example files' names, sorted (``gantry.spec.toml``, …, ``pc-dual-servo.toml``)."""
    return tuple(sorted(p.name for p in EXAMPLES_DIR.glob("*.toml") if p.is_file()))


def example_path(name: str) -> Path:
    """The packaged example file ``name`` (one of :func:`example_names`).

    Raises
    ------
    ValueError
        If there is no such example (the message lists the ones there are).
    """
    names = example_names()
    if name not in names:
        raise ValueError(f"no example file {name!r}; the examples are: {', '.join(names)}")
    return EXAMPLES_DIR / name


def write_examples(directory: str | Path, *, force: bool = False) -> list[ExampleFile]:
    """Write every example file into ``directory`` (created if missing, with its parents).

    Every target is checked before anything is written: a file already there with other bytes
    (or a directory of that name) is refused, and nothing is written, unless ``force`` (then a
    different file is replaced). A file with the same bytes is left alone. Each write is atomic
    (a temporary file, then a rename).

    Parameters
    ----------
    directory : str or Path
        Where the files go (``servotune init DIR`` gives ``DIR/plants``).
    force : bool
        Replace existing files that differ from the examples.

    Returns
    -------
    list of ExampleFile
        One per example file, in :func:`example_names` order, with what was done.

    Raises
    ------
    ExamplesDifferError
        Without ``force``, if a target exists and differs (a :class:`FileExistsError`; the
        message names every such file); nothing was written.
    NotADirectoryError, IsADirectoryError
        If ``directory`` is a file, or a target is a directory (nothing written).
    OSError
        If creating the directory or writing fails (files written before stay complete).

    Examples
    --------
    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp()) / "plants"
    >>> [f.action for f in write_examples(d)][:2]
    ['wrote', 'wrote']
    >>> {f.action for f in write_examples(d)}
    {'unchanged'}
    """
    target_dir = Path(directory)
    nearest = target_dir  # the directory, or its nearest existing parent: must be a directory
    while not nearest.exists() and nearest != nearest.parent:
        nearest = nearest.parent
    if nearest.exists() and not nearest.is_dir():
        raise NotADirectoryError(
            errno.ENOTDIR,
            "is a file, not a directory: give a directory for the example files",
            str(nearest),
        )
    plan: list[tuple[Path, bytes, Literal["wrote", "replaced", "unchanged"]]] = []
    differ: list[Path] = []
    for name in example_names():
        data = (EXAMPLES_DIR / name).read_bytes()
        path = target_dir / name
        if path.is_dir():
            raise IsADirectoryError(
                errno.EISDIR, "is a directory, where an example file goes", str(path)
            )
        if not path.exists():
            plan.append((path, data, "wrote"))
        elif path.read_bytes() == data:
            plan.append((path, data, "unchanged"))
        else:
            differ.append(path)
            plan.append((path, data, "replaced"))
    if differ and not force:
        raise ExamplesDifferError(differ)
    target_dir.mkdir(parents=True, exist_ok=True)
    for path, data, action in plan:
        if action != "unchanged":
            atomic_write_bytes(path, data)
    return [ExampleFile(path, action) for path, _, action in plan]
