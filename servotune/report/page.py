"""The pieces every report page is built from: escaping, tables, embedded PNGs, the page itself.

One self-contained page: its style sheet inline (:data:`PAGE_STYLE`), its figures embedded as PNG
data URIs, its numbers as a JSON block (:func:`data_block`). Used by the tuning report
(:mod:`servotune.report.html`) and the fleet report (:mod:`servotune.report.fleet`).
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from servotune.validate import show_number

__all__ = [
    "PAGE_STYLE",
    "code_html",
    "data_block",
    "escape_html",
    "figure_html",
    "file_uri",
    "fmt_value",
    "page_html",
    "paragraph_html",
    "png_uri",
    "table_html",
]


def png_uri(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, metadata={"Software": None})
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def file_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def escape_html(x: Any) -> str:
    return html.escape(str(x))


def figure_html(uri: str, alt: str, caption: str = "") -> str:
    cap = f"<figcaption>{caption}</figcaption>" if caption else ""
    return f'<figure><img alt="{escape_html(alt)}" src="{uri}">{cap}</figure>'


def table_html(head: Sequence[str], rows: Sequence[Sequence[Any]], bad: Sequence[bool] = ()) -> str:
    """A table of text cells; ``bad`` rows are highlighted."""
    out = ["<table><tr>" + "".join(f"<th>{escape_html(h)}</th>" for h in head) + "</tr>"]
    for i, r in enumerate(rows):
        cls = ' class="fail"' if (i < len(bad) and bad[i]) else ""
        cells = "".join(f"<td>{escape_html(c)}</td>" for c in r)
        out.append(f"<tr{cls}>{cells}</tr>")
    return "\n".join(out) + "</table>"


def fmt_value(x: Any, unit: str = "") -> str:
    if isinstance(x, float | int) and not isinstance(x, bool):
        text = show_number(float(x))
        return f"{text} {unit}" if unit and math.isfinite(float(x)) else text
    return "—" if x is None else str(x)


def paragraph_html(text: str) -> str:
    return f"<p>{escape_html(text)}</p>"


def code_html(text: str) -> str:
    """``text`` escaped, with its `backticked` commands set as code."""
    parts = escape_html(text).split("`")
    return "".join(f"<code>{x}</code>" if i % 2 else x for i, x in enumerate(parts))


# --- the page --------------------------------------------------------------------------------

PAGE_STYLE = (
    "body{font-family:sans-serif;max-width:1100px;margin:0 auto;padding:0 16px;"
    "line-height:1.4;color:#222}"
    "img{max-width:100%;height:auto;display:block}"
    "figure{margin:1em 0}figcaption{font-size:.9em;color:#444}"
    "table{border-collapse:collapse;margin:.8em 0;font-size:.88em;max-width:100%}"
    "td,th{border:1px solid #ccc;padding:2px 6px;vertical-align:top;overflow-wrap:break-word}"
    "th{background:#f4f4f4}tr.fail{background:#fdd}"
    ".summary{border:2px solid #888;border-radius:6px;padding:.2em 1em;background:#f6f6f6}"
    ".summary.pass{border-color:#2a2;background:#efe}"
    ".summary.fail{border-color:#c22;background:#fee}"
    ".winner{border-left:4px solid #36c;padding:.3em .8em;background:#eef3ff}"
    ".comment{border-left:4px solid #999;padding:.3em .8em;background:#f7f7f7}"
    "code{background:#f3f3f3;overflow-wrap:anywhere}nav{font-size:.9em}"
)


def _jsonable(x: Any) -> Any:
    """``x`` as strict JSON: non-finite floats as None, numpy scalars and tuples converted."""
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple | np.ndarray):
        return [_jsonable(v) for v in x]
    return x


def data_block(data: Mapping[str, Any]) -> str:
    text = json.dumps(_jsonable(data), sort_keys=True, ensure_ascii=False, allow_nan=False)
    text = text.replace("<", "\\u003c")  # no "</script>" inside the block
    return f'<script type="application/json" id="servotune-data">{text}</script>'


def page_html(title: str, content: str, data: Mapping[str, Any]) -> str:
    """The whole page: ``title``, ``content`` (HTML) and ``data`` as its JSON block."""
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{escape_html(title)}</title><style>{PAGE_STYLE}</style></head><body>\n"
        + content
        + "\n"
        + data_block(data)
        + "\n</body></html>\n"
    )
