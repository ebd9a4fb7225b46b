"""Joint friction models (ground truth of virtual experiments, and nonlinear identification).

Each model is a frozen dataclass of per-joint coefficient arrays (shape (n_joints,), or
scalars broadcast to all joints) with ``force(dq) -> (n, n_joints)``: the friction force
[N·m or N] opposing the motion, added to the joint torque needed for the motion.

================================  ==========================================================
model                             force
================================  ==========================================================
:class:`CoulombViscous`           :math:`f_c\\,\\mathrm{sign}(\\dot q) + f_v\\dot q + b`; with
                                  ``fc_neg``/``fv_neg`` asymmetric as in Shang 2009, Eq. 2
                                  (:math:`f_c^- + f_v^-\\dot q` for :math:`\\dot q < 0`,
                                  :math:`f_c^-` negative)
:class:`Stribeck`                 :math:`[F_C + (F_S - F_C)e^{-|\\dot q/v_S|^{\\delta_S}}]
                                  \\mathrm{sign}(\\dot q) + F_v\\dot q` (paper 000, Eq. 32;
                                  Olsson et al. 1998)
:class:`PowerLawViscous`          :math:`F_v|\\dot q|^{\\alpha}\\mathrm{sign}(\\dot q) + F_c
                                  \\mathrm{sign}(\\dot q) + B` (paper 003, Section 3.1)
:class:`SmoothStribeck`           :math:`[F_c + (F_s - F_c)e^{-(\\dot q/\\dot q_s)^2}]
                                  \\tfrac{2}{\\pi}\\arctan(K_v\\dot q) + F_v|\\dot q|^{\\alpha}
                                  \\mathrm{sign}(\\dot q)` (paper 003's improved Stribeck)
================================  ==========================================================

:class:`FrictionMemory` wraps any of them as the *steady-state* curve of a friction force with
memory (a state per joint, integrated by the plant): Hess & Soom's frictional memory read as a
first-order lag, :math:`\\dot z = (F_{ss}(\\dot q) - z) / T_m` (Hess, D.P. & Soom, A., "Friction at a
lubricated line contact operating at oscillating sliding velocities", J. Tribology 112, 1990: the
friction follows the steady-state curve with a time lag of milliseconds to tens of milliseconds;
paper 003 §3.4 motivates its recurrent network by such history-dependent friction). At constant
velocity :math:`z = F_{ss}`: a constant-velocity experiment measures the steady-state curve exactly.

``sign(0) = 0`` everywhere (a joint at rest has no Coulomb force in these models).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import ModelError

__all__ = ["CoulombViscous", "FrictionMemory", "FrictionModel", "PowerLawViscous", "SmoothStribeck", "Stribeck"]


def _arrays(obj, names: tuple[str, ...]) -> None:
    for name in names:
        value = getattr(obj, name)
        if value is None:
            continue
        a = np.array(value, dtype=float, ndmin=1)
        if not np.all(np.isfinite(a)):
            raise ModelError(f"{type(obj).__name__}.{name} has non-finite values")
        a.setflags(write=False)
        object.__setattr__(obj, name, a)


def _velocities(dq: FloatArray) -> FloatArray:
    return np.atleast_2d(np.asarray(dq, dtype=float))


class FrictionModel:
    """Base class: ``force(dq)`` with ``dq`` of shape (n, n_joints) or (n_joints,)."""

    def force(self, dq: FloatArray) -> FloatArray:  # pragma: no cover - abstract
        raise NotImplementedError


@dataclasses.dataclass(frozen=True, eq=False)
class CoulombViscous(FrictionModel):
    """Coulomb + viscous friction, symmetric or asymmetric (Shang 2009, Eq. 2)."""

    fc: FloatArray
    fv: FloatArray
    fc_neg: FloatArray | None = None
    fv_neg: FloatArray | None = None
    offset: FloatArray = 0.0

    def __post_init__(self) -> None:
        _arrays(self, ("fc", "fv", "fc_neg", "fv_neg", "offset"))

    def force(self, dq: FloatArray) -> FloatArray:
        v = _velocities(dq)
        if self.fc_neg is None and self.fv_neg is None:
            return self.fc * np.sign(v) + self.fv * v + self.offset
        fc_neg = -self.fc if self.fc_neg is None else self.fc_neg
        fv_neg = self.fv if self.fv_neg is None else self.fv_neg
        pos = np.where(v > 0, self.fc + self.fv * v, 0.0)
        neg = np.where(v < 0, fc_neg + fv_neg * v, 0.0)
        return pos + neg + self.offset


@dataclasses.dataclass(frozen=True, eq=False)
class Stribeck(FrictionModel):
    """Five-parameter Stribeck friction (paper 000, Eq. 32)."""

    fc: FloatArray
    fs: FloatArray
    fv: FloatArray
    vs: FloatArray
    delta: FloatArray = 2.0

    def __post_init__(self) -> None:
        _arrays(self, ("fc", "fs", "fv", "vs", "delta"))
        if np.any(self.vs <= 0):
            raise ModelError("Stribeck velocity vs must be positive")

    def force(self, dq: FloatArray) -> FloatArray:
        v = _velocities(dq)
        return (self.fc + (self.fs - self.fc) * np.exp(-np.abs(v / self.vs) ** self.delta)) * np.sign(v) + self.fv * v


@dataclasses.dataclass(frozen=True, eq=False)
class PowerLawViscous(FrictionModel):
    """Coulomb + power-law viscous friction + offset (paper 003, Section 3.1)."""

    fc: FloatArray
    fv: FloatArray
    alpha: FloatArray
    offset: FloatArray = 0.0

    def __post_init__(self) -> None:
        _arrays(self, ("fc", "fv", "alpha", "offset"))

    def force(self, dq: FloatArray) -> FloatArray:
        v = _velocities(dq)
        s = np.sign(v)
        return self.fv * np.abs(v) ** self.alpha * s + self.fc * s + self.offset


@dataclasses.dataclass(frozen=True, eq=False)
class SmoothStribeck(FrictionModel):
    """Paper 003's improved Stribeck model: arctan-smoothed sign, power-law viscous term."""

    fc: FloatArray
    fs: FloatArray
    fv: FloatArray
    vs: FloatArray
    kv: FloatArray
    alpha: FloatArray = 1.0

    def __post_init__(self) -> None:
        _arrays(self, ("fc", "fs", "fv", "vs", "kv", "alpha"))
        if np.any(self.vs <= 0) or np.any(self.kv <= 0):
            raise ModelError("Stribeck velocity vs and smoothing coefficient kv must be positive")

    def force(self, dq: FloatArray) -> FloatArray:
        v = _velocities(dq)
        smooth = 2.0 / np.pi * np.arctan(self.kv * v)
        stribeck = self.fc + (self.fs - self.fc) * np.exp(-((v / self.vs) ** 2))
        return stribeck * smooth + self.fv * np.abs(v) ** self.alpha * np.sign(v)


@dataclasses.dataclass(frozen=True, eq=False)
class FrictionMemory(FrictionModel):
    """Friction with memory: a first-order lag of time constant ``time_constant`` [s] per joint
    behind the steady-state curve ``steady`` (Hess & Soom 1990; see the module docstring).

    ``force(dq)`` is the steady state (what a constant-velocity experiment measures); the plant
    integrates the friction state ``z`` with :meth:`rate` (:func:`dynid.simulation.control.simulate_control`).
    """

    steady: FrictionModel
    time_constant: FloatArray

    def __post_init__(self) -> None:
        _arrays(self, ("time_constant",))
        if np.any(self.time_constant <= 0):
            raise ModelError("FrictionMemory.time_constant must be positive (0 is the steady-state model itself)")

    def force(self, dq: FloatArray) -> FloatArray:
        return self.steady.force(dq)

    def rate(self, dq: FloatArray, z: FloatArray) -> FloatArray:
        """dz/dt of the friction state ``z`` (n_joints,) at velocities ``dq`` (n_joints,)."""
        return (self.steady.force(dq)[0] - np.asarray(z, dtype=float)) / self.time_constant
