"""Tests of the gantry (servotune.arch.gantry, seed 003)."""
