"""Physical feasibility of a base-parameter vector: is it the image :math:`B\\pi` of a physically
consistent standard vector :math:`\\pi`? (paper 000 §6.2 checks feasibility after the
identification, following Yoshida et al. 1996). A semidefinite feasibility program over the
standard parameters (pseudo-inertias positive semidefinite; Wensing, Kim & Slotine 2017) solved
by Clarabel, directly or through cvxpy; :func:`violating_parameters` names the base parameters
that carry a violation. Split from :mod:`dynid.estimation.identifiability`, which re-exports it."""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import DynidError, InputError, require
from dynid.estimation.physical import _pseudo_inertia_expr
from dynid.model.base_parameters import StandardMap, pseudo_inertia
from dynid.tolerances import RELAXED_LIMIT, clarabel_tolerances, solver_options

__all__ = ["Feasibility", "is_feasible", "violating_parameters"]


@dataclasses.dataclass(frozen=True, eq=False)
class Feasibility:
    """Outcome of :func:`is_feasible` (true in a boolean context when feasible).

    Attributes
    ----------
    feasible : bool
        A physically consistent standard vector maps to the base parameters.
    min_eigenvalues : tuple of float
        Smallest eigenvalue of each body's 4x4 pseudo-inertia at :attr:`standard_params`.
    violated : tuple of str
        Constraints violated at :attr:`standard_params` (empty when feasible), e.g.
        ``"body 2 pseudo-inertia (m2)"`` or ``"fv1 >= 0"``.
    violation : float
        Optimal total slack of the feasibility program (0 when feasible).
    standard_params : array, shape (n_std,)
        The standard vector found: feasible when possible, otherwise the one with the
        least total violation.
    status : str
        Solver status.
    """

    feasible: bool
    min_eigenvalues: tuple[float, ...]
    violated: tuple[str, ...]
    violation: float
    standard_params: FloatArray
    status: str

    def __bool__(self) -> bool:
        return self.feasible


def is_feasible(
    base_params: FloatArray,
    standard_map: StandardMap,
    *,
    tol: float = 1e-6,
    solver: str = "CLARABEL",
) -> Feasibility:
    """Physical feasibility of a base-parameter vector.

    Parameters
    ----------
    base_params : array, shape (p,)
        Base parameters :math:`\\beta` in the order of ``standard_map.B``'s rows (e.g.
        ``result.params`` of a fit on the full problem).
    standard_map : StandardMap
        :math:`\\beta = B\\pi`, the bodies' parameter blocks and the parameters that must be
        non-negative (``problem.standard``).
    tol : float
        Relative tolerance: a body is violated when the smallest eigenvalue of its
        pseudo-inertia is below ``-tol * S``, a non-negative parameter when it is below
        ``-tol * S``, with ``S`` the largest magnitude in the problem (of the base
        parameters, of the pseudo-inertia eigenvalues and of the non-negative parameters
        found; at least 1). The solver's accuracy is its tolerances (1e-8 by default) of that
        scale for an interior point, but on the boundary of the consistent set (an estimate with
        an active constraint) their product with the conditioning of the fibre
        :math:`B\\pi = \\beta` (4.4e-7 of the scale on the cobot6r twin): a violation found is
        therefore re-examined at tighter tolerances (below).
    solver : str
        ``"CLARABEL"`` (default): Clarabel called directly on the conic form below (no cvxpy:
        its import, ~1-2 s, was most of the check's time); ``"cvxpy:NAME"`` or any other name:
        that cvxpy solver, through cvxpy (``"cvxpy:CLARABEL"``: the same solver through cvxpy).

    Returns
    -------
    Feasibility

    Notes
    -----
    The semidefinite program (cvxpy, Clarabel by default)

    .. math::

        \\min_{\\pi, s \\ge 0} \\sum_k s_k + \\sum_i s_i \\quad \\text{s.t.} \\quad
        B\\pi = \\beta, \\quad J_k(\\pi) + s_k \\mathbf 1 \\succeq 0, \\quad
        \\pi_i + s_i \\ge 0 \\;\\; (i \\in \\{I_a, f_v, f_c\\}),

    with :math:`J_k` the pseudo-inertia of body :math:`k` (Wensing, Kim & Slotine 2017;
    the same LMIs as :class:`~dynid.estimation.physical.PhysicalLS`). It always has a
    solution; :math:`\\beta` is feasible iff the optimum is zero. The L1 objective makes
    the slack sparse, so for an infeasible :math:`\\beta` the violated items are a small
    set of bodies/parameters that explain the infeasibility (one such set; another
    may exist). Paper 000 §6.2 checks feasibility after the identification, together
    with the relative standard deviations.
    """
    smap = standard_map
    beta = np.asarray(base_params, dtype=float)
    if beta.shape != (smap.B.shape[0],):
        raise InputError(f"base_params has shape {beta.shape}, the standard map has {smap.B.shape[0]} base parameters")
    if not np.all(np.isfinite(beta)):
        raise InputError("base_params contain NaN/inf")
    if not (np.isfinite(tol) and tol > 0):
        raise InputError(f"tol must be positive, got {tol!r}")
    scale = max(float(np.max(np.abs(beta))), 1.0) if beta.size else 1.0
    if solver == "CLARABEL":
        solve = lambda factor: _feasibility_clarabel(beta, smap, scale, factor)  # noqa: E731
    else:
        solve = _feasibility_cvxpy(beta, smap, scale, solver)
    # A base vector on the boundary of the consistent set (an LMI fit with an active constraint)
    # has a feasibility optimum of 0, which an interior-point solver approaches only to about its
    # tolerances times the conditioning of the fibre B pi = beta: on the cobot6r twin the slack
    # found was 4.9e-5, 6.4e-6 and 3.9e-7 at tol_feas 1e-7, 1e-8 and 1e-9 (about linear), where a
    # real violation stays put. So a verdict "violated" is re-examined at tolerances /10 while the
    # violation keeps shrinking by more than 3x (at most twice, down to tol_feas 1e-11); the last
    # solution decides.
    found = _feasibility_of(*solve(1.0), smap, scale, tol)
    factor = 1.0
    while not found.feasible and factor > 1e-2 and clarabel_tolerances()["tol_feas"] * factor > 1e-11 * (1 + 1e-9):
        factor /= 10.0
        try:
            again = _feasibility_of(*solve(factor), smap, scale, tol)
        except DynidError:  # the tighter solve failed numerically: the verdict stands
            break
        shrank = again.violation < found.violation / 3.0
        found = again if shrank or again.feasible else found
        if not shrank:
            break
    return found


def _feasibility_cvxpy(beta: FloatArray, smap: StandardMap, scale: float, solver: str):
    """The program of :func:`is_feasible` through cvxpy with ``solver``: a function of the
    tolerance factor (:func:`dynid.tolerances.solver_options`) returning what
    :func:`_feasibility_clarabel` returns."""
    n_std, n_b, nn = smap.B.shape[1], len(smap.body_blocks), smap.nonnegative
    cp = require("cvxpy", "sdp")
    solver = solver.removeprefix("cvxpy:")
    if solver not in cp.installed_solvers():
        raise DynidError(f"solver {solver} is not installed (installed: {', '.join(cp.installed_solvers())})")
    pi = cp.Variable(n_std)
    s_body = cp.Variable(n_b, nonneg=True) if n_b else None
    s_nn = cp.Variable(nn.size, nonneg=True) if nn.size else None
    constraints = [smap.B @ pi == beta] + ([pi[smap.zero] == 0] if smap.zero.size else [])
    objective = 0
    for k, blk in enumerate(smap.body_blocks):
        constraints.append(_pseudo_inertia_expr(cp, pi[blk]) + s_body[k] * np.eye(4) >> 0)
    if n_b:
        objective = objective + cp.sum(s_body)
    if nn.size:
        constraints.append(pi[nn] + s_nn >= 0)
        objective = objective + cp.sum(s_nn)
    prob = cp.Problem(cp.Minimize(objective / scale), constraints)

    def solve(factor: float) -> tuple[FloatArray, float, str]:
        try:
            with warnings.catch_warnings():  # "Solution may be inaccurate": reported as the status instead
                warnings.simplefilter("ignore", UserWarning)
                prob.solve(solver=solver, **solver_options(solver, factor))
        except cp.error.SolverError as exc:
            raise DynidError(f"{solver} failed on the feasibility problem ({exc})") from None
        if prob.status not in ("optimal", "optimal_inaccurate") or pi.value is None:
            raise DynidError(f"feasibility check failed: solver status {prob.status!r}")
        return np.asarray(pi.value, dtype=float), float(prob.value), str(prob.status)

    return solve


# Clarabel's statuses in cvxpy's words (cvxpy's CLARABEL interface), so that both paths report alike
_CLARABEL_STATUS = {"Solved": "optimal", "AlmostSolved": "optimal_inaccurate", "PrimalInfeasible": "infeasible",
                    "DualInfeasible": "unbounded", "AlmostPrimalInfeasible": "infeasible_inaccurate",
                    "AlmostDualInfeasible": "unbounded_inaccurate", "MaxIterations": "user_limit",
                    "MaxTime": "user_limit"}


def _feasibility_clarabel(beta: FloatArray, smap: StandardMap, scale: float,
                          factor: float = 1.0) -> tuple[FloatArray, float, str]:
    """The semidefinite program of :func:`is_feasible` in Clarabel's standard form (Goulart & Chen
    2024, arXiv:2405.12762) :math:`\\min q^T x` s.t. :math:`A x + s = b`, :math:`s \\in K`, with
    :math:`x = (\\pi, s_{body}, s_{nn})` and :math:`K` = zero cone (:math:`B\\pi = \\beta`, the
    structural zeros) x non-negative orthant (the slacks, :math:`\\pi_i + s_i`) x one 4x4 PSD cone
    per body (:math:`J_k(\\pi) + s_k\\mathbf 1`: upper triangle by columns, off-diagonal entries
    times :math:`\\sqrt 2`, Clarabel's ``PSDTriangleConeT``). The pseudo-inertia is linear in the
    body's ten parameters, so its coefficients are :func:`pseudo_inertia` of the unit vectors.
    Returns :math:`\\hat\\pi`, the objective :math:`\\sum s / S` and the status in cvxpy's words;
    ``factor`` multiplies the tolerances of :func:`dynid.tolerances.clarabel_tolerances`."""
    clarabel = require("clarabel", "sdp")
    from scipy import sparse

    n_std, n_b, nn, zero = smap.B.shape[1], len(smap.body_blocks), smap.nonnegative, smap.zero
    n_x = n_std + n_b + nn.size
    rows: list[FloatArray] = []
    rhs: list[FloatArray] = []
    eq = np.zeros((smap.B.shape[0] + zero.size, n_x))
    eq[: smap.B.shape[0], :n_std] = smap.B
    eq[smap.B.shape[0] + np.arange(zero.size), zero] = 1.0
    rows.append(eq)
    rhs.append(np.concatenate([beta, np.zeros(zero.size)]))
    # the slacks and pi[nn] + s_nn in the orthant: rows -x, b = 0 (its cone element s = b - A x is x)
    nonneg = np.zeros((n_b + 2 * nn.size, n_x))
    nonneg[np.arange(n_b + nn.size), n_std + np.arange(n_b + nn.size)] = -1.0
    nonneg[n_b + nn.size + np.arange(nn.size), nn] = -1.0
    nonneg[n_b + nn.size + np.arange(nn.size), n_std + n_b + np.arange(nn.size)] = -1.0
    rows.append(nonneg)
    rhs.append(np.zeros(nonneg.shape[0]))
    unit = np.array([pseudo_inertia(e) for e in np.eye(10)])  # (10, 4, 4): J = sum_l unit[l] pi_l
    tri = [(i, j) for j in range(4) for i in range(j + 1)]
    for k, blk in enumerate(smap.body_blocks):
        psd = np.zeros((len(tri), n_x))
        for r, (i, j) in enumerate(tri):
            w = 1.0 if i == j else np.sqrt(2.0)
            psd[r, np.asarray(blk)] = -w * unit[:, i, j]
            if i == j:
                psd[r, n_std + k] = -1.0
        rows.append(psd)
        rhs.append(np.zeros(len(tri)))
    cones = [clarabel.ZeroConeT(eq.shape[0]), clarabel.NonnegativeConeT(nonneg.shape[0])]
    cones += [clarabel.PSDTriangleConeT(4) for _ in range(n_b)]
    if not nonneg.shape[0]:
        cones.pop(1)
    q = np.concatenate([np.zeros(n_std), np.full(n_b + nn.size, 1.0 / scale)])
    A = sparse.csc_matrix(np.vstack(rows))
    P = sparse.csc_matrix((n_x, n_x))
    # A solve that stops short of its tolerances (MaxIterations, NumericalError, InsufficientProgress
    # without an iterate: ill-conditioned data, sooner with tightened tolerances) is retried with them
    # x10 at a time up to RELAXED_LIMIT, as PhysicalLS._solve; the status is then optimal_inaccurate.
    asked = factor
    while True:
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        for name, value in clarabel_tolerances().items():
            setattr(settings, name, value * factor)
        sol = clarabel.DefaultSolver(P, q, A, np.concatenate(rhs), cones, settings).solve()
        status = _CLARABEL_STATUS.get(str(sol.status), "solver_error")
        if str(sol.status) == "InsufficientProgress" and sol.x is not None and sol.z is not None:
            status = "optimal_inaccurate"  # its last iterate, as cvxpy's accept_unknown (dynid.tolerances.solver_options)
        if status in ("optimal", "optimal_inaccurate") and sol.x is not None:
            break
        if status in ("solver_error", "user_limit") and settings.tol_feas * 10.0 <= RELAXED_LIMIT * (1 + 1e-9):
            factor *= 10.0
            continue
        raise DynidError(f"feasibility check failed: solver status {status!r}")
    if factor > asked and status == "optimal":
        status = "optimal_inaccurate"  # solved, at tolerances looser than asked for
    x = np.asarray(sol.x, dtype=float)
    return x[:n_std], float(sol.obj_val), status


def _feasibility_of(pi_hat: FloatArray, value: float, status: str, smap: StandardMap, scale: float,
                    tol: float) -> Feasibility:
    """:class:`Feasibility` from the program's solution (see :func:`is_feasible`)."""
    nn = smap.nonnegative
    eigs = [np.linalg.eigvalsh(pseudo_inertia(pi_hat[blk])) for blk in smap.body_blocks]
    min_eigs = [float(ev[0]) for ev in eigs]
    # one absolute tolerance for the whole problem: relative to a single body, the
    # interior-point solver's last digits on a body it has set to ~0 look like violations
    ref = max([scale] + [float(np.max(np.abs(ev))) for ev in eigs]
              + ([float(np.max(np.abs(pi_hat[nn])))] if nn.size else []))
    violated = [f"body {k + 1} pseudo-inertia ({smap.standard_names[blk[0]]})"
                for k, blk in enumerate(smap.body_blocks) if min_eigs[k] < -tol * ref]
    violated += [f"{smap.standard_names[i]} >= 0" for i in nn if pi_hat[i] < -tol * ref]
    pi_hat.setflags(write=False)
    return Feasibility(
        feasible=not violated,
        min_eigenvalues=tuple(min_eigs),
        violated=tuple(violated),
        violation=value * scale,
        standard_params=pi_hat,
        status=status,
    )


def violating_parameters(names: Sequence[str], feasibility: Feasibility, base_names: Sequence[str],
                         standard_map: StandardMap) -> tuple[str, ...]:
    """The base parameters among ``names`` whose grouping (a row of ``standard_map.B``) involves a
    standard parameter of a constraint :func:`is_feasible` found violated (a body's pseudo-inertia,
    a non-negative joint term): those that make the set physically inconsistent (paper 000 §6.2
    marks them). Empty when feasible."""
    if feasibility.feasible:
        return ()
    smap = standard_map
    std: set[int] = set()
    for v in feasibility.violated:
        if v.startswith("body "):
            std.update(int(i) for i in smap.body_blocks[int(v.split()[1]) - 1])
        else:
            std.add(smap.standard_names.index(v.split(" >= ")[0]))
    touch = np.any(np.abs(smap.B[:, sorted(std)]) > 0, axis=1)
    idx = {n: i for i, n in enumerate(base_names)}
    return tuple(n for n in names if touch[idx[n]])


# ---------------------------------------------------------------------- model sequences
