"""Excitation trajectories with analytic position, velocity and acceleration.

:class:`FourierTrajectory` is the finite Fourier series of Swevers et al. (1997), used
for periodic excitation in papers 002 (Eq. 22) and 004:

.. math::

    q_j(t) = q_{0,j} + \\sum_{k=1}^{K} \\frac{a_{jk}}{\\omega_f k}\\sin(\\omega_f k t)
             - \\frac{b_{jk}}{\\omega_f k}\\cos(\\omega_f k t), \\qquad \\omega_f = 2\\pi f_0 .
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError

__all__ = ["FourierTrajectory"]


@dataclasses.dataclass(frozen=True, eq=False)
class FourierTrajectory:
    """Finite Fourier series per joint (see module docstring).

    Parameters
    ----------
    base_frequency_hz : float
        Fundamental frequency :math:`f_0` [Hz]; the period is ``1 / f0``.
    a, b : array, shape (n_joints, n_harmonics)
        Sine and cosine coefficients [rad/s].
    q0 : array, shape (n_joints,)
        Offsets [rad].
    """

    base_frequency_hz: float
    a: FloatArray
    b: FloatArray
    q0: FloatArray

    def __post_init__(self) -> None:
        a = np.array(self.a, dtype=float, ndmin=2)
        b = np.array(self.b, dtype=float, ndmin=2)
        q0 = np.array(self.q0, dtype=float, ndmin=1)
        if a.shape != b.shape or a.shape[0] != q0.shape[0]:
            raise InputError(f"Fourier coefficients a {a.shape}, b {b.shape} and q0 {q0.shape} do not match")
        if not self.base_frequency_hz > 0:
            raise InputError(f"base frequency must be positive, got {self.base_frequency_hz}")
        for x in (a, b, q0):
            x.setflags(write=False)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "q0", q0)

    @property
    def period(self) -> float:
        return 1.0 / self.base_frequency_hz

    @property
    def n_joints(self) -> int:
        return int(self.q0.shape[0])

    def sample(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Positions, velocities, accelerations at times ``t``; each (n, n_joints)."""
        t = np.asarray(t, dtype=float)
        w = 2 * np.pi * self.base_frequency_hz
        k = np.arange(1, self.a.shape[1] + 1)
        wk = w * k  # (K,)
        s, c = np.sin(np.outer(t, wk)), np.cos(np.outer(t, wk))  # (n, K)
        q = self.q0 + s @ (self.a / wk).T - c @ (self.b / wk).T
        dq = c @ self.a.T + s @ self.b.T
        ddq = -s @ (self.a * wk).T + c @ (self.b * wk).T
        return q, dq, ddq

    def scaled(self, factor: float) -> FourierTrajectory:
        """The same shape with coefficients scaled about ``q0``."""
        return dataclasses.replace(self, a=self.a * factor, b=self.b * factor)

    @classmethod
    def random(
        cls,
        n_joints: int,
        n_harmonics: int,
        base_frequency_hz: float,
        rng: np.random.Generator,
        lower: FloatArray,
        upper: FloatArray,
        max_velocity: FloatArray | float = 2.0,
        max_acceleration: FloatArray | float = 10.0,
        fill: float = 0.8,
        rest_to_rest: bool = False,
    ) -> FourierTrajectory:
        """Random coefficients, scaled per joint to stay inside limits.

        Each joint moves about the middle of its range using at most ``fill`` of the
        half-range, and at most ``max_velocity`` / ``max_acceleration``.

        ``rest_to_rest``: the coefficients are projected onto zero velocity and acceleration at
        ``t = 0`` (hence at every multiple of the period): :math:`\\dot q_j(0) = \\sum_k a_{jk} = 0`
        and :math:`\\ddot q_j(0) = \\omega_f \\sum_k k\\, b_{jk} = 0`. The quintic of paper 003's
        Fourier + quintic excitation (Sec. 4.2, :class:`~dynid.trajectories.FourierQuintic`) is
        then zero and the limits checked here are those of the whole commanded motion; fitting an
        arbitrary series and adding the quintic afterwards leaves the range (the polynomial that
        cancels the end velocities grows with the period: several radians at 0.1 Hz). Needs at
        least two harmonics (with one, both constraints leave no motion).
        """
        lower, upper = np.asarray(lower, float), np.asarray(upper, float)
        a = rng.standard_normal((n_joints, n_harmonics))
        b = rng.standard_normal((n_joints, n_harmonics))
        if rest_to_rest:
            if n_harmonics < 2:
                raise InputError("a rest-to-rest Fourier trajectory needs at least 2 harmonics (with one, zero "
                                 "velocity and acceleration at the ends leave no motion)")
            k = np.arange(1, n_harmonics + 1, dtype=float)
            a = a - a.mean(axis=1, keepdims=True)
            b = b - np.outer(b @ k, k) / (k @ k)
        traj = cls(base_frequency_hz, a, b, (lower + upper) / 2)
        t = np.linspace(0.0, traj.period, 2001)
        q, dq, ddq = traj.sample(t)
        half = fill * (upper - lower) / 2
        ratio = np.min(
            np.vstack(
                [
                    half / np.max(np.abs(q - traj.q0), axis=0),
                    np.broadcast_to(max_velocity, (n_joints,)) / np.max(np.abs(dq), axis=0),
                    np.broadcast_to(max_acceleration, (n_joints,)) / np.max(np.abs(ddq), axis=0),
                ]
            ),
            axis=0,
        )
        return cls(base_frequency_hz, a * ratio[:, None], b * ratio[:, None], traj.q0)
