"""Analysis of the linear loops, below the tuners and the verification that both use it:
:mod:`~servotune.analysis.margins` (every loop's stability margins on the discrete loop as the
runtime runs it, and the fast grid screen the tuners search with) and
:mod:`~servotune.analysis.plant_cases` (the plant sets robustness is judged over)."""
