"""Example configs of the gantry and the linkage with output filter tables appended, for the
tests of their filters (``test_c_gantry_filters.py``, ``test_c_linkage_filters.py``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def filter_tables(filters: Mapping[str, Sequence[Mapping[str, object]]]) -> str:
    """``[[axis.<name>.filters]]`` tables (TOML) of each axis's sections, in order."""
    out = []
    for axis, sections in filters.items():
        for sec in sections:
            rows = [
                f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"' for k, v in sec.items()
            ]
            out += ["", f"[[axis.{axis}.filters]]", *rows]
    return "\n".join(out) + "\n"


def with_filters(example: str, d: Path, tables: str) -> Path:
    """``plants/<example>`` with ``tables`` appended and its rig named by absolute path, written
    into ``d`` (``<stem>-filtered.toml``)."""
    text = (ROOT / "plants" / example).read_text()
    rig = (ROOT / "plants" / "pc-dual-servo.toml").as_posix()
    text = text.replace('rig = "pc-dual-servo.toml"', f'rig = "{rig}"', 1)
    assert rig in text
    path = d / f"{Path(example).stem}-filtered.toml"
    path.write_text(text + tables)
    return path
