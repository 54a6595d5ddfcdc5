"""The example command lines shown under each verb's ``--help`` (:mod:`servotune.cli.parser`)."""

from __future__ import annotations

__all__ = ["EXAMPLES"]

EXAMPLES = {
    "init": [
        "servotune init                  # plants/: the example rig, configs, specs, HAL map",
        "servotune init my-lab --force   # into my-lab/plants/, replacing edited copies",
    ],
    "rig": ["servotune rig plants/pc-dual-servo.toml", "servotune rig my-rig.toml --json"],
    "simulate": [
        "servotune simulate plants/pc-dual-servo.toml --scenario prbs --axis master "
        "--seconds 20 -o log.csv",
        "servotune simulate plants/pc-dual-servo.toml --input exc.csv --closed-loop -o my.csv",
        "servotune simulate plants/belt-axis.toml --scenario track --shaper zvd -o shaped.csv",
    ],
    "autotune": [
        "servotune autotune plants/linuxcnc-autotune.toml --dry-run   # the plan; touches nothing",
        "servotune autotune plants/linuxcnc-autotune.toml --dry-run --guard-output guard.comp",
    ],
    "shaper": [
        "servotune shaper plants/belt-axis.toml                 # auto: the shortest that holds",
        "servotune shaper plants/belt-axis.toml --kind ei --json",
        "servotune shaper plants/belt-axis.toml --hal-output shaper.comp   # halcompile it",
    ],
    "fit": [
        "servotune fit my.csv --axis master                  # summary on stderr",
        "servotune fit my.csv --axis master -o my-rig.toml   # a new rig named my-rig",
        "servotune fit my.csv --axis master --json --plot fit.png",
        "servotune fit logs/*.csv --axis master --fleet fleet.parquet --fleet-report fleet.html",
        "servotune fit capture.txt --axis x --map cmd=pid.0.output,pos=encoder.0.position "
        "--hal-columns pid.0.output,encoder.0.position --period-s 0.001 "
        "--position-scale 2000   # LinuxCNC halsampler",
        "servotune fit own.csv --axis x --map cmd=drive_volts,pos=encoder,ref=setpoint,"
        "exc=exc_volts,time=t   # your logger's CSV: volts, counts, time [s]",
    ],
    "frf": [
        "servotune frf ms-log.csv --axis master -o frf.json --plot frf.png   # a log of "
        "excite --kind multisine --periods 8, played with the loop closed",
        "servotune frf ms-log.csv --axis master --response position --band 1:60 -o frf.csv",
        "servotune frf ms-log.csv --axis master --modes auto   # and the modes fitted to it",
    ],
    "excite": [
        "servotune excite --rig my-rig.toml --axis master --kind prbs --seconds 40 -o exc.csv",
        "servotune excite --rig my-rig.toml --kind multisine --periods 8 --seconds 80 "
        "--band 0.5:50 -o ms.csv   # periodic, for servotune frf",
    ],
    "tune": [
        "servotune tune my-rig.toml -o tuning.json",
        "servotune tune my-rig.toml -o tuning.json --spec plants/pc-dual-servo.spec.toml",
        "servotune tune plants/gantry.toml -o gantry.tuning.json   # a gantry config",
    ],
    "plan": ["servotune plan plants/linkage-6axis.toml -o linkage.plan.json"],
    "verify": [
        "servotune verify tuning.json --spec plants/pc-dual-servo.spec.toml --report reports",
        "servotune verify gantry.tuning.json --spec plants/gantry.spec.toml",
        "servotune verify linkage.plan.json --spec plants/linkage-6axis.spec.toml",
    ],
    "margins": ["servotune margins tuning.json --pm 50 --gm 6 --ms 1.8"],
    "export-table": [
        "servotune export-table tuning.json -o fuzzy.json",
        "servotune export-table tuning.json --format c -o runtime/",
        "servotune export-table -o fuzzy.json   # the workbench's current tuning",
        "servotune export-table tuning.json --format linuxcnc-hal --position-scale 2000 "
        "-o pid-x.hal",
        "servotune export-table tuning.json --format linuxcnc-comp -o servotune.comp",
    ],
    "check-table": ["servotune check-table fuzzy.json"],
    "demo": [
        "servotune demo plants/pc-dual-servo.toml --out reports",
        "servotune demo plants/pc-dual-servo.toml --out reports --full",
    ],
    "compare": [
        "servotune compare plants/pc-dual-servo.toml --spec plants/pc-dual-servo.spec.toml "
        "--seeds 3 --json > figure4.json",
    ],
    "sync": [
        "servotune sync plants/gantry.toml",
        "servotune sync plants/gantry.toml --montecarlo 200 --plot reports/",
    ],
    "linkage": ["servotune linkage plants/linkage-6axis.toml --json --plot reports/"],
    "warmup": [
        "servotune warmup                          # every kernel, once after an install",
        "servotune warmup simulation               # only what simulate needs",
    ],
}
"""One or more command lines per verb, shown under its ``--help``."""
