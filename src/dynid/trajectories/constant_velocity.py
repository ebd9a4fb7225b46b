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

__all__ = ["LABEL_COLUMNS", "ConstantVelocityExperiment", "default_speeds"]

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
        Speed levels [rad/s or m/s], > 0, tested in increasing order.
    window : float
        Duration of each constant-velocity window [s].
    max_acceleration : float
        Largest acceleration of the switching phases and moves [rad/s² or m/s²].
    switch : float
        Shortest switching phase (paper 003's :math:`\\Delta t`) [s].
    rest : float
        Rest before each cycle [s] (the controller settles after the move).
    repetitions : int
        Cycles per speed (paper 003, Sec. 4.4 repeats each set point).
    names : sequence of str, optional
        Joint names for the messages.
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

    def __post_init__(self) -> None:
        pose, lo, hi = (np.array(x, dtype=float, ndmin=1) for x in (self.pose, self.lower, self.upper))
        n = pose.size
        if lo.shape != (n,) or hi.shape != (n,):
            raise InputError(f"pose has {n} joints, the limits {lo.size} and {hi.size}")
        names = tuple(self.names) if self.names is not None else tuple(f"joint {k + 1}" for k in range(n))
        joints = tuple(int(j) for j in self.joints)
        if not joints or any(not 0 <= j < n for j in joints) or len(set(joints)) != len(joints):
            raise InputError(f"joints {list(joints)}: give distinct joint indices in 0..{n - 1}")
        speeds = tuple(sorted(float(v) for v in self.speeds))
        if not speeds or speeds[0] <= 0 or len(set(speeds)) != len(speeds):
            raise InputError(f"speeds {list(self.speeds)}: give distinct positive speeds")
        for key in ("window", "max_acceleration", "switch"):
            if not getattr(self, key) > 0:
                raise InputError(f"{key} must be positive, got {getattr(self, key)}")
        if self.rest < 0 or self.repetitions < 1:
            raise InputError("rest must be >= 0 and repetitions >= 1")
        outside = [names[j] for j in range(n) if not lo[j] <= pose[j] <= hi[j]]
        if outside:
            raise InputError(f"the pose {pose.tolist()} is outside the limits of {', '.join(outside)}")
        for name, val in (("pose", pose), ("names", names), ("joints", joints), ("speeds", speeds)):
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
    def switch_time(self, dv: float) -> float:
        """Duration of a velocity switch of size ``dv`` [s]."""
        return max(self.switch, _PEAK * abs(dv) / self.max_acceleration)

    def cycle_extent(self, v: float) -> tuple[float, float]:
        """Positions a cycle at speed ``v`` reaches, relative to the pose: (below, above) [rad or m]."""
        ta, tr = self.switch_time(v), self.switch_time(2 * v)
        start = -(0.5 * v * ta + 0.5 * v * self.window)
        top = start + 0.5 * v * ta + v * self.window + _REVERSAL_REACH * v * tr
        return start, top

    def _move_time(self, distance: float) -> float:
        vmax = max(self.speeds)
        d = abs(distance)
        return max(self.switch, np.sqrt(_MOVE_ACC * d / self.max_acceleration), _PEAK * d / vmax)

    def _pieces(self) -> list[_Piece]:
        pieces: list[_Piece] = []
        idle = (0, 0.0, 0, 0)
        for j in self.joints:
            q = self.pose[j]
            for v in self.speeds:
                lo_rel, hi_rel = self.cycle_extent(v)
                if self.pose[j] + lo_rel < self.lower[j] or self.pose[j] + hi_rel > self.upper[j]:
                    need = hi_rel - lo_rel
                    raise InputError(
                        f"speed {v:g}: a {self.window:g} s window at {v:g} on {self.names[j]} needs "
                        f"[{self.pose[j] + lo_rel:.4g}, {self.pose[j] + hi_rel:.4g}] ({need:.3g} wide with the switching "
                        f"phases), outside its limits [{self.lower[j]:.4g}, {self.upper[j]:.4g}] about the pose "
                        f"{self.pose[j]:.4g}; lower the speed, shorten the window or raise max_acceleration")
                ta, tr = self.switch_time(v), self.switch_time(2 * v)
                for r in range(1, self.repetitions + 1):
                    start = self.pose[j] + lo_rel
                    if abs(start - q) > 0:
                        pieces.append(_Piece(self._move_time(start - q), _move(start - q, self._move_time(start - q)), j, idle))
                    q = start
                    if self.rest > 0:
                        pieces.append(_Piece(self.rest, _constant(0.0), j, idle))
                    lab = lambda d: (j + 1, v, d, r)  # noqa: E731
                    pieces += [
                        _Piece(ta, _blend(0.0, v, ta), j, lab(0)),
                        _Piece(self.window, _constant(v), j, lab(1)),
                        _Piece(tr, _blend(v, -v, tr), j, lab(0)),
                        _Piece(self.window, _constant(-v), j, lab(-1)),
                        _Piece(ta, _blend(-v, 0.0, ta), j, lab(0)),
                    ]
            back = self.pose[j] - q
            if abs(back) > 0:
                pieces.append(_Piece(self._move_time(back), _move(back, self._move_time(back)), j, idle))
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

    def windows(self) -> list[dict]:
        """Every constant-velocity window: joint index, speed, direction, repetition, start and end [s]."""
        out = []
        for p, t0 in zip(self._pieces_, self._starts[:-1]):
            if p.label[2] != 0:
                out.append({"joint": p.joint, "speed": p.label[1], "direction": p.label[2], "repetition": p.label[3],
                            "start": float(t0), "end": float(t0 + p.duration)})
        return out
