"""Optimal periodic excitation under actuator and workspace limits (papers 002 §3, 003 §4.2,
004 §4), for serial robots (joint space) and closed-loop mechanisms (their independent
coordinates, or the platform pose in task space).

Design variables: the Fourier coefficients :math:`a_{jk}, b_{jk}` and offsets :math:`q_{0,j}`
of :class:`~dynid.trajectories.FourierTrajectory` in the chosen coordinates (and
the fundamental frequency when asked); with ``quintic`` the rest-to-rest Fourier + quintic of
paper 003. One period is sampled at ``samples`` instants; along it:

* serial robots: the base regressor of the joints;
* mechanisms: all joint positions by Newton (warm-started from the previous evaluation, or
  from the closed-form inverse kinematics of the task coordinates), the velocity map, the
  actuator-space regressor (projected equations for redundant actuation).

Constraints (paper 002, Eq. 25), each normalized by its limit and imposed at every sample:
actuator positions, velocities, accelerations, optional actuator forces of the nominal model,
and for mechanisms the workspace (the design coordinates stay in their box) and the
closed-loop condition number (a margin from singularities; an unreachable pose counts as a
violation). The criterion is one of
:data:`~dynid.excitation.optimality.CRITERIA`.

Optimizer: ``starts`` random designs made feasible by shrinking their amplitude (bisection),
each refined by SLSQP (finite-difference gradients, evaluations cached; for the D-, A- and
E-optimal criteria, whose logarithms are flat for the nearly rank-deficient random starts, a
first SLSQP pass minimizes the condition number), keeping the better of SLSQP's point and the
best feasible point it visited, then checked on a grid 8 times finer; a design still violating a limit there is shrunk again, and if it cannot be made
feasible it is reported with its worst violation and never as a success. The criterion of the
returned design and ``initial_value`` (the start's, shrunk onto the fine grid's feasible set) are
both evaluated on that fine grid, and the design is never worse than its start there (the start is
returned when the fine grid ranks it better): a guarantee that holds on any machine, whatever path
SLSQP takes. Seeded: the same seed gives the same design on the same machine.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np
from threadpoolctl import threadpool_limits
from scipy.optimize import minimize

from dynid._typing import FloatArray
from dynid.errors import DynidError, InputError, ModelError
from dynid.excitation.optimality import CRITERIA, criteria, predicted_std
from dynid.model.base_parameters import robot_base_parameters
from dynid.model.closed_loop import actuator_regressor, mechanism_base_parameters
from dynid.model.mechanism import JointCoordinates, Mechanism
from dynid.model.serial_dynamics import regressor
from dynid.tolerances import scaled
from dynid.trajectories import FourierQuintic
from dynid.trajectories import FourierTrajectory

__all__ = ["DesignLimits", "DesignError", "ExcitationDesign", "ExcitationProblem", "Violation"]


def _sized(value, n: int, what: str, of: str, exact: bool = False) -> None:
    """``value`` is None, a number (unless ``exact``) or ``n`` numbers."""
    if value is None:
        return
    a = np.asarray(value, dtype=float)
    if (a.ndim == 0 and exact) or a.ndim > 1 or (a.ndim == 1 and a.size != n):
        raise InputError(f"{what} has {a.size} entries for {n} {of}")


class DesignError(DynidError):
    """No feasible design could be found; the message names the worst violated limit."""


@dataclasses.dataclass(frozen=True)
class DesignLimits:
    """Actuator-space limits (arrays of one value per actuator; None: not imposed).

    ``position``: ``(lower, upper)`` [rad or m] (default: the joint limits of the actuated
    joints); ``velocity``, ``acceleration``, ``force`` (actuator forces of the nominal model):
    symmetric bounds; ``max_condition``: largest closed-loop condition number (mechanisms).
    """

    position: tuple[FloatArray, FloatArray] | None = None
    velocity: FloatArray | None = None
    acceleration: FloatArray | None = None
    force: FloatArray | None = None
    max_condition: float | None = 1e4


@dataclasses.dataclass(frozen=True)
class Violation:
    """The worst limit violation of a design: which limit, which actuator, by how much."""

    limit: str
    actuator: str
    value: float
    bound: float

    def __str__(self) -> str:
        return f"{self.limit} of {self.actuator}: {self.value:.4g} against a limit of {self.bound:.4g}"


@dataclasses.dataclass(frozen=True, eq=False)
class ExcitationDesign:
    """An optimized (or best feasible) excitation.

    ``success`` is True only when the design respects every limit on the fine grid; otherwise
    ``violation`` says which limit is exceeded.
    """

    trajectory: object
    coordinates: tuple[str, ...]
    criterion: str
    value: float
    initial_value: float
    criteria: dict[str, float]
    base_names: tuple[str, ...]
    predicted_std: FloatArray
    nominal_base: FloatArray
    success: bool
    violation: Violation | None
    starts: int
    seed: int
    elapsed_s: float
    evaluations: int

    @property
    def predicted_rel_std_pct(self) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100.0 * self.predicted_std / np.abs(self.nominal_base)


class ExcitationProblem:
    """The design problem of the module docstring.

    Parameters
    ----------
    robot : RobotModel or Mechanism
    coordinates : {"independent", "task"}
        For mechanisms: their independent coordinates or the platform pose.
    harmonics : int
    base_frequency_hz : float
    optimize_frequency : bool
        Also optimize the fundamental frequency (within a factor 2 of ``base_frequency_hz``).
    quintic : bool
        Rest-to-rest Fourier + quintic (paper 003) instead of a periodic series.
    samples : int
        Samples per period used by the optimizer.
    criterion : str
        One of :data:`~dynid.excitation.optimality.CRITERIA`.
    noise_std : array, optional
        Noise standard deviation of each output channel (actuator forces, or the projected
        equations); default 1.
    limits : DesignLimits
    box : (lower, upper), optional
        Range of the offsets of the design coordinates; default: the joint limits of the
        coordinates (for task coordinates: those of the platform chain; for a point: a quarter of
        the mean joint spacing around the reference assembly). The design coordinates stay in it.
    """

    def __init__(
        self,
        robot,
        *,
        coordinates: str = "independent",
        harmonics: int = 5,
        base_frequency_hz: float = 0.1,
        optimize_frequency: bool = False,
        quintic: bool = False,
        samples: int = 64,
        criterion: str = "d_opt",
        noise_std: FloatArray | None = None,
        limits: DesignLimits = DesignLimits(),
        box: tuple[FloatArray, FloatArray] | None = None,
    ) -> None:
        if criterion not in CRITERIA:
            raise InputError(f"unknown criterion {criterion!r}; choose from {list(CRITERIA)}")
        if harmonics < 1 or samples < 8:
            raise InputError("a design needs at least 1 harmonic and 8 samples per period")
        self.mech = isinstance(robot, Mechanism)
        if coordinates == "task":
            if not self.mech:
                raise InputError("task-space designs are for parallel robots; a serial robot is designed in joint space")
            robot = robot.in_task_space()
        elif coordinates != "independent":
            raise InputError(f"coordinates must be 'independent' or 'task', got {coordinates!r}")
        self.robot = robot
        self.harmonics, self.f0, self.opt_f, self.quintic = int(harmonics), float(base_frequency_hz), optimize_frequency, quintic
        self.samples, self.criterion = int(samples), criterion
        lo_j, hi_j = robot.position_limits()
        point_box = None
        if self.mech:
            ind = robot.independent
            self.act = list(robot.actuated)
            if isinstance(ind, JointCoordinates):
                self.coord_joints = list(ind.joints)
                self.names = tuple(robot.pin_model.names[j + 1] for j in self.coord_joints)
            else:  # a point (end-effector) of a planar or spatial mechanism
                self.coord_joints = []
                self.names = tuple("xyz"[a] for a in ind.axes)
                u_ref = robot.coordinates(robot.q_ref)[0]
                steps = [np.linalg.norm(robot.pin_model.jointPlacements[j].translation) for j in range(1, robot.pin_model.njoints)]
                half = 0.25 * float(np.mean(steps))
                point_box = (u_ref - half, u_ref + half)
            self.act_names = tuple(robot.actuated_names)
            self.distribution = "projected" if robot.redundant else None
            n_out = robot.dof if robot.redundant else robot.n_actuators
        else:
            self.coord_joints = list(range(robot.dof))
            self.act = list(range(robot.dof))
            self.names = self.act_names = tuple(robot.joint_names)
            n_out = robot.dof
        self.n_u = len(self.names)
        _sized(noise_std, n_out, "noise_std", "output channels")
        self.noise = np.ones(n_out) if noise_std is None else np.broadcast_to(np.asarray(noise_std, float), (n_out,)).copy()
        default_box = point_box if point_box is not None else (lo_j[self.coord_joints], hi_j[self.coord_joints])
        if box is not None:
            _sized(box[0], self.n_u, "box", "design coordinates", exact=True)
            _sized(box[1], self.n_u, "box", "design coordinates", exact=True)
        box_lo = default_box[0] if box is None else np.asarray(box[0], float)
        box_hi = default_box[1] if box is None else np.asarray(box[1], float)
        if np.any(~np.isfinite(box_lo)) or np.any(~np.isfinite(box_hi)) or np.any(box_hi <= box_lo):
            raise InputError(f"the design coordinates {self.names} need finite ranges (give limits or a box)")
        self.box = (box_lo, box_hi)
        n_a = len(self.act)
        if limits.position is not None:
            _sized(limits.position[0], n_a, "limits.position", "actuators", exact=True)
            _sized(limits.position[1], n_a, "limits.position", "actuators", exact=True)
        for key in ("velocity", "acceleration", "force"):
            _sized(getattr(limits, key), n_a, f"limits.{key}", "actuators")
        pos = limits.position if limits.position is not None else (lo_j[self.act], hi_j[self.act])
        self.limits = dataclasses.replace(limits, position=(np.asarray(pos[0], float), np.asarray(pos[1], float)))
        if not self.mech:
            self._check_reachable()
        if self.mech:
            self.base = mechanism_base_parameters(robot, distribution=self.distribution)
        else:
            self.base = robot_base_parameters(robot)
        self.nominal = robot.nominal_parameters()
        self.nominal_base = self.base.from_standard(self.nominal)
        self.evaluations = 0
        self._cache: dict[bytes, tuple[float, FloatArray]] = {}
        self._q_warm: FloatArray | None = None
        self._best: dict[str, tuple[float, FloatArray]] = {}
        if self.mech:
            u_ref = robot.coordinates(robot.q_ref)[0]
            self.centre = np.clip(u_ref, box_lo, box_hi)
        else:
            self.centre = 0.5 * (box_lo + box_hi)
        if not self.mech and limits.force is not None:
            self._check_holding_forces()

    def _check_reachable(self) -> None:
        """Serial robots (the design coordinates are the actuators): every design starts at rest at
        the centre of the box and shrinks towards it, so position limits that exclude the centre
        make every design infeasible."""
        lo, hi = self.limits.position
        blo, bhi = self.box
        centre = 0.5 * (blo + bhi)
        for j, name in enumerate(self.names):
            rng, box = f"[{lo[j]:.6g}, {hi[j]:.6g}]", f"[{blo[j]:.6g}, {bhi[j]:.6g}]"
            if hi[j] <= lo[j]:
                raise InputError(f"limits.position of {name} {rng}: lower must be below upper")
            if hi[j] <= blo[j] or lo[j] >= bhi[j]:
                raise DesignError(f"no feasible excitation: limits.position of {name} {rng} does not meet the range "
                                  f"of the design coordinate {name} {box}: no design can respect it")
            if not lo[j] < centre[j] < hi[j]:
                raise DesignError(f"no feasible excitation: limits.position of {name} {rng} excludes the centre "
                                  f"{centre[j]:.6g} of the design range {box} where every design starts; give "
                                  "design.box inside the limits")

    def _check_holding_forces(self) -> None:
        """Serial robots: force limits below what the nominal model needs to hold the rest pose at the
        centre of the box cannot be met by any design."""
        q = self.centre[None]
        zero = np.zeros_like(q)
        tau = regressor(self.robot, q, zero, zero)[0] @ self.nominal
        lim = np.broadcast_to(np.asarray(self.limits.force, float), tau.shape)
        over = [j for j in range(tau.size) if abs(tau[j]) > lim[j]]
        if over:
            j = over[0]
            raise DesignError(f"no feasible excitation: limits.force of {self.act_names[j]} is {lim[j]:.4g}, but the "
                              f"nominal model needs {abs(tau[j]):.4g} to hold the rest pose at the centre of the design "
                              "range: no design can respect it")

    # ------------------------------------------------------------------ variables
    @property
    def n_x(self) -> int:
        return 2 * self.n_u * self.harmonics + self.n_u + (1 if self.opt_f else 0)

    def trajectory(self, x: FloatArray):
        """The trajectory of design vector ``x``."""
        K, n = self.harmonics, self.n_u
        a = x[: n * K].reshape(n, K)
        b = x[n * K : 2 * n * K].reshape(n, K)
        q0 = x[2 * n * K : 2 * n * K + n]
        f0 = self.f0 * float(np.exp(x[-1])) if self.opt_f else self.f0
        four = FourierTrajectory(f0, a, b, q0)
        return FourierQuintic(four) if self.quintic else four

    def _times(self, traj, samples: int) -> FloatArray:
        """One period of a periodic trajectory (end excluded), else the whole duration."""
        if isinstance(traj, FourierTrajectory):
            return np.arange(samples) * (traj.period / samples)
        return np.linspace(0.0, traj.duration, samples)

    # ------------------------------------------------------------------ evaluation
    def signals(self, traj, samples: int, warm: bool = True):
        """Actuator positions, velocities, accelerations (n, n_a), the base regressor stack
        (n, n_out, p) and the closed-loop condition numbers (n,) along ``samples`` instants.
        Raises ModelError for an unreachable pose."""
        t = self._times(traj, samples)
        u, du, ddu = traj.sample(t)
        if not self.mech:
            W = regressor(self.robot, u, du, ddu)
            return u, du, ddu, W, np.ones(samples), t
        mech = self.robot
        q0 = None
        if warm and mech.position_guess is None and self._q_warm is not None and self._q_warm.shape[0] == samples:
            q0 = self._q_warm  # the previous evaluation's solution (no closed form to start from)
        try:
            q = mech.solve_positions(u, q0=q0, max_cond=1e12)
        except ModelError:
            if q0 is None:
                raise
            q = mech.solve_positions(u, max_cond=1e12)  # cold start from the reference assembly
        if warm:
            self._q_warm = q
        st = mech.states(q, du, ddu, max_cond=1e14)
        W = actuator_regressor(mech, st, distribution=self.distribution).W
        return st.q[:, self.act], st.dq[:, self.act], st.ddq[:, self.act], W, st.cond, t

    def _forces(self, W_full: FloatArray, traj, samples: int) -> FloatArray:
        if not self.mech or not self.robot.redundant:
            return W_full @ self.nominal
        t = self._times(traj, samples)
        u, du, ddu = traj.sample(t)
        st = self.robot.states(self.robot.solve_positions(u), du, ddu, max_cond=1e14)
        return actuator_regressor(self.robot, st, distribution="min_norm").W @ self.nominal

    def _margins(self, qa, dqa, ddqa, W_full, cond, traj, samples) -> tuple[FloatArray, list[tuple[str, int, float, float, float]]]:
        """Normalized margins (>= 0 feasible) at every sample, and per limit the worst
        ``(limit, actuator index, value, bound, normalized margin)``."""
        L = self.limits
        lo, hi = L.position
        span = np.maximum(hi - lo, 1e-9)
        m_lo, m_hi = (qa - lo) / span, (hi - qa) / span
        parts = [m_lo.ravel(), m_hi.ravel()]
        worst: list[tuple[str, int, float, float, float]] = []
        j_lo, j_hi = int(np.argmin(m_lo.min(axis=0))), int(np.argmin(m_hi.min(axis=0)))
        if m_lo.min() <= m_hi.min():
            worst.append(("position", j_lo, float(qa[:, j_lo].min()), float(lo[j_lo]), float(m_lo.min())))
        else:
            worst.append(("position", j_hi, float(qa[:, j_hi].max()), float(hi[j_hi]), float(m_hi.min())))
        bounded = [("velocity", dqa, L.velocity), ("acceleration", ddqa, L.acceleration)]
        if L.force is not None:
            bounded.append(("force", self._forces(W_full, traj, samples), L.force))
        for name, arr, lim in bounded:
            if lim is None:
                continue
            lim = np.broadcast_to(np.asarray(lim, float), (arr.shape[1],))
            m = 1.0 - np.abs(arr) / lim
            parts.append(m.ravel())
            jj = int(np.argmin(m.min(axis=0)))
            worst.append((name, jj, float(np.abs(arr[:, jj]).max()), float(lim[jj]), float(m.min())))
        if self.mech:  # the design coordinates stay in their box (the workspace asked for)
            u = traj.sample(self._times(traj, samples))[0]
            blo, bhi = self.box
            bspan = np.maximum(bhi - blo, 1e-9)
            m = np.minimum(u - blo, bhi - u) / bspan
            parts.append(m.ravel())
            jj = int(np.argmin(m.min(axis=0)))
            k = int(np.argmin(m[:, jj]))
            worst.append(("workspace", -2 - jj, float(u[k, jj]), float(blo[jj] if u[k, jj] - blo[jj] < bhi[jj] - u[k, jj] else bhi[jj]), float(m.min())))
        if self.mech and L.max_condition is not None:
            m = 1.0 - np.log(cond) / np.log(L.max_condition)
            parts.append(m)
            worst.append(("condition number", -1, float(cond.max()), float(L.max_condition), float(m.min())))
        return np.concatenate(parts), worst

    def _evaluate(self, x: FloatArray, criterion: str | None = None) -> tuple[float, FloatArray]:
        """Objective (``criterion``, default the problem's; log for condition numbers) and
        constraint margins of design ``x``; all criteria are cached, so switching criterion
        costs nothing."""
        crit_name = criterion or self.criterion
        key = np.asarray(x, float).tobytes()
        hit = self._cache.get(key)
        if hit is None:
            self.evaluations += 1
            traj = self.trajectory(x)
            try:
                qa, dqa, ddqa, W_full, cond, _ = self.signals(traj, self.samples)
                margins, _ = self._margins(qa, dqa, ddqa, W_full, cond, traj, self.samples)
                crit = criteria(self.base.regressor(W_full), self.noise, self.nominal_base)
            except ModelError:  # unreachable or singular: infeasible
                crit, margins = None, -np.ones(self._n_constraints())
            if len(self._cache) > 20000:
                self._cache.clear()
            hit = (crit, margins)
            self._cache[key] = hit
        crit, margins = hit
        if crit is None:
            return 1e6, margins
        value = crit[crit_name]
        if crit_name in ("cond", "weighted_cond"):
            value = np.log(value)  # minimize log cond: same optimum, better scaled
        if margins.min() >= 0:
            best = self._best.get(crit_name)
            if best is None or value < best[0]:
                self._best[crit_name] = (float(value), np.array(x, dtype=float))  # best feasible point visited
        return float(value), margins

    def _n_constraints(self) -> int:
        n, na = self.samples, len(self.act)
        L = self.limits
        k = 2 + sum(lim is not None for lim in (L.velocity, L.acceleration, L.force))
        return k * n * na + (n * self.n_u if self.mech else 0) + (n if self.mech and L.max_condition is not None else 0)

    def check(self, traj, factor: int = 8) -> tuple[bool, Violation | None, dict[str, float]]:
        """Feasibility on a grid ``factor`` times finer than the optimizer's, and the criteria.

        Works for any trajectory with ``sample(t)`` (a Fourier design, or a given path such as
        paper 001's circle, which is then evaluated rather than optimized)."""
        samples = self.samples * factor
        try:
            qa, dqa, ddqa, W_full, cond, _ = self.signals(traj, samples, warm=False)
        except ModelError as exc:
            return False, Violation("reachability", str(exc)[:60], float("nan"), float("nan")), {}
        margins, raw = self._margins(qa, dqa, ddqa, W_full, cond, traj, samples)
        crit = criteria(self.base.regressor(W_full), self.noise, self.nominal_base)
        worst = min(raw, key=lambda r: r[4])
        who = self.act_names[worst[1]] if worst[1] >= 0 else ("mechanism" if worst[1] == -1 else self.names[-2 - worst[1]])
        v = Violation(worst[0], who, worst[2], worst[3])
        return bool(margins.min() >= -1e-9), (None if margins.min() >= -1e-9 else v), crit

    # ------------------------------------------------------------------ optimizer
    def _random_start(self, rng: np.random.Generator) -> FloatArray:
        K, n = self.harmonics, self.n_u
        x = np.zeros(self.n_x)
        x[: 2 * n * K] = rng.standard_normal(2 * n * K) / np.tile(np.arange(1, K + 1), 2 * n)  # 1/k roll-off
        x[2 * n * K : 2 * n * K + n] = self.centre
        return x

    def _shrink_to_feasible(self, x: FloatArray, feasible: Callable[[FloatArray], bool]) -> FloatArray | None:
        """Largest amplitude scale s in (0, 1] with the design feasible (bisection)."""
        K, n = self.harmonics, self.n_u

        def shrunk(s: float) -> FloatArray:
            y = x.copy()
            y[: 2 * n * K] *= s
            return y

        if feasible(x):
            return x
        lo, hi = 0.0, 1.0
        if not feasible(shrunk(1e-4)):
            return None
        lo = 1e-4
        for _ in range(30):
            mid = np.sqrt(lo * hi) if lo > 0 else hi / 2
            if feasible(shrunk(mid)):
                lo = mid
            else:
                hi = mid
            if hi / lo < 1.02:
                break
        return shrunk(lo)

    def _local_search(self, x0: FloatArray, criterion: str, max_iter: int, bounds) -> FloatArray | None:
        """SLSQP from the feasible ``x0`` on ``criterion``; returns the best of SLSQP's point and
        the best feasible point it visited, each shrunk onto the feasible set of the fine grid
        (SLSQP's point may sit a hair outside the limits, or far outside when its line search
        failed), or the start itself."""
        self._best.pop(criterion, None)
        f0 = self._evaluate(x0, criterion)[0]
        res = minimize(lambda y: self._evaluate(y, criterion)[0], x0, method="SLSQP", bounds=bounds,
                       constraints=[{"type": "ineq", "fun": lambda y: self._evaluate(y, criterion)[1]}],
                       options={"maxiter": max_iter, "ftol": scaled(1e-6)})
        fine_ok = lambda y: self.check(self.trajectory(y))[0]  # noqa: E731
        candidates = [res.x] + ([self._best[criterion][1]] if criterion in self._best else [])
        x, fx = None, f0
        for c in candidates:
            c = self._shrink_to_feasible(c, fine_ok) if self._evaluate(c, criterion)[0] < f0 else None
            if c is not None and self._evaluate(c, criterion)[0] <= fx:
                x, fx = c, self._evaluate(c, criterion)[0]
        return x if x is not None else self._shrink_to_feasible(x0, fine_ok)

    def optimize(self, *, starts: int = 3, seed: int = 0, max_iter: int = 100,
                 progress: Callable[[str, int, int], None] | None = None) -> ExcitationDesign:
        """Multi-start SLSQP (see module docstring). Raises :class:`DesignError` when no start
        can be made feasible at all (e.g. an offset outside the limits).

        Runs on one BLAS thread: thousands of small SVDs, for which threads only cost (and two
        spinning OpenBLAS threads on a busy machine cost ten times over)."""
        with threadpool_limits(limits=1, user_api="blas"):
            return self._optimize(starts, seed, max_iter, progress)

    def _optimize(self, starts: int, seed: int, max_iter: int, progress) -> ExcitationDesign:
        t0 = time.perf_counter()
        rng = np.random.default_rng(seed)
        K, n = self.harmonics, self.n_u
        bounds = [(None, None)] * (2 * n * K) + list(zip(self.box[0], self.box[1])) + ([(-np.log(2), np.log(2))] if self.opt_f else [])
        coarse_ok = lambda y: self._evaluate(y)[1].min() >= 0  # noqa: E731
        best: tuple[float, FloatArray, float] | None = None
        worst_seen: Violation | None = None
        for s in range(starts):
            if progress:
                progress("design", s, starts)
            start = self._random_start(rng)
            x0 = self._shrink_to_feasible(start, coarse_ok)
            if x0 is None:  # even the smallest motion fails: say which limit, and by how much
                tiny = start.copy()
                tiny[: 2 * n * K] *= 1e-4
                worst_seen = self.check(self.trajectory(tiny), factor=1)[1] or worst_seen
                continue
            inner = x0.copy()
            inner[: 2 * n * K] *= 0.8  # start inside the feasible set, not on its boundary
            if coarse_ok(inner):
                x0 = inner
            f_init = self._evaluate(x0)[0]
            x = x0
            if self.criterion in ("d_opt", "a_opt", "e_opt"):
                # the logarithmic criteria are flat and ill-scaled for the nearly rank-deficient
                # designs random starts give: first make the design well conditioned
                x1 = self._local_search(x, "cond", max(1, max_iter // 2), bounds)
                x = x0 if x1 is None else x1
            x = self._local_search(x, self.criterion, max_iter, bounds)
            if x is None:
                continue
            f = self._evaluate(x)[0]
            if best is None or f < best[0]:
                best = (f, x, f_init, x0)
        if progress:
            progress("design", starts, starts)
        if best is None:
            raise DesignError(
                "no feasible excitation: even a motion of 1e-4 of the start amplitude about the offsets violates "
                + (str(worst_seen) if worst_seen is not None else "a limit")
            )
        f, x, f_init, x0 = best
        if self.criterion in ("cond", "weighted_cond"):
            f, f_init = float(np.exp(f)), float(np.exp(f_init))
        traj = self.trajectory(x)
        ok, viol, crit = self.check(traj)
        # The guarantee, on the fine grid of the reported criteria: the design is no worse than its
        # (feasible) start. The search compares designs on the coarse grid; where the fine grid
        # ranks the start better (a search that barely moved), the start is the design.
        start = self._shrink_to_feasible(x0, lambda y: self.check(self.trajectory(y))[0])
        if start is not None:
            s_ok, _, s_crit = self.check(self.trajectory(start))
            if s_ok and self.criterion in s_crit:
                f_init = s_crit[self.criterion]
                if not (ok and crit.get(self.criterion, np.inf) <= f_init):
                    x, traj, ok, viol, crit = start, self.trajectory(start), s_ok, None, s_crit
        W = self.base.regressor(self.signals(traj, self.samples * 8, warm=False)[3])
        std = predicted_std(W, self.noise, repetitions=1.0 / 8.0)  # one period at the optimizer's sampling
        return ExcitationDesign(
            trajectory=traj, coordinates=self.names, criterion=self.criterion, value=crit.get(self.criterion, f),
            initial_value=f_init, criteria=crit, base_names=self.base.names, predicted_std=std,
            nominal_base=self.nominal_base, success=ok, violation=viol, starts=starts, seed=seed,
            elapsed_s=time.perf_counter() - t0, evaluations=self.evaluations,
        )

    def _centre_vector(self) -> FloatArray:
        x = np.zeros(self.n_x)
        x[2 * self.n_u * self.harmonics : 2 * self.n_u * self.harmonics + self.n_u] = self.centre
        return x

