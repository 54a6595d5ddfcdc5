"""EMPS logs: a real drive's data (MATLAB ``.mat``), read and converted to servotune's log model.

The EMPS (Electro-Mechanical Positioning System) is a linear axis — a drive moving a load along
a line, its position measured at the load in metres — logged at 1 ms while a known position loop
held it (A. Janot, M. Gautier, M. Brunot, "Data Set and Reference Models of EMPS", Workshop on
Nonlinear System Identification Benchmarks, Eindhoven 2019). Each file holds the column vectors
``t`` [s], ``qm`` (load position) [m], ``qg`` (reference position) [m], ``vir`` (drive command)
[V], the scalars ``kp`` [1/s], ``kv`` [V/(m/s)] and ``gtau`` [N/V] and, in the PULSES
experiment, ``pulses_N``.
:func:`read_emps` reads one into an :class:`EmpsLog`; :meth:`EmpsLog.to_log` gives the
:class:`servotune.logs.Log` that :func:`servotune.fit` takes (command, position in counts of
:data:`ENCODER_QUANTUM_M`, reference, pulses as excitation), :meth:`EmpsLog.fit_inputs` the
arguments of :func:`servotune.identify.fit_arrays`.

Physics: the EMPS model is servotune's axis model
-------------------------------------------------
The benchmark's model of the drive (the inverse model its IDIM-LS scripts estimate) is, with the
load speed ``v`` [m/s]::

    m · dv/dt = gtau · vir − Fv · v − Fc · sign(v) − offset

(mass ``m`` [kg], viscous friction ``Fv`` [N/(m/s)], Coulomb friction ``Fc`` [N], a constant
force ``offset`` [N], the drive's force constant ``gtau`` [N/V]). Dividing by ``Fv``::

    (m / Fv) · dv/dt + v = (gtau / Fv) · (vir − offset / gtau − (Fc / gtau) · sign(v))

which is the axis model (docs/formats.md#axis-model),
``tau · dv/dt + v = K · (u + offset_v − coulomb_v · sign(v))``, with ``u = vir`` and the speed
in counts/s (``v / q``, ``q`` = :data:`ENCODER_QUANTUM_M` = 5e-8 m per count):

==============  ====================  ================================================
servotune       EMPS                  units
==============  ====================  ================================================
gain_cps_per_v  ``gtau / (Fv · q)``   [N/V] / ([N·s/m] · [m/count]) = counts/s per V
tau_s           ``m / Fv``            [kg] / [N·s/m] = s
coulomb_v       ``Fc / gtau``         [N] / [N/V] = V
offset_v        ``−offset / gtau``    [N] / [N/V] = V
==============  ====================  ================================================

(``gtau / Fv`` alone is the gain in (m/s)/V; ``1 / q`` = 2e7 counts/m converts it.) The drive
has no delay term in the benchmark's model; servotune's ``delay_s`` may still be fitted. The
asymmetric form of the axis model (a gain and a Coulomb level per direction) maps the same way
per direction (:class:`EmpsPhysics`). :data:`REFERENCE_MODEL` holds the benchmark's own
estimate, in these units through :meth:`EmpsPhysics.to_plant`.

The PULSES experiment
---------------------
``pulses_N`` (a 0/5 square wave, 0.5 s on in every second) is labelled "force pulses sent to
the EMPS, in newtons". In the logged data they are part of the logged drive command: ``vir``
equals the known loop law (:attr:`EmpsLog.loop_command_v`, the data README's formula) plus
1.014 V per unit of ``pulses_N`` (residual 0.005 V rms), so the logged ``vir`` is the command
the motor received, pulses included. (The label does not fit the size: a 5 N pulse would be
5 / gtau = 0.14 V, the logged step is 5.07 V.) This module therefore treats the pulses as a
measured input: they are in ``cmd_v`` already and are not added a second time, so a fit and a
comparison may use the whole log, pulse stretches included. Being known and independent of
the drive's disturbances, they are also what logs call the excitation the law adds
(docs/decisions.md#5-excitation-is-logged): :meth:`EmpsLog.to_log` carries them as ``exc_code`` (at
:data:`PULSE_V_PER_UNIT`), so an instrumental-variable fit may build instruments from them.
The PULSES file's ``qm`` is not on the encoder grid (rounding it to counts moves it by at
most half a count, 2.5e-8 m; :attr:`EmpsLog.grid_error_counts` says by how much).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.io

from servotune.errors import LogFormatError
from servotune.hw import dac as hw_dac
from servotune.io.files import read_bytes
from servotune.io.log import AxisLog, Log
from servotune.plant import Plant
from servotune.validate import check_number, show_value

__all__ = [
    "AXIS_NAME",
    "ENCODER_QUANTUM_M",
    "LOG_DAC_BITS",
    "LOG_DAC_RANGE_V",
    "MODEL_FRICTION",
    "MODEL_STRUCTURE",
    "PULSE_V_PER_UNIT",
    "REFERENCE_MODEL",
    "EmpsLog",
    "EmpsPhysics",
    "read_emps",
]

ENCODER_QUANTUM_M = 5e-8
"""One encoder count at the load [m] (the data README: 50,000 counts per revolution)."""
PULSE_V_PER_UNIT = 1.0
"""Drive command per unit of ``pulses_N`` [V] (the logged ``vir`` steps by 1.014 V per unit)."""
LOG_DAC_BITS = 16
"""D/A resolution :meth:`EmpsLog.to_log` states for its ``exc_code`` column (a code is 0.3 mV;
the EMPS's own D/A is not documented)."""
LOG_DAC_RANGE_V = (-10.0, 10.0)
"""D/A range of that log [V]: the EMPS drive command saturates at ±10 V."""
MODEL_STRUCTURE = "offset,coulomb"
"""The benchmark's rigid model as a :func:`servotune.fit` ``structure``: gain, tau, offset and
Coulomb friction (no delay)."""
MODEL_FRICTION = "sym"
"""The benchmark's rigid model's :func:`servotune.fit` ``friction`` form: the same gain and
Coulomb level both ways."""
AXIS_NAME = "emps"
"""Name of the axis in the :class:`~servotune.logs.Log` built by :meth:`EmpsLog.to_log`."""

_SIGNALS = {"t": "time_logged_s", "qm": "pos_m", "qg": "ref_m", "vir": "cmd_v"}
_CONSTANTS = {"kp": "kp_per_s", "kv": "kv_v_s_per_m", "gtau": "gtau_n_per_v"}
_PULSES = "pulses_N"
_UNIFORM_RTOL = 0.01  # a time stamp may be off its tick by 1 % of the period
_GRID_TOL_COUNTS = 1e-3  # within this of an integer count, a position is on the encoder grid


@dataclass(frozen=True, slots=True, kw_only=True)
class EmpsPhysics:
    """The EMPS drive in physical units (the benchmark's rigid model), per direction optional.

    Parameters
    ----------
    mass_kg : float
        Moving mass [kg], > 0.
    viscous_n_s_per_m : float
        Viscous friction ``Fv`` [N/(m/s)], > 0 (moving positive; both ways if symmetric).
    coulomb_n : float
        Coulomb friction ``Fc`` [N], >= 0 (moving positive; both ways if symmetric).
    offset_n : float
        Constant force ``offset`` subtracted from the drive force [N].
    viscous_neg_n_s_per_m, coulomb_neg_n : float or None
        The negative direction's ``Fv`` [N/(m/s)] and ``Fc`` [N]; None: as the positive one.
    """

    mass_kg: float
    viscous_n_s_per_m: float
    viscous_neg_n_s_per_m: float | None = None
    coulomb_n: float
    coulomb_neg_n: float | None = None
    offset_n: float

    def __post_init__(self) -> None:
        check_number("mass_kg", self.mass_kg, "kg", strict=True)
        check_number("viscous_n_s_per_m", self.viscous_n_s_per_m, "N/(m/s)", strict=True)
        check_number("coulomb_n", self.coulomb_n, "N")
        check_number("offset_n", self.offset_n, "N", lo=-math.inf)
        if self.viscous_neg_n_s_per_m is not None:
            check_number(
                "viscous_neg_n_s_per_m", self.viscous_neg_n_s_per_m, "N/(m/s)", strict=True
            )
        if self.coulomb_neg_n is not None:
            check_number("coulomb_neg_n", self.coulomb_neg_n, "N")

    def to_plant(self, gtau_n_per_v: float) -> Plant:
        """The same drive as servotune's axis model, position in encoder counts.

        Parameters
        ----------
        gtau_n_per_v : float
            Drive force constant [N/V] (the log's ``gtau``).

        Returns
        -------
        Plant
            ``gain = gtau / (Fv · q)`` [counts/s/V], ``tau = m / Fv`` [s],
            ``coulomb = Fc / gtau`` [V], ``offset = −offset / gtau`` [V] (per direction where
            given); no delay, friction-free drive speed limit.

        Examples
        --------
        >>> p = EmpsPhysics(mass_kg=100.0, viscous_n_s_per_m=200.0, coulomb_n=20.0, offset_n=-4.0)
        >>> q = p.to_plant(40.0)
        >>> round(q.gain_cps_per_v), q.tau_s, q.coulomb_v, q.offset_v
        (4000000, 0.5, 0.5, 0.1)
        """
        g = float(gtau_n_per_v)
        extra: dict[str, float] = {}
        if self.viscous_neg_n_s_per_m is not None:
            extra["gain_neg_cps_per_v"] = g / (self.viscous_neg_n_s_per_m * ENCODER_QUANTUM_M)
        if self.coulomb_neg_n is not None:
            extra["coulomb_neg_v"] = self.coulomb_neg_n / g
        return Plant(
            gain_cps_per_v=g / (self.viscous_n_s_per_m * ENCODER_QUANTUM_M),
            tau_s=self.mass_kg / self.viscous_n_s_per_m,
            offset_v=-self.offset_n / g,
            coulomb_v=self.coulomb_n / g,
            **extra,
        )

    @classmethod
    def from_plant(cls, plant: Plant, gtau_n_per_v: float) -> EmpsPhysics:
        """The physical parameters of an axis model in counts (the inverse of :meth:`to_plant`).

        The mass is ``tau · Fv`` with the positive direction's ``Fv``; the plant's delay, speed
        limit and noise have no counterpart and are left out.
        """
        g = float(gtau_n_per_v)
        fv = g / (plant.gain_cps_per_v * ENCODER_QUANTUM_M)
        g_neg, c_neg = plant.gain_neg_cps_per_v, plant.coulomb_neg_v
        return cls(
            mass_kg=plant.tau_s * fv,
            viscous_n_s_per_m=fv,
            coulomb_n=plant.coulomb_v * g,
            offset_n=-plant.offset_v * g,
            viscous_neg_n_s_per_m=None if g_neg is None else g / (g_neg * ENCODER_QUANTUM_M),
            coulomb_neg_n=None if c_neg is None else c_neg * g,
        )

    def to_dict(self) -> dict[str, float | None]:
        """Plain dict of the fields (for JSON)."""
        return {name: getattr(self, name) for name in sorted(self.__slots__)}


REFERENCE_MODEL = EmpsPhysics(
    mass_kg=95.1089, viscous_n_s_per_m=203.5034, coulomb_n=20.3935, offset_n=-3.1648
)
"""The benchmark's own estimate of the rigid model (IDIM-LS, an inverse-model least squares on
``DATA_EMPS.mat``) as the data set's simulation scripts use it (``M1, Fv1, Fc1, OF1`` in
``Simulation_EMPS_Validation.m``; Janot et al. 2019): a second opinion, not the truth."""


@dataclass(frozen=True, slots=True, kw_only=True)
class EmpsLog:
    """One EMPS experiment, in the units the file uses, with conversions to servotune's.

    Attributes
    ----------
    period_s : float
        Sample period [s]: the mean step of ``t``, rounded to 6 significant digits (the stamps
        jitter by about 2e-8 s around their ticks).
    time_logged_s : ndarray of float
        The file's time stamps ``t`` [s] (:attr:`time_s` is the uniform time base).
    pos_m : ndarray of float
        Load position ``qm`` [m].
    ref_m : ndarray of float
        Reference position ``qg`` [m].
    cmd_v : ndarray of float
        Drive command ``vir`` [V] (force = ``gtau_n_per_v · cmd_v``; in the PULSES experiment it
        includes the pulses).
    force_pulses_n : ndarray of float or None
        The file's ``pulses_N`` [N, as the file labels them] where present, else None.
    kp_per_s : float
        Position-loop gain ``kp`` [1/s].
    kv_v_s_per_m : float
        Speed-loop gain ``kv`` [V/(m/s)].
    gtau_n_per_v : float
        Drive force constant ``gtau`` [N/V].
    path : str
        The file it was read from (``""`` if built in memory).
    """

    period_s: float
    time_logged_s: np.ndarray
    pos_m: np.ndarray
    ref_m: np.ndarray
    cmd_v: np.ndarray
    force_pulses_n: np.ndarray | None = None
    kp_per_s: float
    kv_v_s_per_m: float
    gtau_n_per_v: float
    path: str = ""

    def __post_init__(self) -> None:
        check_number("period_s", self.period_s, "s", strict=True, error=LogFormatError)
        check_number("kp_per_s", self.kp_per_s, "1/s", strict=True, error=LogFormatError)
        check_number(
            "kv_v_s_per_m", self.kv_v_s_per_m, "V/(m/s)", strict=True, error=LogFormatError
        )
        check_number("gtau_n_per_v", self.gtau_n_per_v, "N/V", strict=True, error=LogFormatError)
        n = np.shape(self.time_logged_s)
        if len(n) != 1 or n[0] < 3:
            raise LogFormatError(
                f"time_logged_s must be 1-D with at least 3 samples, got shape {n}"
            )
        for name in ("pos_m", "ref_m", "cmd_v", "force_pulses_n"):
            a = getattr(self, name)
            if a is None:
                continue
            if np.shape(a) != n:
                raise LogFormatError(
                    f"{name} has shape {np.shape(a)}, time_logged_s has {n} (one value per sample)"
                )
            bad = ~np.isfinite(a)
            if bad.any():
                raise LogFormatError(f"{name} is not finite at sample {int(np.argmax(bad))}")

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.time_logged_s.shape[0])

    @property
    def time_s(self) -> np.ndarray:
        """Uniform time base [s]: the integer sample index times :attr:`period_s`."""
        return np.arange(self.n_samples, dtype=np.int64) * self.period_s

    @property
    def pos_counts(self) -> np.ndarray:
        """Load position in encoder counts (``qm / 5e-8`` rounded to the nearest) [counts]."""
        return _counts(self.pos_m)

    @property
    def ref_counts(self) -> np.ndarray:
        """Reference position in encoder counts, rounded to the nearest [counts]."""
        return _counts(self.ref_m)

    @property
    def grid_error_counts(self) -> float:
        """Largest distance of ``qm`` from the encoder grid [counts] (0 for an encoder reading;
        up to 0.5 for positions that are not on it)."""
        c = self.pos_m / ENCODER_QUANTUM_M
        return float(np.max(np.abs(c - np.rint(c))))

    @property
    def on_encoder_grid(self) -> bool:
        """True if every ``qm`` is a whole number of counts (within 1e-3 count)."""
        return self.grid_error_counts <= _GRID_TOL_COUNTS

    @property
    def loop_command_v(self) -> np.ndarray:
        """What the position loop commands [V], from the logged positions (data README)::

            vir(k) = kv · (kp · (qg(k) − qm(k)) − dq(k)),  dq(k) = (qf(k) − qf(k−1)) / dt,
            qf(k) = (qm(k) + qm(k−1)) / 2

        NaN at the first two samples (the speed needs ``qm(k−2)``).
        """
        out = np.full(self.n_samples, np.nan)
        dq = (self.pos_m[2:] - self.pos_m[:-2]) / (2.0 * self.period_s)
        out[2:] = self.kv_v_s_per_m * (self.kp_per_s * (self.ref_m[2:] - self.pos_m[2:]) - dq)
        return out

    @property
    def injected_v(self) -> np.ndarray:
        """What was added to the loop's command before the drive: ``cmd_v − loop_command_v`` [V]
        (about 0 in ``DATA_EMPS``; the pulses in ``DATA_EMPS_PULSES``). NaN where
        :attr:`loop_command_v` is."""
        return self.cmd_v - self.loop_command_v

    @property
    def pulses_v(self) -> np.ndarray | None:
        """The pulses as drive command [V] (``pulses_N`` times :data:`PULSE_V_PER_UNIT`), or None
        where the file has none. Already part of :attr:`cmd_v`."""
        if self.force_pulses_n is None:
            return None
        return self.force_pulses_n * PULSE_V_PER_UNIT

    def to_log(self) -> Log:
        """The experiment as a one-axis :class:`~servotune.logs.Log` (axis :data:`AXIS_NAME`).

        ``cmd_v`` is the drive command as logged [V] (pulses included), ``pos_counts`` and
        ``ref_counts`` the positions in counts, and where the file has pulses, ``exc_code`` the
        pulses in the log's D/A codes (:attr:`pulses_v` over one D/A step, rounded). No compute
        time is known: a fitted delay counts from the sample instant.
        """
        pulses = self.pulses_v
        lsb_v = hw_dac.lsb_v(LOG_DAC_BITS, LOG_DAC_RANGE_V)
        exc = None if pulses is None else np.rint(pulses / lsb_v).astype(np.int64)
        axis = AxisLog(
            cmd_v=self.cmd_v,
            pos_counts=self.pos_counts,
            ref_counts=self.ref_counts,
            exc_code=exc,
            name=AXIS_NAME,
        )
        return Log(
            period_s=self.period_s,
            axes={AXIS_NAME: axis},
            metadata={"machine_id": "EMPS"},
            dac_bits=LOG_DAC_BITS,
            dac_range_v=LOG_DAC_RANGE_V,
            path=self.path,
        )

    def fit_inputs(self) -> dict[str, Any]:
        """Keyword arguments for :func:`servotune.identify.fit_arrays`: ``cmd_v`` [V],
        ``pos_counts`` [counts], ``period_s`` [s], ``ref_counts`` [counts] and ``exc_v``
        (:attr:`pulses_v` [V], None without pulses)."""
        return {
            "cmd_v": self.cmd_v,
            "pos_counts": self.pos_counts,
            "period_s": self.period_s,
            "ref_counts": self.ref_counts,
            "exc_v": self.pulses_v,
        }


def read_emps(path: str | Path) -> EmpsLog:
    """Read an EMPS data file (MATLAB v5 ``.mat``, :func:`scipy.io.loadmat`).

    Parameters
    ----------
    path : str or Path
        ``DATA_EMPS.mat`` or ``DATA_EMPS_PULSES.mat`` (or a file with the same variables).

    Returns
    -------
    EmpsLog

    Raises
    ------
    LogFormatError
        One line naming the file: it is missing or unreadable, not a MATLAB file, lacks one of
        ``t, qm, qg, vir, kp, kv, gtau``, holds a non-numeric, non-vector or non-finite one,
        vectors of different lengths, a non-uniform time column or a non-positive constant.
    """
    src = str(path)
    raw = read_bytes(path, LogFormatError, "EMPS file")
    try:
        mat = scipy.io.loadmat(io.BytesIO(raw))
    except Exception as exc:  # loadmat fails on damaged bytes with many exception kinds
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LogFormatError(
            f"EMPS file {src!r} is not a readable MATLAB .mat file ({show_value(why, 80)})"
        ) from None
    missing = [k for k in (*_SIGNALS, *_CONSTANTS) if k not in mat]
    if missing:
        raise LogFormatError(
            f"EMPS file {src!r} has no variable {', '.join(missing)} (an EMPS file holds "
            f"{', '.join((*_SIGNALS, *_CONSTANTS))} and optionally {_PULSES})"
        )
    fields: dict[str, Any] = {}
    for key, name in _SIGNALS.items():
        fields[name] = _vector(mat[key], key, src)
    fields["force_pulses_n"] = _vector(mat[_PULSES], _PULSES, src) if _PULSES in mat else None
    for key, name in _CONSTANTS.items():
        fields[name] = _scalar(mat[key], key, src)
    n = {key: fields[name].size for key, name in _SIGNALS.items()}
    if fields["force_pulses_n"] is not None:
        n[_PULSES] = fields["force_pulses_n"].size
    if len(set(n.values())) != 1:
        raise LogFormatError(f"EMPS file {src!r}: the vectors differ in length {n}")
    fields["period_s"] = _period(fields["time_logged_s"], src)
    try:
        return EmpsLog(**fields, path=src)
    except LogFormatError as exc:
        raise LogFormatError(f"EMPS file {src!r}: {exc}") from None


def _counts(x_m: np.ndarray) -> np.ndarray:
    return np.rint(x_m / ENCODER_QUANTUM_M).astype(np.int64)


def _numeric(value: object, key: str, src: str) -> np.ndarray:
    a = np.asarray(value)
    if a.dtype.kind not in "biuf":
        raise LogFormatError(
            f"EMPS file {src!r}: variable {key!r} is not a real numeric array "
            f"(MATLAB class gives numpy dtype {a.dtype})"
        )
    return a


def _vector(value: object, key: str, src: str) -> np.ndarray:
    a = _numeric(value, key, src)
    if sum(d > 1 for d in a.shape) > 1 or a.size < 3:
        raise LogFormatError(
            f"EMPS file {src!r}: variable {key!r} must be a vector of at least 3 samples, "
            f"got shape {a.shape}"
        )
    v = np.ascontiguousarray(a.ravel(), dtype=np.float64)
    bad = ~np.isfinite(v)
    if bad.any():
        raise LogFormatError(
            f"EMPS file {src!r}: variable {key!r} is not finite at sample {int(np.argmax(bad))}"
        )
    v.setflags(write=False)
    return v


def _scalar(value: object, key: str, src: str) -> float:
    a = _numeric(value, key, src)
    if a.size != 1:
        raise LogFormatError(f"EMPS file {src!r}: {key!r} must be one number, got shape {a.shape}")
    return float(a.ravel()[0])


def _period(t: np.ndarray, src: str) -> float:
    step = (t[-1] - t[0]) / (t.size - 1)
    if not (math.isfinite(step) and step > 0):
        raise LogFormatError(f"EMPS file {src!r}: time 't' does not increase")
    dev = np.abs(t - t[0] - np.arange(t.size) * step)
    k = int(np.argmax(dev))
    if dev[k] > _UNIFORM_RTOL * step:
        raise LogFormatError(
            f"EMPS file {src!r}: time 't' is not uniform: sample {k} is {dev[k]:.3g} s off the "
            f"mean step {step:.6g} s (more than 1 %)"
        )
    return float(f"{step:.6g}")
