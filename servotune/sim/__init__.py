"""Simulation: the one home of the axis tick (:mod:`servotune.sim.tick`).

The single-rig engine (:mod:`servotune.sim.engine`), the gantry (:mod:`servotune.arch.gantry`) and
the linkage (:mod:`servotune.arch.linkage`) compose their kernels from the same compiled steps;
each adds only its scheduling and routing.
"""
