"""Parts of a closed-loop mechanism description: loop closures, joint terms, independent
coordinates, and the kinematic state along samples (see :mod:`dynid.model.mechanism`)."""

from __future__ import annotations

import dataclasses
from typing import Literal

import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import ModelError

__all__ = ["TERM_KINDS", "JointCoordinates", "JointTerm", "KinematicState", "LoopClosure", "PointCoordinates"]

TERM_KINDS = ("inertia", "viscous", "coulomb", "viscous+", "viscous-", "coulomb+", "coulomb-", "offset")
"""Basis functions of joint terms; see :class:`JointTerm`."""


@dataclasses.dataclass(frozen=True)
class LoopClosure:
    """A loop-closure constraint between two points (``"3d"``) or frames (``"6d"``).

    Parameters
    ----------
    name : str
    joint_a, joint_b : int
        pinocchio joint indices the two sides are attached to (0 = the fixed base).
    placement_a, placement_b : pinocchio.SE3
        Placement of the contact point / frame in the joint frame.
    kind : {"3d", "6d"}
        ``"3d"``: the two points coincide (a spherical joint at the cut, MJCF ``<connect>``),
        3 rows; ``"6d"``: the two frames coincide (MJCF ``<weld>``), 6 rows.
    """

    name: str
    joint_a: int
    placement_a: pin.SE3
    joint_b: int
    placement_b: pin.SE3
    kind: Literal["3d", "6d"] = "3d"

    def __post_init__(self) -> None:
        if self.kind not in ("3d", "6d"):
            raise ModelError(f"loop closure {self.name!r}: kind must be '3d' or '6d', got {self.kind!r}")

    @property
    def rows(self) -> int:
        return 3 if self.kind == "3d" else 6


@dataclasses.dataclass(frozen=True)
class JointTerm:
    """One parameter acting on one or more joints through a basis function.

    The generalized force on joint ``j`` (velocity index, 0-based) of every joint listed
    is ``theta * b(qd_j, qdd_j)`` with ``b`` given by ``kind``:

    ============  =============================================  ======================
    kind          b(qd, qdd)                                     e.g.
    ============  =============================================  ======================
    inertia       qdd                                            rotor inertia Ia
    viscous       qd                                             fv
    coulomb       sign(qd)                                       fc
    viscous+      qd if qd > 0 else 0                            Shang 2009, Eq. 2
    viscous-      qd if qd < 0 else 0                            Shang 2009, Eq. 2
    coulomb+      1 if qd > 0 else 0                             Shang 2009, Eq. 2
    coulomb-      1 if qd < 0 else 0 (the parameter is negative) Shang 2009, Eq. 2
    offset        1                                              torque offset
    ============  =============================================  ======================

    A term listing several joints is a coefficient shared by them (PaLiDA's common dry
    friction of all cardan joints, Abdellatif & Heimann).

    With ``weights`` (one per joint) the term acts through the combined velocity
    :math:`w = \\sum_j c_j \\dot q_j` instead: the force on joint ``j`` is
    ``c_j * theta * b(w, dw/dt)``. That is a motor coupled to several joints through its
    transmission (:class:`~dynid.model.transmission.Transmission`, :math:`c_k = C_{k,:}/C_{kk}`):
    its rotor inertia and friction act on the motor's own velocity, by virtual power.
    """

    name: str
    kind: str
    joints: tuple[int, ...]
    weights: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in TERM_KINDS:
            raise ModelError(f"joint term {self.name!r}: unknown kind {self.kind!r}; choose from {list(TERM_KINDS)}")
        object.__setattr__(self, "joints", tuple(int(j) for j in self.joints))
        object.__setattr__(self, "weights", tuple(float(w) for w in self.weights))
        if not self.joints:
            raise ModelError(f"joint term {self.name!r} acts on no joint")
        if self.weights and len(self.weights) != len(self.joints):
            raise ModelError(f"joint term {self.name!r}: {len(self.weights)} weights for {len(self.joints)} joints")


@dataclasses.dataclass(frozen=True)
class JointCoordinates:
    """Independent coordinates that are joint positions (velocity indices, 0-based)."""

    joints: tuple[int, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", tuple(int(j) for j in self.joints))

    @property
    def size(self) -> int:
        return len(self.joints)


@dataclasses.dataclass(frozen=True)
class PointCoordinates:
    """Independent coordinates that are components of a point's world position.

    Parameters
    ----------
    joint : int
        pinocchio joint index the point is attached to.
    placement : pinocchio.SE3
        Placement of the point in that joint's frame (only the translation is used).
    axes : tuple of int
        World components, e.g. ``(0, 1)`` for ``x, y`` of a planar robot.
    """

    joint: int
    placement: pin.SE3
    axes: tuple[int, ...] = (0, 1, 2)

    def __post_init__(self) -> None:
        object.__setattr__(self, "axes", tuple(int(a) for a in self.axes))
        if not self.axes or any(a not in (0, 1, 2) for a in self.axes):
            raise ModelError(f"point coordinates: axes must be a subset of (0, 1, 2), got {self.axes}")

    @property
    def size(self) -> int:
        return len(self.axes)


Coordinates = JointCoordinates | PointCoordinates


@dataclasses.dataclass(frozen=True, eq=False)
class KinematicState:
    """Constraint-consistent states of all joints along samples (see :meth:`Mechanism.states`).

    Attributes
    ----------
    q, dq, ddq : array, shape (n, n_v)
        Positions, velocities and accelerations of all joints.
    G : array, shape (n, n_v, n_u)
        Velocity map :math:`\\dot q = G \\dot u`.
    cond : array, shape (n,)
        1-norm condition number of :math:`[J_c; J_u]` per sample.
    """

    q: FloatArray
    dq: FloatArray
    ddq: FloatArray
    G: FloatArray
    cond: FloatArray

    @property
    def n(self) -> int:
        return int(self.q.shape[0])
