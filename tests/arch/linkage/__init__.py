"""Tests of the multi-CPU linkage (servotune.arch.linkage, seed 002)."""
