"""Drive trains: gear ratios, coupled joints, drive gains and encoder offsets.

A transmission relates motor and joint quantities linearly. With ``n_m`` motors and
``n_v`` joints (square here: one motor per joint),

.. math::

    \\theta_m = C\\,(q - q_0), \\qquad \\tau = C^T \\tau_m, \\qquad \\tau_m = K\\,i,

where :math:`C` holds the gear ratios on its diagonal and the coupling terms off it
(the Stäubli TX40 wrist: motor 6 turns with ``N6 (q5 + q6)``, so ``C[5, 4] = C[5, 5]
= N6``), :math:`K` are current-to-torque drive gains at the motor [N·m/A] and
:math:`q_0` are encoder zero offsets. The torque map is :math:`C^T` by virtual
power: :math:`\\tau^T \\dot q = \\tau_m^T \\dot\\theta_m`.

A coupled motor ``k`` (a row of :math:`C` with several non-zero entries) moves with
the joint-space velocity :math:`w_k = c_k^T \\dot q`, :math:`c_k = C_{k,:}/C_{kk}`;
its rotor inertia and friction add :math:`c_k\\,(I_{a,m}\\dot w_k + f_{v,m} w_k +
f_{c,m}\\,\\mathrm{sign}(w_k))` to the joint torques (see :mod:`dynid.model.serial_dynamics`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError

__all__ = ["Coupling", "Transmission"]


@dataclasses.dataclass(frozen=True)
class Coupling:
    """Motor ``motor`` (1-based) also drives ``joints`` (1-based) with ``weights``.

    ``weights`` multiply the motor's gear ratio: the TX40 wrist is
    ``Coupling(motor=6, joints=(5, 6), weights=(1.0, 1.0))``.
    """

    motor: int
    joints: tuple[int, ...]
    weights: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        joints = tuple(int(j) for j in self.joints)
        weights = tuple(float(w) for w in self.weights) if self.weights else (1.0,) * len(joints)
        if len(weights) != len(joints):
            raise ModelError(f"coupling of motor {self.motor}: {len(joints)} joints but {len(weights)} weights")
        if int(self.motor) not in joints:
            raise ModelError(f"coupling of motor {self.motor} must include its own joint {self.motor}")
        object.__setattr__(self, "motor", int(self.motor))
        object.__setattr__(self, "joints", joints)
        object.__setattr__(self, "weights", weights)


@dataclasses.dataclass(frozen=True, eq=False)
class Transmission:
    """Linear motor-joint map (see module docstring).

    Parameters
    ----------
    matrix : array, shape (n_v, n_v)
        :math:`C`, motor angle per joint angle (gear ratios and couplings).
    drive_gains : array, shape (n_v,)
        :math:`K` [N·m/A] (1 when currents are already torques, or when gains are
        folded into the identified parameters).
    position_offset : array, shape (n_v,)
        :math:`q_0` [rad]: joint angle when the motor encoder reads zero.
    """

    matrix: FloatArray
    drive_gains: FloatArray
    position_offset: FloatArray

    def __post_init__(self) -> None:
        c = np.array(self.matrix, dtype=float)
        n = c.shape[0]
        if c.ndim != 2 or c.shape != (n, n):
            raise ModelError(f"transmission matrix must be square, got shape {c.shape}")
        if np.any(np.diag(c) == 0) or abs(np.linalg.det(c)) < 1e-12 * max(1.0, np.abs(c).max()) ** n:
            raise ModelError("transmission matrix is singular (a gear ratio is zero?)")
        k = np.broadcast_to(np.asarray(self.drive_gains, dtype=float), (n,)).copy()
        off = np.broadcast_to(np.asarray(self.position_offset, dtype=float), (n,)).copy()
        for a in (c, k, off):
            if not np.all(np.isfinite(a)):
                raise ModelError("transmission contains non-finite numbers")
            a.setflags(write=False)
        object.__setattr__(self, "matrix", c)
        object.__setattr__(self, "drive_gains", k)
        object.__setattr__(self, "position_offset", off)

    @classmethod
    def from_ratios(
        cls,
        gear_ratios: Sequence[float],
        couplings: Sequence[Coupling] = (),
        drive_gains: Sequence[float] | float = 1.0,
        position_offset: Sequence[float] | float = 0.0,
    ) -> Transmission:
        """Build :math:`C` from gear ratios ``N`` and couplings (1-based indices)."""
        n_ratios = np.asarray(gear_ratios, dtype=float)
        n = n_ratios.shape[0]
        c = np.diag(n_ratios)
        for cp in couplings:
            if not 1 <= cp.motor <= n or any(not 1 <= j <= n for j in cp.joints):
                raise ModelError(f"coupling {cp} refers to a joint outside 1..{n}")
            for j, w in zip(cp.joints, cp.weights):
                c[cp.motor - 1, j - 1] = n_ratios[cp.motor - 1] * w
        return cls(matrix=c, drive_gains=drive_gains, position_offset=position_offset)

    @classmethod
    def identity(cls, n: int) -> Transmission:
        return cls(matrix=np.eye(n), drive_gains=1.0, position_offset=0.0)

    # ------------------------------------------------------------------ properties
    @property
    def n(self) -> int:
        return int(self.matrix.shape[0])

    @property
    def coupled_motors(self) -> tuple[int, ...]:
        """0-based indices of motors that drive more than one joint."""
        nz = np.count_nonzero(self.matrix, axis=1)
        return tuple(int(k) for k in np.flatnonzero(nz > 1))

    def coupling_weights(self, motor: int) -> FloatArray:
        """:math:`c_k = C_{k,:} / C_{kk}` (0-based ``motor``)."""
        return self.matrix[motor] / self.matrix[motor, motor]

    # ------------------------------------------------------------------ maps
    def _check(self, x: FloatArray, what: str) -> FloatArray:
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != self.n:
            raise InputError(f"{what} has {x.shape[-1] if x.ndim else 0} channels, the transmission has {self.n} motors")
        return x

    def joint_positions(self, theta: FloatArray) -> FloatArray:
        """Joint positions from motor encoder angles, ``q = C^{-1} θ + q0``; shape (n, n_v)."""
        theta = self._check(theta, "motor positions")
        return np.linalg.solve(self.matrix, theta.T).T + self.position_offset

    def joint_rates(self, dtheta: FloatArray) -> FloatArray:
        """Joint velocities (or accelerations) from motor ones, ``C^{-1} θ'``."""
        dtheta = self._check(dtheta, "motor velocities")
        return np.linalg.solve(self.matrix, dtheta.T).T

    def joint_torques(self, tau_motor: FloatArray) -> FloatArray:
        """Joint torques from motor torques, ``τ = C^T τ_m``."""
        tau_motor = self._check(tau_motor, "motor torques")
        return tau_motor @ self.matrix

    def joint_torques_from_currents(self, current: FloatArray) -> FloatArray:
        """Joint torques from motor currents, ``τ = C^T K i``."""
        current = self._check(current, "motor currents")
        return (current * self.drive_gains) @ self.matrix

    def describe(self) -> dict:
        return {
            "matrix": self.matrix.tolist(),
            "drive_gains": self.drive_gains.tolist(),
            "position_offset": self.position_offset.tolist(),
        }
