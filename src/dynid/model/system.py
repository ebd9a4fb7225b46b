"""One protocol for every robot: a serial arm is a mechanism without closures.

The pipeline (identify, simulate, design, Monte Carlo), the estimators' constraint map and the
export see a robot only through :class:`System`: its **actuators** (the joints of a serial arm, the
actuated joints of a parallel robot), the drive train between motors and actuators
(:class:`~dynid.model.transmission.Transmission`: gear ratios, couplings, drive gains, encoder
offsets), its standard parameters and the regression rows that map actuator states to model
outputs. Two implementations:

* :class:`SerialSystem` wraps a :class:`~dynid.model.robot.RobotModel`: the velocity map is
  :math:`G = I` and the actuators are the joints, so the rows are pinocchio's joint-torque
  regressor with the extras (the serial fast path of :func:`dynid.model.serial_dynamics.regressor`,
  no projection, no kinematic solve);
* :class:`ClosedLoopSystem` wraps a :class:`~dynid.model.mechanism.Mechanism`: all joint states
  are solved from the actuator states through the loops
  (:func:`dynid.model.loop_kinematics.actuator_states`, warm-started chunk after chunk) and the
  rows are the virtual-power projection :math:`G_a^{-T}G^T[Y\\;F]`
  (:func:`dynid.model.closed_loop.actuator_regressor`), or the projected equations of a
  redundantly actuated mechanism.

Both read the same configuration: the actuator extras ``Ia``, ``fv``, ``fc``, ``offset``
(rotor inertia, viscous and Coulomb friction, offset) are per-joint columns of a serial layout and
joint terms ``<extra>_<joint>`` on the actuated joints of a mechanism
(:func:`with_actuator_extras`); the transmission maps motor signals to actuator signals for both
(``q_a = C^{-1}θ + q_0``, ``τ_a = C^T K i``).

What stays specific is physical: a redundantly actuated mechanism needs a force model
(:data:`~dynid.model.closed_loop.DISTRIBUTIONS`), a serial arm has none; only a mechanism that
reaches its platform through a chain of joints has a platform pose (``task_coordinates``); only a
mechanism has identical kinematic chains whose bodies may share parameters
(:meth:`System.with_structure`, :mod:`dynid.model.reduction`): its "standard" parameters are then
:math:`\\psi` with :math:`\\pi = T\\psi`, and every stage that works on the standard parameters
(base parameters, rows, nominal values, physical consistency) sees :math:`\\psi` unchanged.
"""

from __future__ import annotations

import dataclasses
import threading
import weakref
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import ConfigError, ModelError
from dynid.model.base_parameters import BaseParameters, StandardMap, consistent_parameters, robot_base_parameters
from dynid.model.closed_loop import DISTRIBUTIONS, actuator_regressor, mechanism_base_parameters
from dynid.model.closures import JointCoordinates, JointTerm
from dynid.model.loop_kinematics import actuator_states, platform_pose, pose_states, states
from dynid.model.mechanism import Mechanism
from dynid.model.reduction import ParameterReduction, reduce_mechanism
from dynid.model.serial_dynamics import regressor
from dynid.model.robot import RobotModel, _normalize_extras, joint_kinds
from dynid.model.transmission import Transmission

__all__ = ["ClosedLoopSystem", "Rows", "SerialSystem", "System", "as_system", "cached_base_parameters",
           "with_actuator_extras", "with_motor_terms"]

EXTRA_KINDS = {"Ia": "inertia", "fv": "viscous", "fc": "coulomb", "offset": "offset", "fv+": "viscous+",
               "fv-": "viscous-", "fc+": "coulomb+", "fc-": "coulomb-"}
"""Joint-term kind of each actuator extra."""


@dataclasses.dataclass(frozen=True, eq=False)
class Rows:
    """Regression rows of a chunk of samples: ``W[i] @ params`` is the model output of sample ``i``
    (standard parameters), ``y`` the measured outputs, ``inconsistency`` the RMS residual of
    redundant actuator positions (zero otherwise)."""

    W: FloatArray
    y: FloatArray
    inconsistency: FloatArray
    joint_dq: FloatArray | None = None  # velocities of all joints (a mechanism's passive ones included)
    Ga: FloatArray | None = None  # (n, n_a, n_u) actuator velocity map of a redundant mechanism (other views of its forces)


class System(Protocol):
    """What the pipeline knows of a robot (module docstring)."""

    kind: str  # "serial" or "closed-loop"
    name: str
    model: Any  # the RobotModel or Mechanism
    transmission: Transmission | None
    dof: int
    n_actuators: int
    redundant: bool
    actuator_names: tuple[str, ...]
    parameter_names: tuple[str, ...]
    task_coordinates: tuple[str, ...]
    max_chunk: int | None  # largest chunk of samples the rows take at once (None: any)
    structure: str  # "full", or the structural reduction of the parameters (dynid.model.reduction)

    def actuator_kinds(self) -> tuple[str, ...]: ...
    def nominal_parameters(self) -> FloatArray: ...
    def body_blocks(self) -> tuple[np.ndarray, ...]: ...
    def force_model(self, requested: str | None) -> str | None: ...
    def channel_names(self, force_model: str | None) -> tuple[str, ...]: ...
    def channels_are_actuators(self, force_model: str | None) -> bool: ...
    def base_parameters(self, force_model: str | None = None, *, n_samples: int | None = None,
                        seed: int = 0, rank_tol: float = 1e-8) -> BaseParameters: ...
    def standard_map(self, base: BaseParameters) -> StandardMap: ...
    def rows(self, force_model: str | None) -> Any: ...
    def friction_pairs(self) -> tuple[list[tuple[str, str, str, int]], list[str]]: ...
    def passive_friction_joints(self) -> tuple[int, ...]: ...
    def still_parameters(self, actuators: Sequence[int]) -> list[str]: ...
    def describe(self) -> dict[str, Any]: ...
    def with_structure(self, structure: str, chains: Any = None) -> System: ...
    def with_coulomb_width(self, actuator_width: Sequence[float] | None) -> System: ...
    def reduce_parameters(self, pi: FloatArray) -> FloatArray: ...
    def expand_parameters(self, params: FloatArray) -> FloatArray: ...


_BASE_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_BASE_LOCK = threading.Lock()


def cached_base_parameters(owner: Any, key: tuple, compute: Callable[[], BaseParameters]) -> BaseParameters:
    """The base parameters of ``owner`` for the settings ``key``, computed once (issue 37, item 5).

    Each computation is a random-state regressor stack and a pivoted QR
    (:func:`~dynid.model.base_parameters.compute_base_parameters`: 0.9 s for a Stewart platform). An
    identify asks more than once for the same model's: the structure decision of
    ``identification.structure = "auto"`` computes the full and the tied model's, then the
    identification asks for the chosen one's (a third computation before this cache); the drive
    gains and the processing's message ask too.

    The cache is keyed on the **object** that defines the regressor, held weakly: the
    :class:`~dynid.model.robot.RobotModel` of a serial arm (frozen; a different Coulomb width,
    payload, transmission or extras is a new model from ``replace``), the :class:`ClosedLoopSystem`
    of a mechanism (frozen; its structure -- the tied or full parameters -- and its chart are a new
    system), plus ``key``: the force model, random-state count, seed and rank tolerance. Two
    objects never share an entry, even when equal, so a result is only reused for the very model
    it was computed from; the entry goes when the model does."""
    try:
        with _BASE_LOCK:
            hit = _BASE_CACHE.get(owner, {}).get(key)
    except TypeError:  # an owner that cannot be weakly referenced: no cache
        return compute()
    if hit is not None:
        return hit
    base = compute()  # outside the lock: another thread may compute the same once more, never a wrong one
    with _BASE_LOCK:
        return _BASE_CACHE.setdefault(owner, {}).setdefault(key, base)


def _velocity_unit(kind: str) -> str:
    return "m/s" if kind == "prismatic" else "rad/s"


# ---------------------------------------------------------------------------------------- serial
class _SerialRows:
    """Rows of a serial robot: the joint-torque regressor (G = I), one buffer reused per chunk."""

    def __init__(self, robot: RobotModel) -> None:
        self.robot, self.data, self.buf = robot, robot.create_data(), None

    def __call__(self, q: FloatArray, dq: FloatArray, ddq: FloatArray, tau: FloatArray, start: int = 0, joint_q: FloatArray | None = None) -> Rows:
        n = q.shape[0]
        shape = (n, self.robot.dof, self.robot.n_standard_params)
        if self.buf is None or self.buf.shape[0] < n:
            self.buf = np.empty(shape)
        W = regressor(self.robot, q, dq, ddq, data=self.data, out=self.buf[:n])
        return Rows(W=W, y=np.asarray(tau, dtype=float), inconsistency=np.zeros(n))


@dataclasses.dataclass(frozen=True, eq=False)
class SerialSystem:
    """A serial (tree) robot as a :class:`System`: actuators = joints, :math:`G = I`."""

    model: RobotModel
    kind: str = dataclasses.field(default="serial", init=False)

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def transmission(self) -> Transmission | None:
        return self.model.transmission

    @property
    def dof(self) -> int:
        return self.model.dof

    @property
    def n_actuators(self) -> int:
        return self.model.dof

    redundant = False
    structure = "full"  # a serial arm has one chain: nothing to tie
    task_coordinates: tuple[str, ...] = ()
    max_chunk = None  # the regressor of a long chunk costs no more per sample (no limit)

    @property
    def actuator_names(self) -> tuple[str, ...]:
        return self.model.joint_names

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return self.model.parameter_names

    def actuator_kinds(self) -> tuple[str, ...]:
        return joint_kinds(self.model.pin_model)

    def nominal_parameters(self) -> FloatArray:
        return self.model.nominal_parameters()

    def body_blocks(self) -> tuple[np.ndarray, ...]:
        return self.model.body_blocks()

    def force_model(self, requested: str | None) -> str | None:
        if requested is not None:
            raise ConfigError(f"identification.force_model applies to redundantly actuated mechanisms; {self.name!r} is "
                              "a serial robot, whose joint torques are unique")
        return None

    def channel_names(self, force_model: str | None) -> tuple[str, ...]:
        return self.model.joint_names

    def channels_are_actuators(self, force_model: str | None) -> bool:
        return True

    def base_parameters(self, force_model: str | None = None, *, n_samples: int | None = None,
                        seed: int = 0, rank_tol: float = 1e-8) -> BaseParameters:
        return cached_base_parameters(
            self.model, (n_samples, seed, rank_tol),
            lambda: robot_base_parameters(self.model, n_samples=n_samples, seed=seed, rank_tol=rank_tol))

    def standard_map(self, base: BaseParameters) -> StandardMap:
        return StandardMap.of(self.model, base)

    def rows(self, force_model: str | None) -> _SerialRows:
        return _SerialRows(self.model)

    def passive_friction_joints(self) -> tuple[int, ...]:
        """Velocity indices of passive joints with Coulomb friction: a serial arm has none."""
        return ()

    def friction_pairs(self) -> tuple[list[tuple[str, str, str, int]], list[str]]:
        """``(joint, Coulomb name, viscous name, velocity column)`` of the joints with ``fc`` and
        ``fv`` extras, and their velocity units."""
        ext = self.model.layout.extra_index
        if "fc" not in ext or "fv" not in ext:
            return [], []
        pn, kinds = self.parameter_names, self.actuator_kinds()
        pairs = [(j, pn[ext["fc"][k]], pn[ext["fv"][k]], k) for k, j in enumerate(self.actuator_names)]
        return pairs, [_velocity_unit(kinds[k]) for k in range(len(pairs))]

    def still_parameters(self, actuators: Sequence[int]) -> list[str]:
        lay = self.model.layout
        return [lay.names[idx[j]] for j in actuators for e, idx in lay.extra_index.items() if e != "offset"]

    def describe(self) -> dict[str, Any]:
        r = self.model
        return {"name": r.name, "kind": "serial", "dof": r.dof, "extras": list(r.extras),
                "transmission": r.transmission.describe() if r.transmission else None}

    def with_coulomb_width(self, actuator_width: Sequence[float] | None) -> SerialSystem:
        """The same robot whose Coulomb terms use the smooth sign with these velocity-noise stds
        per joint (:func:`~dynid.model.serial_dynamics.smooth_sign`; None: the sign)."""
        return dataclasses.replace(self, model=self.model.replace(
            coulomb_width=None if actuator_width is None else tuple(actuator_width)))

    def with_structure(self, structure: str, chains: Any = None) -> SerialSystem:
        """Only ``"full"`` (which ``"auto"`` is here): a serial arm has one chain, nothing to tie."""
        if structure not in ("full", "auto") or chains:
            raise ConfigError(f"identification.structure / identical_chains: {self.name!r} is a serial robot; identical "
                              "chains are those of a closed-loop mechanism")
        return self

    def reduce_parameters(self, pi: FloatArray) -> FloatArray:
        """The system's parameters of the model's standard vector ``pi`` (the same here)."""
        return np.asarray(pi, dtype=float)

    def expand_parameters(self, params: FloatArray) -> FloatArray:
        """The model's standard vector of the system's parameters (the same here)."""
        return np.asarray(params, dtype=float)


# ----------------------------------------------------------------------------------- closed loop
@dataclasses.dataclass(frozen=True, eq=False)
class KnownJointPositions:
    """All joint positions along samples, known to satisfy the loop closures (a simulation's own
    states at its samples: DIDIM's replay, :mod:`dynid.pipeline.control_loop`). Given to the rows as
    ``joint_q`` where the independent joints are the actuated ones, they are the rows' positions as
    they are (:func:`~dynid.model.loop_kinematics.actuator_states` would accept them as they are,
    after a residual and Jacobian per sample) and the velocities, accelerations and velocity map
    come from the compiled :func:`~dynid.model.loop_kinematics.states` (the same closure equations,
    the same values to rounding). Sliced like an array of samples."""

    q: FloatArray

    def __getitem__(self, s: slice) -> KnownJointPositions:
        return KnownJointPositions(self.q[s])


class _MechanismRows:
    """Rows of a mechanism: all joint states from the actuator states (warm-started from the
    previous chunk's solution at the same or the nearest earlier sample), then the actuator-space
    regressor."""

    def __init__(self, mech: Mechanism, force_model: str | None, T: FloatArray | None = None) -> None:
        self.mech, self.force_model, self.T = mech, force_model, T
        self.data = mech.pin_model.createData()
        self.last: tuple[int, FloatArray] | None = None  # (start sample, joint positions) of the previous chunk

    def _guess(self, start: int) -> FloatArray | None:
        if self.last is None:
            return None
        a, Q = self.last
        k = start - a
        return Q[k] if 0 <= k < Q.shape[0] else Q[-1]

    def __call__(self, q: FloatArray, dq: FloatArray, ddq: FloatArray, tau: FloatArray, start: int = 0,
                 joint_q: FloatArray | None = None) -> Rows:
        """``joint_q``: all joint positions where known (a simulated motion): the starting points
        of the position solve (:func:`~dynid.model.loop_kinematics.actuator_states`); or the
        :class:`KnownJointPositions` of the samples, taken as they are where the independent joints
        are the actuated ones and their actuator positions are ``q`` (else the starting points)."""
        if isinstance(joint_q, KnownJointPositions):
            ind, act = self.mech.independent, list(self.mech.actuated)
            if (isinstance(ind, JointCoordinates) and tuple(ind.joints) == tuple(act) and not self.mech.redundant
                    and np.array_equal(joint_q.q[:, act], q)):
                state, resid = states(self.mech, joint_q.q, dq, ddq), np.zeros(q.shape[0])
            else:
                state, resid = actuator_states(self.mech, q, dq, ddq, q0=self._guess(start), sample_offset=start,
                                               q_start=joint_q.q)
        else:
            state, resid = actuator_states(self.mech, q, dq, ddq, q0=self._guess(start), sample_offset=start,
                                           q_start=joint_q)
        self.last = (start, state.q)
        reg = actuator_regressor(self.mech, state, distribution=self.force_model, data=self.data)
        W = reg.W if self.T is None else reg.W @ self.T
        return Rows(W=W, y=reg.outputs(tau), inconsistency=resid, joint_dq=state.dq,
                    Ga=reg.Ga if self.mech.redundant else None)


@dataclasses.dataclass(frozen=True, eq=False)
class ClosedLoopSystem:
    """A closed-loop :class:`~dynid.model.mechanism.Mechanism` as a :class:`System`, with the
    drive train of its actuators and, optionally, a structural reduction of its parameters
    (:meth:`with_structure`: identical chains share parameters; ``model`` stays the full mechanism)."""

    model: Mechanism
    transmission: Transmission | None = None
    reduction: ParameterReduction | None = None
    kind: str = dataclasses.field(default="closed-loop", init=False)
    max_chunk = 2000  # samples solved through the loops at once (batched kinematics hold (n, n_v, n_v) arrays)

    def __post_init__(self) -> None:
        if self.transmission is not None and self.transmission.n != self.model.n_actuators:
            raise ModelError(f"the transmission has {self.transmission.n} motors but {self.model.name!r} has "
                             f"{self.model.n_actuators} actuators")

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def dof(self) -> int:
        return self.model.dof

    @property
    def n_actuators(self) -> int:
        return self.model.n_actuators

    @property
    def redundant(self) -> bool:
        return self.model.redundant

    @property
    def task_coordinates(self) -> tuple[str, ...]:
        return self.model.task_coordinates

    @property
    def actuator_names(self) -> tuple[str, ...]:
        return tuple(self.model.actuated_names)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return self.model.parameter_names if self.reduction is None else self.reduction.names

    @property
    def structure(self) -> str:
        return "full" if self.reduction is None else self.reduction.structure

    def actuator_kinds(self) -> tuple[str, ...]:
        return joint_kinds(self.model.pin_model, self.model.actuated)

    def nominal_parameters(self) -> FloatArray:
        return self.reduce_parameters(self.model.nominal_parameters())

    def body_blocks(self) -> tuple[np.ndarray, ...]:
        return self.model.body_blocks() if self.reduction is None else self.reduction.body_blocks

    def with_coulomb_width(self, actuator_width: Sequence[float] | None) -> ClosedLoopSystem:
        r"""The same system whose Coulomb terms use the smooth sign (:func:`~dynid.model.serial_dynamics.smooth_sign`)
        with velocity-noise stds ``actuator_width`` on the actuated joints; every other joint's is
        propagated from the independent coordinates' through the velocity map at the reference
        configuration, :math:`\sigma_j = \sqrt{\sum_k G_{jk}^2 \sigma_{u,k}^2}` (independent noise;
        the map changes along the motion, the width is a scale, not an exact std)."""
        if actuator_width is None:
            return dataclasses.replace(self, model=dataclasses.replace(self.model, coulomb_width=None))
        mech = self.model
        act = dict(zip(mech.actuated, (float(w) for w in actuator_width)))
        indep = getattr(mech.independent, "joints", None)
        if indep is None or any(j not in act for j in indep):
            raise ConfigError(f"identification.coulomb_smoothing: the independent coordinates of {mech.name!r} are not "
                              "actuated joints; the widths of the other joints cannot be propagated from the actuators'")
        zero = np.zeros((1, len(indep)))
        G = mech.states(mech.q_ref[None], zero, zero).G[0]  # (n_v, n_u)
        sigma_u = np.array([act[j] for j in indep])
        width = np.sqrt((G ** 2) @ (sigma_u ** 2))
        for j, w in act.items():
            width[j] = w
        return dataclasses.replace(self, model=dataclasses.replace(mech, coulomb_width=tuple(width)))

    def with_structure(self, structure: str, chains: Any = None) -> ClosedLoopSystem:
        """The same system whose parameters follow ``structure`` (``"full"``, ``"identical_chains"``,
        ``"paper"``; :func:`dynid.model.reduction.reduce_mechanism`), the chains given, the mechanism's own or
        those found in its description. ``"auto"`` is a choice made from data (:mod:`dynid.pipeline.structure`)."""
        if structure == "auto":
            raise ConfigError("identification.structure = 'auto' is decided from the training log by dynid identify; "
                              "here give 'full', 'identical_chains' or 'paper'")
        return dataclasses.replace(self, reduction=reduce_mechanism(self.model, structure, chains))

    def reduce_parameters(self, pi: FloatArray) -> FloatArray:
        """The system's parameters :math:`\\psi = T^+\\pi` of the mechanism's standard vector ``pi``."""
        return np.asarray(pi, dtype=float) if self.reduction is None else self.reduction.reduce(pi)

    def expand_parameters(self, params: FloatArray) -> FloatArray:
        """The mechanism's standard vector :math:`T\\psi` of the system's parameters."""
        return np.asarray(params, dtype=float) if self.reduction is None else self.reduction.expand(params)

    def force_model(self, requested: str | None) -> str | None:
        m = self.model
        if m.redundant:
            fm = requested or "projected"
            if fm not in DISTRIBUTIONS:
                raise ConfigError(f"identification.force_model = {fm!r}; choose from {list(DISTRIBUTIONS)}")
            return fm
        if requested is not None:
            raise ConfigError(f"identification.force_model applies to redundantly actuated mechanisms; {m.name!r} has "
                              f"{m.n_actuators} actuators for {m.dof} degrees of freedom")
        return None

    def channel_names(self, force_model: str | None) -> tuple[str, ...]:
        """The actuators, or the independent coordinates for the projected equations of a
        redundantly actuated mechanism."""
        if force_model == "projected":
            ind = self.model.independent
            if isinstance(ind, JointCoordinates):
                return tuple(f"u_{self.model.pin_model.names[j + 1]}" for j in ind.joints)
            return tuple(f"u_{'xyz'[a]}" for a in ind.axes)
        return self.actuator_names

    def channels_are_actuators(self, force_model: str | None) -> bool:
        return force_model != "projected"

    def base_parameters(self, force_model: str | None = None, *, n_samples: int | None = None,
                        seed: int = 0, rank_tol: float = 1e-8) -> BaseParameters:
        distribution = force_model if self.redundant else None
        return cached_base_parameters(
            self, (distribution, n_samples, seed, rank_tol),
            lambda: mechanism_base_parameters(self.model, distribution=distribution, n_samples=n_samples, seed=seed,
                                              rank_tol=rank_tol, reduction=self.reduction))

    def standard_map(self, base: BaseParameters) -> StandardMap:
        m, red = self.model, self.reduction
        shift = 0 if red is None else red.n_body_params - m.n_body_params  # joint terms close the vector in both
        return StandardMap(standard_names=self.parameter_names, B=base.B, body_blocks=self.body_blocks(),
                           nonnegative=m.nonnegative_parameters() + shift,
                           reference=consistent_parameters(self.nominal_parameters(), self.body_blocks()),
                           nonpositive=m.nonpositive_parameters() + shift,
                           zero=np.zeros(0, dtype=int) if red is None else red.zero)

    def rows(self, force_model: str | None) -> _MechanismRows:
        return _MechanismRows(self.model, force_model, None if self.reduction is None else self.reduction.T)

    def passive_friction_joints(self) -> tuple[int, ...]:
        """Velocity indices of the passive joints that carry a Coulomb term (``coulomb``,
        ``coulomb+``, ``coulomb-``, alone or shared): where one of them sticks or reverses, its
        friction is whatever holds it, which the model does not describe."""
        act = set(self.model.actuated)
        out = sorted({j for t in self.model.terms if t.kind.startswith("coulomb") and not t.weights
                      for j in t.joints if j not in act})
        return tuple(out)

    def friction_pairs(self) -> tuple[list[tuple[str, str, str, int]], list[str]]:
        """The actuated joints with a Coulomb and a viscous term of their own (as
        :meth:`SerialSystem.friction_pairs`)."""
        m = self.model
        single = {(t.kind, t.joints[0]): t.name for t in m.terms if len(t.joints) == 1}
        pairs, units = [], []
        kinds = self.actuator_kinds()
        for i, (j, name) in enumerate(zip(m.actuated, m.actuated_names)):
            if ("coulomb", j) in single and ("viscous", j) in single:
                pairs.append((name, single[("coulomb", j)], single[("viscous", j)], i))
                units.append(_velocity_unit(kinds[i]))
        return pairs, units

    def platform_pose(self, qa: FloatArray) -> FloatArray:
        """The platform pose of actuator positions (forward kinematics of every sample)."""
        return platform_pose(self.model, qa)

    def pose_rows(self, qa: FloatArray, tau: FloatArray, fs: float, cutoff_hz: float, force_model: str | None, *,
                  pose: FloatArray | None = None, positions: bool = False):
        """Rows of a whole averaged period through the platform pose, filtered in the frequency
        domain (paper 004 §3.3; :func:`dynid.model.loop_kinematics.pose_states`), with the
        actuator velocities (and, with ``positions``, the actuator positions) they imply."""
        state, *_ = pose_states(self.model, qa, fs, cutoff_hz, pose=pose)
        reg = actuator_regressor(self.model.in_task_space(), state, distribution=force_model if self.redundant else None)
        act = list(self.model.actuated)
        W = reg.W if self.reduction is None else reg.W @ self.reduction.T
        rows = Rows(W=W, y=reg.outputs(tau), inconsistency=np.zeros(state.q.shape[0]), joint_dq=state.dq)
        return (rows, state.dq[:, act], state.q[:, act]) if positions else (rows, state.dq[:, act])

    def still_parameters(self, actuators: Sequence[int]) -> list[str]:
        m = self.model
        joints = {m.actuated[a] for a in actuators}
        return [t.name for t in m.terms if t.kind != "offset" and set(t.joints) <= joints]

    def describe(self) -> dict[str, Any]:
        m = self.model
        return {"name": m.name, "kind": "closed-loop", "dof": m.dof, "actuators": list(self.actuator_names),
                "transmission": self.transmission.describe() if self.transmission else None,
                **({} if self.reduction is None else {"parameter_structure": self.reduction.describe()})}


def with_actuator_extras(mech: Mechanism, extras: Sequence[str]) -> Mechanism:
    """``mech`` with a joint term ``<extra>_<joint>`` of each kind in ``extras`` (``Ia``, ``fv``,
    ``fc``, ``offset``: rotor inertia, viscous and Coulomb friction, offset; ``fv+``, ``fv-``,
    ``fc+``, ``fc-``: asymmetric friction, Shang 2009 Eq. 2) on every actuated
    joint that has no single-joint term of that kind yet (nominal value 0); the description's own
    terms are kept as they are."""
    extras = _normalize_extras(extras)  # refuses unknown ones, as a serial layout does
    have = {(t.kind, t.joints[0]) for t in mech.terms if len(t.joints) == 1}
    names = {t.name for t in mech.terms}
    new = []
    for e in extras:
        for j in mech.actuated:
            kind = EXTRA_KINDS[e]
            if (kind, j) in have:
                continue
            name = f"{e}_{mech.pin_model.names[j + 1]}"
            if name in names:
                raise ModelError(f"{mech.name!r} already has a joint term named {name!r} of another kind")
            new.append(JointTerm(name, kind, (j,)))
    if not new:
        return mech
    return dataclasses.replace(mech, terms=mech.terms + tuple(new), q_guess=mech.q_ref)


def with_motor_terms(mech: Mechanism, transmission: Transmission, extras: Sequence[str]) -> Mechanism:
    """``mech`` with the terms of its coupled motors: motor ``k`` of ``transmission`` driving
    several actuators gets ``Iam{k}``, ``fvm{k}``, ``fcm{k}`` (those of ``Ia``, ``fv``, ``fc`` in
    ``extras``) acting through its own velocity :math:`w_k = c_k^T\\dot q_a`, exactly the
    motor-side terms of a serial layout (:mod:`dynid.model.robot`, item 3)."""
    prefix = {"Ia": ("Iam", "inertia"), "fv": ("fvm", "viscous"), "fc": ("fcm", "coulomb")}
    new = []
    for k in transmission.coupled_motors:
        c = transmission.coupling_weights(k)
        nz = np.flatnonzero(c)
        joints = tuple(mech.actuated[a] for a in nz)
        for e in ("Ia", "fv", "fc"):
            if e in extras:
                name, kind = prefix[e]
                new.append(JointTerm(f"{name}{k + 1}", kind, joints, tuple(c[nz])))
    if not new:
        return mech
    return dataclasses.replace(mech, terms=mech.terms + tuple(new), q_guess=mech.q_ref)


def as_system(model, transmission: Transmission | None = None) -> SerialSystem | ClosedLoopSystem:
    """The :class:`System` of a robot model (the only place that tells the two apart); a
    :class:`System` is returned as it is."""
    if isinstance(model, (SerialSystem, ClosedLoopSystem)):
        return model
    if isinstance(model, Mechanism):
        return ClosedLoopSystem(model, transmission)
    if transmission is not None:
        model = model.replace(transmission=transmission)
    return SerialSystem(model)

