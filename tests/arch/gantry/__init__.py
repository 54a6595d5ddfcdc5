"""Tests of the gantry (servotune.arch.gantry; docs/systems.md)."""
