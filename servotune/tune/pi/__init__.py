"""PI design for a position axis.

:func:`pi_loop_shaping` is a closed-form loop-shaping rule used where no tuning exists yet; it
places the crossover where the phase margin target is met given the axis lag
(:mod:`~servotune.tune.pi.shaping`).

:func:`tune_pi` is the synthesis: the largest integral gain under the robustness constraints the
user gives (phase margin, gain margin, peak sensitivity, crossover bound), on the exact discrete
loop, solved as a constrained NLP with casadi/ipopt; every number it reports is re-checked with
python-control. :func:`tune_pi_axis` does the same for one axis of a rig. Its parts, each
importing only those before it:

- :mod:`~servotune.tune.pi.spec`: the targets (:data:`DEFAULT_TARGETS`), their checks and the
  result (:class:`PITuning`);
- :mod:`~servotune.tune.pi.grid`: the discrete plant model, the frequency grids, the grid
  margins and the start point;
- :mod:`~servotune.tune.pi.nlp`: the casadi NLP for one crossing structure of the loop;
- :mod:`~servotune.tune.pi.check`: the re-checks (direct and by python-control) of a design;
- :mod:`~servotune.tune.pi.design`: :func:`tune_pi` and :func:`tune_pi_axis`.
"""

from servotune.tune.pi.design import tune_pi, tune_pi_axis
from servotune.tune.pi.shaping import pi_loop_shaping
from servotune.tune.pi.spec import DEFAULT_TARGETS, PITuning

__all__ = ["DEFAULT_TARGETS", "PITuning", "pi_loop_shaping", "tune_pi", "tune_pi_axis"]
