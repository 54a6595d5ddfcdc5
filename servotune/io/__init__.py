"""File input and output.

:mod:`servotune.io.files` reads and writes bytes, JSON and TOML for every file kind (bounds on
size, nesting, field length; the BOM; atomic writes). The log-format CSV is parsed by
:mod:`servotune.io.log_header` (text, metadata, header) and :mod:`servotune.io.log_rows` (data
rows, time base); :mod:`servotune.io.rig` builds the rig file's tables and edits its plant
table; :mod:`servotune.io.excitation` reads and writes excitation files. The file kinds and
their one reader each:

==============  ===============================================  ===============================
file            reader                                           schema (checked there)
==============  ===============================================  ===============================
log CSV         :func:`servotune.logs.read_log`                  docs/formats.md#log-file
excitation CSV  :func:`servotune.io.excitation.read_excitation`  the log's rows (``read_table``)
rig TOML        :func:`servotune.rig.load_rig`                   ``Rig`` and its sections
spec TOML       :func:`servotune.verify.load_spec`               ``Spec``, ``ScenarioSpec``
tuning JSON     :func:`servotune.tuning.read_tuning`             ``Tuning.from_dict``
tables JSON     :func:`servotune.export.json.load_tables`        ``check_tables``
gantry TOML     :func:`servotune.arch.gantry.load.load_gantry`   ``GantryConfig``
linkage TOML    :func:`servotune.arch.linkage.load_linkage`      ``LinkageConfig``
EMPS .mat       :func:`servotune.io.emps.read_emps`              ``EmpsLog`` (MATLAB variables)
HAL capture     :func:`servotune.io.hal.read_halsampler`,        ``HalCapture``, ``HalSettings``
                :func:`servotune.io.hal.read_halscope`           (``--map``)
mapped CSV      :func:`servotune.io.hal.read_mapped_csv`         the log's rows (``read_table``),
                                                                 ``HalSettings`` (``--map``)
HAL map TOML    :func:`servotune.io.hal_map.read_hal_map`        ``HalSettings`` (``[hal]``)
fleet table     :func:`servotune.io.fleet_table.read_fleet_records` ``servotune.fleet/1`` columns
==============  ===============================================  ===============================

The readers of logs, rigs and excitations stay importable from :mod:`servotune.logs`,
:mod:`servotune.rig` and :mod:`servotune.excite` (where the models they build live).
"""
