"""A designed constant-velocity friction experiment (paper 003, Sec. 3.1 and 4.4), sized from limits.

Paper 003 drives each joint alone, forward and back at constant speed, over a list of speeds
dense at the low end (Sec. 4.4 lists 37 set points from 0.0001 to 45 deg/s, each cycle 12 s),
and takes friction as :math:`F_f(v) = \\tfrac12[\\tau(q, v, 0) - \\tau(q, -v, 0)]` at matched
positions. :func:`design_constant_velocity` decides, per joint, what that experiment can be
inside given position, velocity and acceleration limits:

* the **speeds**: given, or ``n_speeds`` log-spaced over ``speed_range`` (default: from the
  joint's velocity limit :math:`v_{max}` down to :math:`v_{max}/400`, the span of ``dynid
  simulate``'s default list 0.002 to 0.8 rad/s); a speed above the velocity limit is an error;
* the **stroke** :math:`S` (span of the constant-velocity windows, symmetric about the joint's
  pose): given, or the largest whose whole cycle (the quintic switching phases' overshoot
  included, :func:`~dynid.trajectories.constant_velocity.cycle_extent`) stays inside the position
  limits at the fastest speed that still gets ``window`` seconds of steady motion over it;
* each speed's **steady time** :math:`T_v = \\min(S/v, T_{max})` (``max_window``): the fast
  speeds cross the whole stroke, the slow ones run :math:`T_{max}` seconds on its middle (a
  full stroke at 0.002 rad/s would take minutes); with ``min_span`` :math:`s` given, each speed
  gets instead the shortest steady time that covers :math:`s`, within the same bounds:
  :math:`T_v = \\min(\\max(T_{min}, s/v), T_{max}, S/v)` (``window`` :math:`T_{min}`): long windows
  only at the low speeds, where a controller's position transient :math:`e` makes the measured
  speed off by about :math:`e/(vT)` and where Eq. 15's :math:`K_v` is decided
  (:math:`\\arctan(K_v v)` saturates above a few :math:`1/K_v`), short ones elsewhere; a speed
  with :math:`\\min(S/v, T_{max})` below ``window``, or whose cycle leaves the limits, is
  **dropped with a line saying why** (never silently); a joint left without speeds is an error;
* the **switching phases** from the joint's acceleration limit (a quintic velocity switch of
  :math:`\\Delta v` lasts :math:`\\max(\\Delta t, \\tfrac{15}{8}|\\Delta v|/a_{max})`);
* the **matched samples** per speed at the output rate: the forward window's samples after
  ``skip`` seconds whose positions the backward window also covers after its own ``skip``,
  i.e. those in :math:`[t_0 + \\text{skip}, t_1 - \\text{skip}]`; fewer than ``min_samples``
  (the friction extraction's own threshold, :func:`dynid.signals.friction_points.extract_friction_points`)
  drops the speed.

The trajectory itself is :class:`~dynid.trajectories.constant_velocity.ConstantVelocityExperiment`
with a per-joint ``plan``: the generator of ``dynid simulate``'s ``constant_velocity`` kind.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError
from dynid.trajectories.constant_velocity import ConstantVelocityExperiment, cycle_extent

__all__ = ["FrictionDesign", "JointSchedule", "SpeedLevel", "design_constant_velocity", "matched_samples"]

SPEED_SPAN = 400.0
"""Default ratio of the top speed to the lowest (0.8 / 0.002, ``dynid simulate``'s default list)."""


@dataclasses.dataclass(frozen=True)
class SpeedLevel:
    """One speed of a joint: ``speed`` [rad/s or m/s], ``window`` (steady seconds per direction),
    ``span`` (positions the windows cover, ``speed * window``), ``samples`` (forward-window
    samples at the output rate) and ``matched`` (those left for the extraction's pairing)."""

    speed: float
    window: float
    span: float
    samples: int
    matched: int


@dataclasses.dataclass(frozen=True)
class JointSchedule:
    """One joint's part of the experiment."""

    index: int
    name: str
    stroke: float
    velocity_limit: float
    acceleration_limit: float
    levels: tuple[SpeedLevel, ...]
    dropped: tuple[str, ...]
    duration: float  # seconds of the experiment this joint moves in (moves, rests and returns included)


@dataclasses.dataclass(frozen=True, eq=False)
class FrictionDesign:
    experiment: ConstantVelocityExperiment
    joints: tuple[JointSchedule, ...]
    rate_hz: float
    skip: float
    min_samples: int
    window: float
    max_window: float
    min_span: float | None = None

    @property
    def duration(self) -> float:
        return self.experiment.duration

    @property
    def dropped(self) -> tuple[str, ...]:
        return tuple(line for j in self.joints for line in j.dropped)


def matched_samples(start: float, end: float, skip: float, rate_hz: float) -> tuple[int, int]:
    """Samples ``k / rate_hz`` of a window ``[start, end]`` [s]: all of them, and those in
    ``[start + skip, end - skip]`` (see the module docstring)."""
    def count(a: float, b: float) -> int:
        if b < a:
            return 0
        return max(0, int(np.floor(b * rate_hz + 1e-9)) - int(np.ceil(a * rate_hz - 1e-9)) + 1)

    return count(start, end), count(start + skip, end - skip)


def _per_joint(value, n: int, what: str, names) -> np.ndarray:
    arr = np.array(value, dtype=float, ndmin=1)
    if arr.size == 1:
        return np.full(n, float(arr[0]))
    if arr.size != n:
        raise InputError(f"{what} has {arr.size} entries for {n} {names}")
    return arr


def design_constant_velocity(names, pose: FloatArray, lower: FloatArray, upper: FloatArray, velocity, acceleration, *,
                             joints=None, speeds=None, speed_range=None, n_speeds: int = 16, stroke=None,
                             window: float = 2.0, max_window: float = 6.0, switch: float = 0.1, rest: float = 0.3,
                             repetitions: int = 1, skip: float = 0.5, min_samples: int = 10,
                             rate_hz: float = 100.0, min_span: float | None = None) -> FrictionDesign:
    """Size paper 003's constant-velocity experiment from limits (see the module docstring).

    Parameters
    ----------
    names : sequence of str
        The robot's joint names.
    pose, lower, upper : arrays (n_joints,)
        Where the idle joints rest and each stroke is centred; position limits [rad or m].
    velocity, acceleration : float or arrays (n_joints,)
        Velocity and acceleration limits.
    joints : sequence of str, optional
        Joints to test, in order (default all).
    speeds : sequence of float, optional
        The speed levels of every tested joint; else ``n_speeds`` log-spaced over ``speed_range``
        ((low, high); default per joint (v_max / 400, v_max)).
    stroke : float or sequence (one per tested joint), optional
        Span of the constant-velocity windows [rad or m]; default the largest that fits.
    window, max_window : float
        Least and most steady seconds per speed and direction.
    min_span : float, optional
        Least span [rad or m] each window should cover: the steady seconds become
        ``min(max(window, min_span / v), max_window, stroke / v)`` (module docstring); default
        None: ``min(stroke / v, max_window)``.
    switch, rest, repetitions
        As :class:`~dynid.trajectories.constant_velocity.ConstantVelocityExperiment`.
    skip, min_samples : float, int
        The friction extraction's settings (``dynid friction``: seconds left out at the start of
        each window, fewest paired samples).
    rate_hz : float
        Rate at which the samples are counted (the output rate).
    """
    names = tuple(names)
    n = len(names)
    pose, lower, upper = (np.array(x, dtype=float, ndmin=1) for x in (pose, lower, upper))
    vel = _per_joint(velocity, n, "the velocity limit", "joints")
    acc = _per_joint(acceleration, n, "the acceleration limit", "joints")
    joints = tuple(names) if joints is None else tuple(joints)
    if not joints:
        raise InputError("no joints to test: name at least one")
    unknown = [j for j in joints if j not in names]
    if unknown:
        raise InputError(f"joints {unknown} are not joints of the robot ({', '.join(names)})")
    if len(set(joints)) != len(joints):
        raise InputError(f"joints {list(joints)} names a joint twice")
    outside = [f"{nm} = {p:g} not in [{a:g}, {b:g}]" for nm, p, a, b in zip(names, pose, lower, upper) if not a < p < b]
    if outside:
        raise InputError(f"pose: not strictly inside the position limits: {'; '.join(outside)}")
    if min_span is not None and not min_span > 0:
        raise InputError(f"min_span = {min_span:g}: give a positive span [rad or m]")
    if not max_window >= window:
        raise InputError(f"max_window = {max_window:g} s is shorter than window = {window:g} s")
    if (window - 2 * skip) * rate_hz < min_samples:
        raise InputError(f"window = {window:g} s leaves about {max(0.0, (window - 2 * skip) * rate_hz):.0f} matched samples "
                         f"at {rate_hz:g} Hz after skip = {skip:g} s at each end; the friction extraction needs "
                         f"min_samples = {min_samples}: lengthen the window, raise the rate or lower skip")
    idx = [names.index(j) for j in joints]
    strokes = None
    if stroke is not None:
        strokes = _per_joint(stroke, len(idx), "stroke", "joints tested")
    if speeds is not None:
        too_fast = [(names[k], v) for k in idx for v in speeds if v > vel[k]]
        if too_fast:
            nm, v = too_fast[0]
            raise InputError(f"speed {v:g} is above the velocity limit {vel[names.index(nm)]:g} of {nm}")
    if speed_range is not None:
        too_fast = [names[k] for k in idx if speed_range[1] > vel[k]]
        if too_fast:
            raise InputError(f"speed_range reaches {speed_range[1]:g}, above the velocity limit of "
                             f"{too_fast[0]} ({vel[names.index(too_fast[0])]:g})")
    plan, schedules_in = [], []
    for i, k in enumerate(idx):
        nm, below, above = names[k], pose[k] - lower[k], upper[k] - pose[k]
        if speeds is not None:
            cand = [float(v) for v in sorted(speeds)]
        else:
            lo_v, hi_v = speed_range if speed_range is not None else (vel[k] / SPEED_SPAN, vel[k])
            cand = [float(hi_v)] if n_speeds == 1 else [float(v) for v in np.geomspace(lo_v, hi_v, n_speeds)]
        dropped: list[str] = []
        gone: set[float] = set()

        def fits(v: float, steady: float) -> tuple[bool, float, float]:
            a, b = cycle_extent(v, steady, switch, acc[k])
            return pose[k] + a >= lower[k] and pose[k] + b <= upper[k], pose[k] + a, pose[k] + b

        if strokes is not None:
            s_k = float(strokes[i])
            if s_k > 2 * min(below, above):
                raise InputError(f"stroke {s_k:g} of {nm} exceeds {2 * min(below, above):.4g}, the largest symmetric "
                                 f"stroke about its pose {pose[k]:g} inside [{lower[k]:g}, {upper[k]:g}]")
        else:
            s_k = None
            for v in sorted(cand, reverse=True):
                # the cycle at v: S/2 + v*ta/2 below the pose, S/2 + 0.34375 v tr above it (cycle_extent)
                a, b = cycle_extent(v, 0.0, switch, acc[k])
                largest = 2 * min(below + a, above - b) * (1 - 1e-12)
                if largest >= v * window:
                    s_k = largest
                    break
                gone.add(v)
                dropped.append(f"{nm}: speed {v:.4g} dropped: {window:g} s at it need a stroke of {v * window:.4g} "
                               f"and its switching phases leave at most {max(largest, 0.0):.4g} inside the limits")
            if s_k is None:
                raise InputError(f"{nm}: no speed gets {window:g} s of steady motion inside [{lower[k]:g}, {upper[k]:g}] "
                                 f"about {pose[k]:g} (the slowest, {min(cand):.4g}, included)")
        levels = []
        for v in cand:
            if v in gone:
                continue
            steady = float(min(s_k / v, max_window))
            if min_span is not None and steady >= window:
                steady = float(min(max(window, min_span / v), steady))
            if steady < window:
                dropped.append(f"{nm}: speed {v:.4g} dropped: the stroke {s_k:.4g} takes {s_k / v:.3g} s at it, "
                               f"less than window = {window:g} s")
                continue
            ok, a, b = fits(v, steady)
            if not ok:
                dropped.append(f"{nm}: speed {v:.4g} dropped: its cycle needs [{a:.4g}, {b:.4g}], outside the limits "
                               f"[{lower[k]:g}, {upper[k]:g}]")
                continue
            levels.append((v, steady))
        if not levels:
            raise InputError(f"{nm}: no speed fits at the stroke {s_k:g} ({dropped[-1] if dropped else 'none given'})")
        plan.append(tuple(levels))
        schedules_in.append((k, nm, s_k, tuple(dropped)))
    exp = ConstantVelocityExperiment(pose=pose, lower=lower, upper=upper, joints=tuple(idx), plan=tuple(plan),
                                     max_acceleration=acc, switch=switch, rest=rest, repetitions=repetitions,
                                     names=names)
    # count the samples of every forward window (repetition 1; the others are equal in length)
    wins = {(w["joint"], w["speed"]): w for w in exp.windows() if w["direction"] > 0 and w["repetition"] == 1}
    durations = exp.joint_durations()
    schedules = []
    for (k, nm, s_k, dropped), levels in zip(schedules_in, plan):
        out, more = [], []
        for v, steady in levels:
            w = wins[(k, v)]
            total, matched = matched_samples(w["start"], w["end"], skip, rate_hz)
            if matched < min_samples:  # the window check above makes this rare (sampling phase)
                more.append(f"{nm}: speed {v:.4g} keeps {matched} matched samples at {rate_hz:g} Hz, fewer than "
                            f"min_samples = {min_samples}")
            out.append(SpeedLevel(v, steady, v * steady, total, matched))
        if more:
            raise InputError(more[0] + "; lengthen window")
        schedules.append(JointSchedule(k, nm, float(s_k), float(vel[k]), float(acc[k]),
                                       tuple(out), tuple(dropped), durations[k]))
    return FrictionDesign(exp, tuple(schedules), float(rate_hz), float(skip), int(min_samples), float(window),
                          float(max_window), None if min_span is None else float(min_span))
