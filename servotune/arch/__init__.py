"""Machine architectures built from the runtime's axes, one package per architecture.

- :mod:`servotune.arch.gantry`: the fieldbus gantry (two drives on a beam, the
  slave listening to the master's command and feedback on the bus, a sync compensator).
- :mod:`servotune.arch.linkage`: the multi-CPU linkage (a master interpolating,
  broadcasting command blocks on one serial bus to slave CPUs with their own clocks).

Both are described in docs/systems.md.
"""
