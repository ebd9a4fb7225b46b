"""Stopping tolerances of dynid's numerical solvers, in one place.

A solver stops at its tolerance, not at the exact answer, and where it stops depends on the
machine (BLAS kernel, SIMD path, thread count). Every stopping tolerance of an optimization or
iterative solve in dynid is taken from here, so that a result's accuracy can be stated from it
and a test's margin derived from it (:func:`scale`, :func:`clarabel_tolerances`).

=============================================  ==============================================
solver (where)                                 tolerances at scale 1
=============================================  ==============================================
Clarabel, interior point (physically           Clarabel's defaults: gap (absolute and relative),
consistent estimation, the projection of       feasibility and infeasibility 1e-8, KKT ratio 1e-6;
IV/DIDIM onto the consistent set,              its reduced ("almost solved") tolerances 5e-5 /
:func:`~dynid.estimation.is_feasible`)         1e-4 / 5e-12 / 1e-4
scipy ``least_squares`` (TRF: friction         ``xtol = ftol = gtol`` = 1e-12; the Stribeck
curves, hierarchical friction fit, Stribeck    refinement's ``ftol`` 1e-6 (statistical) and
refinement)                                    ``xtol`` 1e-10 (their estimator fields)
SLSQP (excitation design)                      ``ftol`` 1e-6
Gauss-Newton position solve of the loop        1e-10 (infinity norm of the step and of the
closures from actuator coordinates             residual)
feasible GLS / IRLS fixed points               relative change 1e-10 / 1e-9
=============================================  ==============================================

``DYNID_SOLVER_TOL_SCALE`` (environment, a positive number, default 1) multiplies every one of
them. It exists to check that no result, and no test, depends on where a solver happens to
stop: ``make test-robust`` reruns the numerically sensitive tests with 0.01 (tightened 100x)
and 10 (loosened 10x), settings at which every solver above still does its job.

Not scaled, and why: the Newton projections of a mechanism's positions and velocities onto
the loop closures (1e-12, :meth:`~dynid.model.mechanism.Mechanism.project`) already stop at
the rounding level of the kinematics (1e-14 is not reachable on every sample), as does the
accuracy of pinocchio's proximal constrained dynamics in the closed-loop simulator (1e-14); the
statistical stopping rules of the estimators (IV/DIDIM's change in standard deviations,
paper 001; the hierarchical fit's 1e-3 change of the friction curves, paper 003 Algorithm 1)
are part of each method's definition, set in the config and reported with the result.
"""

from __future__ import annotations

import math
import os

from dynid.errors import ConfigError

__all__ = ["ENV", "RELAXED_LIMIT", "clarabel_tolerances", "scale", "scaled", "solver_options"]

ENV = "DYNID_SOLVER_TOL_SCALE"

# Clarabel's own defaults (clarabel 0.11 DefaultSettings), named as its settings are
_CLARABEL = {
    "tol_gap_abs": 1e-8,
    "tol_gap_rel": 1e-8,
    "tol_feas": 1e-8,
    "tol_infeas_abs": 1e-8,
    "tol_infeas_rel": 1e-8,
    "tol_ktratio": 1e-6,
    "reduced_tol_gap_abs": 5e-5,
    "reduced_tol_gap_rel": 5e-5,
    "reduced_tol_feas": 1e-4,
    "reduced_tol_infeas_abs": 5e-12,
    "reduced_tol_infeas_rel": 5e-5,
    "reduced_tol_ktratio": 1e-4,
}


def scale() -> float:
    """The factor ``DYNID_SOLVER_TOL_SCALE`` applies to every stopping tolerance (1 when unset).

    Read at each call, so a process can change it between solves. A value that is not a
    positive finite number, or that would put a tolerance of 1e-12 below the machine epsilon
    (scale < 1e-3), raises :class:`~dynid.errors.ConfigError`."""
    raw = os.environ.get(ENV, "").strip()
    if not raw:
        return 1.0
    try:
        value = float(raw)
    except ValueError:
        raise ConfigError(f"{ENV}={raw!r}: give a positive number (1 = the solvers' own tolerances)") from None
    if not (math.isfinite(value) and 1e-3 <= value <= 1e3):
        raise ConfigError(f"{ENV}={raw!r}: give a number in [0.001, 1000] (1 = the solvers' own tolerances); "
                          "below 0.001 a tolerance of 1e-12 would fall under the machine epsilon")
    return value


def scaled(tolerance: float) -> float:
    """``tolerance`` times :func:`scale`."""
    return float(tolerance) * scale()


def clarabel_tolerances() -> dict[str, float]:
    """Clarabel's stopping tolerances at the current :func:`scale` (keyword arguments of
    cvxpy's ``solve(solver="CLARABEL", ...)`` and attributes of ``clarabel.DefaultSettings``).

    What they guarantee (Goulart & Chen 2024, arXiv:2405.12762, the termination criteria): at
    "Solved" the duality gap is below ``tol_gap_abs`` or below ``tol_gap_rel`` relative to the
    objective, and the primal and dual residuals below ``tol_feas`` relative to the size of the
    problem data; at "AlmostSolved" (cvxpy: ``optimal_inaccurate``) the same with the
    ``reduced_`` tolerances. A test's margin on an optimum is therefore a multiple of these
    times the objective's scale and the problem's conditioning, never a fixed figure."""
    s = scale()
    return {k: v * s for k, v in _CLARABEL.items()}


def solver_options(solver: str, factor: float = 1.0) -> dict:
    """Keyword arguments of cvxpy's ``Problem.solve`` for ``solver``: for Clarabel its scaled
    tolerances (:func:`clarabel_tolerances`) and ``accept_unknown``: when Clarabel stops making
    progress before its tolerances (``InsufficientProgress``, which happens on ill-conditioned
    problems, sooner with tighter tolerances), its last iterate is returned with cvxpy's status
    ``optimal_inaccurate`` instead of an error; the callers check that iterate's constraints
    themselves and report the status. Another cvxpy solver keeps its own defaults (its settings
    have other names and meanings; dynid's default is Clarabel). ``factor`` multiplies Clarabel's
    tolerances once more (a solve retried after a numerical failure, :data:`RELAXED_LIMIT`)."""
    if solver.upper() != "CLARABEL":
        return {}
    return {**{k: v * factor for k, v in clarabel_tolerances().items()}, "accept_unknown": True}


RELAXED_LIMIT = 1e-6
"""The loosest feasibility tolerance to which a Clarabel solve that failed numerically (``NumericalError``:
its KKT system could not be solved to the requested accuracy, which happens on ill-conditioned data and
sooner with tighter tolerances) is retried, by factors of 10 (100 x Clarabel's own 1e-8); the stage
reports the factor and its status is ``optimal_inaccurate``."""
