"""Closed-loop mechanisms: kinematic tree + loop closures + actuators + independent coordinates.

A parallel robot is described, as in DESIGN.md ("Closed-loop mechanisms"), by

* a pinocchio kinematic tree with **all** bodies and all joints, active and passive
  (1-DOF joints only: a universal joint is two revolutes with the cardan ring between
  them, a platform pose is a chain of six 1-DOF joints with massless intermediate bodies,
  a spherical joint at a cut is the loop closure itself, any other is three revolute joints
  through two massless bodies, :class:`BallJoint`);
* loop-closure constraints :math:`c(q) = 0` (:class:`LoopClosure`: point coincidence
  ``"3d"`` = MJCF ``<connect>``, or frame coincidence ``"6d"`` = ``<weld>``);
* the actuated joints;
* the independent coordinates :math:`u` (:class:`JointCoordinates`: a subset of joints,
  typically the actuated ones; or :class:`PointCoordinates`: components of the world
  position of a point, e.g. the end-effector of a planar robot);
* the parameters: inertial parameters of the bodies that have mass, and joint terms
  (:class:`JointTerm`) for rotor inertia, friction (symmetric, asymmetric, shared
  between joints) and offsets, on **any** joint, passive ones included.

Kinematics (:mod:`dynid.model.closed_loop` builds the dynamics on top): with the
constraint Jacobian :math:`J_c` (redundant rows allowed) and the Jacobian :math:`J_u` of
the independent coordinates,

.. math::

    \\begin{bmatrix} J_c \\\\ J_u \\end{bmatrix} \\dot q = \\begin{bmatrix} 0 \\\\ \\dot u \\end{bmatrix},
    \\qquad
    \\begin{bmatrix} J_c \\\\ J_u \\end{bmatrix} \\ddot q =
    \\begin{bmatrix} -\\dot J_c \\dot q \\\\ \\ddot u - \\dot J_u \\dot q \\end{bmatrix},

so :math:`\\dot q = G(q)\\,\\dot u` with :math:`J_c G = 0`, :math:`J_u G = I`. Redundant
constraint rows (a planar loop closed by a 3-D point constraint has an identically zero
``z`` row) are removed once, by a pivoted QR of :math:`J_c` at the assembled reference
configuration, so that the stacked matrix is square and solved per sample in batch.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from types import MappingProxyType

import numpy as np
import pinocchio as pin

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.model import charts, loop_assembly, loop_kinematics
from dynid.model.ball_joints import BallJoint, add_ball_joint, add_universal_joint  # noqa: F401  (re-exported)
from dynid.model.closures import (
    TERM_KINDS,
    Coordinates,
    JointCoordinates,
    JointTerm,
    KinematicState,
    LoopClosure,
    PointCoordinates,
)
from dynid.model.robot import BODY_PARAMS, inertia_from_parameters

__all__ = [
    "TERM_KINDS",
    "BallJoint",
    "add_ball_joint",
    "add_universal_joint",
    "JointCoordinates",
    "JointTerm",
    "LoopClosure",
    "Mechanism",
    "PointCoordinates",
    "KinematicState",
]

_NONNEG_KINDS = ("inertia", "viscous", "coulomb", "viscous+", "viscous-", "coulomb+")


BALL_MARGIN_DEG = 10.0
"""How close [deg] the middle angle of a ball joint's chart may come to ±90° (its singularity)."""


def _skew(p: FloatArray) -> FloatArray:
    return np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])


@dataclasses.dataclass(frozen=True, eq=False)
class Mechanism:
    """A closed-loop mechanism (see module docstring).

    Parameters
    ----------
    pin_model : pinocchio.Model
        Kinematic tree with all bodies and joints (1-DOF joints); copied.
    closures : sequence of LoopClosure
    actuated : sequence of int
        Velocity indices (0-based) of the actuated joints, in actuator order.
    independent : JointCoordinates or PointCoordinates, optional
        Independent coordinates; default: the actuated joints, or for redundant actuation the
        subset of them whose velocity map is best conditioned over a sample of the workspace
        (:meth:`rank_charts`; recorded in ``independent_choice``).
    terms : sequence of JointTerm
        Joint terms (friction, rotor inertia, offsets) in parameter order.
    massless : sequence of int
        pinocchio joint indices whose bodies carry no parameters (virtual bodies, e.g. the
        intermediate links of a 6-joint platform chain). Their inertias must be zero.
    nominal_terms : mapping of str to float
        Nominal values of the joint terms (missing ones are 0).
    q_guess : array, shape (n_v,), optional
        A configuration near an assembly of the loops (default: the neutral one). The
        reference configuration ``q_ref`` is the assembly closest to it.
    name, source : str
    notes : sequence of str
        Modelling choices a user should know (shown by ``dynid info``).
    task_coordinates : sequence of str
        Names of the joints whose positions are the platform (end-effector) pose when the tree
        reaches the platform through a chain of 1-DOF joints (``PX, PY, PZ, RZ, RY, RX`` in
        the built-ins), as many as the degrees of freedom: the task-space coordinates
        :meth:`in_task_space` switches to.
    task_ik : callable, optional
        Closed-form inverse kinematics ``task_ik(pose (n, n_task)) -> q (n, n_v)`` for the task
        coordinates; :meth:`solve_positions` of the task-space mechanism starts Newton from it
        (one step checks it) instead of walking from the previous sample.
    position_guess : callable, optional
        Set by :meth:`in_task_space`: initial guesses of :meth:`solve_positions` from ``u``.
    identical_chains : groups of chains of joint names, optional
        Kinematic chains that are identical by the robot's symmetry (a built-in's own knowledge),
        the default chains of the structural reduction (:mod:`dynid.model.reduction`).
    symmetric_zero : sequence of str
        Standard parameters that the papers' symmetric-body simplification fixes at zero
        (structure ``"paper"``, :mod:`dynid.model.reduction`).
    ball_joints : sequence of BallJoint
        Spherical joints modelled as three hinges through two massless bodies (the MJCF
        reader's ``<joint type="ball">``, the URDF reader's ``SPHERICAL`` joints,
        :func:`add_ball_joint`): the hinges' bodies must be massless but the last (the first
        two count as ``massless`` without being listed there);
        that one's parameters are named after ``body``; a configuration within
        ``BALL_MARGIN_DEG`` of the chart's singularity is refused (one-line ModelError).
    coulomb_width : sequence of float, optional
        Per joint (velocity index), the velocity-noise std of the Coulomb terms' smooth sign
        (:func:`~dynid.model.serial_dynamics.smooth_sign`); None: the sign itself (default).
    independent_choice : str
        How the independent coordinates were chosen when none were given to a redundantly
        actuated mechanism (:meth:`choose_independent`); empty when given (or when they are the
        actuated joints of a non-redundant one). Set by the mechanism itself, kept by
        ``dataclasses.replace``.
    """

    pin_model: pin.Model
    closures: tuple[LoopClosure, ...]
    actuated: tuple[int, ...]
    independent: Coordinates | None = None
    terms: tuple[JointTerm, ...] = ()
    massless: tuple[int, ...] = ()
    nominal_terms: Mapping[str, float] = dataclasses.field(default_factory=dict)
    q_guess: FloatArray | None = None
    name: str = "mechanism"
    source: str = ""
    notes: tuple[str, ...] = ()
    task_coordinates: tuple[str, ...] = ()
    task_ik: object = None
    position_guess: object = None
    identical_chains: tuple = ()
    symmetric_zero: tuple[str, ...] = ()
    ball_joints: tuple[BallJoint, ...] = ()
    coulomb_width: tuple[float, ...] | None = None
    independent_choice: str = ""

    # derived
    bodies: tuple[int, ...] = dataclasses.field(init=False)
    parameter_names: tuple[str, ...] = dataclasses.field(init=False)
    term_incidence: np.ndarray = dataclasses.field(init=False, repr=False)  # (n_v, n_terms): term k acts on joint j
    term_groups: tuple = dataclasses.field(init=False, repr=False)  # ((kind, term indices), ...) of unweighted terms
    q_ref: FloatArray = dataclasses.field(init=False)
    constraint_rows: np.ndarray = dataclasses.field(init=False)
    mobility: int = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        m = pin.Model(self.pin_model)
        # rotor inertia is a joint term ("inertia"), never hidden in the tree: pinocchio's RNEA
        # would add model.armature, its regressor would not
        if np.any(np.asarray(m.armature) != 0.0):
            raise ModelError(
                f"mechanism {self.name!r}: the pinocchio model has a non-zero armature; "
                "give rotor inertias as 'inertia' joint terms (loaders convert them)"
            )
        set_ = object.__setattr__
        set_(self, "pin_model", m)
        for j in range(1, m.njoints):
            if m.joints[j].nv != 1 or m.joints[j].nq != 1:
                raise ModelError(
                    f"joint {m.names[j]!r} ({m.joints[j].shortname()}) is not a 1-DOF joint; "
                    "model multi-DOF joints as chains of revolute/prismatic joints (a spherical joint at a cut is a '3d' closure)"
                )
        set_(self, "closures", tuple(self.closures))
        set_(self, "actuated", tuple(int(a) for a in self.actuated))
        set_(self, "terms", tuple(self.terms))
        # the two intermediate bodies of a ball joint are massless by construction (checked below)
        names = list(m.names)
        ball_mids = {names.index(h) for b in self.ball_joints for h in tuple(b.hinges)[:2] if h in names}
        set_(self, "massless", tuple(sorted({int(j) for j in self.massless} | ball_mids)))
        set_(self, "notes", tuple(self.notes))
        set_(self, "task_coordinates", tuple(self.task_coordinates))
        missing = [n for n in self.task_coordinates if n not in m.names[1:]]
        if missing:
            raise ModelError(f"task coordinates {missing} are not joints of {self.name!r}")
        set_(self, "nominal_terms", MappingProxyType(dict(self.nominal_terms)))
        nv = m.nv
        if not self.closures:
            raise ModelError(f"mechanism {self.name!r} has no loop closure; a robot without closures is a serial RobotModel")
        names = [c.name for c in self.closures]
        for c in self.closures:
            for side, j in (("a", c.joint_a), ("b", c.joint_b)):
                if not 0 <= j < m.njoints:
                    raise ModelError(f"loop closure {c.name!r}: joint_{side} index {j} does not exist (model has {m.njoints - 1} joints)")
            if c.joint_a == c.joint_b:
                raise ModelError(f"loop closure {c.name!r} connects joint {m.names[c.joint_a]!r} to itself")
        if len(set(names)) != len(names):
            raise ModelError(f"duplicate loop-closure names in {names}")
        if not self.actuated:
            raise ModelError(f"mechanism {self.name!r} has no actuated joint")
        bad = [a for a in self.actuated if not 0 <= a < nv]
        if bad or len(set(self.actuated)) != len(self.actuated):
            raise ModelError(f"actuated joints {list(self.actuated)} must be distinct velocity indices in [0, {nv})")
        for t in self.terms:
            badj = [j for j in t.joints if not 0 <= j < nv]
            if badj:
                raise ModelError(f"joint term {t.name!r} refers to joints {badj} outside [0, {nv})")
        tnames = [t.name for t in self.terms]
        if len(set(tnames)) != len(tnames):
            raise ModelError("duplicate joint-term names")
        incidence = np.zeros((nv, len(self.terms)))  # incidence[j, k] = 1 if term k acts on joint j (c_j if weighted)
        for k, t in enumerate(self.terms):
            incidence[list(t.joints), k] = t.weights if t.weights else 1.0
        incidence.setflags(write=False)
        set_(self, "term_incidence", incidence)
        plain = [k for k, t in enumerate(self.terms) if not t.weights]
        kinds = dict.fromkeys(self.terms[k].kind for k in plain)
        set_(self, "term_groups", tuple((kind, np.array([k for k in plain if self.terms[k].kind == kind]))
                                        for kind in kinds))
        unknown = sorted(set(self.nominal_terms) - set(tnames))
        if unknown:
            raise ModelError(f"nominal values given for unknown joint terms {unknown}")
        for j in self.massless:
            if not 1 <= j < m.njoints:
                raise ModelError(f"massless body index {j} does not exist")
            if np.any(np.abs(m.inertias[j].toDynamicParameters()) > 0.0):
                ball = next((b.name for b in self.ball_joints if m.names[j] in tuple(b.hinges)[:2]), None)
                if ball is not None:
                    raise ModelError(f"ball joint {ball!r}: the body of its hinge {m.names[j]!r} must be massless "
                                     "(the ball's body hangs from its last hinge)")
                raise ModelError(f"body of joint {m.names[j]!r} is declared massless but has non-zero inertia")
        bodies = tuple(j for j in range(1, m.njoints) if j not in self.massless)
        set_(self, "bodies", bodies)
        set_(self, "ball_joints", tuple(self.ball_joints))
        if self.coulomb_width is not None:
            cw = tuple(float(x) for x in self.coulomb_width)
            if len(cw) != m.nv or not all(np.isfinite(x) and x >= 0 for x in cw):
                raise ModelError(f"coulomb_width needs {m.nv} finite values >= 0 (one per joint), got {list(cw)}")
            set_(self, "coulomb_width", cw)
        set_(self, "_ball_middle", self._check_balls())
        pnames = [f"{p}_{self.body_label(j)}" for j in bodies for p in BODY_PARAMS] + tnames
        set_(self, "parameter_names", tuple(pnames))
        set_(self, "symmetric_zero", tuple(self.symmetric_zero))
        if set(self.symmetric_zero) - set(pnames):
            raise ModelError(f"symmetric_zero names unknown parameters {sorted(set(self.symmetric_zero) - set(pnames))[:3]}")
        auto = self.independent is None  # redundant actuation: chosen in _check_topology (choose_independent)
        indep = self.independent if self.independent is not None else JointCoordinates(self.actuated)
        if isinstance(indep, JointCoordinates):
            badj = [j for j in indep.joints if not 0 <= j < nv]
            if badj:
                raise ModelError(f"independent joint coordinates {badj} outside [0, {nv})")
        elif not 0 <= indep.joint < m.njoints:
            raise ModelError(f"independent point attached to joint index {indep.joint}, which does not exist")
        set_(self, "independent", indep)
        self._check_topology(auto)

    # ------------------------------------------------------------------ ball joints
    def _check_balls(self) -> tuple[tuple[str, int], ...]:
        """(ball name, q index of its middle hinge) per ball joint, after checking that its
        hinges are a chain of 1-DOF revolute joints whose first two bodies are massless."""
        m = self.pin_model
        names = list(m.names)
        out = []
        for b in self.ball_joints:
            missing = [h for h in b.hinges if h not in names]
            if len(b.hinges) != 3 or missing:
                raise ModelError(f"ball joint {b.name!r}: hinges {list(b.hinges)} are not three joints of the model")
            ids = [names.index(h) for h in b.hinges]
            if m.parents[ids[1]] != ids[0] or m.parents[ids[2]] != ids[1]:
                raise ModelError(f"ball joint {b.name!r}: hinges {list(b.hinges)} are not a chain")
            if any(j not in self.massless for j in ids[:2]):
                raise ModelError(f"ball joint {b.name!r}: the bodies of hinges {list(b.hinges[:2])} must be massless")
            if not all(m.joints[j].shortname().startswith("JointModelR") for j in ids):
                raise ModelError(f"ball joint {b.name!r}: hinges {list(b.hinges)} must be revolute joints")
            out.append((b.name, int(m.joints[ids[1]].idx_q)))
        return tuple(out)

    def body_label(self, joint: int) -> str:
        """The name in the parameter names (``m_<label>``) of the body of pinocchio joint
        ``joint``: the joint's name, or the body's for the last hinge of a ball joint."""
        name = self.pin_model.names[joint]
        return next((b.body for b in self.ball_joints if b.hinges[2] == name), name)

    def check_ball_charts(self, q: FloatArray, what: str = "configuration") -> None:
        """Refuse configurations ``q`` (n_v,) or (n, n_v) where a ball joint's middle angle is
        within ``BALL_MARGIN_DEG`` of ±90° (its three-hinge chart is singular there)."""
        if not self._ball_middle:
            return
        q = np.atleast_2d(np.asarray(q, dtype=float))
        limit = np.sin(np.radians(BALL_MARGIN_DEG))
        for name, iq in self._ball_middle:
            bad = np.flatnonzero(np.abs(np.cos(q[:, iq])) < limit)
            if bad.size:
                i = int(bad[0])
                raise ModelError(
                    f"{what}{f' sample {i}' if q.shape[0] > 1 else ''}: ball joint {name!r} is at "
                    f"{np.degrees(q[i, iq]):.1f} deg on its middle hinge {self.pin_model.names[iq + 1]!r}, within "
                    f"{BALL_MARGIN_DEG:g} deg of the singularity of its three-hinge chart (gimbal lock at ±90 deg)"
                )

    # ------------------------------------------------------------------ set-up checks
    def _check_topology(self, auto: bool = False) -> None:
        """Assemble the loops, find the independent constraint rows, check the mobility
        (:func:`dynid.model.charts.check_topology`)."""
        charts.check_topology(self, auto)

    # ------------------------------------------------------------------ independent coordinates (dynid.model.charts)
    WORKSPACE_SAMPLES = charts.WORKSPACE_SAMPLES

    def _workspace_samples(self, q_ref: FloatArray, Jc: FloatArray, data: pin.Data, seed: int = 0) -> FloatArray:
        return charts.workspace_samples(self, q_ref, Jc, data, seed)

    def rank_charts(self, q: FloatArray) -> list[tuple[tuple[int, ...], float]]:
        """Subsets of the actuated joints as independent coordinates, best first, with the worst
        condition number of their velocity map over the configurations ``q`` (n, n_v)
        (:func:`dynid.model.charts.rank_charts`)."""
        return charts.rank_charts(self, q)

    def _choice_text(self, ranked: list[tuple[tuple[int, ...], float]], n: int, over: str) -> str:
        return charts.choice_text(self, ranked, n, over)

    def choose_independent(self, q: FloatArray, over: str = "log samples") -> Mechanism:
        """The same mechanism with the best-conditioned actuated joints over the configurations ``q``
        as independent coordinates (:func:`dynid.model.charts.choose_independent`)."""
        return charts.choose_independent(self, q, over)

    def _chart_hint(self, Jc: FloatArray, mob: int, limit: int = 4, budget: int = 5000) -> str:
        return charts.chart_hint(self, Jc, mob, limit, budget)

    def _assemble(self, q0: FloatArray, data: pin.Data, tol: float = 1e-12, max_iter: int = 100) -> FloatArray:
        """Closest assembly to ``q0``: Gauss–Newton on c(q) = 0 with minimum-norm steps. When it
        does not converge the loops cannot close (an unreachable loop: Gauss–Newton ends at the
        least-squares gap): the error names the closure with the largest residual [m, rad]."""
        q = q0.copy()
        for _ in range(max_iter):
            c = self._constraint_residual(q, data)
            if np.linalg.norm(c, np.inf) < tol:
                return q
            J = self._constraint_jacobian(q, data, exact=True)
            step = np.linalg.lstsq(J, -c, rcond=1e-10)[0]
            q = q + step
        c = self._constraint_residual(q, data)
        ends = np.cumsum([cl.rows for cl in self.closures])
        per = [float(np.linalg.norm(part, np.inf)) if np.all(np.isfinite(part)) else np.inf
               for part in np.split(c, ends[:-1])]
        worst = int(np.argmax(per))
        cl = self.closures[worst]
        raise ModelError(
            f"cannot assemble the loops of {self.name!r}: closure {cl.name!r} ({cl.kind}) cannot close near the given "
            f"configuration (constraint residual {per[worst]:.3g} after {max_iter} Gauss-Newton steps)"
        )

    def in_task_space(self) -> Mechanism:
        """The same mechanism with the platform pose (``task_coordinates``) as independent
        coordinates, e.g. for task-space trajectories and control (paper 004, Eq. 16)."""
        if not self.task_coordinates:
            raise ModelError(f"{self.name!r} declares no task coordinates (a platform reached through a joint chain)")
        joints = tuple(list(self.pin_model.names).index(n) - 1 for n in self.task_coordinates)
        return dataclasses.replace(self, independent=JointCoordinates(joints), q_guess=self.q_ref, position_guess=self.task_ik,
                                   independent_choice="")

    # ------------------------------------------------------------------ sizes and names
    @property
    def nv(self) -> int:
        return int(self.pin_model.nv)

    @property
    def dof(self) -> int:
        """Degrees of freedom (mobility) of the closed mechanism."""
        return int(self.mobility)

    @property
    def n_actuators(self) -> int:
        return len(self.actuated)

    @property
    def redundant(self) -> bool:
        """True when there are more actuators than degrees of freedom (actuation redundancy)."""
        return self.n_actuators > self.dof

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(self.pin_model.names[1:])

    def with_chart(self, actuated: Sequence[str] | None = None, independent: Sequence[str] | None = None) -> Mechanism:
        """The same mechanism with other actuated joints (names, in actuator order) and/or other
        independent coordinates (joint names; default: the actuated joints). Joint terms stay
        as they are; the topology checks run again (a wrong set is a one-line :class:`ModelError`
        that lists valid choices)."""
        names = list(self.joint_names)

        def index(refs: Sequence[str], what: str) -> tuple[int, ...]:
            bad = [r for r in refs if r not in names]
            if bad:
                raise ModelError(f"{what} {bad} are not joints of {self.name!r}; joints: {names}")
            if len(set(refs)) != len(refs):
                raise ModelError(f"{what} {list(refs)} name a joint twice")
            return tuple(names.index(r) for r in refs)

        act = self.actuated if actuated is None else index(actuated, "actuated joints")
        if independent is None and actuated is not None:  # new actuators: their own chart (chosen again if redundant)
            return dataclasses.replace(self, actuated=act, independent=None, independent_choice="")
        if independent is None:
            return self
        return dataclasses.replace(self, actuated=act, independent=JointCoordinates(index(independent, "independent coordinates")),
                                   independent_choice="")

    @property
    def actuated_names(self) -> list[str]:
        return [self.pin_model.names[a + 1] for a in self.actuated]

    @property
    def n_standard_params(self) -> int:
        return len(self.parameter_names)

    @property
    def n_body_params(self) -> int:
        return 10 * len(self.bodies)

    def term_index(self, name: str) -> int:
        for k, t in enumerate(self.terms):
            if t.name == name:
                return self.n_body_params + k
        raise ModelError(f"no joint term named {name!r}")

    def position_limits(self) -> tuple[FloatArray, FloatArray]:
        lo = np.array(self.pin_model.lowerPositionLimit, dtype=float)
        hi = np.array(self.pin_model.upperPositionLimit, dtype=float)
        bad = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi <= lo) | (np.abs(lo) > 1e6) | (np.abs(hi) > 1e6)
        lo[bad], hi[bad] = -np.inf, np.inf
        return lo, hi

    def actuator_selection(self) -> FloatArray:
        """:math:`S_a`, shape (n_a, n_v): ``q_a = S_a q``."""
        Sa = np.zeros((self.n_actuators, self.nv))
        Sa[np.arange(self.n_actuators), list(self.actuated)] = 1.0
        return Sa

    # ------------------------------------------------------------------ parameters
    def nominal_parameters(self) -> FloatArray:
        """Standard parameters of the model's own inertias and the nominal joint terms."""
        m = self.pin_model
        pi = np.zeros(self.n_standard_params)
        for k, j in enumerate(self.bodies):
            pi[10 * k : 10 * k + 10] = m.inertias[j].toDynamicParameters()
        for k, t in enumerate(self.terms):
            pi[self.n_body_params + k] = float(self.nominal_terms.get(t.name, 0.0))
        return pi

    def body_blocks(self) -> tuple[np.ndarray, ...]:
        return tuple(np.arange(10 * k, 10 * k + 10) for k in range(len(self.bodies)))

    def nonnegative_parameters(self) -> np.ndarray:
        """Indices of joint terms that are non-negative physically (``coulomb-`` is not)."""
        nb = self.n_body_params
        return np.array([nb + k for k, t in enumerate(self.terms) if t.kind in _NONNEG_KINDS], dtype=int)

    def nonpositive_parameters(self) -> np.ndarray:
        """Indices of joint terms that are non-positive physically (``coulomb-``, Shang 2009 Eq. 2)."""
        nb = self.n_body_params
        return np.array([nb + k for k, t in enumerate(self.terms) if t.kind == "coulomb-"], dtype=int)

    def with_parameters(self, params: FloatArray) -> pin.Model:
        """A pinocchio tree whose body inertias come from ``params`` (joint terms are not in it)."""
        params = np.asarray(params, dtype=float)
        if params.shape != (self.n_standard_params,):
            raise ModelError(f"expected {self.n_standard_params} standard parameters, got shape {params.shape}")
        m = pin.Model(self.pin_model)
        for k, j in enumerate(self.bodies):
            m.inertias[j] = inertia_from_parameters(params[10 * k : 10 * k + 10])
        return m

    # ------------------------------------------------------------------ constraints (one sample)
    def _points(self, data: pin.Data, joint: int, placement: pin.SE3) -> pin.SE3:
        return data.oMi[joint] * placement

    def _point_jacobian(self, data: pin.Data, joint: int, p: FloatArray) -> tuple[FloatArray, FloatArray]:
        """World linear Jacobian of the body point at world position ``p``, and angular Jacobian."""
        nv = self.pin_model.nv
        if joint == 0:
            return np.zeros((3, nv)), np.zeros((3, nv))
        J = pin.getJointJacobian(self.pin_model, data, joint, pin.ReferenceFrame.WORLD)
        jl, ja = J[:3], J[3:]
        return jl - _skew(p) @ ja, ja

    def _constraint_residual(self, q: FloatArray, data: pin.Data) -> FloatArray:
        return loop_kinematics.closure_residual(self, q, data)

    def _constraint_jacobian(self, q: FloatArray, data: pin.Data, exact: bool = False) -> FloatArray:
        """:math:`J_c` (all rows). ``exact``: rotation rows are :math:`\\partial\\log_3/\\partial q`
        (for Newton); otherwise the relative angular velocity in the world frame (same null space)."""
        return loop_kinematics.closure_jacobian(self, q, data, exact)

    def _coordinate_values(self, q: FloatArray, data: pin.Data) -> FloatArray:
        ind = self.independent
        if isinstance(ind, JointCoordinates):
            return q[list(ind.joints)]
        pin.forwardKinematics(self.pin_model, data, q)
        p = self._points(data, ind.joint, ind.placement).translation
        return p[list(ind.axes)]

    def _coordinate_jacobian(self, q: FloatArray, data: pin.Data) -> FloatArray:
        ind = self.independent
        nv = self.pin_model.nv
        if isinstance(ind, JointCoordinates):
            J = np.zeros((ind.size, nv))
            J[np.arange(ind.size), list(ind.joints)] = 1.0
            return J
        pin.computeJointJacobians(self.pin_model, data, q)
        p = self._points(data, ind.joint, ind.placement).translation
        return self._point_jacobian(data, ind.joint, p)[0][list(ind.axes)]

    # ------------------------------------------------------------------ public kinematics
    def constraint_residual(self, q: FloatArray) -> FloatArray:
        """:math:`c(q)` stacked over closures: point gaps [m] and, for ``6d``, the relative
        rotation vector :math:`R_a\\log_3(R_a^T R_b)` in world axes [rad].
        Shape ``(n_c,)`` or ``(n, n_c)``."""
        q = np.asarray(q, dtype=float)
        data = self.pin_model.createData()
        if q.ndim == 1:
            return self._constraint_residual(self._check_q(q[None])[0], data)
        return np.array([self._constraint_residual(qi, data) for qi in self._check_q(q)])

    def constraint_jacobian(self, q: FloatArray) -> FloatArray:
        """:math:`J_c(q)` with all (possibly redundant) rows, shape ``(n_c, n_v)``."""
        q = self._check_q(np.atleast_2d(np.asarray(q, dtype=float)))[0]
        return self._constraint_jacobian(q, self.pin_model.createData())

    def coordinates(self, q: FloatArray, *, data: pin.Data | None = None) -> FloatArray:
        """Independent coordinates :math:`u(q)`, shape ``(n, n_u)``. ``data``: working memory of
        ``pin_model`` to reuse (a controller calls this every period; creating it costs about
        100 us for the hexapod)."""
        q = self._check_q(np.atleast_2d(np.asarray(q, dtype=float)))
        data = self.pin_model.createData() if data is None else data
        return np.array([self._coordinate_values(qi, data) for qi in q])

    def coordinate_velocities(self, q: FloatArray, dq: FloatArray, *, data: pin.Data | None = None) -> FloatArray:
        """:math:`\\dot u = J_u(q)\\dot q`, shape ``(n, n_u)``; ``data`` as in :meth:`coordinates`."""
        q = self._check_q(np.atleast_2d(np.asarray(q, dtype=float)))
        dq = self._check_q(np.atleast_2d(np.asarray(dq, dtype=float)), "dq")
        data = self.pin_model.createData() if data is None else data
        return np.array([self._coordinate_jacobian(qi, data) @ vi for qi, vi in zip(q, dq)])

    def project(self, q: FloatArray, dq: FloatArray | None = None, *, tol: float = 1e-12, max_iter: int = 10,
                data: pin.Data | None = None, vtol: float | None = None):
        """The nearest assembled configuration (minimum-norm Gauss–Newton steps on the
        independent constraint rows) and, if given, the velocity projected on the constraint
        tangent space (:math:`\\dot q - J_c^+ J_c \\dot q`). Used to remove the drift of a
        numerical integration; one sample, shapes ``(n_v,)``. ``data`` as in :meth:`coordinates`.

        ``vtol``: leave ``dq`` as it is where no position step was taken and its constraint
        residual :math:`\\|J_c \\dot q\\|_\\infty` is at most ``vtol`` (the same rule as the
        positions' ``tol``: a state already on the closures within the tolerances is returned
        unchanged; the simulator's every-period projection, which then skips the QR of
        :math:`J_c` on most periods, :func:`dynid.simulation.closed_loop.simulate_mechanism_control`).
        None (default): always project."""
        q = np.array(q, dtype=float)
        if not (np.isfinite(q).all() and (dq is None or np.isfinite(dq).all())):
            # a diverged integration: say so before LAPACK sees NaN (it prints to the terminal)
            raise ModelError("cannot project onto the loop closures: the configuration is not finite (the motion diverged)")
        data = self.pin_model.createData() if data is None else data
        rows = self.constraint_rows
        lk = loop_kinematics
        point = lk._closures(self).all_3d  # point closures: residual and Jacobian in one pass, the same values
        for _ in range(max_iter):
            if point:
                c, J = lk.point_closure_rows(self, q, data)
            else:
                geometry = lk.closure_geometry(self, q, data)  # one pass for the residual and the Jacobian
                c = lk.closure_residual(self, q, data, geometry)[rows]
            gap = np.abs(c).max(initial=0.0)  # the infinity norm
            if not np.isfinite(gap):
                raise ModelError("cannot project onto the loop closures: the closure residual is not finite")
            if gap < tol:
                break
            q = q - lk.lstsq_full_rank(J if point else lk.closure_jacobian(self, q, data, True, geometry)[rows], c)
        else:
            raise ModelError(f"cannot project onto the loop closures (residual {np.linalg.norm(c, np.inf):.3g})")
        if dq is None:
            return q
        if not point:
            J = lk.closure_jacobian(self, q, data, False, geometry)[rows]  # geometry: at this q
        dq = np.asarray(dq, dtype=float)
        if vtol is not None and _ == 0 and np.abs(J @ dq).max(initial=0.0) <= vtol:
            return q, dq
        f = lk.row_space(J)
        if f is None:
            return q, dq - np.linalg.lstsq(J, J @ dq, rcond=None)[0]
        Q = f[0]  # J^+ J = Q Q^T, the projector onto the rows of J
        return q, dq - Q @ (Q.T @ dq)

    def _check_q(self, q: FloatArray, name: str = "q") -> FloatArray:
        if q.ndim != 2 or q.shape[1] != self.nv:
            raise InputError(f"{name} must have shape (n, {self.nv}), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise InputError(f"{name} contains NaN or infinite values")
        return q

    def solve_positions(
        self,
        u: FloatArray,
        *,
        q0: FloatArray | None = None,
        tol: float = 1e-12,
        max_iter: int = 30,
        max_cond: float = 1e8,
    ) -> FloatArray:
        """Numeric forward kinematics: all joint positions from independent coordinates.

        Newton's method on :math:`[c(q); u(q) - u^*] = 0` (independent constraint rows),
        warm-started from the previous sample (the first from ``q0``, default ``q_ref``).

        Parameters
        ----------
        u : array, shape (n, n_u)
        q0 : array, shape (n_v,) or (n, n_v), optional
            Initial guess(es); a 2-D array gives one guess per sample (e.g. a closed-form
            inverse kinematics), which is then only refined.
        tol : float
            Convergence threshold on the infinity norm of the residual [m, rad];
            1e-12 is far below any encoder resolution.
        max_cond : float
            Largest accepted condition number of :math:`[J_c; J_u]`.

        Raises
        ------
        ModelError
            When Newton does not converge (unreachable pose: the message gives the residual
            and the condition number) or the configuration is singular.
        """
        return loop_assembly.solve_positions(self, u, q0, tol, max_iter, max_cond)

    def states(
        self,
        q: FloatArray,
        du: FloatArray,
        ddu: FloatArray,
        *,
        max_cond: float = 1e8,
        data: pin.Data | None = None,
    ) -> KinematicState:
        """Velocities and accelerations of all joints from those of the independent coordinates.

        Parameters
        ----------
        q : array, shape (n, n_v)
            Assembled positions, :math:`c(q) \\approx 0` (e.g. from :meth:`solve_positions`):
            the Jacobian rows use the position of one side of each closure for both.
        du, ddu : array, shape (n, n_u)
        max_cond : float
            Largest accepted condition number of :math:`[J_c; J_u]` (1-norm); beyond it
            the configuration is reported as singular.
        data : pinocchio.Data, optional
            Working memory of ``pin_model`` to reuse call after call (a controller); every
            quantity read from it is recomputed first, so the result does not depend on it.

        Returns
        -------
        KinematicState
            With :math:`\\dot q = G\\dot u` and :math:`\\ddot q = G\\ddot u + \\ddot q_0`,
            :math:`\\ddot q_0` solving :math:`J_c \\ddot q_0 = -\\dot J_c \\dot q`,
            :math:`J_u \\ddot q_0 = -\\dot J_u \\dot q` (batched over samples, see
            :mod:`dynid.model.loop_kinematics`).
        """
        self.check_ball_charts(q, "states")
        return loop_kinematics.states(self, q, du, ddu, max_cond=max_cond, data=data)

    def kinematic_state(self, q: FloatArray, dq: FloatArray, ddq: FloatArray, *, max_cond: float = 1e8) -> KinematicState:
        """Wrap given joint positions, velocities and accelerations (e.g. from a constrained
        simulation) with the velocity map :math:`G(q)`; nothing is recomputed but G.
        ``q`` must be assembled (:math:`c(q) \\approx 0`), as for :meth:`states`."""
        self.check_ball_charts(q, "kinematic_state")
        return loop_kinematics.kinematic_state(self, q, dq, ddq, max_cond=max_cond)
