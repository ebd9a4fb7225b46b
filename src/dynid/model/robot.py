"""Robot models and the layout of their standard parameters.

Standard parameter vector (names are generated, never hand-typed):

1. per body ``j`` (pinocchio joint ``j`` = 1..n_b), in pinocchio's order and frame,
   ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` with names ``m1, mx1, ..., Izz1``:
   mass, first moments :math:`m c` and inertia about the **joint frame origin**,
   expressed in the joint frame (``pinocchio.Inertia.toDynamicParameters``);
2. per joint DOF ``j`` the enabled extras, in this order: rotor (armature) inertia
   ``Ia{j}`` [kg·m²], viscous ``fv{j}`` [N·m·s/rad], Coulomb ``fc{j}`` [N·m],
   torque offset ``off{j}`` [N·m] (joint-side, in joint units), and the asymmetric friction
   ``fv+{j}``, ``fv-{j}``, ``fc+{j}``, ``fc-{j}`` (:data:`ASYMMETRIC_EXTRAS`);
3. per coupled motor ``k`` (see :mod:`dynid.model.transmission`) the motor-side terms
   ``Iam{k}``, ``fvm{k}``, ``fcm{k}`` on the motor velocity in joint units
   :math:`w_k = c_k^T \\dot q`.

The joint torques are then linear in this vector (see :mod:`dynid.model.serial_dynamics`):

.. math::

    \\tau = Y_{rb}(q,\\dot q,\\ddot q)\\,\\pi_{rb} + I_a\\ddot q + f_v\\dot q
    + f_c\\,\\mathrm{sign}(\\dot q) + \\tau_{off}
    + \\sum_k c_k\\,(I_{a,m,k}\\dot w_k + f_{v,m,k} w_k + f_{c,m,k}\\,\\mathrm{sign}(w_k)).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from types import MappingProxyType

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import ModelError
from dynid.model.transmission import Transmission

__all__ = [
    "ALL_EXTRAS",
    "ASYMMETRIC_EXTRAS",
    "BODY_PARAMS",
    "JOINT_EXTRAS",
    "ParameterLayout",
    "RobotModel",
    "check_inertia",
    "inertia_defect",
    "joint_kinds",
]

BODY_PARAMS: tuple[str, ...] = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
"""Per-body inertial parameters in pinocchio's order."""

JOINT_EXTRAS: tuple[str, ...] = ("Ia", "fv", "fc", "offset")
"""Per-joint extras enabled by default, in their fixed order."""

ASYMMETRIC_EXTRAS: tuple[str, ...] = ("fv+", "fv-", "fc+", "fc-")
"""Asymmetric friction extras (Shang 2009, Eq. 2): viscous and Coulomb coefficients of each
direction of motion, on :math:`\\dot q^+ = \\max(\\dot q, 0)`, :math:`\\dot q^- = \\min(\\dot q, 0)`,
:math:`[\\dot q > 0]` and :math:`[\\dot q < 0]` (the ``fc-`` coefficient is the force at negative
velocities: non-positive)."""

ALL_EXTRAS: tuple[str, ...] = JOINT_EXTRAS + ASYMMETRIC_EXTRAS
"""Every per-joint extra, in layout order."""

_EXTRA_PREFIX = {"Ia": "Ia", "fv": "fv", "fc": "fc", "offset": "off", "fv+": "fv+", "fv-": "fv-", "fc+": "fc+",
                 "fc-": "fc-"}
_MOTOR_PREFIX = {"Ia": "Iam", "fv": "fvm", "fc": "fcm"}


def _normalize_extras(extras: Sequence[str]) -> tuple[str, ...]:
    unknown = [e for e in extras if e not in ALL_EXTRAS]
    if unknown:
        raise ModelError(f"unknown joint extras {unknown}; choose from {list(ALL_EXTRAS)}")
    return tuple(e for e in ALL_EXTRAS if e in extras)


@dataclasses.dataclass(frozen=True, eq=False)
class ParameterLayout:
    """Names and positions of the standard parameters (see module docstring)."""

    n_bodies: int
    nv: int
    extras: tuple[str, ...]
    coupled_motors: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "extras", _normalize_extras(self.extras))
        names: list[str] = []
        for j in range(1, self.n_bodies + 1):
            names.extend(f"{p}{j}" for p in BODY_PARAMS)
        extra_index: dict[str, list[int]] = {e: [] for e in self.extras}
        for j in range(1, self.nv + 1):
            for e in self.extras:
                extra_index[e].append(len(names))
                names.append(f"{_EXTRA_PREFIX[e]}{j}")
        motor_index: dict[str, list[int]] = {e: [] for e in self.extras if e in _MOTOR_PREFIX}
        for k in self.coupled_motors:
            for e in motor_index:
                motor_index[e].append(len(names))
                names.append(f"{_MOTOR_PREFIX[e]}{k + 1}")
        object.__setattr__(self, "names", tuple(names))
        object.__setattr__(
            self, "extra_index", MappingProxyType({e: np.array(v, dtype=int) for e, v in extra_index.items()})
        )
        object.__setattr__(
            self, "motor_index", MappingProxyType({e: np.array(v, dtype=int) for e, v in motor_index.items()})
        )

    names: tuple[str, ...] = dataclasses.field(init=False)
    extra_index: Mapping[str, np.ndarray] = dataclasses.field(init=False)
    motor_index: Mapping[str, np.ndarray] = dataclasses.field(init=False)

    @property
    def n_body_params(self) -> int:
        return 10 * self.n_bodies

    @property
    def n_params(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ModelError(f"no standard parameter named {name!r}") from None


def inertia_from_parameters(block: FloatArray) -> pin.Inertia:
    """Spatial inertia from ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (joint frame).

    Any non-zero mass is accepted (RNEA stays linear in the parameters even for
    non-physical values); a zero mass needs zero first moments (a massless rotor-like body).
    """
    block = np.asarray(block, dtype=float)
    m = block[0]
    if m == 0.0:
        if np.any(block[1:4] != 0.0):
            raise ModelError("a body with zero mass cannot have a non-zero first moment")
        ixx, ixy, iyy, ixz, iyz, izz = block[4:]
        rot = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        return pin.Inertia(0.0, np.zeros(3), rot)
    return pin.Inertia.FromDynamicParameters(block)


def inertia_defect(mass: float, inertia: FloatArray, where: str, com: FloatArray | None = None,
                   rtol: float = 1e-9) -> str | None:
    """What makes a body's inertial data impossible for a rigid body, or None when nothing does.

    A negative or non-finite mass and non-finite inertia entries raise :class:`ModelError` (no
    rigid body is near them). Otherwise the defects are those of the rotational inertia about the
    centre of mass (3 x 3): not positive semi-definite, or principal moments that break the
    triangle inequality (each at most the sum of the other two); together, the covariance of the
    mass distribution :math:`\\Sigma_c = \\tfrac12\\mathrm{tr}(I_c)\\mathbf 1 - I_c` is not positive
    semi-definite (Wensing, Kim & Slotine, RA-L 2017: the pseudo-inertia condition).

    Tolerance, relative to the body's own inertia scale: a defect counts when it exceeds
    ``rtol`` times :math:`s = \\max_i |\\lambda_i(I_c)| + m\\,\\|c\\|^2`, with ``com`` :math:`c` the centre
    of mass in the body's frame (default the origin). :math:`s` bounds the largest principal
    moment about the frame's origin, the inertia the standard parameters hold (a 1.3 kg head
    written with moments of 1e-35 kg*m^2 at 0.11 m has :math:`s` = 1.7e-2 kg*m^2, not 1e-35).
    ``where`` names the body in the messages.
    """
    if not np.isfinite(mass) or mass < 0:
        raise ModelError(f"{where}: mass {mass:g} kg is {'negative' if mass < 0 else 'not finite'}")
    I = np.asarray(inertia, dtype=float)
    c = np.zeros(3) if com is None else np.asarray(com, dtype=float)
    if not np.all(np.isfinite(I)):
        raise ModelError(f"{where}: the inertia has non-finite entries")
    if not np.all(np.isfinite(c)):
        raise ModelError(f"{where}: the centre of mass has non-finite coordinates")
    w = np.linalg.eigvalsh(0.5 * (I + I.T))
    tol = rtol * max(float(np.abs(w).max()) + float(mass) * float(c @ c), 1e-300)
    moments = ", ".join(f"{x:.6g}" for x in w)
    if w[0] < -tol:
        return f"the inertia is not positive semi-definite (principal moments {moments} kg*m^2)"
    if w[2] > w[0] + w[1] + tol:
        return (f"the principal moments of inertia {moments} kg*m^2 break the triangle inequality "
                f"({w[2]:.6g} > {w[0]:.6g} + {w[1]:.6g}); no rigid body has them")
    return None


def check_inertia(mass: float, inertia: FloatArray, where: str, rtol: float = 1e-9,
                  com: FloatArray | None = None) -> None:
    """Refuse a body that no physical body can be (:func:`inertia_defect`, same tolerance):
    :class:`ModelError` naming it (``where``) and the defect."""
    defect = inertia_defect(mass, inertia, where, com, rtol)
    if defect is not None:
        raise ModelError(f"{where}: {defect}")


def joint_kinds(model: pin.Model, velocity_indices: Sequence[int] | None = None) -> tuple[str, ...]:
    """``"revolute"`` or ``"prismatic"`` for each 1-DOF joint of ``model`` (all, in velocity
    order, or those at ``velocity_indices``); other joints are ``"other"``."""
    kind: dict[int, str] = {}
    for jm in model.joints[1:]:
        name = jm.shortname()
        k = ("prismatic" if "Prismatic" in name or name.startswith("JointModelP")
             else "revolute" if "Revolute" in name or name.startswith("JointModelR") else "other")
        for v in range(jm.idx_v, jm.idx_v + jm.nv):
            kind[v] = k if jm.nv == 1 else "other"
    idx = range(model.nv) if velocity_indices is None else velocity_indices
    return tuple(kind[int(v)] for v in idx)


def _frozen_copy(model: pin.Model) -> pin.Model:
    return pin.Model(model)


@dataclasses.dataclass(frozen=True, eq=False)
class RobotModel:
    """A serial (tree) robot: pinocchio model + joint extras + transmission.

    Parameters
    ----------
    pin_model : pinocchio.Model
        Kinematic tree and nominal inertias (copied; treat as immutable). A non-zero
        ``armature`` (an MJCF description's rotor inertias) becomes the nominal ``Ia`` (unless
        ``nominal_extras`` gives it) and is cleared in the copy: rotor inertia reaches pinocchio's
        RNEA through :meth:`with_parameters` only, when the layout has ``Ia``.
    name : str
        Human-readable name.
    extras : sequence of str
        Enabled joint extras, a subset of :data:`JOINT_EXTRAS`.
    transmission : Transmission, optional
        Motor-joint map; couplings add motor-side extra parameters.
    nominal_extras : mapping, optional
        Nominal values of the extras, e.g. ``{"Ia": [...], "fv": [...]}`` and for
        coupled motors ``{"Iam": {6: 0.01}}``; missing ones are 0.
    source : str
        Where the model came from (file path or ``builtin:<name>``).
    coulomb_width : sequence of float, optional
        Per joint, the velocity-noise std [rad/s or m/s] of the Coulomb terms' smooth sign
        (:func:`~dynid.model.serial_dynamics.smooth_sign`); None: the sign itself (default).
    """

    pin_model: pin.Model
    name: str = "robot"
    extras: tuple[str, ...] = JOINT_EXTRAS
    transmission: Transmission | None = None
    nominal_extras: Mapping[str, object] = dataclasses.field(default_factory=dict)
    source: str = ""
    coulomb_width: tuple[float, ...] | None = None

    layout: ParameterLayout = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        m = _frozen_copy(self.pin_model)
        for j in range(1, m.njoints):
            if m.joints[j].nv != 1:
                raise ModelError(
                    f"joint {m.names[j]!r} has {m.joints[j].nv} DOF; serial RobotModel supports 1-DOF joints "
                    "(closed-loop and multi-DOF joints are handled by Mechanism)"
                )
        armature = np.array(m.armature, dtype=float)
        if np.any(armature != 0.0):
            # one route for rotor inertia: a description's armature (MJCF) is the nominal Ia, and the model's
            # armature is set from the parameters only (with_parameters), so that rnea and the regressor agree
            # (as Mechanism's MJCF loader does with its Ia_<joint> terms)
            m.armature = np.zeros(m.nv)
            if "Ia" not in self.nominal_extras:
                object.__setattr__(self, "nominal_extras", {**dict(self.nominal_extras), "Ia": armature})
        object.__setattr__(self, "pin_model", m)
        object.__setattr__(self, "extras", _normalize_extras(self.extras))
        if self.transmission is not None and self.transmission.n != m.nv:
            raise ModelError(f"transmission has {self.transmission.n} motors but the robot has {m.nv} joints")
        coupled = self.transmission.coupled_motors if self.transmission is not None else ()
        object.__setattr__(self, "layout", ParameterLayout(m.njoints - 1, m.nv, self.extras, coupled))
        object.__setattr__(self, "nominal_extras", MappingProxyType(dict(self.nominal_extras)))
        if self.coulomb_width is not None:
            w = tuple(float(x) for x in self.coulomb_width)
            if len(w) != m.nv or not all(np.isfinite(x) and x >= 0 for x in w):
                raise ModelError(f"coulomb_width needs {m.nv} finite values >= 0 (one per joint), got {list(w)}")
            object.__setattr__(self, "coulomb_width", w)

    # ------------------------------------------------------------------ basics
    @property
    def dof(self) -> int:
        return int(self.pin_model.nv)

    @property
    def n_actuators(self) -> int:
        return self.dof if self.transmission is None else self.transmission.n

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(self.pin_model.names[1:])

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return self.layout.names

    @property
    def n_standard_params(self) -> int:
        return self.layout.n_params

    def body_blocks(self) -> tuple[np.ndarray, ...]:
        """Indices of each body's ``[m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (as
        :meth:`dynid.model.mechanism.Mechanism.body_blocks`)."""
        return tuple(np.arange(10 * b, 10 * b + 10) for b in range(self.layout.n_bodies))

    def create_data(self) -> pin.Data:
        """Working memory for pinocchio algorithms on this model."""
        return self.pin_model.createData()

    def position_limits(self) -> tuple[FloatArray, FloatArray]:
        """Lower and upper joint limits; infinite or absent limits become ±π."""
        lo = np.array(self.pin_model.lowerPositionLimit, dtype=float)
        hi = np.array(self.pin_model.upperPositionLimit, dtype=float)
        bad = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi <= lo) | (np.abs(lo) > 1e6) | (np.abs(hi) > 1e6)
        lo[bad], hi[bad] = -np.pi, np.pi
        return lo, hi

    def replace(self, **changes: object) -> RobotModel:
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ parameters
    def nominal_parameters(self) -> FloatArray:
        """Standard parameter vector of the model's own inertias and nominal extras."""
        m = self.pin_model
        lay = self.layout
        pi = np.zeros(lay.n_params)
        for j in range(1, m.njoints):
            pi[10 * (j - 1) : 10 * j] = m.inertias[j].toDynamicParameters()
        for e, idx in lay.extra_index.items():
            val = self.nominal_extras.get(e)
            if val is not None:
                pi[idx] = np.broadcast_to(np.asarray(val, dtype=float), (lay.nv,))
        for e, idx in lay.motor_index.items():
            val = self.nominal_extras.get(_MOTOR_PREFIX[e], {})
            for pos, k in zip(idx, lay.coupled_motors):
                pi[pos] = float(dict(val).get(k + 1, 0.0))  # type: ignore[arg-type]
        return pi

    def with_parameters(self, params: FloatArray) -> pin.Model:
        """A pinocchio model whose body inertias are taken from ``params``.

        Extras are not represented in the returned model except rotor inertia,
        which goes to ``model.armature`` (pinocchio's RNEA includes it).
        """
        params = np.asarray(params, dtype=float)
        if params.shape != (self.layout.n_params,):
            raise ModelError(f"expected {self.layout.n_params} standard parameters, got shape {params.shape}")
        m = pin.Model(self.pin_model)
        for j in range(1, m.njoints):
            m.inertias[j] = inertia_from_parameters(params[10 * (j - 1) : 10 * j])
        if "Ia" in self.layout.extra_index:
            m.armature = params[self.layout.extra_index["Ia"]].copy()
        return m
