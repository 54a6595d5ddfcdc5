"""Bit-true models of the rig hardware: 8253 timer, PCL833-style counter, PCL728-style D/A.

Pure, vectorised functions (numpy in, numpy out) plus the scalar kernels the closed-loop engine
compiles in; the identifier uses the same unwrap to read logs and the exporter the same constants.
"""

from servotune.hw import counter, dac, timer

__all__ = ["counter", "dac", "timer"]
