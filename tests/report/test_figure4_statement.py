"""The Figure-4 statement is derived from the measured numbers (issue 18, point 5): swapping the
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
        "The composite law does not win on the objective: 1096 against PID + feedforward's 1007"
        in said
    )
    assert "contrary to the seed's Figure 4" in said
    assert "max sync error: composite is lowest" in said
    assert "RMS sync error: PID + feedforward is lowest" in said
    # swap the objective of composite and pid_ff: the verdict turns
    swapped = {k: dict(v) for k, v in TABLE.items()}
    swapped["composite"]["itae"], swapped["pid_ff"]["itae"] = 1007.0, 1096.0
    turned = figure4_statement(swapped)
    assert (
        "The composite law wins on the objective: 1007 against PID + feedforward's 1096" in turned
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
