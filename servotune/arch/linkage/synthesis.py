"""Tuning of the linkage's axes: the PI gains a linkage config leaves out
(docs/systems.md#multi-cpu-linkage).

:func:`axis_gains` tells every axis's gains (given, the file's, or tuned with
:func:`~servotune.tune.pi.tune_pi`); :func:`resolve_gains` fills them into the config. A loader
only loads (:func:`~servotune.arch.linkage.config.load_linkage`) and a runner only runs
(:func:`~servotune.arch.linkage.run.run_linkage` refuses an axis without gains): the caller
resolves, ``run_linkage(resolve_gains(load_linkage(path)))``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from servotune.arch.linkage.config import LinkageConfig
from servotune.errors import ConfigError
from servotune.laws.pi import PIGains
from servotune.tune.pi import DEFAULT_TARGETS, tune_pi
from servotune.validate import show_value

__all__ = ["TUNE_TARGETS", "AxisGains", "axis_gains", "resolve_gains"]

TUNE_TARGETS = DEFAULT_TARGETS
"""Robustness targets of :func:`~servotune.tune.pi.tune_pi` for axes without explicit gains."""


@dataclass(frozen=True, slots=True, kw_only=True)
class AxisGains:
    """The PI gains one axis runs with (:func:`axis_gains`).

    Attributes
    ----------
    gains : PIGains
        ``kp`` [codes/count], ``ki`` [codes/(count·s)].
    tuned : bool
        True if tuned with :func:`~servotune.tune.pi.tune_pi` (the file gave none).
    """

    gains: PIGains
    tuned: bool

    def to_dict(self) -> dict[str, Any]:
        """Plain dict: ``kp``, ``ki``, ``tuned``."""
        return {"ki": float(self.gains.ki), "kp": float(self.gains.kp), "tuned": self.tuned}


def axis_gains(
    config: LinkageConfig, given: Mapping[str, PIGains] | None = None
) -> dict[str, AxisGains]:
    """PI gains of every axis: ``given``, else the config's, else tuned.

    An axis without gains is tuned with :func:`~servotune.tune.pi.tune_pi` at the linkage's
    ``period_s``, the rig's ``compute_s`` and D/A step, with its output filters in the loop,
    for :data:`TUNE_TARGETS` (phase margin 50°, gain margin 8 dB, max sensitivity 1.6); about a
    second per axis. Nothing is cached.
    The config's gains count as tuned if :func:`resolve_gains` tuned them
    (:attr:`~servotune.arch.linkage.config.LinkageAxis.gains_tuned`).

    Parameters
    ----------
    config : LinkageConfig
    given : mapping of str to PIGains, optional
        Gains by axis name that override the config's.

    Returns
    -------
    dict of str to AxisGains
        By axis name, in column order.

    Raises
    ------
    ConfigError
        If ``given`` names an axis that does not exist.
    """
    given = dict(given or {})
    bad = sorted(set(given) - set(config.axis_names))
    if bad:
        raise ConfigError(
            f"gains for unknown axis {show_value(bad[0])}; axes: {list(config.axis_names)}"
        )
    out: dict[str, AxisGains] = {}
    for a in config.axes:
        if a.name in given:
            out[a.name] = AxisGains(gains=given[a.name], tuned=False)
            continue
        if a.gains is not None:
            out[a.name] = AxisGains(gains=a.gains, tuned=a.gains_tuned)
            continue
        r = tune_pi(
            a.plant,
            period_s=config.period_s,
            compute_s=config.rig.timer.compute_s,
            lsb_v=config.rig.dac.lsb_v,
            filters=config.axis_filters(a.name),
            **TUNE_TARGETS,
        )
        out[a.name] = AxisGains(gains=r.gains, tuned=True)
    return out


def resolve_gains(
    config: LinkageConfig, given: Mapping[str, PIGains] | None = None
) -> LinkageConfig:
    """The config with every axis's PI gains filled in (:func:`axis_gains`): ``given``, else
    the config's, else tuned with :func:`~servotune.tune.pi.tune_pi`.

    An axis whose gains were tuned here is marked
    (:attr:`~servotune.arch.linkage.config.LinkageAxis.gains_tuned`), so a run shows it as
    tuned (:attr:`~servotune.arch.linkage.result.AxisResult.tuned`); a config already resolved
    comes back unchanged. Nothing is cached.

    Parameters
    ----------
    config : LinkageConfig
    given : mapping of str to PIGains, optional
        Gains by axis name that override the config's (not marked as tuned).

    Returns
    -------
    LinkageConfig
        Every axis with ``kp`` and ``ki``.

    Raises
    ------
    ConfigError
        If ``given`` names an axis that does not exist or holds a gain out of range (the
        message names ``axis.<name>.kp``).
    """
    gains = axis_gains(config, given)
    axes = []
    for a in config.axes:
        g = gains[a.name]
        try:
            axes.append(replace(a, kp=g.gains.kp, ki=g.gains.ki, gains_tuned=g.tuned))
        except ConfigError as exc:
            raise ConfigError(f"axis.{a.name}.{exc}") from None
    return replace(config, axes=tuple(axes))
