"""The Figure-4 statement is derived from the measured numbers
(docs/systems.md#figure-4): swapping the
numbers changes the words."""

from __future__ import annotations

from servotune.report.text import figure4_statement

TABLE = {
    "pid": {"itae": 1500.0, "max_sync_counts": 2100.0, "rms_sync_counts": 700.0,
            "rise_s": 0.080, "settling_s": 0.300},
    "pid_ff": {"itae": 1007.0, "max_sync_counts": 1400.0, "rms_sync_counts": 480.0,
               "rise_s": 0.076, "settling_s": 0.250},
    "composite": {"itae": 1096.0, "max_sync_counts": 1300.0, "rms_sync_counts": 490.0,
                  "rise_s": 0.076, "settling_s": 0.260},
}  # fmt: skip


def test_the_statement_follows_the_numbers() -> None:
    said = figure4_statement(TABLE)
    assert (
        "The composite law does not win on the objective: 1096 counts·s² against PID + "
        "feedforward's 1007 counts·s²" in said
    )
    assert "contrary to the seed's Figure 4" in said
    assert "max sync error: composite is lowest" in said
    assert "RMS sync error: PID + feedforward is lowest" in said
    # swap the objective of composite and pid_ff: the verdict turns
    swapped = {k: dict(v) for k, v in TABLE.items()}
    swapped["composite"]["itae"], swapped["pid_ff"]["itae"] = 1007.0, 1096.0
    turned = figure4_statement(swapped)
    assert (
        "The composite law wins on the objective: 1007 counts·s² against PID + feedforward's "
        "1096 counts·s²" in turned
    )
    assert "as the seed's Figure 4 claims" in turned and "does not win" not in turned
    assert turned != said


def test_a_tie_is_called_a_tie() -> None:
    said = figure4_statement(TABLE).splitlines()
    assert said[3].startswith("rise time: PID + feedforward and composite tie (")


def test_every_metric_names_its_winner_with_all_values() -> None:
    lines = figure4_statement(TABLE).splitlines()
    assert lines[0].startswith("ITAE of the sync error (the tuning objective): PID + feedforward")
    assert "PID 1500, PID + feedforward 1007, composite 1096 counts·s²" in lines[0]
    assert lines[4] == (
        "settling time: PID + feedforward is lowest (PID 300, PID + feedforward 250, "
        "composite 260 ms)"
    )


HELD_OUT = {s: {**row, "heldout_max_sync_counts": v, "heldout_pass_pct": p}
            for (s, row), v, p in zip(TABLE.items(), (1900.0, 1200.0, 1250.0),
                                      (90.0, 100.0, 95.0), strict=True)}  # fmt: skip


def test_held_out_figures_get_their_own_verdict() -> None:
    said = figure4_statement(HELD_OUT)
    assert "held out: worst max sync error: PID + feedforward is lowest" in said
    # a share of passing plant sets: higher is better
    assert "held out: plant sets keeping every limit: PID + feedforward is highest" in said
    assert (
        "The composite law does not win on the held-out scenarios' worst max sync error: "
        "1250 counts against PID + feedforward's 1200 counts"
    ) in said
    swapped = {k: dict(v) for k, v in HELD_OUT.items()}
    swapped["composite"]["heldout_max_sync_counts"] = 1100.0
    turned = figure4_statement(swapped)
    assert (
        "The composite law wins on the held-out scenarios' worst max sync error: 1100 "
        "counts against PID + feedforward's 1200 counts"
    ) in turned


def test_a_lead_inside_the_spread_over_seeds_is_not_a_clear_win() -> None:
    table = {k: dict(v) for k, v in TABLE.items()}
    table["composite"]["itae"] = 1000.0  # ahead of PID + feedforward's 1007 on average
    spread = {s: {"itae": (row["itae"] - 20.0, row["itae"] + 20.0)} for s, row in table.items()}
    said = figure4_statement(table, spread)
    assert "The composite law is ahead on the objective on average" in said
    assert "not clearly: the ranges over the seeds overlap" in said
    assert "composite 1000 (980–1020)" in said and "over the seeds in brackets" in said
    apart = {s: {"itae": (row["itae"] - 2.0, row["itae"] + 2.0)} for s, row in table.items()}
    said = figure4_statement(table, apart)
    assert "The composite law wins on the objective: 1000 counts·s²" in said


def test_a_structure_without_a_feasible_tuning_is_named() -> None:
    table = {k: dict(v) for k, v in TABLE.items()}
    table["pid"]["itae"] = None  # JSON's inf
    said = figure4_statement(table)
    assert "No tuning within the constraints and budget for PID" in said
    assert (
        "ITAE of the sync error (the tuning objective): PID + feedforward is lowest (PID + " in said
    )
