"""Payload identification: the 10 inertial parameters of a load (a tool, a part) rigidly attached to one body.

The payload model
-----------------
The payload's standard parameters :math:`\\phi = [m, mc_x, mc_y, mc_z, I_{xx}, I_{xy}, I_{yy}, I_{xz}, I_{yz},
I_{zz}]` are those of pinocchio's ``Inertia.toDynamicParameters`` in the frame of the body that carries it
(the mount body's joint frame; inertia about that frame's origin), the convention of every body of dynid
(DESIGN.md). A rigidly attached load adds to its body's parameters (mass, first moments and inertias about
one origin in one frame are additive), and the joint torques are linear in the body's parameters through the
body's 10 columns of the standard regressor (Atkeson, An & Hollerbach 1986; pinocchio
``computeJointTorqueRegressor``), so

.. math::

    \\tau_{loaded} = Y_{arm}(q,\\dot q,\\ddot q)\\,\\pi_{arm} + Y_{b}(q,\\dot q,\\ddot q)\\,\\phi,

with :math:`Y_b` the mount body's 10 columns: the *payload regressor* (:func:`payload_regressor`).

Given the arm (:func:`fit_given_arm`)
-------------------------------------
An earlier identification of the arm without the payload gives :math:`\\hat\\beta_a` (its base parameters,
friction included) with covariance :math:`\\Sigma_a`. On a log with the payload mounted the arm's predicted
torques are subtracted, :math:`r = y - W_a\\hat\\beta_a`, and :math:`\\phi` is estimated from
:math:`r = Y_b\\phi + W_a(\\beta_a - \\hat\\beta_a) + e`:

* identifiability on the log: the independent columns of :math:`Y_b` over the log's rows (pivoted QR of the
  stacked per-channel factors, the rule of :func:`dynid.model.base_parameters._base_from_r`), so the
  estimated vector is :math:`\\beta_p = B_p\\phi` (all 10 when the motion and the mount excite them; the
  others regrouped, each dependent direction reported); a known mass is subtracted first
  (:math:`r - m\\,Y_{b,m}`) and the other 9 follow the same rule;
* Gautier's WLS (per-channel weights :math:`1/\\sigma_j^2` from the OLS residuals, paper 001 Eqs. 14-16)
  with the payload's pseudo-inertia :math:`J(\\phi) \\succeq 0` (Wensing, Kim & Slotine 2017) through
  :class:`dynid.estimation.physical.PhysicalLS` (a known mass an equality);
* covariance: :math:`\\hat\\beta_a` comes from another log, so it is independent of this log's noise and

  .. math::

      \\mathrm{Cov}(\\hat\\beta_p) = s^2 (X^T\\Omega X)^{-1} + M\\Sigma_a M^T,
      \\qquad M = (X^T\\Omega X)^{-1} X^T\\Omega W_a,

  with :math:`X` the payload's identifiable columns and :math:`\\Omega` the WLS weights: the first term is
  this log's noise, the second the arm estimate's error carried through its regressor (first order; exact
  for a linear arm model). Both are computed from the compressed factors of :math:`[X, W_a, r]`; nothing
  else (a model error of the arm beyond its covariance, friction that changes with the load) is in them.

Jointly with the arm (:func:`joint_problem`, :func:`fit_joint`)
----------------------------------------------------------------
Experiments with and without the payload identify the arm and the payload together: each experiment's
factors hold the arm's base columns (shared) and the 10 payload columns (zero where the payload is not
mounted), the experiments' factors are stacked per (experiment, channel) as :mod:`dynid.pipeline.experiments`
stacks them, and WLS (or the physically consistent WLS over every body and the payload) runs on them.
``dynid identify`` reaches it through ``[[data]] payload = true`` and a ``[payload]`` table
(:mod:`dynid.pipeline.joint_payload`: the configured OLS or WLS, the pseudo-inertia constraint on the
payload block only; docs/guide/payloads.md).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import InputError, ModelError
from dynid.estimation.linear import gautier_noise_std
from dynid.estimation.problem import RegressionProblem, _qr_r
from dynid.estimation.results import IdentificationResult
from dynid.model.base_parameters import BaseParameters, StandardMap, _base_from_r, body_violation, pseudo_inertia

__all__ = ["PAYLOAD_NAMES", "PAYLOAD_FIELDS", "PayloadFit", "payload_regressor", "fit_given_arm", "joint_problem",
           "fit_joint", "describe_payload", "derived_covariance"]

PAYLOAD_FIELDS = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
PAYLOAD_NAMES = tuple(f"{f}_payload" for f in PAYLOAD_FIELDS)
"""Names of the payload's 10 standard parameters (pinocchio's order; body name ``"payload"`` for
:attr:`~dynid.model.base_parameters.StandardMap.body_names` and the physical constraints)."""

RANK_TOL = 1e-8
"""Relative level (unit-norm columns, pivoted QR) below which a payload direction counts as not excited by the
log: the base-parameter rule of :func:`dynid.model.base_parameters.robot_base_parameters`."""


def payload_regressor(robot, joint: int, q: FloatArray, dq: FloatArray, ddq: FloatArray) -> FloatArray:
    """The payload regressor of a serial robot: the 10 standard-regressor columns of the body of pinocchio joint
    ``joint`` (1-based), shape (n, n_v, 10); ``Y @ phi`` is the joint torques the payload ``phi`` adds."""
    from dynid.model.serial_dynamics import regressor

    if not 1 <= int(joint) <= len(robot.body_blocks()):
        raise ModelError(f"joint index {joint} is not a body of {robot.name!r} (1..{len(robot.body_blocks())})")
    return regressor(robot, q, dq, ddq)[..., robot.body_blocks()[int(joint) - 1]]


# ------------------------------------------------------------------------------------ factor algebra
def _transform(problem: RegressionProblem, names: Sequence[str], T: FloatArray, offset: FloatArray) -> RegressionProblem:
    """The problem of the columns ``A T`` and output ``y - A offset`` (A the problem's columns): per channel the
    R factor of ``[F_A T, F_y - F_A offset]`` (F the augmented factor: same Gram matrix, so same least squares)."""
    p = problem.n_params
    f = problem.factors
    out = []
    for j in range(problem.n_channels):
        A, y = f[j][:, :p], f[j][:, p]
        out.append(_qr_r(np.column_stack([A @ T, y - A @ offset]), T.shape[1] + 1)[: T.shape[1] + 1])
    return RegressionProblem(tuple(names), problem.channel_names, np.array(out), problem.n_obs, meta=dict(problem.meta))


def _stacked_r(problem: RegressionProblem) -> FloatArray:
    return np.vstack([problem.R[j] for j in range(problem.n_channels)])


# ------------------------------------------------------------------------------------ given the arm
@dataclasses.dataclass(frozen=True, eq=False)
class PayloadFit:
    """A payload estimate.

    Attributes
    ----------
    result : IdentificationResult
        The estimate of the identifiable payload parameters ``beta_p = B phi`` (names: the independent payload
        parameters); its covariance includes the arm's (``cov_noise + cov_arm``) where the arm gave one.
    standard : array (10,)
        A physically consistent payload ``phi`` giving the estimate (all 10 when they are all identifiable).
    base : BaseParameters
        The payload's identifiable directions on the log (``standard_names`` = :data:`PAYLOAD_NAMES`).
    mass_known : float or None
    cov_noise, cov_arm : array (r, r) or None
        The two terms of the covariance (module docstring); ``cov_arm`` None without an arm covariance.
    identified : tuple of str
        The standard parameters that have an interval of their own: independent with no regrouping, and the
        known mass.
    unidentifiable : list of str
        The regroupings of the directions the log does not excite, e.g. ``"Iyy_payload := ... "``.
    """

    result: IdentificationResult
    standard: FloatArray
    base: BaseParameters
    mass_known: float | None
    cov_noise: FloatArray | None
    cov_arm: FloatArray | None
    identified: tuple[str, ...]
    unidentifiable: tuple[str, ...]

    def std_of(self) -> dict[str, float]:
        """Standard deviation of each parameter in :attr:`identified` (0 for a known mass) [SI]."""
        out = {}
        bse = None if self.result.cov_params is None else self.result.bse
        for name in self.identified:
            if name == PAYLOAD_NAMES[0] and self.mass_known is not None:
                out[name] = 0.0
            elif bse is not None:
                out[name] = float(bse[list(self.result.names).index(name)])
        return out

    def standard_covariance(self) -> FloatArray | None:
        """Covariance of the 10 standard parameters when all are identified (zeros in the mass row and column
        when it is known); None otherwise or without a covariance."""
        cov = self.result.cov_params
        if cov is None or len(self.identified) != 10:
            return None
        idx = [PAYLOAD_NAMES.index(n) for n in self.result.names]
        out = np.zeros((10, 10))
        out[np.ix_(idx, idx)] = cov
        return out


def _payload_map(base: BaseParameters) -> StandardMap:
    return StandardMap(standard_names=PAYLOAD_NAMES, B=base.B, body_blocks=(np.arange(10),),
                       nonnegative=np.zeros(0, dtype=int), reference=None)


def fit_given_arm(problem: RegressionProblem, arm_names: Sequence[str], arm_cov: FloatArray | None, *,
                  mass: float | None = None, physical: bool = True, solver: str = "CLARABEL",
                  rank_tol: float = RANK_TOL) -> PayloadFit:
    """The payload from a log with it mounted, the arm known (module docstring).

    Parameters
    ----------
    problem : RegressionProblem
        Compressed rows of the loaded log, columns :data:`PAYLOAD_NAMES` followed by ``arm_names`` (the arm's
        base regressor), output the measured efforts *minus the arm's prediction* :math:`y - W_a\\hat\\beta_a`.
    arm_names : sequence of str
        The arm's base parameter names (the problem's last columns).
    arm_cov : array (r_a, r_a) or None
        Covariance of the arm's estimate (None: the intervals hold this log's noise alone).
    mass : float, optional
        A known payload mass [kg] (the other 9 parameters are estimated).
    physical : bool
        Pseudo-inertia :math:`\\succeq 0` (cvxpy); False: plain WLS.
    """
    names = tuple(problem.names)
    if names[:10] != PAYLOAD_NAMES or names[10:] != tuple(arm_names):
        raise InputError(f"the problem's columns must be {PAYLOAD_NAMES} then the arm's {len(arm_names)} base parameters")
    n_arm = len(arm_names)
    if arm_cov is not None:
        arm_cov = np.asarray(arm_cov, dtype=float)
        if arm_cov.shape != (n_arm, n_arm):
            raise InputError(f"the arm covariance has shape {arm_cov.shape}, expected {(n_arm, n_arm)}")
    if mass is not None and not (np.isfinite(mass) and mass > 0):
        raise InputError(f"a known payload mass must be a positive number of kg, got {mass!r}")
    # free payload columns (the mass taken out when known), then the arm's: y - m Y_m
    free = list(range(1, 10)) if mass is not None else list(range(10))
    p = problem.n_params
    T = np.zeros((p, len(free) + n_arm))
    T[free, np.arange(len(free))] = 1.0
    T[10 + np.arange(n_arm), len(free) + np.arange(n_arm)] = 1.0
    off = np.zeros(p)
    if mass is not None:
        off[0] = mass
    free_names = [PAYLOAD_NAMES[i] for i in free]
    full = _transform(problem, free_names + list(arm_names), T, off)
    own = full.select(free_names)
    sub = _base_from_r(_stacked_r(own), free_names, rank_tol, int(np.sum(problem.n_obs)), 0)
    # the base over the 10 standard names: dependent regroupings in the free columns, a known mass in none
    indep = np.array([PAYLOAD_NAMES.index(free_names[i]) for i in sub.independent], dtype=int)
    dep = np.setdiff1d(np.arange(10), indep)
    K = np.zeros((len(indep), len(dep)))
    for c, i in enumerate(sub.dependent):
        K[:, list(dep).index(PAYLOAD_NAMES.index(free_names[i]))] = sub.K[:, c]
    base = BaseParameters(PAYLOAD_NAMES, indep, dep, K, rank_tol, sub.n_samples, 0)
    x_names = list(base.names)
    xp = full.select(x_names + list(arm_names))
    xonly = full.select(x_names)
    xonly = dataclasses.replace(xonly, expressions=base.expressions(),
                                standard=_payload_map(base) if physical else None)
    if physical:
        from dynid.estimation.physical import BodyBounds, PhysicalConstraints, PhysicalLS

        bounds = {"payload": BodyBounds(mass=(mass, mass))} if mass is not None else {}
        est = PhysicalLS(weighting="wls", constraints=PhysicalConstraints(bodies=bounds, sign=False), solver=solver)
        res = est.fit(xonly)
        standard = np.array([res.solver["standard_params"][n] for n in PAYLOAD_NAMES])
        if base.n_base == len(free):  # every parameter identified: PhysicalLS's note on unidentifiable ones is moot
            res = dataclasses.replace(res, notes=tuple(n for n in res.notes if not n.startswith("standard parameters:")))
    else:
        from dynid.estimation.linear import WLS

        res = WLS().fit(xonly)
        standard = base.to_standard(res.params)
        if mass is not None:
            standard[0] = mass
    # the arm's share of the covariance: M = (X^T W X)^-1 X^T W W_a with the fit's weights 1/sigma_j^2
    sigma = gautier_noise_std(xonly)
    nx = len(x_names)
    gxx, gxa = np.zeros((nx, nx)), np.zeros((nx, n_arm))
    for j in range(xp.n_channels):
        F = xp.factors[j]
        w = 1.0 / sigma[j] ** 2
        gxx += w * F[:, :nx].T @ F[:, :nx]
        gxa += w * F[:, :nx].T @ F[:, nx:nx + n_arm]
    cov_noise = None if res.cov_params is None else np.asarray(res.cov_params)
    cov_arm = None
    if arm_cov is not None:
        M = np.linalg.solve(gxx, gxa)
        cov_arm = M @ arm_cov @ M.T
    if cov_noise is not None:
        total = cov_noise + (0.0 if cov_arm is None else cov_arm)
        note = ("payload covariance: this log's noise (WLS) + the arm estimate's covariance carried through its "
                "regressor, M Sigma_arm M^T" if cov_arm is not None else
                "payload covariance: this log's noise only (the arm result has no covariance)")
        res = dataclasses.replace(res, cov_params=total).with_notes(note)
    identified = tuple(n for r, n in enumerate(base.names) if not np.any(base.K[r] != 0.0))
    if mass is not None:
        identified = (PAYLOAD_NAMES[0],) + identified
    unid = []
    for c, i in enumerate(base.dependent):
        if mass is not None and i == 0:
            continue
        into = [e for r, e in enumerate(base.expressions()) if base.K[r, c] != 0.0]
        unid.append(f"{PAYLOAD_NAMES[i]}: " + ("no effect on the joint torques of this log" if not into else
                                               "appears only within " + "; ".join(into)))
    unid = tuple(unid)
    return PayloadFit(res, standard, base, mass, cov_noise, cov_arm, identified, unid)


# ------------------------------------------------------------------------------------ jointly with the arm
def joint_problem(problems: Sequence[RegressionProblem], mounted: Sequence[bool],
                  arm_standard: StandardMap | None = None) -> RegressionProblem:
    """The stacked factors of experiments with and without the payload (module docstring).

    ``problems[i]``: experiment i compressed with columns (the arm's base parameters, then
    :data:`PAYLOAD_NAMES`: the mount body's 10 standard-regressor columns, computed whether or not the payload
    is mounted; no standard map), output the measured efforts. ``arm_standard``: the arm's map to its standard
    parameters (:meth:`~dynid.model.system.System.standard_map`), extended by the payload block for the
    physically consistent fit. ``mounted[i]``: whether experiment i carries the payload; where it
    does not, the payload columns are zeroed (their factor re-triangularized: :math:`F Z` has the Gram matrix of
    :math:`A Z`). Channels are named ``"<i>:<channel>"`` as :func:`dynid.pipeline.experiments.stack` names them;
    the payload's own columns are its parameters (identity map)."""
    if len(problems) != len(mounted) or not problems:
        raise InputError(f"{len(problems)} experiments but {len(mounted)} payload flags")
    first = problems[0]
    if tuple(first.names[-10:]) != PAYLOAD_NAMES:
        raise InputError("each experiment's last 10 columns must be the payload's (PAYLOAD_NAMES)")
    if not any(mounted):
        raise InputError("no experiment carries the payload: nothing identifies it")
    if all(mounted):
        raise InputError("every experiment carries the payload: the arm and the payload cannot be told apart "
                         "(their mount body's columns coincide); add an experiment without it")
    p = first.n_params
    factors, n_obs, channels = [], [], []
    for i, (pr, on) in enumerate(zip(problems, mounted)):
        if pr.names != first.names or pr.channel_names != first.channel_names:
            raise InputError(f"experiment {i}: its columns or channels differ from experiment 0's")
        f = pr.factors
        if not on:
            f = f.copy()
            f[:, :, p - 10:p] = 0.0
            f = np.array([_qr_r(f[j], p + 1)[: p + 1] for j in range(pr.n_channels)])
        factors.append(f)
        n_obs.append(pr.n_obs)
        channels += [f"{i}:{c}" for c in pr.channel_names]
    standard = None
    if arm_standard is not None:
        sm = arm_standard
        if sm.B.shape[0] != p - 10:
            raise InputError(f"the arm's standard map has {sm.B.shape[0]} base parameters, the experiments {p - 10}")
        n_std, r = sm.B.shape[1], sm.B.shape[0]
        B = np.zeros((r + 10, n_std + 10))
        B[:r, :n_std] = sm.B
        B[r:, n_std:] = np.eye(10)
        ref = None if sm.reference is None else np.r_[sm.reference, np.zeros(10)]
        standard = StandardMap(standard_names=tuple(sm.standard_names) + PAYLOAD_NAMES, B=B,
                               body_blocks=tuple(sm.body_blocks) + (np.arange(n_std, n_std + 10),),
                               nonnegative=sm.nonnegative, reference=ref, nonpositive=sm.nonpositive, zero=sm.zero)
    return RegressionProblem(first.names, tuple(channels), np.concatenate(factors), np.concatenate(n_obs),
                             expressions=None, standard=standard, meta=dict(first.meta))


def fit_joint(stacked: RegressionProblem, *, physical: bool = False, mass: float | None = None,
              weighting: str = "wls", solver: str = "CLARABEL", rank_tol: float = RANK_TOL) -> IdentificationResult:
    """WLS (Gautier's weights per (experiment, channel); ``weighting = "ols"``: one weight) of
    :func:`joint_problem`'s stacked factors, or with ``physical`` the physically consistent fit: with the arm's
    standard map in the stack every body of the arm and the payload (pseudo-inertia :math:`\\succeq 0`), without
    it the payload block only (the arm's base parameters free); ``mass``: a known payload mass, an equality
    (``physical`` only). Refuses a stack in which the payload is not identifiable from the arm (the rank of the
    stacked columns is checked first, naming the directions that are not)."""
    R = _stacked_r(stacked)
    base = _base_from_r(R, stacked.names, rank_tol, int(np.sum(stacked.n_obs)), 0)
    if base.n_base < stacked.n_params:
        lost = [stacked.names[i] for i in base.dependent]
        raise InputError(f"the experiments do not identify {', '.join(lost)} (the stacked columns have rank "
                         f"{base.n_base} of {stacked.n_params}): excite the arm without the payload and with it")
    if mass is not None and not physical:
        raise InputError("a known payload mass is an equality of the physically consistent fit (physical=True)")
    if mass is not None and stacked.standard is None:
        return _fit_joint_known_mass(stacked, mass, weighting, solver)
    if physical:
        from dynid.estimation.physical import BodyBounds, PhysicalConstraints, PhysicalLS

        own = stacked.standard is None
        if own:  # the payload block only: the arm's base parameters are their own "standard"
            p = stacked.n_params
            sm = StandardMap(standard_names=tuple(stacked.names), B=np.eye(p),
                             body_blocks=(np.arange(p - 10, p),), nonnegative=np.zeros(0, dtype=int), reference=None)
            stacked = dataclasses.replace(stacked, standard=sm)
        bounds = {"payload": BodyBounds(mass=(mass, mass))} if mass is not None else {}
        kw = {"constraints": PhysicalConstraints(bodies=bounds, sign=False)} if (own or bounds) else {}
        return PhysicalLS(weighting=weighting, solver=solver, **kw).fit(stacked)
    from dynid.estimation.linear import OLS, WLS

    return (OLS() if weighting == "ols" else WLS()).fit(stacked)


def _fit_joint_known_mass(stacked: RegressionProblem, mass: float, weighting: str, solver: str) -> IdentificationResult:
    """The joint fit with the payload's mass known: its column moved to the output (``y - m Y_m``), the other
    columns fitted by the physically consistent WLS whose payload body is ``[m, the 9 estimated]`` (the mass an
    equality of the pseudo-inertia constraint, not an active bound), so that an unconstrained optimum that is
    consistent keeps its covariance; the result has the problem's columns, the mass's row and column zero."""
    from dynid.estimation.physical import BodyBounds, PhysicalConstraints, PhysicalLS

    p = stacked.n_params
    keep = [k for k in range(p) if k != p - 10]
    T = np.zeros((p, p - 1))
    T[keep, np.arange(p - 1)] = 1.0
    off = np.zeros(p)
    off[p - 10] = mass
    names = [stacked.names[k] for k in keep]
    sub = _transform(stacked, names, T, off)
    B = np.zeros((p - 1, p))
    B[np.arange(p - 1), keep] = 1.0
    sm = StandardMap(standard_names=tuple(stacked.names), B=B, body_blocks=(np.arange(p - 10, p),),
                     nonnegative=np.zeros(0, dtype=int), reference=None)
    sub = dataclasses.replace(sub, standard=sm)
    res = PhysicalLS(weighting=weighting, solver=solver, constraints=PhysicalConstraints(
        bodies={"payload": BodyBounds(mass=(mass, mass))}, sign=False)).fit(sub)
    params = np.insert(np.asarray(res.params, float), p - 10, mass)
    cov = None
    if res.cov_params is not None:
        cov = np.zeros((p, p))
        cov[np.ix_(keep, keep)] = res.cov_params
    return dataclasses.replace(res, names=tuple(stacked.names), params=params, cov_params=cov).with_notes(
        f"known payload mass {mass:g} kg: its column moved to the output, the other parameters estimated")


# ------------------------------------------------------------------------------------ physical description
def describe_payload(phi: FloatArray) -> dict[str, Any]:
    """Mass [kg], centre of mass [m] and inertia about it [kg m^2] (3x3, mount-frame axes), principal moments
    and axes, and the consistency check (pseudo-inertia's smallest eigenvalue; the violation, '' when
    consistent) of a payload's 10 parameters."""
    phi = np.asarray(phi, dtype=float)
    m, h = float(phi[0]), phi[1:4]
    ixx, ixy, iyy, ixz, iyz, izz = phi[4:10]
    I_o = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    c = h / m if m > 0 else np.full(3, np.nan)
    I_c = I_o - m * (float(c @ c) * np.eye(3) - np.outer(c, c)) if m > 0 else np.full((3, 3), np.nan)
    lam, axes = (np.linalg.eigh(I_c) if m > 0 else (np.full(3, np.nan), np.full((3, 3), np.nan)))
    return {"mass": m, "com": c, "inertia_com": I_c, "principal_moments": lam, "principal_axes": axes,
            "min_pseudo_inertia_eigenvalue": float(np.linalg.eigvalsh(pseudo_inertia(phi))[0]),
            "violation": body_violation(phi)}


def derived_covariance(phi: FloatArray, cov: FloatArray) -> dict[str, FloatArray]:
    """First-order (delta-method) covariances of the centre of mass (3x3) and of the inertia about it (6x6,
    order xx, xy, yy, xz, yz, zz) from the 10 parameters' covariance: central differences of
    :func:`describe_payload`, steps 1e-6 of each parameter's scale."""
    phi = np.asarray(phi, dtype=float)

    def f(v):
        d = describe_payload(v)
        Ic = d["inertia_com"]
        return np.r_[d["com"], Ic[0, 0], Ic[0, 1], Ic[1, 1], Ic[0, 2], Ic[1, 2], Ic[2, 2]]

    J = np.zeros((9, 10))
    for k in range(10):
        h = 1e-6 * max(abs(phi[k]), float(np.sqrt(max(cov[k, k], 0.0))), 1e-9)
        e = np.zeros(10)
        e[k] = h
        J[:, k] = (f(phi + e) - f(phi - e)) / (2 * h)
    C = J @ cov @ J.T
    return {"com": C[:3, :3], "inertia_com": C[3:, 3:]}
