"""File input and output, below every module that reads or writes a file.

:mod:`servotune.io.files` reads and writes bytes, JSON and TOML for every file kind (bounds on
size, nesting, field length; the BOM; atomic writes). A log is the :class:`~servotune.io.log.Log`
of :mod:`servotune.io.log` (with its text, ``format_log``); the log-format CSV is read by
:mod:`servotune.io.log_table` (a file's typed columns), :mod:`servotune.io.log_header` (text,
metadata, header) and :mod:`servotune.io.log_rows` (data rows, time base), and a log file into a
``Log`` by :mod:`servotune.logs`; :mod:`servotune.io.sections` builds a configuration file's
tables (the rig file's, the architectures') into dataclasses. The readers that check a file
against a model above this package live beside that model: the excitation files in
:mod:`servotune.excitation_file` (against the rig), a rig's plant table rewritten in
:mod:`servotune.rig.edit`, the EMPS benchmark in
:mod:`servotune.identify.emps` (its physics in the axis model's terms), the fleet table in
:mod:`servotune.fleet.table` (the fit's parameters as columns). The file kinds and their one
reader each:

==============  ==================================================  ===============================
file            reader                                              schema (checked there)
==============  ==================================================  ===============================
log CSV         :func:`servotune.logs.read_log`                     docs/formats.md#log-file
excitation CSV  :func:`servotune.excitation_file.read_excitation`   the log's rows (``read_table``)
rig TOML        :func:`servotune.rig.load_rig`                      ``Rig`` and its sections
spec TOML       :func:`servotune.verify.load_spec`                  ``Spec``, ``ScenarioSpec``
tuning JSON     :func:`servotune.tuning.read_tuning`                ``Tuning.from_dict``
tables JSON     :func:`servotune.export.json.load_tables`           ``check_tables``
gantry TOML     :func:`servotune.arch.gantry.load.load_gantry`      ``GantryConfig``
linkage TOML    :func:`servotune.arch.linkage.load_linkage`         ``LinkageConfig``
EMPS .mat       :func:`servotune.identify.emps.read_emps`           ``EmpsLog`` (MATLAB variables)
HAL capture     :func:`servotune.io.hal.read_halsampler`,           ``HalCapture``, ``HalSettings``
                :func:`servotune.io.hal.read_halscope`              (``--map``)
mapped CSV      :func:`servotune.io.hal.read_mapped_csv`            the log's rows (``read_table``),
                                                                    ``HalSettings`` (``--map``)
HAL map TOML    :func:`servotune.io.hal_map.read_hal_map`           ``HalSettings`` (``[hal]``)
fleet table     :func:`servotune.fleet.table.read_fleet_records`    ``servotune.fleet/1`` columns
==============  ==================================================  ===============================

The readers of logs, rigs and excitations stay importable from :mod:`servotune.logs`,
:mod:`servotune.rig` and :mod:`servotune.excite` (where the models they build live).
"""
