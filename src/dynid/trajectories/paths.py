"""More trajectories with analytic position, velocity and acceleration (issue 4, item 1).

Every class here has ``sample(t) -> (x, dx, ddx)``, arrays of shape (n, dim), and a
``duration`` [s] like :class:`~dynid.trajectories.FourierTrajectory`:

* :class:`FourierQuintic`: a Fourier series plus one quintic polynomial per coordinate so
  that velocity and acceleration are zero at both ends and the end position equals the
  start position (paper 003, Section 4.2: Fourier + quintic excitation);
* :class:`BidirectionalVelocity`: constant-velocity segments of alternating sign with
  smooth switching, one velocity group per period, for friction pre-identification
  (paper 003, Section 3.1, Eqs. for :math:`\\dot q_i(t)`); the switching ramps are quintic
  smoothsteps (continuous acceleration) where paper 003 uses linear ramps;
* :class:`CirclePath` and :class:`PolylinePath`: a point moving at constant speed along a
  circle or a polyline (paper 001, Section 4: circle of radius 0.04 m at 0.2 m/s; the
  rectangle with its diagonals for validation), with smooth start and stop ramps (the
  polyline stops at each corner, where the direction changes);
* :class:`Repeated`: periodic repetition of a trajectory;
* :func:`zyx_angular_velocity`: angular velocity and acceleration of a pose whose
  orientation is :math:`R_z(\\psi)R_y(\\theta)R_x(\\varphi)` from the angle rates (paper 004,
  Eq. 16, :math:`v = \\mathcal H\\dot x`, :math:`a = \\mathcal H\\ddot x + \\dot{\\mathcal H}\\dot x`,
  written for the z-y-x chain of the built-in platforms).

Speed profiles are piecewise polynomials (``scipy.interpolate.PPoly``) integrated and
differentiated exactly.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.interpolate import PPoly

from dynid._typing import FloatArray
from dynid.errors import InputError
from dynid.trajectories.fourier import FourierTrajectory

__all__ = [
    "BidirectionalVelocity",
    "CirclePath",
    "Embedded",
    "FourierQuintic",
    "PolylinePath",
    "Repeated",
    "zyx_angular_velocity",
]

# quintic smoothstep b(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 (coefficients of tau^5 .. tau^0)
_SMOOTH = np.array([6.0, -15.0, 10.0, 0.0, 0.0, 0.0])


def _blend(v0: float, v1: float, dt: float) -> np.ndarray:
    """PPoly coefficients (highest power first, in local time) of v0 -> v1 over dt."""
    scale = np.array([dt**-5, dt**-4, dt**-3, dt**-2, dt**-1, 1.0])
    c = (v1 - v0) * _SMOOTH * scale
    c[-1] += v0
    return c


def _speed_profile(pieces: list[tuple[float, np.ndarray]]) -> PPoly:
    """A PPoly from (duration, coefficients of degree 5) pieces."""
    x = np.concatenate([[0.0], np.cumsum([d for d, _ in pieces])])
    c = np.array([co for _, co in pieces]).T
    return PPoly(c, x, extrapolate=True)


def _profile_samples(v: PPoly, t: FloatArray, duration: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Path parameter s, its rate and second derivative at ``t`` (clamped to [0, duration])."""
    s_poly = v.antiderivative()
    tc = np.clip(t, 0.0, duration)
    s, ds, dds = s_poly(tc), v(tc), v.derivative()(tc)
    outside = (t < 0) | (t > duration)
    ds = np.where(outside, 0.0, ds)
    dds = np.where(outside, 0.0, dds)
    return s, ds, dds


def _rest_to_rest(length: float, speed: float, ramp: float) -> list[tuple[float, np.ndarray]]:
    """Smooth ramp to ``speed``, cruise, ramp to rest: pieces covering ``length``."""
    if ramp * speed > length:
        raise InputError(f"segment of length {length:.4g} is too short for ramps of {ramp} s at {speed} (units/s)")
    cruise = (length - ramp * speed) / speed  # each ramp covers speed * ramp / 2
    pieces = [(ramp, _blend(0.0, speed, ramp))]
    if cruise > 0:
        pieces.append((cruise, np.array([0, 0, 0, 0, 0, speed], dtype=float)))
    pieces.append((ramp, _blend(speed, 0.0, ramp)))
    return pieces


@dataclasses.dataclass(frozen=True, eq=False)
class FourierQuintic:
    """Fourier series + quintic polynomial with rest at both ends (paper 003).

    :math:`q(t) = F(t) + p(t)` on :math:`[0, T]`, ``T`` the Fourier period, with the quintic
    :math:`p` chosen per coordinate so that :math:`\\dot q = \\ddot q = 0` at ``t = 0`` and
    ``t = T`` and :math:`q(0) = q(T) = F(0)`. Outside ``[0, T]`` the trajectory rests.
    """

    fourier: FourierTrajectory

    def __post_init__(self) -> None:
        T = self.fourier.period
        _, dq0, ddq0 = self.fourier.sample(np.array([0.0]))
        # p(0) = p(T) = 0, p'(0) = p'(T) = -F'(0), p''(0) = p''(T) = -F''(0)
        rows = []
        for t in (0.0, T):
            rows.append([t**k for k in range(6)])
            rows.append([k * t ** (k - 1) if k else 0.0 for k in range(6)])
            rows.append([k * (k - 1) * t ** (k - 2) if k > 1 else 0.0 for k in range(6)])
        M = np.array(rows)
        rhs = np.stack([np.zeros_like(dq0[0]), -dq0[0], -ddq0[0]] * 2)  # (6, n_joints)
        object.__setattr__(self, "coef", np.linalg.solve(M, rhs))  # (6, n_joints), ascending powers

    coef: FloatArray = dataclasses.field(init=False)

    @property
    def duration(self) -> float:
        return self.fourier.period

    def sample(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        tc = np.clip(t, 0.0, self.duration)
        q, dq, ddq = self.fourier.sample(tc)
        k = np.arange(6)
        P = tc[:, None] ** k
        dP = np.where(k > 0, k * tc[:, None] ** np.maximum(k - 1, 0), 0.0)
        ddP = np.where(k > 1, k * (k - 1) * tc[:, None] ** np.maximum(k - 2, 0), 0.0)
        q, dq, ddq = q + P @ self.coef, dq + dP @ self.coef, ddq + ddP @ self.coef
        outside = ((t < 0) | (t > self.duration))[:, None]
        return q, np.where(outside, 0.0, dq), np.where(outside, 0.0, ddq)


@dataclasses.dataclass(frozen=True, eq=False)
class BidirectionalVelocity:
    """Constant-velocity segments of alternating sign for one coordinate (paper 003, Sec. 3.1).

    Each velocity group ``v_g`` takes one period ``T``: the velocity is a square wave
    :math:`+v_g, -v_g, +v_g` (quarter, half, quarter period) whose switches take ``switch``
    seconds each; the motion starts from rest, passes from group to group through a ramp
    :math:`v_g \\to v_{g+1}`, ends at rest, and returns to ``q0`` at the end (within a group
    the coordinate sweeps about :math:`q_0 \\pm v_g T/4`).

    Parameters
    ----------
    speeds : sequence of float
        Velocity magnitude of each group (> 0) [rad/s or m/s].
    period : float
        Duration of one group [s].
    switch : float
        Duration of each velocity switch [s] (``< period / 4``).
    q0 : float
        Position at the start [rad or m].
    """

    speeds: tuple[float, ...]
    period: float
    switch: float
    q0: float = 0.0

    def __post_init__(self) -> None:
        speeds = tuple(float(v) for v in np.atleast_1d(self.speeds))
        if not speeds or min(speeds) <= 0:
            raise InputError(f"speeds must be positive, got {speeds}")
        if not 0 < self.switch < self.period / 4:
            raise InputError(f"switch duration {self.switch} must be in (0, period/4 = {self.period / 4})")
        object.__setattr__(self, "speeds", speeds)
        h = self.switch
        pieces: list[tuple[float, np.ndarray]] = []
        prev = 0.0
        for v in speeds:
            # +v from 0 to T/4 (the first h/2 ramps from the previous level), -v to 3T/4, +v to T
            pieces.append((h, _blend(prev, v, h)))
            pieces.append((self.period / 4 - h, np.array([0, 0, 0, 0, 0, v], float)))
            pieces.append((h, _blend(v, -v, h)))
            pieces.append((self.period / 2 - h, np.array([0, 0, 0, 0, 0, -v], float)))
            pieces.append((h, _blend(-v, v, h)))
            pieces.append((self.period / 4 - h, np.array([0, 0, 0, 0, 0, v], float)))
            prev = v
        pieces.append((h, _blend(prev, 0.0, h)))
        object.__setattr__(self, "_velocity", _speed_profile(pieces))

    _velocity: PPoly = dataclasses.field(init=False, repr=False)

    @property
    def duration(self) -> float:
        return float(self._velocity.x[-1])

    def sample(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        s, ds, dds = _profile_samples(self._velocity, t, self.duration)
        return (self.q0 + s)[:, None], ds[:, None], dds[:, None]


@dataclasses.dataclass(frozen=True, eq=False)
class CirclePath:
    """A point going round a circle at constant speed (paper 001, Section 4).

    Parameters
    ----------
    centre : (2,) [m]; radius : float [m]; speed : float [m/s]
    turns : float
        Number of revolutions (paper 001: 15).
    clockwise : bool
        Direction (paper 001: clockwise).
    start_angle : float
        Polar angle of the start point [rad].
    ramp : float
        Duration of the smooth start and stop [s] (the speed is constant in between).
    """

    centre: tuple[float, float]
    radius: float
    speed: float
    turns: float = 1.0
    clockwise: bool = True
    start_angle: float = 0.0
    ramp: float = 0.2

    def __post_init__(self) -> None:
        if self.radius <= 0 or self.speed <= 0 or self.turns <= 0:
            raise InputError("circle radius, speed and number of turns must be positive")
        length = 2 * np.pi * self.radius * self.turns
        object.__setattr__(self, "_velocity", _speed_profile(_rest_to_rest(length, self.speed, self.ramp)))

    _velocity: PPoly = dataclasses.field(init=False, repr=False)

    @property
    def duration(self) -> float:
        return float(self._velocity.x[-1])

    def sample(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        s, ds, dds = _profile_samples(self._velocity, t, self.duration)
        sign = -1.0 if self.clockwise else 1.0
        r = self.radius
        phi, dphi, ddphi = self.start_angle + sign * s / r, sign * ds / r, sign * dds / r
        c, si = np.cos(phi), np.sin(phi)
        x = np.stack([self.centre[0] + r * c, self.centre[1] + r * si], axis=1)
        dx = np.stack([-r * si * dphi, r * c * dphi], axis=1)
        ddx = np.stack([-r * c * dphi**2 - r * si * ddphi, -r * si * dphi**2 + r * c * ddphi], axis=1)
        return x, dx, ddx


@dataclasses.dataclass(frozen=True, eq=False)
class PolylinePath:
    """A point along straight segments at constant speed, stopping at each vertex.

    Each segment is rest-to-rest: a smooth ramp of ``ramp`` seconds to ``speed``, cruise,
    and a ramp to rest (a corner at full speed would need an infinite acceleration).

    Parameters
    ----------
    vertices : array, shape (m, d) [m]
    speed : float [m/s]; ramp : float [s]
    """

    vertices: FloatArray
    speed: float
    ramp: float = 0.1

    def __post_init__(self) -> None:
        P = np.array(self.vertices, dtype=float, ndmin=2)
        if P.shape[0] < 2:
            raise InputError("a polyline needs at least two vertices")
        L = np.linalg.norm(np.diff(P, axis=0), axis=1)
        if np.any(L <= 0):
            raise InputError("a polyline has two equal consecutive vertices")
        pieces, starts = [], [0.0]
        for length in L:
            seg = _rest_to_rest(float(length), self.speed, self.ramp)
            pieces += seg
            starts.append(starts[-1] + sum(d for d, _ in seg))
        P.setflags(write=False)
        object.__setattr__(self, "vertices", P)
        object.__setattr__(self, "_segments", (np.array(starts), L))
        object.__setattr__(self, "_velocity", _speed_profile(pieces))

    _velocity: PPoly = dataclasses.field(init=False, repr=False)
    _segments: tuple = dataclasses.field(init=False, repr=False)

    @property
    def duration(self) -> float:
        return float(self._velocity.x[-1])

    def sample(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        s, ds, dds = _profile_samples(self._velocity, t, self.duration)
        starts, L = self._segments
        cum = np.concatenate([[0.0], np.cumsum(L)])
        k = np.clip(np.searchsorted(starts, np.clip(t, 0, self.duration), side="right") - 1, 0, L.size - 1)
        P = self.vertices
        u = (P[k + 1] - P[k]) / L[k, None]
        x = P[k] + (s - cum[k])[:, None] * u
        return x, ds[:, None] * u, dds[:, None] * u


@dataclasses.dataclass(frozen=True, eq=False)
class Repeated:
    """``count`` repetitions of a periodic trajectory (positions, velocities and accelerations
    must agree at both ends of one period; checked to 1e-9)."""

    trajectory: object
    count: int

    def __post_init__(self) -> None:
        if self.count < 1:
            raise InputError(f"count must be >= 1, got {self.count}")
        T = self.period
        a, b = self.trajectory.sample(np.array([0.0])), self.trajectory.sample(np.array([T]))
        for name, x, y in zip(("position", "velocity", "acceleration"), a, b):
            if not np.allclose(x, y, atol=1e-9, rtol=0):
                raise InputError(f"trajectory is not periodic: its {name} differs at t = 0 and t = {T:g} s")

    @property
    def period(self) -> float:
        traj = self.trajectory
        return float(traj.period if hasattr(traj, "period") and not callable(traj.period) else traj.duration)

    @property
    def duration(self) -> float:
        return self.count * self.period

    def sample(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        local = np.where(t >= self.duration, self.period, np.mod(np.clip(t, 0, None), self.period))
        local = np.where(t < 0, 0.0, local)
        return self.trajectory.sample(local)


def zyx_angular_velocity(
    angles: FloatArray, rates: FloatArray, accelerations: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """World angular velocity and acceleration of :math:`R = R_z(\\psi)R_y(\\theta)R_x(\\varphi)`.

    Parameters
    ----------
    angles, rates, accelerations : array, shape (n, 3)
        :math:`(\\psi, \\theta, \\varphi)` in the order of the platform chains (RZ, RY, RX)
        and their first and second time derivatives.

    Returns
    -------
    omega, domega : array, shape (n, 3)
        :math:`\\omega = \\mathcal H\\dot x`, :math:`\\dot\\omega = \\mathcal H\\ddot x +
        \\dot{\\mathcal H}\\dot x` (paper 004, Eq. 16) with
        :math:`\\mathcal H = [e_z,\\; R_z e_y,\\; R_z R_y e_x]`.
    """
    a = np.atleast_2d(np.asarray(angles, float))
    r = np.atleast_2d(np.asarray(rates, float))
    acc = np.atleast_2d(np.asarray(accelerations, float))
    psi, th = a[:, 0], a[:, 1]
    dpsi, dth = r[:, 0], r[:, 1]
    cp, sp, ct, st = np.cos(psi), np.sin(psi), np.cos(th), np.sin(th)
    z = np.zeros_like(psi)
    o = np.ones_like(psi)
    H = np.stack([np.stack([z, z, o], 1), np.stack([-sp, cp, z], 1), np.stack([cp * ct, sp * ct, -st], 1)], 2)
    dH = np.stack(
        [
            np.stack([z, z, z], 1),
            np.stack([-cp * dpsi, -sp * dpsi, z], 1),
            np.stack([-sp * ct * dpsi - cp * st * dth, cp * ct * dpsi - sp * st * dth, -ct * dth], 1),
        ],
        2,
    )
    omega = np.einsum("nij,nj->ni", H, r)
    domega = np.einsum("nij,nj->ni", H, acc) + np.einsum("nij,nj->ni", dH, r)
    return omega, domega


@dataclasses.dataclass(frozen=True, eq=False)
class Embedded:
    """A path of ``k`` coordinates placed in ``n`` coordinates: the path drives the coordinates
    ``axes``, the others stay at ``rest`` (e.g. a circle of a hexapod platform in the x-y plane
    at its home height and orientation)."""

    path: object
    axes: tuple[int, ...]
    rest: FloatArray

    def __post_init__(self) -> None:
        rest = np.array(self.rest, dtype=float, ndmin=1)
        axes = tuple(int(a) for a in self.axes)
        if len(set(axes)) != len(axes) or any(not 0 <= a < rest.size for a in axes):
            raise InputError(f"axes {axes} must be distinct indices of the {rest.size} coordinates")
        object.__setattr__(self, "rest", rest)
        object.__setattr__(self, "axes", axes)

    @property
    def duration(self) -> float:
        return float(self.path.duration)

    def sample(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        x, dx, ddx = self.path.sample(t)
        n = x.shape[0]
        q = np.tile(self.rest, (n, 1))
        dq, ddq = np.zeros_like(q), np.zeros_like(q)
        q[:, self.axes], dq[:, self.axes], ddq[:, self.axes] = x, dx, ddx
        return q, dq, ddq
