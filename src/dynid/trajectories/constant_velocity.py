"""Bidirectional constant-velocity experiments for friction identification (paper 003, Sec. 3.1).

One joint moves at a time while the others hold a pose. For each joint, each speed :math:`v`
of a list and each repetition, the moving joint

1. goes from where it is to the start of the cycle (a quintic rest-to-rest move) and rests;
2. accelerates to :math:`+v`, holds :math:`+v` for ``window`` seconds (the *forward window*),
   switches to :math:`-v`, holds :math:`-v` for ``window`` seconds over the same positions
   backwards (the *backward window*) and decelerates to rest where the cycle started.

Each switch of velocity :math:`v_0 \\to v_1` is a quintic smoothstep in the velocity
(acceleration continuous and zero at both ends; paper 003's switching phases :math:`\\Delta t`
are linear ramps), lasting :math:`\\max(\\Delta t, \\tfrac{15}{8}|v_1 - v_0|/a_{max})` so that the
acceleration stays within ``max_acceleration``. The reversal :math:`+v \\to -v` has zero net
displacement, so both windows cover the same stroke :math:`v\\,T_w`, centred on the joint's pose:
paper 003's pairing of :math:`\\tau(q, \\dot q, 0)` and :math:`\\tau(q, -\\dot q, 0)` at equal positions.
After its last cycle the joint returns to its pose.

The schedule is either one list of ``speeds`` with one ``window`` for every joint (``dynid
simulate``'s ``[trajectory]`` table) or a ``plan``: per joint its own (speed, window) pairs, and
a ``max_acceleration`` per joint (the experiment ``dynid design`` sizes from the limits, see
:func:`dynid.excitation.friction_design.design_constant_velocity`). Both build the same pieces.

:meth:`ConstantVelocityExperiment.labels` marks every instant with the moving joint
(``cv_joint``: 1-based index, 0 while nothing is measured), the speed level (``cv_speed``
[rad/s or m/s]), the window (``cv_direction``: +1 forward, -1 backward, 0 elsewhere: moves,
rests, switching phases) and the repetition (``cv_repetition``, from 1).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.interpolate import PPoly

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["LABEL_COLUMNS", "ConstantVelocityExperiment", "cycle_extent", "default_speeds", "switch_duration"]

LABEL_COLUMNS = ("cv_joint", "cv_speed", "cv_direction", "cv_repetition")

# quintic smoothstep s(x) = 10x^3 - 15x^4 + 6x^5: peak slope 15/8; its integral over [0, 1] is 1/2,
# and the reversal +v -> -v reaches 0.34375 v dt beyond its start (at x = 1/2).
_SMOOTH = np.array([6.0, -15.0, 10.0, 0.0, 0.0, 0.0])
_PEAK = 15.0 / 8.0
_REVERSAL_REACH = 0.34375
# a quintic rest-to-rest move of length D over T: peak velocity 15/8 D/T, peak acceleration 10/sqrt(3) D/T^2
_MOVE_ACC = 10.0 / np.sqrt(3.0)


def default_speeds() -> tuple[float, ...]:
    """Sixteen speeds from 0.002 to 0.8 rad/s, log-spaced (dense at low speed, where the Stribeck
    and smoothing terms act; paper 003, Sec. 4.4 spaces its 37 set points likewise). Sixteen
    leave eight to fit when every other one is held out: two more than the improved Stribeck
    model's six coefficients."""
    return tuple(float(v) for v in np.geomspace(0.002, 0.8, 16))


def switch_duration(dv: float, switch: float, max_acceleration: float) -> float:
    """Duration of a quintic velocity switch of size ``dv``: at least ``switch`` [s] and long
    enough that its peak acceleration :math:`\\tfrac{15}{8}|dv|/\\Delta t` stays within
    ``max_acceleration`` (paper 003, Sec. 3.1's switching phase :math:`\\Delta t`)."""
    return max(switch, _PEAK * abs(dv) / max_acceleration)


def cycle_extent(v: float, window: float, switch: float, max_acceleration: float) -> tuple[float, float]:
    """Positions a cycle at speed ``v`` reaches, relative to its centre: (below, above) [rad or m].

    The windows cover :math:`v\\,T_w` centred on the pose; the start switch adds
    :math:`\\tfrac12 v\\Delta t_a` below and the reversal reaches :math:`0.34375\\,v\\,\\Delta t_r` above."""
    ta, tr = switch_duration(v, switch, max_acceleration), switch_duration(2 * v, switch, max_acceleration)
    start = -(0.5 * v * ta + 0.5 * v * window)
    top = start + 0.5 * v * ta + v * window + _REVERSAL_REACH * v * tr
    return start, top


def _blend(v0: float, v1: float, dt: float) -> np.ndarray:
    scale = np.array([dt**-5, dt**-4, dt**-3, dt**-2, dt**-1, 1.0])
    c = (v1 - v0) * _SMOOTH * scale
    c[-1] += v0
    return c


def _constant(v: float) -> np.ndarray:
    return np.array([0.0, 0.0, 0.0, 0.0, 0.0, v])


def _move(distance: float, dt: float) -> np.ndarray:
    """Velocity of a quintic rest-to-rest move: D/T * 30 x^2 (1 - x)^2, x = t/T."""
    return distance * np.array([0.0, 30.0 / dt**5, -60.0 / dt**4, 30.0 / dt**3, 0.0, 0.0])


@dataclasses.dataclass(frozen=True)
class _Piece:
    duration: float
    coeffs: np.ndarray
    joint: int  # index of the moving joint
    label: tuple[int, float, int, int]  # cv_joint, cv_speed, cv_direction, cv_repetition


@dataclasses.dataclass(frozen=True, eq=False)
class ConstantVelocityExperiment:
    """The friction experiment of paper 003, Sec. 3.1 (see the module docstring).

    Parameters
    ----------
    pose : array, shape (n_joints,)
        Where the joints are held [rad or m]; each stroke is centred on its joint's entry.
    lower, upper : array, shape (n_joints,)
        Position limits [rad or m]; every cycle, switching phases included, stays inside.
    joints : sequence of int
        Indices of the joints to test, in order.
    speeds : sequence of float
        Speed levels [rad/s or m/s], > 0, tested in increasing order (ignored with ``plan``).
    window : float
        Duration of each constant-velocity window [s] (ignored with ``plan``).
    max_acceleration : float or array (n_joints,)
        Largest acceleration of the switching phases and moves [rad/s² or m/s²], one for all
        joints or one per joint.
    switch : float
        Shortest switching phase (paper 003's :math:`\\Delta t`) [s].
    rest : float
        Rest before each cycle [s] (the controller settles after the move).
    repetitions : int
        Cycles per speed (paper 003, Sec. 4.4 repeats each set point).
    names : sequence of str, optional
        Joint names for the messages.
    plan : sequence, optional
        For each entry of ``joints``, its ``(speed, window)`` pairs (speeds distinct, > 0, tested in
        increasing order; windows > 0 [s]); replaces ``speeds`` and ``window``, and ``speeds``
        becomes the sorted union of the plan's speeds.
    """

    pose: FloatArray
    lower: FloatArray
    upper: FloatArray
    joints: tuple[int, ...]
    speeds: tuple[float, ...] = dataclasses.field(default_factory=default_speeds)
    window: float = 2.0
    max_acceleration: float = 5.0
    switch: float = 0.1
    rest: float = 0.3
    repetitions: int = 1
    names: tuple[str, ...] | None = None
    plan: tuple[tuple[tuple[float, float], ...], ...] | None = None

    def __post_init__(self) -> None:
        pose, lo, hi = (np.array(x, dtype=float, ndmin=1) for x in (self.pose, self.lower, self.upper))
        n = pose.size
        if lo.shape != (n,) or hi.shape != (n,):
            raise InputError(f"pose has {n} joints, the limits {lo.size} and {hi.size}")
        names = tuple(self.names) if self.names is not None else tuple(f"joint {k + 1}" for k in range(n))
        joints = tuple(int(j) for j in self.joints)
        if not joints or any(not 0 <= j < n for j in joints) or len(set(joints)) != len(joints):
            raise InputError(f"joints {list(joints)}: give distinct joint indices in 0..{n - 1}")
        if self.plan is None:
            speeds = tuple(sorted(float(v) for v in self.speeds))
            if not speeds or speeds[0] <= 0 or len(set(speeds)) != len(speeds):
                raise InputError(f"speeds {list(self.speeds)}: give distinct positive speeds")
            if not self.window > 0:
                raise InputError(f"window must be positive, got {self.window}")
            plan = tuple(tuple((v, self.window) for v in speeds) for _ in joints)
        else:
            plan = tuple(tuple(sorted((float(v), float(w)) for v, w in p)) for p in self.plan)
            if len(plan) != len(joints):
                raise InputError(f"plan has {len(plan)} entries for {len(joints)} joints")
            for j, p in zip(joints, plan):
                vs = [v for v, _ in p]
                if not p or vs[0] <= 0 or len(set(vs)) != len(vs) or not all(w > 0 for _, w in p):
                    raise InputError(f"plan of {names[j]}: give distinct positive speeds with positive windows")
            speeds = tuple(sorted({v for p in plan for v, _ in p}))
        acc = np.array(self.max_acceleration, dtype=float, ndmin=1)
        if acc.size not in (1, n) or not np.all(acc > 0):
            raise InputError(f"max_acceleration must be positive, one value or one per joint ({n}), got {self.max_acceleration}")
        if not self.switch > 0:
            raise InputError(f"switch must be positive, got {self.switch}")
        if self.rest < 0 or self.repetitions < 1:
            raise InputError("rest must be >= 0 and repetitions >= 1")
        outside = [names[j] for j in range(n) if not lo[j] <= pose[j] <= hi[j]]
        if outside:
            raise InputError(f"the pose {pose.tolist()} is outside the limits of {', '.join(outside)}")
        for name, val in (("pose", pose), ("names", names), ("joints", joints), ("speeds", speeds), ("plan", plan)):
            object.__setattr__(self, name, val)
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)
        pieces = self._pieces()
        starts = np.concatenate([[0.0], np.cumsum([p.duration for p in pieces])])
        velocity = {}
        for j in joints:
            c = np.array([p.coeffs if p.joint == j else np.zeros(6) for p in pieces]).T
            velocity[j] = PPoly(c, starts, extrapolate=False)
        object.__setattr__(self, "_starts", starts)
        object.__setattr__(self, "_pieces_", tuple(pieces))
        object.__setattr__(self, "_velocity", velocity)
        object.__setattr__(self, "_position", {j: v.antiderivative() for j, v in velocity.items()})

    _starts: np.ndarray = dataclasses.field(init=False, repr=False)
    _pieces_: tuple = dataclasses.field(init=False, repr=False)
    _velocity: dict = dataclasses.field(init=False, repr=False)
    _position: dict = dataclasses.field(init=False, repr=False)

    # ------------------------------------------------------------------ construction
    def acceleration(self, joint: int | None = None) -> float:
        """The acceleration limit of joint index ``joint`` (None: of all, when one is given) [rad/s² or m/s²]."""
        acc = np.array(self.max_acceleration, dtype=float, ndmin=1)
        return float(acc[0] if acc.size == 1 else acc[joint])

    def switch_time(self, dv: float, joint: int | None = None) -> float:
        """Duration of a velocity switch of size ``dv`` [s] (of joint index ``joint`` when the
        acceleration limits differ per joint)."""
        return max(self.switch, _PEAK * abs(dv) / self.acceleration(joint))

    def cycle_extent(self, v: float, window: float | None = None, joint: int | None = None) -> tuple[float, float]:
        """Positions a cycle at speed ``v`` with constant-velocity windows of ``window`` seconds
        (default :attr:`window`) reaches, relative to the pose: (below, above) [rad or m]."""
        return cycle_extent(v, self.window if window is None else window, self.switch, self.acceleration(joint))

    def _move_time(self, distance: float, joint: int) -> float:
        vmax = max(v for v, _ in self.plan[self.joints.index(joint)])
        d = abs(distance)
        return max(self.switch, np.sqrt(_MOVE_ACC * d / self.acceleration(joint)), _PEAK * d / vmax)

    def _pieces(self) -> list[_Piece]:
        pieces: list[_Piece] = []
        idle = (0, 0.0, 0, 0)
        for j, plan in zip(self.joints, self.plan):
            q = self.pose[j]
            for v, window in plan:
                lo_rel, hi_rel = self.cycle_extent(v, window, j)
                if self.pose[j] + lo_rel < self.lower[j] or self.pose[j] + hi_rel > self.upper[j]:
                    need = hi_rel - lo_rel
                    raise InputError(
                        f"speed {v:g}: a {window:g} s window at {v:g} on {self.names[j]} needs "
                        f"[{self.pose[j] + lo_rel:.4g}, {self.pose[j] + hi_rel:.4g}] ({need:.3g} wide with the switching "
                        f"phases), outside its limits [{self.lower[j]:.4g}, {self.upper[j]:.4g}] about the pose "
                        f"{self.pose[j]:.4g}; lower the speed, shorten the window or raise max_acceleration")
                ta, tr = self.switch_time(v, j), self.switch_time(2 * v, j)
                for r in range(1, self.repetitions + 1):
                    start = self.pose[j] + lo_rel
                    if abs(start - q) > 0:
                        dt = self._move_time(start - q, j)
                        pieces.append(_Piece(dt, _move(start - q, dt), j, idle))
                    q = start
                    if self.rest > 0:
                        pieces.append(_Piece(self.rest, _constant(0.0), j, idle))
                    lab = lambda d: (j + 1, v, d, r)  # noqa: E731
                    pieces += [
                        _Piece(ta, _blend(0.0, v, ta), j, lab(0)),
                        _Piece(window, _constant(v), j, lab(1)),
                        _Piece(tr, _blend(v, -v, tr), j, lab(0)),
                        _Piece(window, _constant(-v), j, lab(-1)),
                        _Piece(ta, _blend(-v, 0.0, ta), j, lab(0)),
                    ]
            back = self.pose[j] - q
            if abs(back) > 0:
                dt = self._move_time(back, j)
                pieces.append(_Piece(dt, _move(back, dt), j, idle))
            pieces.append(_Piece(max(self.rest, self.switch), _constant(0.0), j, idle))
        return pieces

    # ------------------------------------------------------------------ sampling
    @property
    def duration(self) -> float:
        return float(self._starts[-1])

    def sample(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Positions, velocities, accelerations of all joints at ``t`` (n,): each (n, n_joints);
        before 0 and after :attr:`duration` the joints rest at the pose."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        n = t.size
        q = np.tile(self.pose, (n, 1))
        dq = np.zeros((n, self.pose.size))
        ddq = np.zeros_like(dq)
        tc = np.clip(t, 0.0, self.duration)
        inside = (t >= 0) & (t <= self.duration)
        for j, vel in self._velocity.items():
            q[:, j] += self._position[j](tc)
            dq[:, j] = np.where(inside, vel(tc), 0.0)
            ddq[:, j] = np.where(inside, vel.derivative()(tc), 0.0)
        return q, dq, ddq

    def labels(self, t: FloatArray) -> dict[str, FloatArray]:
        """The columns of :data:`LABEL_COLUMNS` at ``t`` (n,) (see the module docstring)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        k = np.clip(np.searchsorted(self._starts, t, side="right") - 1, 0, len(self._pieces_) - 1)
        table = np.array([p.label for p in self._pieces_], dtype=float)[k]
        table[(t < 0) | (t > self.duration)] = 0.0
        return {name: table[:, i] for i, name in enumerate(LABEL_COLUMNS)}

    def joint_durations(self) -> dict[int, float]:
        """Seconds each tested joint moves or rests in its part of the experiment (joint index -> s)."""
        out = {j: 0.0 for j in self.joints}
        for p in self._pieces_:
            out[p.joint] += p.duration
        return out

    def windows(self) -> list[dict]:
        """Every constant-velocity window: joint index, speed, direction, repetition, start and end [s]."""
        out = []
        for p, t0 in zip(self._pieces_, self._starts[:-1]):
            if p.label[2] != 0:
                out.append({"joint": p.joint, "speed": p.label[1], "direction": p.label[2], "repetition": p.label[3],
                            "start": float(t0), "end": float(t0 + p.duration)})
        return out
