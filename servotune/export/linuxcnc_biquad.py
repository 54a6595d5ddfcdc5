"""Filter sections as LinuxCNC's own ``biquad`` component (docs/runtime.md#filters).

LinuxCNC's ``biquad`` (``loadrt biquad names=…``) computes, in floating point,
``H(z) = (n0 + n1·z⁻¹ + n2·z⁻²) / (1 + d1·z⁻¹ + d2·z⁻²)``; with ``type`` 0 it runs the
coefficients set in its ``n0, n1, n2, d1, d2`` parameters. :func:`biquad_hal_text` writes,
for quantised sections (:class:`servotune.laws.filters.SectionQ`), the ``setp`` lines of one
``biquad`` instance per section, in series: each coefficient the runtime's exactly
(``q · 2^−frac_bits``, a double holds it without rounding), so LinuxCNC runs the same linear
filter as servotune's runtime. What differs is the arithmetic: the runtime's integer tick
rounds its output to whole D/A codes (with error feedback, :func:`servotune.laws.filters.
biquad_step`), LinuxCNC's stays in doubles; on D/A codes the two outputs differ by at most
about one code (tests/hal/test_linuxcnc_biquad.py measures it in real HAL). A filter is
linear with unit DC gain where it is a notch or a low-pass, so the same coefficients serve a
LinuxCNC loop whose output is in volts.

A LinuxCNC ``biquad`` needs a floating-point thread at the period the sections were designed
for (the bilinear transform is pre-warped at that period).
"""

from __future__ import annotations

from collections.abc import Sequence

from servotune.digest import with_digest_line
from servotune.errors import ExportError
from servotune.laws.filters import SectionQ

__all__ = ["biquad_hal_text"]


def biquad_hal_text(sections: Sequence[SectionQ], *, names: Sequence[str], period_s: float) -> str:
    """HAL lines setting LinuxCNC ``biquad`` instances ``names`` (one per section, in series
    order) to the sections' coefficients; the file carries its digest line.

    Parameters
    ----------
    sections : sequence of SectionQ
        Quantised sections (:func:`servotune.laws.filters.quantize_section`).
    names : sequence of str
        The ``biquad`` instances' names (``loadrt biquad names=…``), one per section.
    period_s : float
        The period the sections were designed for [s] (said in the file; the thread's).

    Raises
    ------
    ExportError
        No section, or not one name per section, or a name that is not a HAL name.
    """
    if not sections or len(names) != len(sections):
        raise ExportError(
            f"biquad export: one name per section, got {len(names)} names for "
            f"{len(sections)} sections"
        )
    for name in names:
        if not name or any(not (c.isalnum() or c in "-_.") for c in name):
            raise ExportError(f"biquad export: {name!r} is not a HAL name")
    lines = [
        "# servotune: filter sections as LinuxCNC's biquad, in series (float; the runtime's",
        "# quantised coefficients exactly). Load them first:",
        f"#   loadrt biquad names={','.join(names)}",
        f"#   addf <name> <thread>, each in order, the thread's period {period_s!r} s",
    ]
    for k, (name, sec) in enumerate(zip(names, sections, strict=True)):
        b, a = sec.ba()
        lines.append(f"# section {k + 1}: frac_bits {sec.frac_bits}")
        lines.append(f"setp {name}.type 0")
        for pin, value in (
            ("n0", b[0]),
            ("n1", b[1]),
            ("n2", b[2]),
            ("d1", a[1]),
            ("d2", a[2]),
        ):
            lines.append(f"setp {name}.{pin} {float(value)!r}")
        lines.append(f"setp {name}.enable 1")
    return with_digest_line("\n".join(lines) + "\n", "#")
