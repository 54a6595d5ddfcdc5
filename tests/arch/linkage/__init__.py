"""Tests of the multi-CPU linkage (servotune.arch.linkage; docs/systems.md)."""
