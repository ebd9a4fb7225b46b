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

The dataclasses check their coefficients once, at construction; their ``force`` evaluates a
module-level function of the coefficient arrays that checks nothing (:func:`coulomb_viscous_force`,
:func:`stribeck_force`, :func:`power_law_force`, :func:`smooth_stribeck_force`), which the curve fits
of :mod:`dynid.estimation.friction_curves` call directly, and :func:`force_function` gives a
one-sample evaluator for the simulation loops (millions of calls).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import ModelError

__all__ = ["CoulombViscous", "FrictionMemory", "FrictionModel", "PowerLawViscous", "SmoothStribeck", "Stribeck",
           "coulomb_viscous_force", "force_function", "power_law_force", "smooth_stribeck_force", "stribeck_force"]

_TWO_OVER_PI = 2.0 / np.pi


def coulomb_viscous_force(v, fc, fv, fc_neg=None, fv_neg=None, offset=0.0):
    """Coulomb + viscous friction at velocities ``v`` (Shang 2009, Eq. 2; :class:`CoulombViscous`).

    The validation-free evaluation behind :meth:`CoulombViscous.force`: ``v`` and the
    coefficients are arrays (or floats) that broadcast together, and the result has their
    broadcast shape; nothing is checked or converted (the dataclass checked its coefficients
    once, at construction).

    Parameters
    ----------
    v : array
        Velocities [rad/s or m/s].
    fc, fv : array or float
        Coulomb [N·m or N] and viscous [N·m·s/rad or N·s/m] coefficients (for :math:`\\dot q > 0`
        when ``fc_neg``/``fv_neg`` are given).
    fc_neg, fv_neg : array or float, optional
        The coefficients for :math:`\\dot q < 0` (``fc_neg`` negative); default ``-fc``, ``fv``.
    offset : array or float
        Constant torque added at every velocity.

    Returns
    -------
    array
        :math:`f_c\\,\\mathrm{sign}(\\dot q) + f_v\\dot q + b`, or the asymmetric form.
    """
    if fc_neg is None and fv_neg is None:
        return fc * np.sign(v) + fv * v + offset
    fc_neg = -fc if fc_neg is None else fc_neg
    fv_neg = fv if fv_neg is None else fv_neg
    pos = np.where(v > 0, fc + fv * v, 0.0)
    neg = np.where(v < 0, fc_neg + fv_neg * v, 0.0)
    return pos + neg + offset


def stribeck_force(v, fc, fs, fv, vs, delta=2.0):
    """Five-parameter Stribeck friction at velocities ``v`` (paper 000, Eq. 32; :class:`Stribeck`):
    :math:`[F_C + (F_S - F_C)e^{-|\\dot q/v_S|^{\\delta_S}}]\\mathrm{sign}(\\dot q) + F_v\\dot q`.

    Validation-free (see :func:`coulomb_viscous_force`): ``v`` and the coefficients broadcast
    together; ``vs`` must be positive (not checked).
    """
    return (fc + (fs - fc) * np.exp(-np.power(np.abs(v / vs), delta))) * np.sign(v) + fv * v


def power_law_force(v, fc, fv, alpha, offset=0.0):
    """Coulomb + power-law viscous friction + offset at velocities ``v`` (paper 003, Eq. 13;
    :class:`PowerLawViscous`): :math:`F_v|\\dot q|^{\\alpha}\\mathrm{sign}(\\dot q) + F_c\\,
    \\mathrm{sign}(\\dot q) + B`.

    Validation-free (see :func:`coulomb_viscous_force`).
    """
    s = np.sign(v)
    return fv * np.power(np.abs(v), alpha) * s + fc * s + offset


def smooth_stribeck_force(v, fc, fs, fv, vs, kv, alpha=1.0):
    """Paper 003's improved Stribeck friction at velocities ``v`` (Eq. 15; :class:`SmoothStribeck`):
    :math:`[F_c + (F_s - F_c)e^{-(\\dot q/\\dot q_s)^2}]\\tfrac{2}{\\pi}\\arctan(K_v\\dot q) +
    F_v|\\dot q|^{\\alpha}\\mathrm{sign}(\\dot q)`.

    Validation-free (see :func:`coulomb_viscous_force`); ``vs`` and ``kv`` must be positive (not
    checked).
    """
    smooth = _TWO_OVER_PI * np.arctan(kv * v)
    stribeck = fc + (fs - fc) * np.exp(-np.square(v / vs))
    return stribeck * smooth + fv * np.power(np.abs(v), alpha) * np.sign(v)


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
        return coulomb_viscous_force(_velocities(dq), self.fc, self.fv, self.fc_neg, self.fv_neg, self.offset)


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
        return stribeck_force(_velocities(dq), self.fc, self.fs, self.fv, self.vs, self.delta)


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
        return power_law_force(_velocities(dq), self.fc, self.fv, self.alpha, self.offset)


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
        return smooth_stribeck_force(_velocities(dq), self.fc, self.fs, self.fv, self.vs, self.kv, self.alpha)


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


class _OneSample:
    """Base of :func:`force_function`'s evaluators: picklable (module-level classes holding the
    coefficient arrays), unlike closures."""

    __slots__ = ()


class _CoulombViscousOne(_OneSample):
    __slots__ = ("fc", "fv", "offset")

    def __init__(self, m: CoulombViscous) -> None:
        self.fc, self.fv, self.offset = m.fc, m.fv, m.offset

    def __call__(self, v: FloatArray) -> FloatArray:
        return _add(_add(_mul(self.fc, _sign(v)), _mul(self.fv, v)), self.offset)


class _SmoothStribeckOne(_OneSample):
    __slots__ = ("fc", "dfs", "fv", "vs", "kv", "alpha")

    def __init__(self, m: SmoothStribeck) -> None:
        self.fc, self.fv, self.vs, self.kv, self.alpha = m.fc, m.fv, m.vs, m.kv, m.alpha
        self.dfs = m.fs - m.fc

    def __call__(self, v: FloatArray) -> FloatArray:
        smooth = _mul(_TWO_OVER_PI_0D, _arctan(_mul(self.kv, v)))
        stribeck = _add(self.fc, _mul(self.dfs, _exp(_neg(_square(_div(v, self.vs))))))
        return _add(_mul(stribeck, smooth), _mul(_mul(self.fv, _power(_abs(v), self.alpha)), _sign(v)))


class _PureOne(_OneSample):
    __slots__ = ("fn", "args")

    def __init__(self, fn: Callable[..., FloatArray], *args) -> None:
        self.fn, self.args = fn, args

    def __call__(self, v: FloatArray) -> FloatArray:
        return self.fn(v, *self.args)


class _ForceOne(_OneSample):
    __slots__ = ("model",)

    def __init__(self, model: FrictionModel) -> None:
        self.model = model

    def __call__(self, v: FloatArray) -> FloatArray:
        return self.model.force(v)[0]


_add, _mul, _div, _neg, _square, _sign, _abs = np.add, np.multiply, np.divide, np.negative, np.square, np.sign, np.abs
_exp, _arctan, _power = np.exp, np.arctan, np.power
_TWO_OVER_PI_0D = np.array(_TWO_OVER_PI)


def force_function(model: FrictionModel) -> Callable[[FloatArray], FloatArray]:
    """The friction of ``model`` at one sample, ``f(dq) -> (n_joints,)`` with ``dq`` of shape
    (n_joints,), for loops that evaluate it millions of times (the plant of
    :func:`dynid.simulation.control.simulate_control`: four Runge–Kutta stages per substep).

    The same floating-point operations on the same operands as ``model.force(dq)[0]`` (so the
    same result to the last bit), without :meth:`~FrictionModel.force`'s conversion of ``dq``;
    for :class:`SmoothStribeck` and the symmetric :class:`CoulombViscous` (the models simulated
    most) with what does not depend on the velocity (:math:`F_s - F_c`) formed once and the
    ufuncs called directly. ``dq`` must be a float array of shape (n_joints,) (or one that
    broadcasts with the coefficients); nothing is checked.

    Parameters
    ----------
    model : FrictionModel
        The classes of this module (:class:`FrictionMemory`: its steady-state curve,
        :meth:`FrictionMemory.force`); any other model is evaluated by its
        :meth:`~FrictionModel.force`.

    Returns
    -------
    callable
        A picklable ``f(dq) -> force``.
    """
    if isinstance(model, FrictionMemory):
        return force_function(model.steady)
    if isinstance(model, SmoothStribeck):
        return _SmoothStribeckOne(model)
    if isinstance(model, CoulombViscous):
        if model.fc_neg is None and model.fv_neg is None:
            return _CoulombViscousOne(model)
        return _PureOne(coulomb_viscous_force, model.fc, model.fv, model.fc_neg, model.fv_neg, model.offset)
    if isinstance(model, Stribeck):
        return _PureOne(stribeck_force, model.fc, model.fs, model.fv, model.vs, model.delta)
    if isinstance(model, PowerLawViscous):
        return _PureOne(power_law_force, model.fc, model.fv, model.alpha, model.offset)
    return _ForceOne(model)
