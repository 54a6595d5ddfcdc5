"""Tests of the architectures (servotune.arch), mirroring the package."""
