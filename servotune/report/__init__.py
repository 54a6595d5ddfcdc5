"""Results for people: text for the terminal (:mod:`.text`), the HTML report (:mod:`.html`) and
the verdict and next step that head it (:mod:`.summary`).

Formatting lives here, above the layers that compute the results; the library never prints.
"""

from servotune.report.html import loop_response, write_report
from servotune.report.text import (
    format_comparison,
    format_linkage_summary,
    format_rig_facts,
    format_table,
)

__all__ = [
    "format_comparison",
    "format_linkage_summary",
    "format_rig_facts",
    "format_table",
    "loop_response",
    "write_report",
]
