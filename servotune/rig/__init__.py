"""The rig (docs/formats.md#rig-file): the hardware around the loop and its axes, read from and
written to ``plants/*.toml``. ``servotune.rig`` is where the rig is imported from; it re-exports
the names of its modules:

- :mod:`servotune.rig.model`: the model, :class:`Rig` and its sections (:class:`Timer`,
  :class:`Counter`, :class:`Dac`, :class:`Encoder`, :class:`Axis`, :class:`PlantFit`), each
  checked when built, and their bounds (``MAX_*``);
- :mod:`servotune.rig.file`: rig files loaded, checked and described (:func:`load_rig`,
  :func:`describe_rig`, :func:`plant_from_table` …) and a fitted plant written into one
  (:func:`write_plant`);
- :mod:`servotune.rig.edit`: a rig file's plant table edited in place, comments and layout kept,
  for :func:`write_plant`.

The TOML tables are built into the model's dataclasses by
:func:`servotune.io.sections.build_section`.
"""

from __future__ import annotations

from servotune.examples import EXAMPLES_DIR as EXAMPLES_DIR
from servotune.rig.edit import FLOAT_SIGNIFICANT_DIGITS as FLOAT_SIGNIFICANT_DIGITS
from servotune.rig.file import (
    EXAMPLE_RIG_PATH,
    check_plant,
    describe_rig,
    filters_from_array,
    load_rig,
    modes_from_array,
    plant_from_table,
    rig_from_dict,
    write_plant,
)
from servotune.rig.file import MAX_DELAY_S as MAX_DELAY_S
from servotune.rig.file import MAX_NOISE_COUNTS as MAX_NOISE_COUNTS
from servotune.rig.file import MAX_PLANT_GAIN as MAX_PLANT_GAIN
from servotune.rig.file import MAX_TAU_S as MAX_TAU_S
from servotune.rig.file import MIN_TAU_S as MIN_TAU_S
from servotune.rig.model import (
    FIT_METHODS,
    FIT_PCT_KEYS,
    FRICTION_FORMS,
    ROLES,
    Axis,
    Counter,
    Dac,
    Encoder,
    PlantFit,
    Rig,
    Timer,
)
from servotune.rig.model import MAX_CHANNEL as MAX_CHANNEL
from servotune.rig.model import MAX_CLOCK_HZ as MAX_CLOCK_HZ
from servotune.rig.model import MAX_COUNTS as MAX_COUNTS
from servotune.rig.model import MAX_DAC_RANGE_V as MAX_DAC_RANGE_V
from servotune.rig.model import MAX_LOCK_GAIN as MAX_LOCK_GAIN
from servotune.rig.model import MAX_PULSES as MAX_PULSES
from servotune.rig.model import MAX_READ_SKEW_S as MAX_READ_SKEW_S
from servotune.rig.model import MAX_SPEED_RPM as MAX_SPEED_RPM
from servotune.rig.model import MIN_SPEED_LIMIT_RPM as MIN_SPEED_LIMIT_RPM

__all__ = [  # the names of servotune.rig.model's and servotune.rig.file's __all__
    "EXAMPLE_RIG_PATH",
    "FIT_METHODS",
    "FIT_PCT_KEYS",
    "FRICTION_FORMS",
    "ROLES",
    "Axis",
    "Counter",
    "Dac",
    "Encoder",
    "PlantFit",
    "Rig",
    "Timer",
    "check_plant",
    "describe_rig",
    "filters_from_array",
    "load_rig",
    "modes_from_array",
    "plant_from_table",
    "rig_from_dict",
    "write_plant",
]
