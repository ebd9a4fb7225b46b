"""``[identification] hierarchical = true``: hierarchical iterative identification (paper 003 §3.3,
Algorithm 1; dynid issue 19, item 2).

The joint torque splits into a rigid-body part linear in the friction-free base parameters and a
nonlinear friction curve per joint (paper 003, Eq. 37):
:math:`\\tau = \\Phi_{br}\\,\\xi_r + \\tau_f(\\dot q)`. The two are fitted in turn:

0. starting friction :math:`\\theta_{f,0}`: the coefficients of ``friction_model`` in a ``dynid
   friction`` result (``friction_prior = "friction.json"``, paper 003 Sec. 3.1, Algorithm 1 lines
   1-4), or, without one, the family fitted per joint to :math:`\\tau - \\Phi_{br}\\xi_r` with
   :math:`\\xi_r` the rigid-body part of a one-shot WLS that has linear Coulomb + viscous columns
   per joint (the usual dynid model);
1. rigid-body base parameters :math:`\\xi_r` by the configured estimator (OLS or WLS, + LMI with
   ``physical_consistency = true``: the existing machinery, :mod:`dynid.estimation.physical`) on
   :math:`\\tau - \\tau_f(\\dot q; \\theta_{f,k})` with the regressor *without* friction columns
   (Algorithm 1, lines 8-10; the robot's ``fc``/``fv`` extras are left out, the rotor inertia
   ``Ia`` and the offset stay: the offset is even in the velocity, the ``B`` of Eq. 13, which the
   constant-velocity extraction cancels);
2. training residual per joint, :math:`\\mathrm{RMSE}_j` of :math:`\\tau - \\Phi_{br}\\xi_r -
   \\tau_f` (line 12);
3. friction refit per joint on :math:`\\tau - \\Phi_{br}\\xi_r` (line 15):
   :func:`~dynid.estimation.friction_curves.fit_curve` with the paper's positivity bounds, on the
   rows folded to positive speed (:math:`v = |\\dot q|`, :math:`F = \\mathrm{sign}(\\dot q)\\,r`;
   every family is odd), warm-started from the previous coefficients;
4. stop (our reading of §3.3's criteria, whose text is garbled: it names the RMSE threshold
   :math:`\\varepsilon_{RMSE}` twice and Algorithm 1's ``while`` tests the RMSE itself, which no
   fit goes below on data noisier than 0.05 N·m) when **both** hold, as the prose says
   ("continue until both convergence criteria are satisfied"):

   * RMSE: the change of every joint's training RMSE since the previous iteration is at most
     0.05 N·m and the sum of those changes at most 0.3 N·m;
   * parameters: the friction curves have stopped moving, measured where they act: for each joint
     the relative change of its curve on the training rows, :math:`c_j = \\|f_j(\\dot q;
     \\theta_{f,k+1}) - f_j(\\dot q; \\theta_{f,k})\\|_2 / \\max(\\|f_j(\\cdot;\\theta_{f,k+1})\\|_2,
     \\|f_j(\\cdot;\\theta_{f,k})\\|_2)`, and :math:`\\|c\\|_2 \\le 10^{-3}` over the joints. The paper
     measures the change of the coefficient vector; its coefficients have different units, and some
     directions do not act on the data: with :math:`F_s \\to 0` the Stribeck velocity is free, with the
     arctan saturated over the measured speeds :math:`k_v` can wander by orders of magnitude; an
     element-wise relative change of such a coefficient stays near 1 while the curve, and the
     residual, no longer change (the paper 003 twin: Proposed-FBPE's training RMSE constant to six
     digits from iteration 16 while that measure stayed 0.45-1.0 up to iteration 50). The
     element-wise coefficient change is still recorded per iteration (``coef_change``);

   or after 50 iterations (not converged: said in the notes). If the total training RMSE rises
   (line 15 refits only when it falls) by more than 1e-4 of itself, the previous iterate is kept and
the loop stops.

Both fits minimise the same per-joint sum of squares (the WLS weights are per joint), so the
alternation is block-coordinate descent on one objective. The result's parameters are the
rigid-body base parameters; the friction coefficients (std from the Jacobian of the last refit,
conditional on :math:`\\xi_r`, assuming independent residuals: low-pass filtered residuals are
correlated, so these are optimistic) and the iteration history are in ``solver["hierarchical"]``.
Prediction adds the fitted friction curves to :math:`\\Phi_{br}\\xi_r`.

Mechanisms (closed kinematic chains, parallel robots; dynid issue 19 item 2, the mechanism half).
The actuator equations of :mod:`dynid.model.closed_loop` are
:math:`y = T\\,G^T\\big(Y\\pi + F\\varphi\\big)` with :math:`F` the joint terms of *every* joint.
Which friction gets a nonlinear curve is a modelling choice; dynid's is:

* **a curve of the family on each actuated joint** (the actuators' own friction, which paper 003
  measures and models: Eq. 13-15 are motor/gearbox friction laws); the actuated joints' linear
  ``coulomb``/``viscous`` terms (symmetric or asymmetric) leave the regressor, their rotor inertia
  and offset stay (as the serial ``Ia``/offset do);
* **the passive joints keep their linear friction columns in the rigid-body (linear) step.**
  Reasons: (i) a passive joint's velocity is not an independent signal, :math:`\\dot q_p = G_p(q)
  \\dot u`, and its friction reaches every equation through the configuration-dependent
  :math:`G`; a nonlinear curve per passive joint (up to six coefficients each, a spherical joint
  counting three hinges) adds many weakly excited nonlinear coefficients whose combinations the
  data may not separate, and a nonlinear least squares has no base-parameter reduction to group
  the unidentifiable ones, which the linear step has (:mod:`dynid.model.base_parameters`: a
  passive term that only acts in combination is grouped, one that does not act is dropped);
  (ii) passive joints are unpowered bearings, whose friction is small and well described by
  Coulomb + viscous terms; the Stribeck hump and the power law are properties of the
  motor-gearbox units (paper 003 Sec. 3.1 measures them on the drives); (iii) it is what
  ``dynid simulate``'s ``[robot.friction]`` plants: the configured law on the actuated joints,
  the description's linear terms on the passive ones; (iv) the linear passive columns stay under
  the LMI/sign constraints of ``physical_consistency`` with everything else.
  The objective is unchanged: step 1 fits :math:`\\xi_r` *and* the passive friction on
  :math:`y - P\\,\\tau_f`, step 3 the curves on :math:`y - \\Phi_{br}\\xi_r`: still
  block-coordinate descent on one sum of squares.

How an actuator's curve reaches the equations (:func:`friction_projection`): the friction
:math:`f_a` of the actuated joints enters :math:`G^T S_a^T f_a = G_a^T f_a`, so the channels
see :math:`P f_a` with :math:`P = T G_a^T`: the identity for a non-redundant mechanism
(:math:`T = G_a^{-T}`) and for the ``"min_norm_local_friction"`` force model (the actuators'
own terms stay local, paper 001 Eq. 5); :math:`G_a^T` for the ``"projected"`` equations of a
redundantly actuated one (each equation mixes several actuators' friction: paper 001 Eq. 4-6);
:math:`(G_a^T)^+ G_a^T` for ``"min_norm"``. With :math:`P = I` the refit is the serial per-joint
fit; otherwise it is one bounded nonlinear least squares over all the curves' coefficients on
all the channels, :math:`\\min_\\theta \\sum_{k,c} w_c^2\\big(r_{kc} - \\sum_j P_{kcj}
f_j(\\dot q_{a,j,k}; \\theta_j)\\big)^2`, with the same positivity bounds per joint,
per-channel weights :math:`w_c = 1/\\mathrm{RMSE}_c` (those of the WLS) and starting values
from a grid of the nonlinear coefficients (the same grid point on every joint, scaled to its
speeds) with the linear ones by one non-negative least squares over all the joints; later
iterations warm-start from the previous curves. Standard errors: :math:`s^2 (J^T J)^{-1}` of that
joint fit (conditional on :math:`\\xi_r`; optimistic as above). Prediction uses the same
:math:`P` on the held-out rows.

Refused with a one-line error (the reason in it): parallel decimation (does not commute with the
curve), the ``pose`` domain of periodic processing (its rows are built through the platform pose
of a whole averaged period; the hierarchical loop works on time-domain rows and has not been
validated there), and coupled motors whose friction acts through a combination of actuator
velocities (a curve is a function of one actuator's velocity).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.errors import ConfigError, InputError
from dynid.estimation import IdentificationResult, ProblemBuilder
from dynid.estimation.friction_curves import MODELS, CurveFit, fit_curve
from dynid.tolerances import scaled

__all__ = ["FAMILIES", "EPS_RMSE", "EPS_TOTAL", "EPS_PARAM", "MAX_ITER", "HierarchicalFriction", "check_config",
           "rigid_robot_config", "rigid_system", "friction_projection", "read_prior", "hierarchical_fit",
           "plot_history"]

FAMILIES = {"linear": "coulomb_viscous", "stribeck": "stribeck", "powerlaw": "power_law", "arctan": "smooth_stribeck"}
"""``friction_model`` (with ``hierarchical = true``) -> :data:`~dynid.estimation.friction_curves.MODELS` key:
paper 003 Eq. 2, Eq. 14, Eq. 13 (without the even offset B) and Eq. 15 (the improved Stribeck model)."""

EQUATIONS = {"linear": "Eq. 2", "stribeck": "Eq. 14", "powerlaw": "Eq. 13", "arctan": "Eq. 15"}
EPS_RMSE = 0.05  # N*m, change of each joint's RMSE (paper 003 Sec. 3.3 (1))
EPS_TOTAL = 0.3  # N*m, sum over the joints
EPS_PARAM = 1e-3  # relative change of the friction coefficients (Sec. 3.3 (2))
MAX_ITER = 50  # Sec. 3.3 (3)
RISE_TOL = 1e-4  # relative rise of the total training RMSE that stops the loop (the WLS weights move with
# each iteration, so at the fixed point the unweighted RMSE wanders by round-off-sized amounts)
_FRICTION_EXTRAS = ("fv", "fc", "fv+", "fv-", "fc+", "fc-")
_FRICTION_KINDS = ("viscous", "coulomb", "viscous+", "viscous-", "coulomb+", "coulomb-")  # a mechanism's joint terms


@dataclasses.dataclass(frozen=True, eq=False)
class HierarchicalFriction:
    """The fitted friction curves: ``family`` (config name), ``model`` (friction_curves name),
    ``joints``, ``velocity`` (their columns in the actuator velocities), ``fits`` (one
    :class:`~dynid.estimation.friction_curves.CurveFit` per joint)."""

    family: str
    model: str
    joints: tuple[str, ...]
    fits: tuple[CurveFit, ...]
    projection: str = "identity"  # how the curves reach the channels: PROJECTIONS (mechanisms, module docstring)

    @property
    def params(self) -> np.ndarray:
        return np.array([f.params for f in self.fits])

    def force(self, dq: FloatArray) -> FloatArray:
        """The friction of each joint (n, n_joints) at its velocity."""
        dq = np.atleast_2d(np.asarray(dq, dtype=float))
        return np.column_stack([f.force(dq[:, j]) for j, f in enumerate(self.fits)])

    def channel_force(self, dq: FloatArray, Ga: FloatArray | None = None) -> FloatArray:
        """The friction as the channels see it, :math:`P f(\\dot q_a)` (:func:`friction_projection`;
        ``Ga``: a redundant mechanism's actuator velocity map of the same rows)."""
        F = self.force(dq)
        P = friction_projection(self.projection, Ga)
        return F if P is None else np.einsum("ncj,nj->nc", P, F)

    def predict(self, result: IdentificationResult, W: FloatArray, dq: FloatArray,
                Ga: FloatArray | None = None) -> FloatArray:
        """Outputs of rigid-body base parameters ``result.params`` plus the friction curves."""
        return W @ result.params + self.channel_force(dq, Ga)

    def as_dict(self) -> dict[str, Any]:
        return {j: {n: {"value": float(v), "std": None if not np.isfinite(s) else float(s), "at_bound": bool(b)}
                    for n, v, s, b in zip(f.names, f.params, f.std, f.at_bound)}
                for j, f in zip(self.joints, self.fits)}


PROJECTIONS = {"identity": "the identity (each actuator's friction on its own channel)",
               "projected": "G_a^T (the projected equations mix the actuators' friction)",
               "min_norm": "(G_a^T)^+ G_a^T (the minimum-norm distribution mixes the actuators' friction)"}
"""How the actuators' friction reaches the channels, :math:`P = T G_a^T` (module docstring)."""


def projection_kind(system, force_model: str | None) -> str:
    """The :data:`PROJECTIONS` key of a system and its force model."""
    if system.kind == "serial" or not system.redundant or force_model == "min_norm_local_friction":
        return "identity"
    if force_model in ("projected", "min_norm"):
        return force_model
    raise ConfigError(f"identification.hierarchical = true: unknown force model {force_model!r}")


def friction_projection(kind: str, Ga: FloatArray | None) -> FloatArray | None:
    """:math:`P` (n, n_ch, n_a) of :data:`PROJECTIONS` ``kind`` from the actuator velocity map
    ``Ga`` (n, n_a, n_u) of a redundant mechanism; None for the identity."""
    if kind == "identity":
        return None
    if Ga is None:
        raise InputError(f"hierarchical identification: the {kind!r} friction projection needs the actuator velocity map")
    GaT = np.asarray(Ga, dtype=float).transpose(0, 2, 1)  # (n, n_u, n_a)
    if kind == "projected":
        return GaT
    return np.matmul(np.linalg.pinv(GaT), GaT)  # min_norm: (G_a^T)^+ G_a^T, (n, n_a, n_a)


def check_config(cfg, system) -> None:
    """Refusals that need the robot (before any data is read)."""
    p = cfg.processing
    if p.decimate > 1 and p.decimate_method == "parallel":
        raise ConfigError("identification.hierarchical = true subtracts a nonlinear friction curve of the velocity; a "
                          "low-pass of the regressor columns does not commute with it: use "
                          "processing.decimate_method = 'samples'")
    if p.periodic is not None and p.periodic.domain == "pose":
        raise ConfigError("identification.hierarchical = true works on time-domain rows; processing.periodic.domain = "
                          "'pose' builds the rows of a whole averaged period through the platform pose, where the loop "
                          "has not been validated: use processing.periodic.domain = 'time' or no periodic processing")
    if system.kind != "serial":
        act = set(system.model.actuated)
        coupled = [t.name for t in system.model.terms if t.weights and t.kind in _FRICTION_KINDS and set(t.joints) <= act]
        if coupled:
            raise ConfigError(f"identification.hierarchical = true fits one friction curve per actuator velocity; "
                              f"{', '.join(coupled)} act through a combination of actuator velocities (coupled motors): "
                              "remove the couplings' friction (robot.extras without fv, fc)")


def rigid_robot_config(rcfg):
    """``[robot]`` without the friction extras: the friction-free regressor :math:`\\Phi_{br}`."""
    return dataclasses.replace(rcfg, extras=tuple(e for e in rcfg.extras if e not in _FRICTION_EXTRAS))


def rigid_system(system):
    """A mechanism's system without the linear friction terms of its actuated joints (those the
    curves replace; their rotor inertia and offset, and every passive joint's terms, stay: module
    docstring). A serial system is returned as it is (:func:`rigid_robot_config` already left
    its friction extras out)."""
    if system.kind == "serial":
        return system
    mech = system.model
    act = set(mech.actuated)
    drop = {t.name for t in mech.terms
            if t.kind in _FRICTION_KINDS and not t.weights and set(t.joints) <= act}
    if not drop:
        return system
    rigid = dataclasses.replace(
        mech, terms=tuple(t for t in mech.terms if t.name not in drop),
        nominal_terms={k: v for k, v in mech.nominal_terms.items() if k not in drop},
        symmetric_zero=tuple(n for n in mech.symmetric_zero if n not in drop), q_guess=mech.q_ref)
    return dataclasses.replace(system, model=rigid)


def replaced_terms(system, original=None) -> tuple[list[str], list[str]]:
    """(the actuated joints' linear friction terms the curves replace, found in ``original``, the
    system before :func:`rigid_system`; the passive joints' friction terms that stay linear in the
    rigid-body step) of a mechanism, by name."""
    mech = (original or system).model
    act = set(mech.actuated)
    replaced = [t.name for t in mech.terms if t.kind in _FRICTION_KINDS and not t.weights and set(t.joints) <= act]
    passive = [t.name for t in system.model.terms if t.kind in _FRICTION_KINDS and not set(t.joints) <= act]
    return replaced, passive


def read_prior(path: Path, family: str, joints: tuple[str, ...]) -> np.ndarray:
    """The coefficients (n_joints, p) of ``family`` per joint from a ``dynid friction`` result."""
    model = FAMILIES[family]
    try:
        doc = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise InputError(f"identification.friction_prior: {path} not found (the friction.json of dynid friction)") from None
    except (OSError, ValueError) as e:
        raise InputError(f"identification.friction_prior: {path} is not readable JSON ({e})") from None
    if not (isinstance(doc, dict) and isinstance(doc.get("joints"), dict)):
        raise InputError(f"identification.friction_prior: {path} is not a dynid friction result (friction.json)")
    out = []
    for j in joints:
        entry = doc.get("joints", {}).get(j)
        if entry is None:
            raise InputError(f"identification.friction_prior: {path} has no joint {j!r} (it has "
                             f"{sorted(doc.get('joints', {}))})")
        m = entry.get("models", {}).get(model)
        if m is None:
            raise InputError(f"identification.friction_prior: {path} has no {model!r} fit for joint {j!r} "
                             f"(friction_model = {family!r}; run dynid friction with models = [..., {model!r}])")
        c = m["coefficients"]
        out.append([float(c[n]["value"]) for n in MODELS[model]])
    return np.array(out)


def _fold(dq: FloatArray, r: FloatArray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """The rows of one joint folded to positive speed, and the speed range for bounds and start grid."""
    sel = keep & (np.abs(dq) > 0)
    v, f = np.abs(dq[sel]), np.sign(dq[sel]) * r[sel]
    if v.size == 0:
        raise InputError("hierarchical identification: a joint has no moving training sample")
    vmax = float(v.max())
    return v, f, (max(float(np.percentile(v, 1)), 1e-3 * vmax), vmax)


def _fit_friction(model: str, dq: FloatArray, r: FloatArray, keep: np.ndarray,
                  start: np.ndarray | None) -> tuple[CurveFit, ...]:
    fits = []
    for j in range(dq.shape[1]):
        v, f, rng = _fold(dq[:, j], r[:, j], keep[:, j])
        fits.append(fit_curve(model, v, f, speed_range=rng, start=None if start is None else start[j]))
    return tuple(fits)


def _joint_rows(dq: FloatArray, keep: np.ndarray) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """The samples any channel keeps and each joint's speed range there (bounds and start grid)."""
    rows = keep.any(axis=1)
    ranges = []
    for j in range(dq.shape[1]):
        v = np.abs(dq[rows, j])
        v = v[v > 0]
        if v.size == 0:
            raise InputError("hierarchical identification: an actuator has no moving training sample")
        vmax = float(v.max())
        ranges.append((max(float(np.percentile(v, 1)), 1e-3 * vmax), vmax))
    return rows, ranges


def _basis(model: str, nonlinear: dict[str, float], v: FloatArray) -> dict[str, FloatArray]:
    """The columns of the linear coefficients (fc, fs, fv) of ``model`` at signed velocities ``v``
    for fixed nonlinear ones (the odd extension of :func:`~dynid.estimation.friction_curves._starts`)."""
    s, a = np.sign(v), np.abs(v)
    arc = 2 / np.pi * np.arctan(nonlinear["kv"] * a) if "kv" in nonlinear else np.ones_like(a)
    e = np.exp(-((a / nonlinear["vs"]) ** 2)) if "vs" in nonlinear else np.zeros_like(a)
    return {"fc": s * arc * (1 - e), "fs": s * arc * e, "fv": s * a ** nonlinear.get("alpha", 1.0)}


def _grid_starts(model: str, dq: FloatArray, r: FloatArray, P: FloatArray, w: np.ndarray, mask: np.ndarray,
                 ranges, lo: np.ndarray, hi: np.ndarray, keep: int = 3) -> list[np.ndarray]:
    """Starting points of the joint fit: the nonlinear coefficients on a grid (one grid point for
    every joint, scaled to its speeds), the linear ones by one NNLS over all joints and channels."""
    import itertools

    from scipy.optimize import nnls

    names = MODELS[model]
    nonlinear = [n for n in names if n not in ("fc", "fs", "fv")]
    lin = [n for n in names if n in ("fc", "fs", "fv")]
    p, nj = len(names), dq.shape[1]
    unit = {"vs": np.geomspace(0.5, 1.0, 8), "kv": np.geomspace(0.1, 100.0, 7), "alpha": np.array([0.3, 0.5, 0.7, 1.0, 1.4])}
    trials = []
    target = (r * w)[mask]
    for combo in itertools.product(*(range(unit[n].size) for n in nonlinear)):
        x = np.zeros(nj * p)
        cols = []
        for j in range(nj):
            vmin, vmax = ranges[j]
            nl = {}
            for n, i in zip(nonlinear, combo):
                if n == "vs":
                    g = np.geomspace(max(vmin / 2, lo[j * p + names.index("vs")]), vmax, 8)
                    nl[n] = g[i]
                elif n == "kv":
                    nl[n] = unit["kv"][i] / vmin
                else:
                    nl[n] = unit[n][i]
            b = _basis(model, nl, dq[:, j])
            cols += [(P[:, :, j] * b[n][:, None] * w)[mask] for n in lin]
            for n, v in nl.items():
                x[j * p + names.index(n)] = v
        coef, res = nnls(np.column_stack(cols), target)
        for j in range(nj):
            for k, n in enumerate(lin):
                x[j * p + names.index(n)] = coef[j * len(lin) + k]
        trials.append((res, np.clip(x, lo, hi)))
    trials.sort(key=lambda t: t[0])
    return [x for _, x in trials[:keep]]


def _fit_projected(model: str, dq: FloatArray, r: FloatArray, keep: np.ndarray, P: FloatArray, weights: np.ndarray,
                   start: np.ndarray | None) -> tuple[CurveFit, ...]:
    """The curves of all joints at once on all channels (module docstring, mechanisms): bounded
    nonlinear least squares of :math:`w_c (r_{kc} - \\sum_j P_{kcj} f_j(\\dot q_{kj}))` on the kept
    rows, with the positivity bounds of :func:`~dynid.estimation.friction_curves.fit_curve` per
    joint and the analytic Jacobian (:func:`~dynid.estimation.friction_curves.projected_jacobian`);
    warm-started from ``start`` (n_joints, p) or from :func:`_grid_starts`."""
    from scipy.optimize import least_squares

    from dynid.estimation.friction_curves import _bounds, curve_force, fit_statistics, projected_jacobian

    names = MODELS[model]
    p, nj = len(names), dq.shape[1]
    rows, ranges = _joint_rows(dq, keep)
    dq, r, P, mask = dq[rows], r[rows], P[rows], keep[rows]
    w = np.broadcast_to(np.asarray(weights, dtype=float)[None, :], r.shape)
    bl, bh = zip(*(_bounds(names, np.abs(dq[:, j]), ranges[j]) for j in range(nj)))
    lo, hi = np.concatenate(bl), np.concatenate(bh)

    def resid(x):
        F = np.column_stack([curve_force(model, x[j * p:(j + 1) * p], dq[:, j]) for j in range(nj)])
        return ((r - np.einsum("ncj,nj->nc", P, F)) * w)[mask]

    def jac(x):
        return projected_jacobian(model, x, dq, P, w, mask)

    starts = ([np.asarray(start, dtype=float).reshape(-1)] if start is not None
              else _grid_starts(model, dq, r, P, w, mask, ranges, lo, hi))
    best = None
    for x0 in starts:
        x0 = np.minimum(np.maximum(x0, lo), hi)
        res = least_squares(resid, x0, bounds=(lo, hi), method="trf", x_scale="jac", xtol=scaled(1e-12), ftol=scaled(1e-12),
                            gtol=scaled(1e-12), max_nfev=500 * p * nj, jac=jac)
        if best is None or res.cost < best.cost:
            best = res
    x = best.x
    at_bound, cov, std, chi2_red = fit_statistics(resid, x, lo, hi)
    F = np.column_stack([curve_force(model, x[j * p:(j + 1) * p], dq[:, j]) for j in range(nj)])
    rmse = float(np.sqrt(np.mean(((r - np.einsum("ncj,nj->nc", P, F)))[mask] ** 2)))  # of the whole joint fit
    out = []
    for j in range(nj):
        sl = slice(j * p, (j + 1) * p)
        out.append(CurveFit(model=model, names=names, params=x[sl].copy(), std=std[sl].copy(),
                            at_bound=at_bound[sl].copy(), cov=cov[sl, sl].copy(), rmse=rmse, chi2_red=chi2_red,
                            n_points=int(mask.sum()), success=bool(best.success), message=str(best.message)))
    return tuple(out)


def _refit(model: str, dq: FloatArray, r: FloatArray, keep: np.ndarray, P: FloatArray | None,
           weights: np.ndarray | None, start: np.ndarray | None) -> tuple[CurveFit, ...]:
    """Per-joint fits where each channel is its joint's (:math:`P = I`), else the joint fit."""
    if P is None:
        return _fit_friction(model, dq, r, keep, start)
    return _fit_projected(model, dq, r, keep, P, weights, start)


def _rel_change(new: np.ndarray, old: np.ndarray) -> float:
    scale = np.maximum(np.abs(new), np.abs(old))
    d = np.where(scale > 0, np.abs(new - old) / np.where(scale > 0, scale, 1.0), 0.0)
    return float(np.linalg.norm(d))


def _curve_change(new: HierarchicalFriction, old: HierarchicalFriction, dq: FloatArray, rows: np.ndarray) -> float:
    """The L2 norm over the joints of each friction curve's relative change on the training rows
    ``rows`` (module docstring, stopping rule (2))."""
    a, b = new.force(dq[rows]), old.force(dq[rows])
    scale = np.maximum(np.linalg.norm(a, axis=0), np.linalg.norm(b, axis=0))
    d = np.where(scale > 0, np.linalg.norm(a - b, axis=0) / np.where(scale > 0, scale, 1.0), 0.0)
    return float(np.linalg.norm(d))


def _rmse(y: FloatArray, pred: FloatArray, keep: np.ndarray) -> np.ndarray:
    e = np.where(keep, y - pred, 0.0)
    return np.sqrt((e ** 2).sum(axis=0) / np.maximum(keep.sum(axis=0), 1))


def _start_from_linear(W, y, dq, keep, names, channels, model, P=None, joints=None):
    """Algorithm 1 without a pre-identified friction: a one-shot WLS with linear Coulomb + viscous
    columns (through ``P`` for a mechanism's mixed channels), then the family fitted to
    tau - Phi_r xi_r (xi_r: its rigid-body part)."""
    from dynid.estimation import WLS

    n, n_ch, r = W.shape
    if P is None:
        aug = np.zeros((n, n_ch, r + 2 * n_ch))
        aug[:, :, :r] = W
        for j in range(n_ch):
            aug[:, j, r + j] = np.sign(dq[:, j])
            aug[:, j, r + n_ch + j] = dq[:, j]
        b = ProblemBuilder(tuple(names) + tuple(f"fc_{c}" for c in channels) + tuple(f"fv_{c}" for c in channels),
                           channels)
        b.add(aug, y, keep)
        lin = WLS().fit(b.build())
        resid = y - W @ lin.params[:r]
        return _fit_friction(model, dq, resid, keep, None), lin
    nj = dq.shape[1]
    aug = np.concatenate([W, P * np.sign(dq)[:, None, :], P * dq[:, None, :]], axis=2)
    b = ProblemBuilder(tuple(names) + tuple(f"fc_{c}" for c in joints) + tuple(f"fv_{c}" for c in joints), channels)
    b.add(aug, y, keep)
    lin = WLS().fit(b.build())
    resid = y - W @ lin.params[:r]
    assert lin.params.size == r + 2 * nj
    return _fit_projected(model, dq, resid, keep, P, 1.0 / np.maximum(lin.rmse_per_channel, 1e-12), None), lin


def hierarchical_fit(W: FloatArray, y: FloatArray, dq: FloatArray, keep: np.ndarray | None, *, family: str,
                     joints: tuple[str, ...], estimator, names: tuple[str, ...], channels: tuple[str, ...],
                     build_kwargs: dict[str, Any], prior: np.ndarray | None = None, prior_source: str | None = None,
                     progress=None, projection: str = "identity", Ga: FloatArray | None = None,
                     mechanism: dict[str, Any] | None = None) -> tuple[IdentificationResult, HierarchicalFriction]:
    """Algorithm 1 of paper 003 on base-regressor rows ``W`` (n, n_ch, r) of the friction-free
    model, measured torques ``y`` (n, n_ch), joint velocities ``dq`` (n, n_ch) and the rows kept
    per joint (``keep``; None: all). ``estimator``: the rigid-body estimator (``.fit(problem)``);
    ``build_kwargs``: what :meth:`ProblemBuilder.build` needs (expressions, standard map, meta).
    Returns the rigid-body result (``solver["hierarchical"]``: friction, history, stop) and the
    friction curves.

    A mechanism: ``dq`` (n, n_a) the actuator velocities, the curves reach the channels through
    :data:`PROJECTIONS` ``projection`` (``Ga`` (n, n_a, n_u): a redundant mechanism's actuator
    velocity map of the rows); ``mechanism``: what the result records of the modelling choice
    (module docstring)."""
    model = FAMILIES[family]
    P = friction_projection(projection, Ga)
    keep = np.ones(y.shape, dtype=bool) if keep is None else np.broadcast_to(keep if keep.ndim == 2 else keep[:, None],
                                                                            y.shape)
    if prior is not None:
        fits = tuple(CurveFit(model=model, names=MODELS[model], params=np.asarray(p, dtype=float),
                              std=np.full(len(p), np.nan), at_bound=np.zeros(len(p), bool),
                              cov=np.full((len(p), len(p)), np.nan), rmse=float("nan"), chi2_red=float("nan"),
                              n_points=0, success=True, message="prior") for p in prior)
        start = f"friction_prior {prior_source}"
        linear = None
    else:
        fits, linear = _start_from_linear(W, y, dq, keep, names, channels, model, P, joints)
        start = ("fitted to tau - Phi_r xi_r, xi_r the rigid-body part of a one-shot WLS with linear Coulomb + "
                 "viscous columns")
    theta = np.array([f.params for f in fits])
    rows = keep.any(axis=1)
    history: list[dict[str, Any]] = []
    prev_rmse = None
    result = best = None
    stop = "max_iterations"
    for k in range(1, MAX_ITER + 1):
        if progress is not None:
            progress("hierarchical iterations", k - 1, MAX_ITER)
        fr = HierarchicalFriction(family, model, joints, fits, projection)
        tf = fr.channel_force(dq, Ga)
        b = ProblemBuilder(names, channels)
        b.add(W, y - tf, keep)
        res = estimator.fit(b.build(**build_kwargs))
        rigid = W @ res.params
        rmse = _rmse(y, rigid + tf, keep)
        if prev_rmse is not None and rmse.sum() > prev_rmse.sum() * (1 + RISE_TOL):
            stop = "rmse_rose"
            history.append({"iteration": k, "rmse_per_joint": rmse.tolist(), "rmse_total": float(rmse.sum()),
                            "rmse_change_per_joint": (rmse - prev_rmse).tolist(), "param_change": None,
                            "kept": False})
            break
        new_fits = _refit(model, dq, y - rigid, keep, P, 1.0 / np.maximum(rmse, 1e-12), theta)
        new_theta = np.array([f.params for f in new_fits])
        dpar = _curve_change(HierarchicalFriction(family, model, joints, new_fits, projection), fr, dq, rows)
        dcoef = _rel_change(new_theta, theta)
        drmse = np.full(rmse.shape, np.inf) if prev_rmse is None else np.abs(rmse - prev_rmse)
        history.append({"iteration": k, "rmse_per_joint": rmse.tolist(), "rmse_total": float(rmse.sum()),
                        "rmse_change_per_joint": None if prev_rmse is None else (rmse - prev_rmse).tolist(),
                        "param_change": dpar, "coef_change": dcoef, "kept": True})
        result, best = res, HierarchicalFriction(family, model, joints, new_fits, projection)
        fits, theta, prev_rmse = new_fits, new_theta, rmse
        rmse_ok = bool(np.all(drmse <= EPS_RMSE) and drmse.sum() <= EPS_TOTAL)
        if rmse_ok and dpar <= EPS_PARAM:
            stop = "converged"
            break
    if progress is not None:
        progress("hierarchical iterations", MAX_ITER, MAX_ITER)
    assert result is not None and best is not None
    iterations = sum(1 for h in history if h["kept"])
    info = {
        "family": family, "model": model, "equation": f"paper 003 {EQUATIONS[family]}",
        "start": start, "stop": stop, "iterations": iterations, "converged": stop == "converged",
        "rules": {"rmse_change_per_joint": EPS_RMSE, "rmse_change_total": EPS_TOTAL, "param_change": EPS_PARAM,
                  "max_iterations": MAX_ITER,
                  "reading": "stop when every joint's training-RMSE change <= 0.05 N*m, their sum <= 0.3 N*m and the "
                             "L2 norm over the joints of each friction curve's relative change on the training "
                             "rows <= 1e-3 (both criteria); at most 50 iterations; stop and keep the previous "
                             "iterate if the total RMSE rises"},
        "friction": best.as_dict(),
        "friction_fit_rmse": {j: f.rmse for j, f in zip(joints, best.fits)},
        "history": history,
    }
    if linear is not None:
        info["start_linear_wls_rmse_per_joint"] = linear.rmse_per_channel.tolist()
    if mechanism is not None:
        info["mechanism"] = {**mechanism, "projection": projection, "projection_means": PROJECTIONS[projection],
                             "friction_fit": ("per actuator on its own channel" if P is None else
                                              "one bounded nonlinear least squares over all actuators' curves on all "
                                              "channels, weighted by 1/RMSE per channel")}
    notes = [f"hierarchical iterative identification (paper 003 Sec. 3.3, Algorithm 1), friction {family!r} "
             f"({EQUATIONS[family]}); start: {start}; "
             + (f"converged after {iterations} iterations" if stop == "converged" else
                f"NOT converged: stopped after {iterations} iterations ({stop})"),
             "friction per joint (value +- std from the last refit, conditional on the rigid-body part):"]
    if mechanism is not None:
        notes.insert(1, "mechanism: " + info["mechanism"]["choice"] + f"; the curves reach the channels through "
                     f"{PROJECTIONS[projection]}; {info['mechanism']['friction_fit']}")
    for j, f in zip(joints, best.fits):
        notes.append(f"  {j}: " + ", ".join(f"{n} {v:.4g}" + ("" if not np.isfinite(s) else f" +- {s:.2g}")
                                             + (" (at bound)" if b else "")
                                             for n, v, s, b in zip(f.names, f.params, f.std, f.at_bound)))
    notes.append("iteration history (training RMSE per joint, total, relative change of the friction curves):")
    for h in history:
        notes.append(f"  {h['iteration']:>2}: " + " ".join(f"{v:.4g}" for v in h["rmse_per_joint"])
                     + f" | {h['rmse_total']:.4g} | "
                     + ("-" if h["param_change"] is None else f"{h['param_change']:.3g}")
                     + ("" if h["kept"] else " (RMSE rose: not kept)"))
    result = dataclasses.replace(result, method=f"{result.method}+hierarchical({family})",
                                 solver={**result.solver, "hierarchical": info}).with_notes(*notes)
    return result, best


def plot_history(info: dict[str, Any], joints: tuple[str, ...], path: Path) -> None:
    """``hierarchical.png``: training RMSE per joint and total, and the relative friction change,
    per iteration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h = info["history"]
    it = [x["iteration"] for x in h]
    rm = np.array([x["rmse_per_joint"] for x in h])
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for j, name in enumerate(joints):
        ax[0].plot(it, rm[:, j], marker=".", label=name)
    ax[0].plot(it, rm.sum(axis=1), "k--", marker="o", label="total")
    ax[0].set_xlabel("iteration")
    ax[0].set_ylabel("training RMSE [N*m or N]")
    ax[0].set_yscale("log")
    ax[0].legend(fontsize=7)
    pc = [(x["iteration"], x["param_change"]) for x in h if x["param_change"] is not None]
    if pc:
        ax[1].semilogy(*zip(*pc), marker="o")
    ax[1].axhline(EPS_PARAM, color="r", ls=":", label=f"threshold {EPS_PARAM:g}")
    ax[1].set_xlabel("iteration")
    ax[1].set_ylabel("relative change of the friction curves")
    ax[1].legend(fontsize=7)
    fig.suptitle(f"hierarchical identification, {info['family']} ({info['equation']}): {info['stop']} "
                 f"after {info['iterations']} iterations")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
