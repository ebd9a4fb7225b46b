"""Physically consistent identification: LMI/SDP constraints on the standard parameters,
an estimate of the base parameters, optional regularization towards a reference.

The estimate is the base-parameter vector :math:`\\beta = B\\pi` of a standard vector
:math:`\\pi` that is physically consistent (the LMI formulation of Sousa & Cortesão 2014,
OLS-FBPE, paper 003 Eq. 12; standard parameters are free in the null space of :math:`B`):

.. math::

    \\min_{\\pi} \\; \\frac{\\| R (B\\pi - \\hat\\beta_{LS}) \\|^2}{s^2}
    + \\lambda\\, D(\\pi, \\pi_0)
    \\quad \\text{s.t.} \\quad
    J_k(\\pi) \\succeq \\varepsilon \\mathbf 1_4 \\;\\; \\forall k, \\qquad
    \\text{bounds on } m_k,\\; c_k = h_k/m_k, \\qquad
    I_a, f_v, f_c \\ge 0, \\; f_c^- \\le 0,

* :math:`(R, \\hat\\beta_{LS}, s^2)`: the triangular factor, optimum and residual variance of
  the unconstrained OLS, WLS (per-channel weights from OLS residuals, Gautier) or
  Gauss–Markov (full cross-channel covariance) fit of the compressed problem. The first term
  is exactly the *increase* of the weighted residual sum of squares over the unconstrained
  optimum, in units of :math:`s^2` (a :math:`\\chi^2`-like number: an increase of 1 is one
  noise variance), so the SDP never sees the raw samples (60 000 rows become ``p x p``);
* :math:`J_k` the 4x4 pseudo-inertia of body :math:`k` (Wensing, Kim & Slotine, RA-L 2017):
  :math:`J \\succeq 0` is full physical consistency (positive mass, the triangle
  inequalities of the principal moments at the centre of mass, and a density that exists);
  :math:`\\varepsilon \\ge 0` is a margin (paper 003 after Eq. 12: "subtracting an
  infinitesimal positive scalar from the diagonal");
* mass bounds :math:`m_{lo} \\le m \\le m_{hi}`; a centre-of-mass box
  :math:`m\\,c_{lo} \\le h \\le m\\,c_{hi}` (linear because :math:`m > 0`); a centre-of-mass
  ellipsoid :math:`\\| \\mathrm{diag}(a)^{-1} (h - m c_0) \\| \\le m` (second-order cone);
* the regularizer (optional): Euclidean :math:`D = \\|\\pi - \\pi_0\\|^2` (paper 003 Eq. 22,
  SI units as they come), or the log-det (Bregman, "entropic") divergence of Lee, Wensing &
  Park (IEEE T-RO 2020, the convex form of the geometric distance cited by paper 003 Eq. 23)
  on each body,

  .. math::

      D_k = \\log\\frac{\\det J_{0,k}}{\\det J_k} + \\mathrm{tr}(J_{0,k}^{-1} J_k) - 4,

  plus the Euclidean term on the joint terms (rotor inertia, friction, offsets), which have
  no pseudo-inertia. :math:`\\lambda` is in units of the residual's :math:`\\chi^2`.

Steps (cvxpy; Clarabel by default):

1. The SDP above. Its interior-point solution lies in the relative interior of the optimal
   set, so a constraint found at its boundary is one that binds.
2. Without regularization, when the residual increase is below :math:`10^{-6}` (the
   unconstrained optimum is feasible) :math:`\\hat\\beta_{LS}` is returned unchanged, with
   its least-squares covariance.
3. The standard vector: with regularization, the SDP's own (unique) solution. Without, the
   SDP is solved a second time with a tie-break :math:`\\eta \\|\\pi - \\pi_0\\|` added to
   the residual norm (:math:`\\eta`: :math:`10^{-3}` of the residual norm per reference norm),
   which picks a feasible vector near the reference among those that (almost) give the
   estimate; the residual increase it costs is reported (``stages.standard``), the estimate
   is that of the first solve. (Exact when the unconstrained optimum is feasible: the residual
   norm has a kink there, so the tie-break cannot move the estimate.) A "closest point with
   :math:`B\\pi` fixed" SDP is numerically degenerate when constraints are active (the feasible
   standard vectors of a boundary estimate form a thin set, on which Clarabel and SCS both
   fail), hence the tie-break. When constraints are active, the standard vectors of the
   estimate can be far from the reference (e.g. a large mass that a grouped first moment
   needs): prior knowledge enters only through regularization.

Uncertainty:

* no active constraint, no regularization: the least-squares covariance;
* no active constraint, with regularization: the covariance of the regularized estimate
  conditional on the reference, by the sandwich
  :math:`B H^{+} A^T A H^{+} B^T` with :math:`A = RB/s` and
  :math:`H = A^T A + \\tfrac{\\lambda}{2} \\nabla^2 D` (it ignores the bias towards the
  reference; the result says so);
* an active constraint: the estimate sits on the boundary of the feasible set, its
  distribution is not Gaussian and no covariance is reported; the result names the active
  constraints.
The standard parameters themselves have no standard error (they are not identifiable).
"""

from __future__ import annotations

import collections
import dataclasses
import threading
import time
import warnings
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import DynidError, InputError, require
from dynid.estimation.linear import _channel_noise_std, _Solve, gautier_noise_std, whitened_solve
from dynid.estimation.problem import RegressionProblem
from dynid.estimation.results import IdentificationResult
from dynid.model.base_parameters import StandardMap, pseudo_inertia
from dynid.tolerances import RELAXED_LIMIT, scaled, solver_options

__all__ = ["BodyBounds", "PhysicalConstraints", "PhysicalLS", "REGULARIZATIONS", "WEIGHTINGS", "logdet_divergence"]

WEIGHTINGS = ("ols", "wls", "gm")
REGULARIZATIONS = ("none", "euclidean", "logdet")
_LOGDET_REL_EIG = 1e-9  # smallest / largest pseudo-inertia eigenvalue a log-det reference needs
_UNCHANGED = 1e-6  # chi^2 units: below this residual increase the unconstrained optimum is feasible
_TIE_BREAK = 1e-3  # weight (x distance scale) of the closest-to-reference tie-break, in residual-norm units


def _pseudo_inertia_expr(cp, x):
    m, mx, my, mz, ixx, ixy, iyy, ixz, iyz, izz = (x[i] for i in range(10))
    tr = ixx + iyy + izz
    return cp.bmat(
        [
            [0.5 * tr - ixx, -ixy, -ixz, mx],
            [-ixy, 0.5 * tr - iyy, -iyz, my],
            [-ixz, -iyz, 0.5 * tr - izz, mz],
            [mx, my, mz, m],
        ]
    )


def _vec3(v, what: str) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"{what} must be 3 finite numbers, got {v!r}")
    return tuple(float(x) for x in a)  # type: ignore[return-value]


@dataclasses.dataclass(frozen=True, kw_only=True)
class BodyBounds:
    """Bounds on one body, in its parameter frame (the joint frame, pinocchio's convention).

    Parameters
    ----------
    mass : (low, high), optional
        Mass bounds [kg]; ``high`` may be ``inf``; ``low == high``: a known mass (an equality, never
        reported as an active constraint).
    com_box : (low xyz, high xyz), optional
        Box that contains the centre of mass [m].
    com_ellipsoid : (centre xyz, semi-axes xyz), optional
        Axis-aligned ellipsoid that contains the centre of mass [m].
    """

    mass: tuple[float, float] | None = None
    com_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    com_ellipsoid: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None

    def __post_init__(self) -> None:
        if self.mass is not None:
            lo, hi = (float(v) for v in self.mass)
            if not (np.isfinite(lo) and lo >= 0 and (hi > lo or (hi == lo and lo > 0))):
                raise InputError(f"mass bounds must satisfy 0 <= low < high (or low == high > 0: a known mass), "
                                 f"got {list(self.mass)}")
            object.__setattr__(self, "mass", (lo, hi))
        if self.com_box is not None:
            lo3, hi3 = _vec3(self.com_box[0], "com_box low"), _vec3(self.com_box[1], "com_box high")
            if not all(a < b for a, b in zip(lo3, hi3)):
                raise InputError(f"com_box needs low < high on every axis, got {lo3} and {hi3}")
            object.__setattr__(self, "com_box", (lo3, hi3))
        if self.com_ellipsoid is not None:
            c3, a3 = _vec3(self.com_ellipsoid[0], "com_ellipsoid centre"), _vec3(self.com_ellipsoid[1], "com_ellipsoid semi-axes")
            if not all(a > 0 for a in a3):
                raise InputError(f"com_ellipsoid semi-axes must be positive, got {a3}")
            object.__setattr__(self, "com_ellipsoid", (c3, a3))


@dataclasses.dataclass(frozen=True, kw_only=True)
class PhysicalConstraints:
    """The constraints of a physically consistent fit (see the module docstring).

    Parameters
    ----------
    margin : float
        :math:`\\varepsilon`: every body's pseudo-inertia :math:`\\succeq \\varepsilon \\mathbf 1`
        (SI units of the matrix entries, kg·m² / kg·m / kg). 0: plain consistency.
    bodies : mapping of body name to BodyBounds
        Per-body bounds; names as in :attr:`StandardMap.body_names` (``"3"`` for ``m3``,
        ``"qa1"`` for ``m_qa1``).
    sign : bool
        Rotor inertias and friction coefficients >= 0 (each direction of an asymmetric
        model; the negative-direction Coulomb coefficient <= 0).
    """

    margin: float = 0.0
    bodies: Mapping[str, BodyBounds] = dataclasses.field(default_factory=dict)
    sign: bool = True

    def __post_init__(self) -> None:
        if not (np.isfinite(self.margin) and self.margin >= 0):
            raise InputError(f"margin must be a non-negative number, got {self.margin!r}")
        for k, v in dict(self.bodies).items():
            if not isinstance(v, BodyBounds):
                raise InputError(f"bounds of body {k!r} must be a BodyBounds, got {type(v).__name__}")
        object.__setattr__(self, "bodies", MappingProxyType(dict(self.bodies)))


def logdet_divergence(pi: FloatArray, reference: FloatArray, body_blocks) -> float:
    """Sum over bodies of the log-det divergence :math:`D_k` (module docstring) [-]; inf when a
    pseudo-inertia is not positive definite."""
    total = 0.0
    for blk in body_blocks:
        J, J0 = pseudo_inertia(np.asarray(pi)[blk]), pseudo_inertia(np.asarray(reference)[blk])
        s, ld = np.linalg.slogdet(J)
        s0, ld0 = np.linalg.slogdet(J0)
        if s <= 0 or s0 <= 0:
            return float("inf")
        total += ld0 - ld + float(np.trace(np.linalg.solve(J0, J))) - 4.0
    return total


@dataclasses.dataclass(frozen=True)
class _Fit:
    s: _Solve
    weights_note: str
    noise_std: FloatArray
    label: str


# compiled (DPP) problems of PhysicalLS._compiled, least recently used dropped first; one cache
# per thread (a cached problem holds its parameter values and solution while it is solved)
_COMPILED_LOCAL = threading.local()
_COMPILED_SIZE = 8


@dataclasses.dataclass(frozen=True, kw_only=True)
class PhysicalLS:
    """Physically consistent OLS / WLS / Gauss–Markov, optionally regularized (module docstring).

    Parameters
    ----------
    weighting : {"wls", "ols", "gm"}
        The residual measure: OLS, WLS with per-joint weights from OLS residuals (Gautier), or
        Gauss–Markov with a full cross-channel noise covariance (given as
        ``noise_covariance``, or estimated from the residuals; the problem needs its
        cross-channel factor).
    noise_covariance : array (n_ch, n_ch), optional
        For ``"gm"``.
    constraints : PhysicalConstraints
    regularization : {"none", "euclidean", "logdet"}
    regularization_weight : float
        :math:`\\lambda \\ge 0` (0 with ``"none"``).
    reference : array (n_standard,), optional
        :math:`\\pi_0`; default the problem's nominal (CAD) standard parameters.
    solver : str
        cvxpy solver (Clarabel by default).
    active_tol : float
        A body constraint is reported active when its smallest pseudo-inertia eigenvalue is
        within ``active_tol`` times its largest of the margin; a bound likewise.
    feasibility_tol : float
        Solver-accuracy buffer :math:`\\tau` (SI units of the constrained quantities): the SDP
        is solved with every constraint tightened by :math:`2\\tau` (pseudo-inertia
        :math:`\\succeq (\\varepsilon + 2\\tau)\\mathbf 1`, rotor inertia and friction
        :math:`\\ge 2\\tau`, ...) and the closest-standard-parameters step by :math:`\\tau`, so
        the reported standard parameters satisfy the constraints as stated (e.g. smallest
        eigenvalue :math:`\\ge \\varepsilon`) despite the interior-point solver's finite accuracy.
    """

    weighting: str = "wls"
    noise_covariance: tuple[tuple[float, ...], ...] | None = None
    constraints: PhysicalConstraints = PhysicalConstraints()
    regularization: str = "none"
    regularization_weight: float = 0.0
    reference: tuple[float, ...] | None = None
    solver: str = "CLARABEL"
    active_tol: float = 1e-6
    feasibility_tol: float = 1e-8

    # ------------------------------------------------------------------ set-up
    def _check(self, problem: RegressionProblem) -> tuple[StandardMap, FloatArray | None]:
        if self.weighting not in WEIGHTINGS:
            raise InputError(f"weighting must be one of {', '.join(WEIGHTINGS)}, got {self.weighting!r}")
        if self.regularization not in REGULARIZATIONS:
            raise InputError(f"regularization must be one of {', '.join(REGULARIZATIONS)}, got {self.regularization!r}")
        lam = self.regularization_weight
        if not (np.isfinite(lam) and lam >= 0):
            raise InputError(f"regularization_weight must be a non-negative number, got {lam!r}")
        if (self.regularization == "none") != (lam == 0):
            raise InputError("regularization and regularization_weight go together: a weight > 0 needs "
                             "regularization = 'euclidean' or 'logdet', and those need a weight > 0")
        if self.noise_covariance is not None and self.weighting != "gm":
            raise InputError(f"a noise covariance is for weighting 'gm', not {self.weighting!r}")
        smap = problem.standard
        if smap is None:
            raise InputError("physically consistent estimation needs the problem's map to standard parameters")
        unknown = sorted(set(self.constraints.bodies) - set(smap.body_names))
        if unknown:
            raise InputError(f"bounds given for unknown bodies {unknown}; bodies: {', '.join(smap.body_names)}")
        ref = smap.reference if self.reference is None else np.asarray(self.reference, dtype=float)
        if ref is not None:
            ref = np.asarray(ref, dtype=float)
            if ref.shape != (smap.B.shape[1],) or not np.all(np.isfinite(ref)):
                raise InputError(f"reference must be {smap.B.shape[1]} finite standard parameters, got shape {ref.shape}")
        if self.regularization != "none" and ref is None:
            raise InputError(f"regularization = {self.regularization!r} needs reference standard parameters "
                             "(the model has no nominal values)")
        if self.regularization == "logdet":
            # relative: a reference whose smallest eigenvalue is rounding noise (a point mass or a
            # thin rod, 1e-18 against 1e2) is singular for the divergence too (the solver would
            # end "unbounded")
            eigs = [np.linalg.eigvalsh(pseudo_inertia(ref[blk])) for blk in smap.body_blocks]
            bad = [name for name, ev in zip(smap.body_names, eigs) if ev[0] <= _LOGDET_REL_EIG * max(abs(ev[-1]), 1e-300)]
            if bad:
                raise InputError("the log-det divergence needs a reference whose every body has a positive definite "
                                 f"pseudo-inertia (smallest eigenvalue above {_LOGDET_REL_EIG:g} of the largest); not so "
                                 f"for bodies {bad} (use regularization = 'euclidean')")
        return smap, ref

    def _unconstrained(self, problem: RegressionProblem) -> _Fit:
        if self.weighting == "ols":
            s = whitened_solve(problem, np.ones(problem.n_channels))
            return _Fit(s, "OLS (no weights)", _channel_noise_std(problem, s.rss), "OLS")
        if self.weighting == "wls":
            sigma = gautier_noise_std(problem)
            s = whitened_solve(problem, 1.0 / sigma**2)
            return _Fit(s, "weights 1/sigma_j^2 per channel; sigma_j from OLS residuals (Gautier)", sigma, "WLS")
        from dynid.estimation.generalized import GaussMarkov, gls_solve

        gm = GaussMarkov(noise_covariance=self.noise_covariance).fit(problem)
        cov = np.asarray(gm.solver["noise_covariance"], dtype=float)
        s = gls_solve(problem, cov)
        return _Fit(s, f"Gauss-Markov: full noise covariance from {gm.solver['covariance_from']}",
                    np.sqrt(np.diag(cov)), "GM")

    # ------------------------------------------------------------------ the SDP pieces
    def _constraints(self, cp, smap: StandardMap, pi, tau: float = 0.0) -> list:
        """The constraints, each tightened by ``tau`` (solver-accuracy buffer, see :meth:`fit`)."""
        cons = []
        eps = self.constraints.margin + tau
        for name, blk in zip(smap.body_names, smap.body_blocks):
            J = _pseudo_inertia_expr(cp, pi[blk])
            cons.append(J - eps * np.eye(4) >> 0 if eps > 0 else J >> 0)
            b = self.constraints.bodies.get(name)
            if b is None:
                continue
            m, h = pi[blk[0]], pi[blk[1:4]]
            if b.mass is not None and b.mass[0] == b.mass[1]:  # a known mass: an equality, not tightened
                cons.append(m == b.mass[0])
            elif b.mass is not None:
                cons.append(m >= b.mass[0] + tau)
                if np.isfinite(b.mass[1]):
                    cons.append(m <= b.mass[1] - tau)
            if b.com_box is not None:
                cons += [h - m * np.array(b.com_box[0]) >= tau, m * np.array(b.com_box[1]) - h >= tau]
            if b.com_ellipsoid is not None:
                c0, a = np.array(b.com_ellipsoid[0]), np.array(b.com_ellipsoid[1])
                cons.append(cp.norm(cp.multiply(1.0 / a, h - m * c0)) + tau <= m)
        if smap.zero.size:  # the structural simplification's zeros (dynid.model.reduction): equalities, not bounds
            cons.append(pi[smap.zero] == 0)
        if self.constraints.sign:
            if smap.nonnegative.size:
                cons.append(pi[smap.nonnegative] >= tau)
            if smap.nonpositive.size:
                cons.append(pi[smap.nonpositive] <= -tau)
        return cons

    def _divergence(self, cp, smap: StandardMap, pi, ref: FloatArray | None, kind: str):
        """cvxpy expression of D(pi, ref) (0 reference when none)."""
        ref0 = np.zeros(smap.B.shape[1]) if ref is None else ref
        if kind != "logdet":
            return cp.sum_squares(pi - ref0)
        body = np.concatenate(smap.body_blocks) if smap.body_blocks else np.zeros(0, dtype=int)
        rest = np.setdiff1d(np.arange(smap.B.shape[1]), body)
        expr = 0
        for blk in smap.body_blocks:
            J0inv = np.linalg.inv(pseudo_inertia(ref0[blk]))
            J = _pseudo_inertia_expr(cp, pi[blk])
            expr = expr - cp.log_det(J) + cp.trace(J0inv @ J)
        if rest.size:
            expr = expr + cp.sum_squares(pi[rest] - ref0[rest])
        return expr

    def _solve(self, cp, prob, what: str) -> dict:
        """Solve ``prob``; a numerical failure of Clarabel is retried with its tolerances x10 at a
        time up to a feasibility tolerance of :data:`dynid.tolerances.RELAXED_LIMIT` (the stage then
        reports ``tolerance_factor`` and the status ``optimal_inaccurate``); the callers check the
        solution's constraints themselves."""
        t0 = time.perf_counter()
        factor = 1.0
        while True:
            try:
                with warnings.catch_warnings():  # "solution may be inaccurate": the status says so
                    warnings.simplefilter("ignore", UserWarning)
                    prob.solve(solver=self.solver, **solver_options(self.solver, factor))
                break
            except cp.error.SolverError as exc:
                opts = solver_options(self.solver, 10.0 * factor)
                if not opts or opts["tol_feas"] > RELAXED_LIMIT * (1 + 1e-9):
                    raise DynidError(f"{self.solver} failed on {what} ({str(exc).splitlines()[0]})") from None
                factor *= 10.0
        st = prob.solver_stats
        status = str(prob.status)
        if factor > 1.0 and status == "optimal":
            status = "optimal_inaccurate"  # solved, at tolerances looser than asked for
        return {"status": status, "iterations": getattr(st, "num_iters", None) if st else None,
                "solve_time_s": getattr(st, "solve_time", None) if st else None, "wall_time_s": time.perf_counter() - t0,
                "tolerance_factor": factor}

    def _compiled(self, cp, smap, shape: tuple, tau: float, tie: bool):
        """The problem min ||A pi - d|| (+ ||eta pi - eta ref||, the tie-break, with ``tie``) under
        the constraints tightened by ``tau``, with A, d (eta, eta ref) as cvxpy Parameters, from a
        small per-thread cache: cvxpy compiles a parametrized (DPP) problem once and
        solves it again with new data without canonicalizing it (on the 3-RPS Stribeck fits,
        which alternate with this polish a few hundred times, canonicalization was 95 % of the
        SDP time). Returns ``(prob, pi, params)``."""
        key = (repr(self.constraints), smap.B.shape[1], tuple(smap.body_names),
               tuple(tuple(int(i) for i in b) for b in smap.body_blocks), smap.zero.tobytes(),
               smap.nonnegative.tobytes(), smap.nonpositive.tobytes(), tuple(shape), float(tau), bool(tie))
        cache = getattr(_COMPILED_LOCAL, "problems", None)
        if cache is None:
            cache = _COMPILED_LOCAL.problems = collections.OrderedDict()
        hit = cache.get(key)
        if hit is not None:
            cache.move_to_end(key)
            return hit
        n = smap.B.shape[1]
        pi = cp.Variable(n)
        A_p, d_p = cp.Parameter(tuple(shape)), cp.Parameter(shape[0])
        # the residual as a second-order cone (its square as a quadratic form squares the
        # condition number of R and costs the solver digits)
        obj = cp.norm(A_p @ pi - d_p)
        params = [A_p, d_p]
        if tie:  # eta ||pi - ref|| = ||eta pi - eta ref|| (eta >= 0): parameter-affine inside the norm (DPP)
            e_p, r_p = cp.Parameter(nonneg=True), cp.Parameter(n)
            obj = obj + cp.norm(e_p * pi - r_p)
            params += [e_p, r_p]
        hit = (cp.Problem(cp.Minimize(obj), self._constraints(cp, smap, pi, tau)), pi, params)
        cache[key] = hit
        while len(cache) > _COMPILED_SIZE:
            cache.popitem(last=False)
        return hit

    def _sdp(self, cp, smap, A, d, extra=None, squared: bool = False, tie: tuple | None = None):
        """min ||A pi - d|| (+ its square with ``squared``) + extra(pi) (or, with ``tie`` =
        (eta, ref), + eta ||pi - ref||, through the compiled-problem cache) under the constraints,
        tightened by a buffer that is widened until the solution satisfies them as stated."""
        tau = scaled(self.feasibility_tol)  # follows the solver's feasibility tolerance
        for _attempt in range(4):
            if extra is None:
                prob, pi, params = self._compiled(cp, smap, A.shape, 2 * tau, tie is not None)
                params[0].value, params[1].value = A, d
                if tie is not None:
                    params[2].value, params[3].value = float(tie[0]), float(tie[0]) * np.asarray(tie[1], dtype=float)
            else:
                pi = cp.Variable(smap.B.shape[1])
                resid = cp.norm(A @ pi - d)
                obj = (cp.square(resid) if squared else resid) + extra(pi)
                prob = cp.Problem(cp.Minimize(obj), self._constraints(cp, smap, pi, 2 * tau))
            info = self._solve(cp, prob, "the physically consistent problem")
            info["data_norm"] = float(np.linalg.norm(d))  # the scale of Clarabel's residual tolerances
            status = info["status"]
            if status not in ("optimal", "optimal_inaccurate") or pi.value is None:
                hint = " (do the bounds exclude every physically consistent body?)" if "infeasible" in status else ""
                raise DynidError(f"physically consistent estimation failed: solver status {status!r}{hint}")
            out = np.array(pi.value, dtype=float)  # a copy: a cached problem's variable is reused
            if min(slack for _, slack, _ in self._margins(smap, out)) >= 0:
                info["buffer"] = 2 * tau
                return out, info
            tau *= 10.0  # the solver's accuracy did not cover the buffer: a wider one
        raise DynidError("physically consistent estimation: the solver's solution violates the constraints "
                         f"beyond a buffer of {2 * tau / 10:g}; try another solver")

    # ------------------------------------------------------------------ fit
    def fit(self, problem: RegressionProblem) -> IdentificationResult:
        smap, ref = self._check(problem)
        cp = require("cvxpy", "sdp")
        if self.solver not in cp.installed_solvers():
            raise DynidError(f"solver {self.solver} is not installed (installed: {', '.join(cp.installed_solvers())}); "
                             "install it or choose another")
        fit = self._unconstrained(problem)
        s = fit.s
        # chi^2 units; floored for noise-free (synthetic) data, where the residual variance is ~0
        s2 = max(s.scale, 1e-12 * float(np.sum((s.R @ s.beta) ** 2)) / max(s.dof, 1), 1e-300)
        A = (s.R @ smap.B) / np.sqrt(s2)
        d = (s.R @ s.beta) / np.sqrt(s2)
        kind = self.regularization
        lam = self.regularization_weight
        stages: dict = {}
        ref0 = np.zeros(smap.B.shape[1]) if ref is None else ref
        if lam == 0:
            beta, pi_std, cost, unchanged, active, stages = self._closest(cp, smap, A, d, s.beta, ref0)
        else:
            pi_sdp, stages["sdp"] = self._sdp(cp, smap, A, d, lambda pi: lam * self._divergence(cp, smap, pi, ref, kind),
                                              squared=True)
            pi_std, unchanged = pi_sdp, False
            cost = float(np.sum((A @ pi_sdp - d) ** 2))
            beta = smap.B @ pi_sdp
            # with regularization the move is the regularization's: no nearest constraint named
            active = self._active(smap, pi_sdp, stages["sdp"]["buffer"])
        return self._result(problem, smap, fit, beta, pi_std, ref, cost, active, stages, unchanged, A)

    def project(self, beta: FloatArray, cov: FloatArray, smap: StandardMap) -> dict:
        """The physically consistent base parameters closest to ``beta`` in the metric of its
        covariance: :math:`\\arg\\min_\\pi (B\\pi - \\hat\\beta)^T \\Sigma^{-1} (B\\pi - \\hat\\beta)`
        under the constraints (the SDP of :meth:`fit` with :math:`A = U^{-1}B`,
        :math:`d = U^{-1}\\hat\\beta`, :math:`\\Sigma = UU^T`).

        For WLS this is exactly what :meth:`fit` computes (its objective is the residual's
        increase over the unconstrained optimum, :math:`(\\beta - \\hat\\beta)^T \\Sigma^{-1}
        (\\beta - \\hat\\beta)` in :math:`\\chi^2` units); here it serves estimators whose
        covariance is not a least-squares one (DIDIM's fixed point). The feasible set is
        convex and, when the model is right, contains the truth :math:`\\beta^*`; a projection
        onto a closed convex set is non-expansive in its metric, so
        :math:`\\|P\\hat\\beta - \\beta^*\\|_{\\Sigma^{-1}} \\le \\|\\hat\\beta - \\beta^*\\|_{\\Sigma^{-1}}`:
        the confidence ellipsoid of :math:`\\Sigma` centred on the projection contains the truth
        whenever the one centred on :math:`\\hat\\beta` does (a conservative region; per-parameter
        intervals inherit no such guarantee). Regularization does not apply (it would move the
        estimate by a prior, not by the data).

        Returns a dict: ``params`` (projected base parameters), ``standard_params`` (a
        consistent standard vector that gives them, tie-broken towards the reference as in
        :meth:`fit`), ``distance_chi2`` (the Mahalanobis distance squared of the move),
        ``active_constraints``, ``unchanged`` and ``stages``.
        """
        if self.regularization != "none":
            raise InputError("the projection onto the physically consistent set takes no regularization")
        cp = require("cvxpy", "sdp")
        if self.solver not in cp.installed_solvers():
            raise DynidError(f"solver {self.solver} is not installed (installed: {', '.join(cp.installed_solvers())})")
        import scipy.linalg as sla

        b = np.asarray(beta, dtype=float)
        S = 0.5 * (np.asarray(cov, dtype=float) + np.asarray(cov, dtype=float).T)
        try:
            U = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise InputError("the covariance to project with is not positive definite") from None
        A = sla.solve_triangular(U, smap.B, lower=True)
        d = sla.solve_triangular(U, b, lower=True)
        ref0 = np.zeros(smap.B.shape[1]) if smap.reference is None else np.asarray(smap.reference, dtype=float)
        params, pi_std, cost, unchanged, active, stages = self._closest(cp, smap, A, d, b, ref0)
        return {"params": params, "standard_params": pi_std, "distance_chi2": cost, "active_constraints": active,
                "unchanged": unchanged, "stages": stages}

    def _closest(self, cp, smap: StandardMap, A, d, beta0: FloatArray, ref0: FloatArray):
        """The constrained minimum of :math:`\\|A\\pi - d\\|` (``beta0``, the unconstrained
        optimum, returned unchanged when it is feasible), a standard vector that gives it
        tie-broken towards ``ref0`` (module docstring, step 3), and the active constraints (the
        nearest one named when the optimum moved but none sits on the boundary within the
        tolerance). Returns ``(beta, pi_std, cost, unchanged, active, stages)``."""
        stages: dict = {}
        pi_sdp, stages["sdp"] = self._sdp(cp, smap, A, d)
        cost = float(np.sum((A @ pi_sdp - d) ** 2))
        unchanged = cost <= _UNCHANGED  # a feasible unconstrained optimum is returned unchanged
        beta = beta0.copy() if unchanged else smap.B @ pi_sdp
        scale = float(np.linalg.norm(smap.B.T @ np.linalg.lstsq(smap.B @ smap.B.T, beta0 - smap.B @ ref0, rcond=None)[0]))
        eta = _TIE_BREAK / max(scale + float(np.linalg.norm(ref0)), 1e-12)
        pi_std, stages["standard"] = self._sdp(cp, smap, A, d, tie=(eta, ref0))
        stages["standard"]["residual_increase_chi2"] = float(np.sum((A @ pi_std - d) ** 2)) - cost
        # what bounds that increase: pi_sdp is feasible for the tie-break problem, so at its optimum
        # ||A pi_std - d|| - ||A pi_sdp - d|| <= weight * (||pi_sdp - ref|| - ||pi_std - ref||)
        stages["standard"]["tie_break"] = {"weight": float(eta),
                                           "reference_distance_before": float(np.linalg.norm(pi_sdp - ref0)),
                                           "reference_distance_after": float(np.linalg.norm(pi_std - ref0))}
        buf = stages["sdp"]["buffer"]
        active = [] if unchanged else (self._active(smap, pi_sdp, buf) or [self._nearest(smap, pi_sdp, buf)])
        return beta, pi_std, cost, unchanged, active, stages

    # ------------------------------------------------------------------ reporting
    def _margins(self, smap: StandardMap, pi: FloatArray) -> list[tuple[str, float, float]]:
        """(constraint, slack, scale) for every constraint at ``pi``."""
        eps = self.constraints.margin
        out = []
        for name, blk in zip(smap.body_names, smap.body_blocks):
            ev = np.linalg.eigvalsh(pseudo_inertia(pi[blk]))
            out.append((f"body {name} pseudo-inertia", ev[0] - eps, max(abs(ev[-1]), 1e-300)))
            b = self.constraints.bodies.get(name)
            m, h = pi[blk[0]], pi[blk[1:4]]
            if b is None:
                continue
            if b.mass is not None and b.mass[0] != b.mass[1]:  # a known mass is an equality: no slack to report
                out.append((f"body {name} mass >= {b.mass[0]:g}", m - b.mass[0], max(abs(m), 1e-300)))
                if np.isfinite(b.mass[1]):
                    out.append((f"body {name} mass <= {b.mass[1]:g}", b.mass[1] - m, max(abs(m), 1e-300)))
            if b.com_box is not None:
                lo, hi = np.array(b.com_box[0]), np.array(b.com_box[1])
                out.append((f"body {name} centre-of-mass box", float(np.min(np.r_[h - m * lo, m * hi - h])),
                            max(abs(m) * float(np.max(np.abs(np.r_[lo, hi]))), 1e-300)))
            if b.com_ellipsoid is not None:
                c0, a = np.array(b.com_ellipsoid[0]), np.array(b.com_ellipsoid[1])
                out.append((f"body {name} centre-of-mass ellipsoid", m - float(np.linalg.norm((h - m * c0) / a)),
                            max(abs(m), 1e-300)))
        if self.constraints.sign:
            scale = max([1e-300] + [abs(pi[i]) for i in np.r_[smap.nonnegative, smap.nonpositive].astype(int)])
            out += [(f"{smap.standard_names[i]} >= 0", pi[i], scale) for i in smap.nonnegative]
            out += [(f"{smap.standard_names[i]} <= 0", -pi[i], scale) for i in smap.nonpositive]
        return out

    def _active(self, smap, pi, buffer: float) -> list[str]:
        """Constraints at the boundary of the SDP's solution (tightened by ``buffer``)."""
        return [n for n, slack, scale in self._margins(smap, pi) if slack - buffer <= self.active_tol * scale]

    def _nearest(self, smap, pi, buffer: float) -> str:
        n, slack, scale = min(self._margins(smap, pi), key=lambda t: (t[1] - buffer) / t[2])
        return f"{n} (relative slack {(slack - buffer) / scale:.1e})"

    def _covariance(self, smap, A, pi_std) -> FloatArray:
        """Sandwich covariance of the regularized estimate (module docstring); ``A`` is scaled by
        :math:`1/s`, so its right-hand side has unit covariance."""
        lam, P = self.regularization_weight, smap.B.shape[1]
        if self.regularization != "logdet":
            # H = A^T A + lam I: in A's right singular vectors H^-1 A^T A H^-1 is diag(s^2 / (s^2 + lam)^2),
            # exactly 0 on A's null space (the standard directions the data leave free), where forming
            # H and its pseudo-inverse would leave rounding of order eps * s_max^2 / lam^2 (1e-5 relative
            # standard errors on a well-excited arm at lam = 1e-2)
            _, sv, vt = np.linalg.svd(A, full_matrices=False)
            return smap.B @ ((vt.T * (sv**2 / (sv**2 + lam) ** 2)) @ vt) @ smap.B.T
        hess = 2.0 * np.eye(P)
        if self.regularization == "logdet":
            body = np.concatenate(smap.body_blocks)
            hess[np.ix_(body, body)] = 0.0
            eye = np.eye(10)
            for blk in smap.body_blocks:
                Jinv = np.linalg.inv(pseudo_inertia(pi_std[blk]))
                dJ = [pseudo_inertia(eye[i]) for i in range(10)]
                h = np.array([[np.trace(Jinv @ dJ[a] @ Jinv @ dJ[b]) for b in range(10)] for a in range(10)])
                hess[np.ix_(blk, blk)] = h
        H = A.T @ A + 0.5 * lam * hess
        Hp = np.linalg.pinv(H, rcond=1e-14)
        cov_pi = Hp @ A.T @ A @ Hp
        return smap.B @ cov_pi @ smap.B.T

    def _result(self, problem, smap, fit: _Fit, beta, pi_std, ref, cost, active, stages, unchanged, A) -> IdentificationResult:
        s = fit.s
        lam = self.regularization_weight
        label = f"{fit.label}+LMI" + ("" if lam == 0 else f"+{'Reg' if self.regularization == 'euclidean' else 'LogDet'}")
        rss = problem.rss_per_channel(beta)
        eps = self.constraints.margin
        min_eigs = {name: float(np.linalg.eigvalsh(pseudo_inertia(pi_std[blk]))[0])
                    for name, blk in zip(smap.body_names, smap.body_blocks)}
        notes = [f"physically consistent {fit.label}: every body's pseudo-inertia >= {eps:g} I"
                 + (", rotor inertia and friction >= 0 (each direction)" if self.constraints.sign else "")
                 + (f", bounds on bodies {', '.join(self.constraints.bodies)}" if self.constraints.bodies else "")
                 + f" (LMI, cvxpy/{self.solver})", fit.weights_note]
        if lam > 0:
            notes.append(f"regularized towards the reference standard parameters: {self.regularization} "
                         f"(weight {lam:g} in units of the residual chi^2)")
        if unchanged:
            notes.append("the unconstrained optimum is physically consistent: returned unchanged, least-squares covariance")
            cov = s.cov
            se_note = "least-squares covariance (no constraint active)"
        elif active:
            cov = None
            se_note = ("not defined: the estimate lies on the boundary of the feasible set (active: "
                       + ", ".join(active) + "), so no covariance is reported")
            notes.append(f"residual increase over the unconstrained optimum: {cost:.4g} (chi^2 units); " + se_note)
        else:
            cov = self._covariance(smap, A, pi_std)
            se_note = ("sandwich covariance of the regularized estimate, conditional on the reference; it does not "
                       "include the bias towards the reference")
            notes.append(f"no constraint active; {se_note}")
        notes.append("standard parameters: a physically consistent vector near "
                     + ("the reference" if ref is not None else "zero (no reference)")
                     + (" (the regularized optimum)" if lam > 0 else " that gives the estimate up to the tie-break's "
                        f"reported cost ({stages['standard']['residual_increase_chi2']:.2g} chi^2)")
                     + "; they have no standard error (not identifiable)")
        relaxed = max(v.get("tolerance_factor", 1.0) for v in stages.values())
        if relaxed > 1.0:
            notes.append(f"the solver failed numerically at the requested tolerances and was solved at {relaxed:g} x them "
                         "(status optimal_inaccurate; constraints checked as stated)")
        it = [v.get("iterations") for v in stages.values() if v.get("iterations") is not None]
        main = stages["sdp"]
        return IdentificationResult(
            method=label,
            names=problem.names,
            params=np.asarray(beta, dtype=float),
            cov_params=cov,
            dof=s.dof,
            scale=float(s.scale),
            channel_names=problem.channel_names,
            n_obs=problem.n_obs,
            rss_per_channel=rss,
            noise_std=fit.noise_std,
            condition_number=s.cond,
            expressions=problem.expressions,
            solver={
                "algorithm": "SDP on the compressed whitened problem (LMI pseudo-inertia constraints)",
                "solver": self.solver,
                "status": main["status"],
                "unchanged": unchanged,
                "iterations": int(sum(it)) if it else None,
                "stages": stages,
                "margin": eps,
                "min_pseudo_inertia_eigenvalue": list(min_eigs.values()),
                "min_pseudo_inertia_eigenvalue_by_body": min_eigs,
                "active_constraints": list(active),
                "residual_increase_chi2": cost,
                "regularization": {"kind": self.regularization, "weight": lam,
                                   "divergence": None if ref is None else (
                                       logdet_divergence(pi_std, ref, smap.body_blocks) if self.regularization == "logdet"
                                       else float(np.sum((pi_std - ref) ** 2)))},
                "standard_params": dict(zip(smap.standard_names, pi_std.tolist())),
                "standard_reference": None if ref is None else ("given" if self.reference is not None else "nominal"),
                "standard_error": se_note,
                "unconstrained_params": s.beta.tolist(),
            },
            provenance=dict(problem.meta),
            notes=tuple(notes),
        )
