"""A physically consistent standard vector for base-parameter estimates (what a simulator loads).

The data fix the base parameters :math:`\\beta = B\\pi` only; the standard vector :math:`\\pi`
written to ``model.urdf`` / ``model.mjcf`` is one of many, and the closest-to-prior choice
among *all* vectors with those base parameters (:meth:`~dynid.model.base_parameters.BaseParameters.to_standard`)
can give a body a negative mass or an inertia no rigid body has. The rule here:

.. math::

    \\pi^\\star = \\arg\\min_\\pi \\; \\lVert S^{-1}(\\pi - \\pi_0) \\rVert_2
    \\quad\\text{s.t.}\\quad B\\pi = \\hat\\beta, \\qquad J_k(\\pi) \\succeq 0 \\;\\; \\forall k,

* :math:`\\pi_0`: the prior (the model's nominal standard parameters);
* :math:`S`: a magnitude per parameter, the RMS of the prior's nonzero values of its kind
  (mass, first moment, inertia, each kind of joint term;
  :func:`~dynid.model.base_parameters.parameter_scales`), so that kilograms and
  kilogram-square-metres are not compared as numbers;
* :math:`J_k` the 4x4 pseudo-inertia of body :math:`k` (Wensing, Kim & Slotine, RA-L 2017):
  :math:`J \\succeq 0` is full physical consistency: mass
  :math:`\\ge 0`, the inertia about the centre of mass positive semidefinite and satisfying the
  triangle inequalities. The SDPs ask :math:`J_k \\succeq \\varepsilon_k\\mathbf 1`,
  :math:`\\varepsilon_k` = :data:`MARGIN` of the largest eigenvalue of the prior's :math:`J_k` (at
  least :math:`2\\tau`, :math:`\\tau` Clarabel's feasibility tolerance, :mod:`dynid.tolerances`), so
  every mass is positive and the answer stays consistent through the solver's finite accuracy and
  step 4's final move;
* joint terms (rotor inertia, friction, offsets) carry no constraint: they pass through as the
  base parameters fix them (each is its own base parameter, or a fixed combination);
* the zeros of a structural simplification (:mod:`dynid.model.reduction`) stay zero.

Steps:

1. The closed form without the LMIs, :math:`\\pi_0 + S(BS)^+(\\hat\\beta - B\\pi_0)`. When every
   body of it is consistent it is :math:`\\pi^\\star` (the LMIs are inactive) and no SDP runs;
   in particular :math:`\\pi^\\star = \\pi_0` when the prior already maps to the estimate.
2. Otherwise, the mismatch first: :math:`r^\\star = \\min \\lVert L^{-1}(B\\pi - \\hat\\beta)\\rVert`
   over consistent :math:`\\pi` (:math:`LL^T` the estimate's covariance, the mismatch in standard
   deviations: the same metric as :meth:`~dynid.estimation.physical.PhysicalLS.project`; without a
   covariance, :math:`L` = diag of each base parameter's magnitude through :math:`S`,
   :math:`\\lVert (BS)_{i,:}\\rVert`).
3. Then the prior: :math:`\\min \\lVert S^{-1}(\\pi - \\pi_0)\\rVert` over consistent :math:`\\pi`
   with :math:`B\\pi = \\hat\\beta` when :math:`r^\\star \\le \\delta` (a consistent vector gives the
   estimate; :math:`\\delta` the accuracy of step 2's optimum, :func:`mismatch_slack`), else with
   :math:`\\lVert L^{-1}(B\\pi - \\hat\\beta)\\rVert \\le r^\\star + \\delta` (the mismatch held at its
   minimum; a slab, not an equality: the consistent vectors of the closest consistent base
   parameters form a thin set, on which an equality-constrained SDP is numerically degenerate, see
   :mod:`dynid.estimation.physical`, step 3).
4. When :math:`r^\\star \\le \\delta`, the answer is moved onto :math:`B\\pi = \\hat\\beta` to
   rounding by the smallest :math:`S^{-1}`-norm correction :math:`S(BS)^+(\\hat\\beta - B\\pi)` (of
   the size of the solver's tolerance, inside the margin), so the exported model reproduces the
   estimate to rounding (``exact``). Otherwise the result says by how much the exported vector
   misses the estimate (``mismatch``, in standard deviations), for the export's warnings: at most
   :math:`r^\\star` + ``stages["slack"]`` + ``stages["slack_prior"]`` (the second SDP's residual on
   the slab), and :math:`r^\\star` is the least mismatch of the vectors whose bodies keep the margin.

A solver answer outside the consistent set (an interior-point method stalls at tolerances too
tight for ill-conditioned data, then returns its last iterate) is solved again at tolerances x10
(at most three times); nothing inconsistent is ever returned.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import DynidError, InputError, require
from dynid.model.base_parameters import StandardMap, body_violation, pseudo_inertia
from dynid.tolerances import RELAXED_LIMIT, clarabel_tolerances, scaled

__all__ = ["MARGIN", "ConsistentStandard", "consistent_standard", "mismatch_slack"]

_FEASIBILITY = 1e-8  # Clarabel's tol_feas at scale 1: the LMI buffer tau (times DYNID_SOLVER_TOL_SCALE)
MARGIN = 1e-5
"""Each body's pseudo-inertia :math:`\\succeq` this fraction of the largest eigenvalue of the
prior's (at least :math:`2\\tau`) in the SDPs: room for the final move onto
:math:`B\\pi = \\hat\\beta` (of the solver's accuracy, about 1e-8 to 1e-6 of the parameters'
magnitudes) to keep every body consistent; a change of the exported inertias far below any
measurement (0.01 g on a 1 kg body)."""


@dataclasses.dataclass(frozen=True)
class ConsistentStandard:
    """The standard vector of :func:`consistent_standard` and how it was found.

    Attributes
    ----------
    params : array (p,)
        The standard vector: every body physically consistent.
    exact : bool
        :math:`B\\pi = \\hat\\beta` to rounding (False: no consistent vector gives the estimate;
        ``mismatch`` says by how much it is missed).
    mismatch : float
        :math:`\\lVert L^{-1}(B\\pi - \\hat\\beta)\\rVert` [standard deviations of the estimate, or
        base-parameter magnitudes without a covariance].
    projected : bool
        False: the closed form (step 1) was already consistent, no SDP ran.
    metric : str
        What :math:`L` is.
    stages : dict
        Solver status, iterations and times of the SDPs.
    notes : tuple of str
        What the export's warnings must say beyond ``exact``/``mismatch``.
    """

    params: FloatArray
    exact: bool
    mismatch: float
    projected: bool
    metric: str
    stages: dict
    notes: tuple[str, ...] = ()


def mismatch_slack(r_star: float, d_norm: float, tolerance_factor: float = 1.0, status: str = "optimal") -> float:
    """How far above its true minimum Clarabel may stop on :math:`\\min\\lVert A\\pi - d\\rVert`
    (a second-order cone objective): the duality gap ``tol_gap_abs + tol_gap_rel * max(1, r)`` and
    the primal residual ``tol_feas * max(1, ||d||)`` of the cone constraint, ten times over
    (:func:`dynid.tolerances.clarabel_tolerances`; their ``reduced_`` values when the solve ended
    ``optimal_inaccurate``; ``tolerance_factor``: a solve at looser tolerances)."""
    t = clarabel_tolerances()
    pre = "reduced_" if status != "optimal" else ""
    return 10.0 * tolerance_factor * (t[pre + "tol_gap_abs"] + t[pre + "tol_gap_rel"] * max(1.0, r_star)
                                      + t[pre + "tol_feas"] * max(1.0, d_norm))


def _consistent(pi: FloatArray, smap: StandardMap) -> bool:
    return all(not body_violation(pi[blk]) for blk in smap.body_blocks) and not np.any(pi[smap.zero] != 0.0)


class _Conic:
    """A problem :math:`\\min t` over :math:`x = (\\pi, t)` in Clarabel's standard form (Goulart &
    Chen 2024, arXiv:2405.12762): :math:`A x + s = b`, :math:`s \\in K`, with :math:`K` a product of
    zero cones (equalities), second-order cones (:math:`t \\ge \\lVert\\cdot\\rVert`, the slab) and
    one 4x4 PSD cone per body (:math:`J_k(\\pi) - \\varepsilon_k\\mathbf 1`: upper triangle by
    columns, off-diagonal entries times :math:`\\sqrt 2`, ``PSDTriangleConeT``; the pseudo-inertia
    is linear in the body's ten parameters, its coefficients :func:`pseudo_inertia` of the unit
    vectors), as :func:`dynid.estimation.identifiability.is_feasible` builds it (no cvxpy import)."""

    _UNIT = np.array([pseudo_inertia(e) for e in np.eye(10)])  # (10, 4, 4): J = sum_l unit[l] pi_l
    _TRI = [(i, j) for j in range(4) for i in range(j + 1)]

    def __init__(self, p: int) -> None:
        self.clarabel = require("clarabel", "sdp")
        self.p, self.rows, self.rhs, self.cones = p, [], [], []

    def _add(self, M: FloatArray, b: FloatArray, cone) -> None:
        self.rows.append(M)
        self.rhs.append(b)
        self.cones.append(cone)

    def equal(self, E: FloatArray, e: FloatArray) -> None:
        """:math:`E\\pi = e`."""
        self._add(np.c_[E, np.zeros(E.shape[0])], np.asarray(e, dtype=float), self.clarabel.ZeroConeT(E.shape[0]))

    def norm_bound(self, M: FloatArray, m: FloatArray, bound: float | None) -> None:
        """:math:`\\lVert M\\pi - m\\rVert \\le t` (``bound`` None) or :math:`\\le` ``bound``."""
        head = np.zeros((1, self.p + 1))
        if bound is None:
            head[0, -1] = -1.0  # s_0 = t
        body = np.c_[-M, np.zeros(M.shape[0])]  # s = M pi - m
        self._add(np.vstack([head, body]), np.concatenate([[0.0 if bound is None else bound], -m]),
                  self.clarabel.SecondOrderConeT(M.shape[0] + 1))

    def psd(self, blk: FloatArray, eps: float) -> None:
        """:math:`J(\\pi_{blk}) \\succeq \\varepsilon\\mathbf 1`."""
        M = np.zeros((len(self._TRI), self.p + 1))
        b = np.zeros(len(self._TRI))
        for r, (i, j) in enumerate(self._TRI):
            w = 1.0 if i == j else np.sqrt(2.0)
            M[r, np.asarray(blk)] = -w * self._UNIT[:, i, j]
            if i == j:
                b[r] = -eps
        self._add(M, b, self.clarabel.PSDTriangleConeT(4))

    def solve(self, what: str, factor: float = 1.0) -> tuple[FloatArray | None, dict]:
        """:math:`\\pi` and the stage's record, at Clarabel's tolerances times ``factor``; a solve that
        stops short of them is retried with them x10 at a time up to
        :data:`~dynid.tolerances.RELAXED_LIMIT` (as :class:`~dynid.estimation.physical.PhysicalLS`);
        the status in cvxpy's words."""
        from scipy import sparse

        from dynid.estimation.feasibility import _CLARABEL_STATUS

        clarabel = self.clarabel
        q = np.zeros(self.p + 1)
        q[-1] = 1.0
        P = sparse.csc_matrix((self.p + 1, self.p + 1))
        A = sparse.csc_matrix(np.vstack(self.rows))
        b = np.concatenate(self.rhs)
        t0, asked = time.perf_counter(), factor
        while True:
            settings = clarabel.DefaultSettings()
            settings.verbose = False
            for name, value in clarabel_tolerances().items():
                setattr(settings, name, value * factor)
            sol = clarabel.DefaultSolver(P, q, A, b, self.cones, settings).solve()
            status = _CLARABEL_STATUS.get(str(sol.status), "solver_error")
            if str(sol.status) == "InsufficientProgress" and sol.x is not None and sol.z is not None:
                status = "optimal_inaccurate"  # its last iterate (dynid.tolerances.solver_options)
            if status in ("optimal", "optimal_inaccurate") and sol.x is not None:
                break
            if status in ("solver_error", "user_limit") and settings.tol_feas * 10.0 <= RELAXED_LIMIT * (1 + 1e-9):
                factor *= 10.0
                continue
            return None, {"status": status, "what": what, "tolerance_factor": factor,
                          "wall_time_s": time.perf_counter() - t0}
        if factor > asked and status == "optimal":
            status = "optimal_inaccurate"  # solved, at tolerances looser than asked for
        return (np.asarray(sol.x, dtype=float)[: self.p],
                {"status": status, "iterations": int(sol.iterations), "tolerance_factor": factor,
                 "wall_time_s": time.perf_counter() - t0})


def consistent_standard(beta: FloatArray, smap: StandardMap, prior: FloatArray, scale: FloatArray,
                        cov: FloatArray | None = None) -> ConsistentStandard:
    """The physically consistent standard vector closest to ``prior`` that gives the base
    parameters ``beta`` (module docstring: the rule and its steps).

    Parameters
    ----------
    beta : array (r,)
        The estimate's base parameters :math:`\\hat\\beta`.
    smap : StandardMap
        :math:`B`, the bodies' parameter blocks and the structural zeros.
    prior : array (p,)
        :math:`\\pi_0`.
    scale : array (p,)
        :math:`S`: positive magnitudes per parameter (:func:`~dynid.model.base_parameters.parameter_scales`).
    cov : array (r, r), optional
        The estimate's covariance (the mismatch metric); None or not positive definite: the
        base parameters' magnitudes.

    Returns
    -------
    ConsistentStandard

    Raises
    ------
    DynidError
        The solver fails, or its answer is not consistent even with the widened buffer.
    """
    B = np.asarray(smap.B, dtype=float)
    beta = np.asarray(beta, dtype=float)
    prior = np.asarray(prior, dtype=float)
    s = np.asarray(scale, dtype=float)
    r, p = B.shape
    if beta.shape != (r,) or prior.shape != (p,) or s.shape != (p,):
        raise InputError(f"consistent_standard: beta {beta.shape}, prior {prior.shape}, scale {s.shape} for a "
                         f"{r} x {p} base map")
    if not (np.all(np.isfinite(beta)) and np.all(np.isfinite(prior)) and np.all(np.isfinite(s) & (s > 0))):
        raise InputError("consistent_standard: base parameters, prior and scales must be finite (scales positive)")
    s_move = s.copy()
    s_move[smap.zero] = 0.0  # a structural zero does not move
    BS_pinv = np.linalg.pinv(B * s_move)

    def onto(pi: FloatArray) -> FloatArray:  # the smallest S^-1-norm move onto B pi = beta
        return pi + s_move * (BS_pinv @ (beta - B @ pi))

    pi1 = onto(prior)
    if _consistent(pi1, smap):
        return ConsistentStandard(pi1, True, 0.0, False, "", {})

    L, metric = None, "standard deviations of the estimate"
    if cov is not None:
        c = 0.5 * (np.asarray(cov, dtype=float) + np.asarray(cov, dtype=float).T)
        if c.shape == (r, r) and np.all(np.isfinite(c)):
            try:
                L = np.linalg.cholesky(c)
            except np.linalg.LinAlgError:
                L = None
    if L is None:
        L = np.diag(np.linalg.norm(B * s, axis=1))
        metric = "magnitudes of the base parameters (no covariance)"
    import scipy.linalg as sla

    A = sla.solve_triangular(L, B, lower=True)
    d = sla.solve_triangular(L, beta, lower=True)
    tau = scaled(_FEASIBILITY)
    body_scale = [float(np.abs(np.linalg.eigvalsh(pseudo_inertia(prior[blk]))).max()) for blk in smap.body_blocks]
    stages: dict = {}

    def problem(tau: float) -> _Conic:  # the consistent set, with the margin
        c = _Conic(p)
        if smap.zero.size:
            c.equal(np.eye(p)[smap.zero], np.zeros(smap.zero.size))
        for blk, sc in zip(smap.body_blocks, body_scale):
            c.psd(blk, max(MARGIN * sc, 2 * tau))
        return c

    notes: tuple[str, ...] = ()
    factor = 1.0
    for _attempt in range(4):
        # step 2: the smallest mismatch over consistent vectors
        miss = problem(tau)
        miss.norm_bound(A, d, None)
        pi2, stages["mismatch"] = miss.solve("the smallest base-parameter mismatch", factor)
        if pi2 is None and metric.startswith("standard deviations"):
            # an estimate known far better in some directions than others (nearly noise-free data)
            # makes the covariance metric too ill-conditioned for the solver: the magnitudes instead
            L = np.diag(np.linalg.norm(B * s, axis=1))
            metric = ("magnitudes of the base parameters (the covariance of the estimate is too ill-conditioned "
                      "for the solver)")
            A = sla.solve_triangular(L, B, lower=True)
            d = sla.solve_triangular(L, beta, lower=True)
            miss = problem(tau)
            miss.norm_bound(A, d, None)
            pi2, stages["mismatch"] = miss.solve("the smallest base-parameter mismatch", factor)
        if pi2 is None:
            raise DynidError(f"no physically consistent standard vector found: solver status "
                             f"{stages['mismatch']['status']!r} on the base-parameter mismatch")
        pi2[smap.zero] = 0.0  # equality-constrained: exactly, not to the solver's tolerance
        r_star = float(np.linalg.norm(A @ pi2 - d))
        delta = mismatch_slack(r_star, float(np.linalg.norm(d)), stages["mismatch"]["tolerance_factor"],
                               stages["mismatch"]["status"])
        # step 3: the closest to the prior with B pi = beta (a consistent vector gives it) or within the mismatch
        near = problem(tau)
        exact_set = r_star <= delta
        if exact_set:
            near.equal(B, beta)
        else:
            near.norm_bound(A, d, r_star + delta)
        near.norm_bound(np.diag(1.0 / s), prior / s, None)
        pi3, stages["prior"] = near.solve("the closest consistent vector to the prior", factor)
        stages["prior"]["constraint"] = "B pi = beta" if exact_set else "mismatch <= minimum + slack"
        notes = () if pi3 is not None else (
            f"the solver could not find the closest vector to the prior (status {stages['prior']['status']!r}): "
            "the consistent vector of the smallest mismatch is exported, which the prior did not choose",)
        if pi3 is None:
            pi3 = pi2
        pi3[smap.zero] = 0.0
        if _consistent(pi3, smap):
            break
        # the solver's answer is outside the consistent set: it stopped short (too tight tolerances stall an
        # interior-point method on ill-conditioned data) or its accuracy did not cover the buffer
        factor *= 10.0
        tau *= 10.0
    else:
        raise DynidError("no physically consistent standard vector found: the solver's answers violate the "
                         f"pseudo-inertia constraints at tolerances up to {factor / 10:g} x Clarabel's")
    # how far the second SDP may leave the slab (its primal residual): the bound on the exported mismatch is
    # mismatch_min + slack + slack_prior
    slack_prior = mismatch_slack(r_star, float(np.linalg.norm(d)), stages["prior"]["tolerance_factor"],
                                 stages["prior"]["status"])
    stages.update(buffer=2 * tau, margin_relative=MARGIN, mismatch_min=r_star, slack=delta, slack_prior=slack_prior)
    if r_star <= delta:
        polished = onto(pi3)
        if _consistent(polished, smap):
            return ConsistentStandard(polished, True, 0.0, True, metric, stages, notes)
    mismatch = float(np.linalg.norm(A @ pi3 - d))
    return ConsistentStandard(pi3, False, mismatch, True, metric, stages, notes)
