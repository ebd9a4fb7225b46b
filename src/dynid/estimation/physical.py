"""Physically consistent least squares: LMI constraints on the standard parameters.

The estimate is the base-parameter vector :math:`\\beta = B\\pi` of a standard vector
:math:`\\pi` that is physically consistent, found by the semidefinite program

.. math::

    \\min_{\\pi} \\; \\| R_w B \\pi - c_w \\|_2 \\quad \\text{s.t.} \\quad
    J_k(\\pi) \\succeq 0 \\;\\; \\forall \\text{ bodies } k, \\qquad
    \\pi_i \\ge 0 \\;\\; i \\in \\{I_a, f_v, f_c\\},

where :math:`(R_w, c_w)` is the compressed, whitened least-squares problem (OLS, or
WLS with per-joint weights from OLS residuals, Gautier) and :math:`J_k` the 4x4
pseudo-inertia of body :math:`k` (Wensing, Kim & Slotine, IEEE RA-L 2017; the LMI
formulation of Sousa & Cortesão 2014 cited in paper 003 §3.2). The standard
parameters are free in the null space of :math:`B`; the returned standard vector is
one feasible solution (not yet the one closest to a reference).

Uncertainty: when no constraint is active the constrained and unconstrained optima
coincide and the least-squares covariance applies; when constraints are active the
estimate sits on the boundary of the feasible set and no covariance is reported (the
result says so and names the active constraints).

Solved with cvxpy and Clarabel on the ``p x p`` compressed factor (fast whatever the
number of samples).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dynid.errors import DynidError, InputError, require
from dynid.estimation.linear import _channel_noise_std, gautier_noise_std, whitened_solve
from dynid.estimation.problem import RegressionProblem
from dynid.estimation.results import IdentificationResult
from dynid.model.base_parameters import pseudo_inertia

__all__ = ["PhysicalLS"]


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


@dataclasses.dataclass(frozen=True, kw_only=True)
class PhysicalLS:
    """Least squares subject to physical consistency of every body (see module docstring).

    Parameters
    ----------
    weighting : {"wls", "ols"}
        Per-joint weights from OLS residuals (Gautier), or none.
    solver : str
        cvxpy solver name (Clarabel by default).
    active_tol : float
        A body's constraint is reported active when the smallest eigenvalue of its
        pseudo-inertia is below ``active_tol`` times its largest; a bound when a
        non-negative parameter is below ``active_tol`` times the largest of them.
    """

    weighting: str = "wls"
    solver: str = "CLARABEL"
    active_tol: float = 1e-6

    def fit(self, problem: RegressionProblem) -> IdentificationResult:
        if self.weighting not in ("wls", "ols"):
            raise InputError(f"weighting must be 'wls' or 'ols', got {self.weighting!r}")
        smap = problem.standard
        if smap is None:
            raise InputError("physically consistent estimation needs the problem's map to standard parameters")
        cp = require("cvxpy", "sdp")
        if self.solver not in cp.installed_solvers():
            raise DynidError(f"solver {self.solver} is not installed (installed: {', '.join(cp.installed_solvers())})")
        weights = 1.0 / gautier_noise_std(problem) ** 2 if self.weighting == "wls" else np.ones(problem.n_channels)
        uncon = whitened_solve(problem, weights)
        # the compressed whitened problem of the unconstrained fit: min || R beta - c ||
        p = problem.n_params
        r, c = uncon.R, uncon.c
        scale = np.linalg.norm(c) or 1.0
        pi = cp.Variable(smap.B.shape[1])
        constraints = [_pseudo_inertia_expr(cp, pi[blk]) >> 0 for blk in smap.body_blocks]
        if smap.nonnegative.size:
            constraints.append(pi[smap.nonnegative] >= 0)
        objective = cp.Minimize(cp.norm(r @ (smap.B @ pi) - c) / scale)
        prob = cp.Problem(objective, constraints)
        try:
            prob.solve(solver=self.solver)
        except cp.error.SolverError as exc:
            raise DynidError(f"{self.solver} failed on the physically consistent problem ({exc})") from None
        if prob.status not in ("optimal", "optimal_inaccurate") or pi.value is None:
            raise DynidError(f"physically consistent estimation failed: solver status {prob.status!r}")
        pi_hat = np.asarray(pi.value, dtype=float)
        beta = smap.B @ pi_hat
        rss = problem.rss_per_channel(beta)
        dof = problem.n_total - p
        # which constraints are active?
        min_eigs, active = [], []
        for k, blk in enumerate(smap.body_blocks):
            ev = np.linalg.eigvalsh(pseudo_inertia(pi_hat[blk]))
            min_eigs.append(float(ev[0]))
            if ev[0] <= self.active_tol * max(ev[-1], 1e-300):
                active.append(f"body {k + 1} pseudo-inertia")
        if smap.nonnegative.size:
            ref = max(float(np.max(np.abs(pi_hat[smap.nonnegative]))), 1e-12)
            active += [f"{smap.standard_names[i]} >= 0" for i in smap.nonnegative if pi_hat[i] <= self.active_tol * ref]
        notes = [
            f"physically consistent {'WLS' if self.weighting == 'wls' else 'OLS'}: every body's pseudo-inertia >= 0, "
            "rotor inertia and friction >= 0 (LMI, cvxpy/" + self.solver + ")"
        ]
        if active:
            cov = None
            notes.append(
                "active constraints: " + ", ".join(active)
                + "; the estimate lies on the boundary of the feasible set, so no covariance is reported"
            )
        else:
            cov = uncon.cov
            notes.append("no constraint is active: the least-squares covariance applies")
        if self.weighting == "wls":
            notes.append("weights 1/sigma_j^2 per channel; sigma_j from OLS residuals (Gautier)")
        s2 = float(np.sum(weights * rss) / dof)
        return IdentificationResult(
            method=f"{'WLS' if self.weighting == 'wls' else 'OLS'}+LMI",
            names=problem.names,
            params=beta,
            cov_params=cov,
            dof=dof,
            scale=s2,
            channel_names=problem.channel_names,
            n_obs=problem.n_obs,
            rss_per_channel=rss,
            noise_std=np.sqrt(1.0 / weights) if self.weighting == "wls" else _channel_noise_std(problem, rss),
            condition_number=uncon.cond,
            expressions=problem.expressions,
            solver={
                "algorithm": "SDP on the compressed whitened problem",
                "solver": self.solver,
                "status": prob.status,
                "iterations": prob.solver_stats.num_iters if prob.solver_stats else None,
                "solve_time_s": prob.solver_stats.solve_time if prob.solver_stats else None,
                "min_pseudo_inertia_eigenvalue": min_eigs,
                "active_constraints": active,
                "standard_params": dict(zip(smap.standard_names, pi_hat.tolist())),
                "unconstrained_params": uncon.beta.tolist(),
            },
            provenance=dict(problem.meta),
            notes=tuple(notes),
        )
