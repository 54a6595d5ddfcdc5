"""The master's interpolation of the path (ahead of time) and the contour-error search."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from servotune._numba_cache import jit
from servotune.arch.linkage.config import LinkageConfig, Move
from servotune.budget import check_memory, format_count
from servotune.errors import ConfigError

__all__ = [
    "ArcGeometry",
    "Interpolation",
    "contour_distances",
    "interpolate",
]

_CONTOUR_WINDOW = 4000  # largest number of ticks searched either side of the current one
# bytes per master tick and axis: interpolated positions and commands, padded path and
# commands, actual, error (48), with a margin
TICK_BYTES_PER_AXIS = 64
TRACE_BYTES_PER_AXIS = 40  # run_linkage(trace=True): reference, code, positions, speed
TICK_BYTES = 64  # queue traces, move index per tick (and CPU)


@dataclass(frozen=True, slots=True, kw_only=True)
class ArcGeometry:
    """An arc of the path as interpolated.

    Parameters
    ----------
    move : int
        Index of the move in the path's list of moves.
    plane : tuple of int
        Column indices of the plane axes.
    centre : tuple of float
        Centre [counts].
    radius_counts : float
        Programmed radius [counts].
    start_rad, sweep_rad : float
        Start angle and signed swept angle [rad] (> 0: ccw).
    cruise_ticks : tuple of int
        First and last row at the constant (cruise) feed; the whole move if the profile is
        triangular.
    """

    move: int
    plane: tuple[int, int]
    centre: tuple[float, float]
    radius_counts: float
    start_rad: float
    sweep_rad: float
    cruise_ticks: tuple[int, int]


@dataclass(frozen=True, slots=True, kw_only=True)
class Interpolation:
    """The master's interpolated path: one position per axis per tick.

    Attributes
    ----------
    period_s : float
        Tick period [s].
    axis_names : tuple of str
    positions : ndarray, shape (ticks, axes)
        Programmed position at ``k · period_s`` [counts] (row 0: the start, all 0).
    commands : ndarray of int64, shape (ticks, axes)
        ``positions`` rounded to whole counts: what is broadcast [counts]. Each move's last
        row is its target exactly.
    move_of_tick : ndarray of int64, shape (ticks,)
        The move each row belongs to (row 0 belongs to move 0).
    move_ends : tuple of int
        Last row of each move (it starts at the previous move's last row).
    feeds_cps : tuple of float
        Feed of each move after clamping to the limits [counts/s].
    lengths_counts : tuple of float
        Path length of each move in the space of all axes [counts].
    move_axes : ndarray of bool, shape (moves, axes)
        The axes a move's contour error is measured in (arc: its plane; line: the axes it moves).
    arcs : tuple of ArcGeometry
    """

    period_s: float
    axis_names: tuple[str, ...]
    positions: np.ndarray
    commands: np.ndarray
    move_of_tick: np.ndarray
    move_ends: tuple[int, ...]
    feeds_cps: tuple[float, ...]
    lengths_counts: tuple[float, ...]
    move_axes: np.ndarray
    arcs: tuple[ArcGeometry, ...]

    @property
    def n_ticks(self) -> int:
        """Rows (ticks) including the start row."""
        return int(self.positions.shape[0])

    @property
    def duration_s(self) -> float:
        """Time from the start to the end of the last move [s]."""
        return (self.n_ticks - 1) * self.period_s

    def move_start_tick(self, m: int) -> int:
        """Row where move ``m`` starts (the previous move's last row; 0 for the first)."""
        return 0 if m == 0 else self.move_ends[m - 1]


def _trapezoid(
    length: float, feed: float, accel: float, t: np.ndarray
) -> tuple[np.ndarray, float, float, float]:
    """Distance along a move at times ``t`` [s], duration, ramp and cruise times [s].

    Rest to rest: accelerate at ``accel``, cruise at ``feed``, decelerate; a move too short to
    reach the feed is triangular with peak ``sqrt(accel · length)``.
    """
    if feed * feed / accel <= length:
        t_a = feed / accel
        t_c = (length - feed * feed / accel) / feed
    else:
        feed = math.sqrt(accel * length)
        t_a = feed / accel
        t_c = 0.0
    dur = 2.0 * t_a + t_c
    d_a = 0.5 * accel * t_a * t_a
    s = np.where(
        t < t_a,
        0.5 * accel * t * t,
        np.where(t < t_a + t_c, d_a + feed * (t - t_a), length - 0.5 * accel * (dur - t) ** 2),
    )
    return np.clip(np.where(t >= dur, length, s), 0.0, length), dur, t_a, t_c


def _check_ticks(config: LinkageConfig, ticks: float, where: str) -> None:
    """Refuse a path whose interpolation up to ``where`` (``ticks`` long) exceeds the budget."""
    n_ax = config.n_axes
    per_tick = n_ax * TICK_BYTES_PER_AXIS + TICK_BYTES
    check_memory(
        ticks * per_tick,
        f"linkage {config.name!r}: interpolating the path up to {where}",
        f"{format_count(ticks)} ticks of {config.period_s:g} s × {per_tick} bytes",
    )


@dataclass(frozen=True, slots=True)
class _Circle:
    """The circle an arc move runs on, as :func:`_arc_circle` resolves it."""

    plane: tuple[int, int]  # column indices of the plane axes
    cx: float
    cy: float
    r: float  # radius [counts]
    th0: float  # start angle [rad]
    sign: float  # 1.0: ccw, -1.0: cw
    sweep: float  # unsigned swept angle [rad]


def _arc_circle(
    mv: Move, pos: np.ndarray, end: np.ndarray, col: dict[str, int], where: str
) -> _Circle:
    """The circle of an arc from ``pos``; sets ``end``'s plane axes where ``angle_deg`` puts
    them (an end given by ``to`` must lie on the circle within 1 count)."""
    assert mv.plane is not None and mv.centre is not None
    plane = (col[mv.plane[0]], col[mv.plane[1]])
    i, j = plane
    cx, cy = float(mv.centre[0]), float(mv.centre[1])
    r = math.hypot(pos[i] - cx, pos[j] - cy)
    if r < 1.0:
        raise ConfigError(
            f"{where}: the arc starts at its centre ({cx:g}, {cy:g}) [counts]; the "
            f"start must lie on the circle"
        )
    th0 = math.atan2(pos[j] - cy, pos[i] - cx)
    sign = 1.0 if mv.direction == "ccw" else -1.0
    if mv.angle_deg is not None:
        sweep = math.radians(mv.angle_deg)
        if math.isclose(math.remainder(mv.angle_deg, 360.0), 0.0, abs_tol=1e-9):
            end[i], end[j] = pos[i], pos[j]  # whole turns end where they start
        else:
            end[i] = cx + r * math.cos(th0 + sign * sweep)
            end[j] = cy + r * math.sin(th0 + sign * sweep)
    else:
        r_end = math.hypot(end[i] - cx, end[j] - cy)
        if abs(r_end - r) > 1.0:
            raise ConfigError(
                f"{where}: the arc's start is {r:.1f} counts from the centre but its "
                f"end {r_end:.1f}: not on one circle (within 1 count)"
            )
        th1 = math.atan2(end[j] - cy, end[i] - cx)
        sweep = (sign * (th1 - th0)) % (2.0 * math.pi)
        if sweep < 1e-9:
            sweep = 2.0 * math.pi  # end = start: a full circle
    return _Circle(plane=plane, cx=cx, cy=cy, r=r, th0=th0, sign=sign, sweep=sweep)


def _arc_length_and_feed(
    c: _Circle, pos: np.ndarray, end: np.ndarray, feed: float, accel: float
) -> tuple[float, float]:
    """An arc's path length in the space of all axes (helical) [counts] and its feed clamped
    so that the centripetal acceleration in its plane stays within ``accel`` [counts/s]."""
    i, j = c.plane
    others = end - pos
    others[[i, j]] = 0.0
    arc_len = c.r * c.sweep
    length = math.hypot(arc_len, float(np.sqrt(np.sum(others * others))))
    # centripetal acceleration in the plane (speed there = feed · arc_len / length)
    feed = min(feed, math.sqrt(accel * c.r) * length / arc_len)
    return length, feed


def _arc_rows(seg: np.ndarray, c: _Circle, u: np.ndarray) -> None:
    """Put an arc's plane axes on its circle in the sampled rows ``seg`` (``u``: the fraction
    of the path length at each row)."""
    i, j = c.plane
    th = c.th0 + u * c.sign * c.sweep
    seg[:, i] = c.cx + c.r * np.cos(th)
    seg[:, j] = c.cy + c.r * np.sin(th)


def _arc_geometry(
    m: int, c: _Circle, tick: int, n: int, t_a: float, t_c: float, period: float
) -> ArcGeometry:
    """The :class:`ArcGeometry` of move ``m``, starting at row ``tick`` and ``n`` rows long."""
    c0, c1 = math.ceil(t_a / period - 1e-9), math.floor((t_a + t_c) / period + 1e-9)
    cruise = (tick + c0, tick + c1) if c1 > c0 else (tick, tick + n)
    return ArcGeometry(
        move=m,
        plane=c.plane,
        centre=(c.cx, c.cy),
        radius_counts=c.r,
        start_rad=c.th0,
        sweep_rad=c.sign * c.sweep,
        cruise_ticks=cruise,
    )


def interpolate(config: LinkageConfig) -> Interpolation:
    """Interpolate the path, as the master does before motion.

    Every move runs from rest to rest with a trapezoidal feed profile (accelerate at
    ``max_accel_cps2``, cruise, decelerate; triangular if too short). The feed is clamped to
    ``max_feed_cps`` and, for an arc, so that the centripetal acceleration in its plane stays
    within ``max_accel_cps2``. Lines are linear in every axis; arcs are circular in their plane
    while the other axes named in ``to`` move linearly (helical interpolation), the feed being
    along the path in the space of all axes. The profile is sampled every period; each move
    takes a whole number of ticks (its last tick reaches the target exactly) and the next move
    starts there.

    Parameters
    ----------
    config : LinkageConfig

    Returns
    -------
    Interpolation

    Raises
    ------
    ConfigError
        If a move does not move, or an arc's start and end are not on one circle (radii
        differing by more than 1 count) or its start is at its centre.

    Examples
    --------
    >>> from servotune.arch.linkage import load_linkage
    >>> from servotune.rig import EXAMPLE_RIG_PATH
    >>> cfg = load_linkage(EXAMPLE_RIG_PATH.parent / "linkage-6axis.toml")
    >>> ip = interpolate(cfg)
    >>> ip.commands.shape[1], ip.commands[0].tolist() == [0] * 6
    (6, True)
    """
    names = config.axis_names
    col = {n: i for i, n in enumerate(names)}
    period = config.period_s
    accel = config.path.max_accel_cps2
    pos = np.zeros(len(names))
    rows: list[np.ndarray] = [pos.copy()[None, :]]
    move_of: list[np.ndarray] = [np.zeros(1, dtype=np.int64)]
    ends: list[int] = []
    feeds: list[float] = []
    lengths: list[float] = []
    arcs: list[ArcGeometry] = []
    move_axes = np.zeros((len(config.path.moves), len(names)), dtype=bool)
    tick = 0
    for m, mv in enumerate(config.path.moves):
        where = f"path.move[{m}]"
        if mv.kind == "dwell":
            assert mv.dwell_s is not None
            _check_ticks(config, tick + mv.dwell_s / period, where)
            n = max(1, round(mv.dwell_s / period))
            rows.append(np.repeat(pos[None, :], n, axis=0))
            move_of.append(np.full(n, m, dtype=np.int64))
            move_axes[m] = True  # a dwell's contour is the distance to the held point
            tick += n
            ends.append(tick)
            feeds.append(0.0)
            lengths.append(0.0)
            continue
        assert mv.feed_cps is not None
        end = pos.copy()
        for ax, v in mv.to.items():
            end[col[ax]] = float(v)
        feed = min(mv.feed_cps, config.path.max_feed_cps)
        circle: _Circle | None = None
        if mv.kind == "line":
            delta = end - pos
            length = float(np.sqrt(np.sum(delta * delta)))
            move_axes[m] = delta != 0.0
        else:
            circle = _arc_circle(mv, pos, end, col, where)
            length, feed = _arc_length_and_feed(circle, pos, end, feed, accel)
            move_axes[m, list(circle.plane)] = True
        if length <= 0.0:
            raise ConfigError(f"{where}: the move does not move any axis (length 0 counts)")
        with np.errstate(over="ignore", invalid="ignore"):  # an absurd move: refused below
            _, dur, t_a, t_c = _trapezoid(length, feed, accel, np.zeros(1))
        _check_ticks(config, tick + dur / period, where)
        n = max(1, math.ceil(dur / period - 1e-9))
        t = np.arange(1, n + 1, dtype=np.int64) * period
        s, *_ = _trapezoid(length, feed, accel, t)
        u = s / length
        seg = pos[None, :] + u[:, None] * (end - pos)[None, :]
        if circle is not None:
            _arc_rows(seg, circle, u)
            arcs.append(_arc_geometry(m, circle, tick, n, t_a, t_c, period))
        seg[-1] = end
        rows.append(seg)
        move_of.append(np.full(n, m, dtype=np.int64))
        tick += n
        ends.append(tick)
        feeds.append(feed)
        lengths.append(length)
        pos = end
    positions = np.concatenate(rows)
    commands = np.rint(positions).astype(np.int64)
    return Interpolation(
        period_s=period,
        axis_names=names,
        positions=positions,
        commands=commands,
        move_of_tick=np.concatenate(move_of),
        move_ends=tuple(ends),
        feeds_cps=tuple(feeds),
        lengths_counts=tuple(lengths),
        move_axes=move_axes,
        arcs=tuple(arcs),
    )


@jit
def contour_distances(path, actual, move_of_tick, move_axes):
    """Distance from each actual point to the programmed polyline, near the current tick."""
    n, n_ax = actual.shape
    n_p = path.shape[0]
    # segments that move: skip runs of equal points quickly
    nxt = np.empty(n_p, dtype=np.int64)
    nxt[n_p - 1] = n_p - 1
    for j in range(n_p - 2, -1, -1):
        same = True
        for a in range(n_ax):
            if path[j + 1, a] != path[j, a]:
                same = False
                break
        nxt[j] = nxt[j + 1] if same else j
    prv = np.empty(n_p, dtype=np.int64)
    prv[0] = 0
    for j in range(1, n_p):
        same = True
        for a in range(n_ax):
            if path[j, a] != path[j - 1, a]:
                same = False
                break
        prv[j] = prv[j - 1] if same else j
    seg_max = 0.0
    for j in range(n_p - 1):
        d2 = 0.0
        for a in range(n_ax):
            d = path[j + 1, a] - path[j, a]
            d2 += d * d
        if d2 > seg_max:
            seg_max = d2
    seg_max = math.sqrt(seg_max)
    out = np.empty(n)
    for k in range(n):
        kk = min(k, n_p - 1)
        m = move_of_tick[kk]
        d2 = 0.0
        for a in range(n_ax):
            if move_axes[m, a]:
                d = actual[k, a] - path[kk, a]
                d2 += d * d
        best = math.sqrt(d2)
        reach = 2.0 * best + seg_max + 1.0
        for direction in (1, -1):
            j = kk if direction == 1 else kk - 1
            steps = 0
            while 0 <= j < n_p - 1 and steps < _CONTOUR_WINDOW:
                if direction == 1:
                    j = nxt[j]
                    if j >= n_p - 1:
                        break
                else:
                    j = prv[j + 1] - 1 if prv[j + 1] > 0 else j
                    if j < 0:
                        break
                # segment j -> j+1 in the move's axes
                ab = 0.0
                aq = 0.0
                far0 = 0.0
                far1 = 0.0
                for a in range(n_ax):
                    if move_axes[m, a]:
                        da = path[j + 1, a] - path[j, a]
                        dq = actual[k, a] - path[j, a]
                        ab += da * da
                        aq += da * dq
                        f0 = path[j, a] - path[kk, a]
                        f1 = path[j + 1, a] - path[kk, a]
                        far0 += f0 * f0
                        far1 += f1 * f1
                u = aq / ab if ab > 0.0 else 0.0
                u = min(max(u, 0.0), 1.0)
                d2 = 0.0
                for a in range(n_ax):
                    if move_axes[m, a]:
                        d = actual[k, a] - (path[j, a] + u * (path[j + 1, a] - path[j, a]))
                        d2 += d * d
                d = math.sqrt(d2)
                if d < best:
                    best = d
                if far0 > reach * reach and far1 > reach * reach:
                    break
                j += direction
                steps += 1
        out[k] = best
    return out
