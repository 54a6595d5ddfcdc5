"""Machine architectures built from the runtime's axes, one package per architecture.

- :mod:`servotune.arch.linkage`: the multi-CPU linkage of seed 002 (a master interpolating,
  broadcasting command blocks on one serial bus to slave CPUs with their own clocks).
"""
