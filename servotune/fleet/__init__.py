"""Fleet fits: the logs of many machines identified at once, their spread, the machines that
stand out against the fleet, the ones that drifted since their previous fit, and the fleet's
measured spread as a Monte-Carlo plant distribution.

One module per concept:

- :mod:`servotune.fleet.rows`: one log and axis of a fleet (:class:`FleetRow`), how a log is
  fitted (:func:`fit_fleet_log`), the machine id and date of a log, each machine's latest fit
  (:func:`latest_fits`) and reading the fleet table;
- :mod:`servotune.fleet.summary`: the fleet's robust spread, outliers and drift
  (:func:`summarise_fleet`);
- :mod:`servotune.fleet.fit`: the whole run over an executor (:func:`fit_fleet`) and writing
  the table;
- :mod:`servotune.fleet.spread`: the fleet's machines as the plant distribution of a
  Monte-Carlo verification (:func:`fleet_spread`);
- :mod:`servotune.fleet.table`: the fleet table's columns and its two file forms, Parquet and
  CSV (the records as the rows and the fit read and write them).

Every name of the first four is importable from ``servotune.fleet``, and the table's
:data:`FLEET_SCHEMA`.
"""

from __future__ import annotations

from servotune.fleet.fit import FLEET_CLUSTER_MIN_LOGS, FleetResult, fit_fleet, write_fleet_table
from servotune.fleet.rows import (
    FleetFitOptions,
    FleetRow,
    fit_fleet_log,
    latest_fits,
    machine_and_date,
    read_fleet_table,
)
from servotune.fleet.spread import FleetSpread, fleet_spread
from servotune.fleet.summary import (
    DRIFT_K,
    MAD_TO_SD,
    MIN_MACHINES,
    OUTLIER_Z,
    Drift,
    FleetSummary,
    Outlier,
    ParameterSpread,
    chance_outlier_rate,
    robust_spread,
    robust_z,
    summarise_fleet,
)
from servotune.fleet.table import FLEET_SCHEMA

__all__ = [
    "DRIFT_K",
    "FLEET_CLUSTER_MIN_LOGS",
    "FLEET_SCHEMA",
    "MAD_TO_SD",
    "MIN_MACHINES",
    "OUTLIER_Z",
    "Drift",
    "FleetFitOptions",
    "FleetResult",
    "FleetRow",
    "FleetSpread",
    "FleetSummary",
    "Outlier",
    "ParameterSpread",
    "chance_outlier_rate",
    "fit_fleet",
    "fit_fleet_log",
    "fleet_spread",
    "latest_fits",
    "machine_and_date",
    "read_fleet_table",
    "robust_spread",
    "robust_z",
    "summarise_fleet",
    "write_fleet_table",
]
