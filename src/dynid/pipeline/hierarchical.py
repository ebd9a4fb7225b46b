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
   * parameters: :math:`\\|(\\theta_{f,k+1} - \\theta_{f,k}) / \\max(|\\theta_{f,k+1}|,
     |\\theta_{f,k}|)\\|_2 \\le 10^{-3}` over all joints' coefficients (the relative change,
     element by element: the coefficients have different units);

   or after 50 iterations (not converged: said in the notes). If the total training RMSE rises
   (line 15 refits only when it falls) by more than 1e-4 of itself, the previous iterate is kept and
the loop stops.

Both fits minimise the same per-joint sum of squares (the WLS weights are per joint), so the
alternation is block-coordinate descent on one objective. The result's parameters are the
rigid-body base parameters; the friction coefficients (std from the Jacobian of the last refit,
conditional on :math:`\\xi_r`, assuming independent residuals: low-pass filtered residuals are
correlated, so these are optimistic) and the iteration history are in ``solver["hierarchical"]``.
Prediction adds the fitted friction curves to :math:`\\Phi_{br}\\xi_r`.

Serial robots only: a mechanism's actuator equations carry the friction of passive joints through
the loops (and the projected equations mix actuators), which a per-actuator curve fit on its own
channel cannot separate.
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

__all__ = ["FAMILIES", "EPS_RMSE", "EPS_TOTAL", "EPS_PARAM", "MAX_ITER", "HierarchicalFriction", "check_config",
           "rigid_robot_config", "read_prior", "hierarchical_fit", "plot_history"]

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


@dataclasses.dataclass(frozen=True, eq=False)
class HierarchicalFriction:
    """The fitted friction curves: ``family`` (config name), ``model`` (friction_curves name),
    ``joints``, ``velocity`` (their columns in the actuator velocities), ``fits`` (one
    :class:`~dynid.estimation.friction_curves.CurveFit` per joint)."""

    family: str
    model: str
    joints: tuple[str, ...]
    fits: tuple[CurveFit, ...]

    @property
    def params(self) -> np.ndarray:
        return np.array([f.params for f in self.fits])

    def force(self, dq: FloatArray) -> FloatArray:
        dq = np.atleast_2d(np.asarray(dq, dtype=float))
        return np.column_stack([f.force(dq[:, j]) for j, f in enumerate(self.fits)])

    def predict(self, result: IdentificationResult, W: FloatArray, dq: FloatArray) -> FloatArray:
        """Outputs of rigid-body base parameters ``result.params`` plus the friction curves."""
        return W @ result.params + self.force(dq)

    def as_dict(self) -> dict[str, Any]:
        return {j: {n: {"value": float(v), "std": None if not np.isfinite(s) else float(s), "at_bound": bool(b)}
                    for n, v, s, b in zip(f.names, f.params, f.std, f.at_bound)}
                for j, f in zip(self.joints, self.fits)}


def check_config(cfg, system) -> None:
    """Refusals that need the robot (before any data is read)."""
    if system.kind != "serial":
        raise ConfigError("identification.hierarchical = true is for serial robots: a mechanism's actuator equations "
                          "carry passive-joint friction through the loops, which a per-actuator friction curve cannot "
                          "separate")
    p = cfg.processing
    if p.decimate > 1 and p.decimate_method == "parallel":
        raise ConfigError("identification.hierarchical = true subtracts a nonlinear friction curve of the velocity; a "
                          "low-pass of the regressor columns does not commute with it: use "
                          "processing.decimate_method = 'samples'")
    if p.periodic is not None and p.periodic.domain == "pose":
        raise ConfigError("identification.hierarchical = true is for serial robots (processing.periodic.domain = 'pose' "
                          "is for platforms)")


def rigid_robot_config(rcfg):
    """``[robot]`` without the friction extras: the friction-free regressor :math:`\\Phi_{br}`."""
    return dataclasses.replace(rcfg, extras=tuple(e for e in rcfg.extras if e not in _FRICTION_EXTRAS))


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


def _rel_change(new: np.ndarray, old: np.ndarray) -> float:
    scale = np.maximum(np.abs(new), np.abs(old))
    d = np.where(scale > 0, np.abs(new - old) / np.where(scale > 0, scale, 1.0), 0.0)
    return float(np.linalg.norm(d))


def _rmse(y: FloatArray, pred: FloatArray, keep: np.ndarray) -> np.ndarray:
    e = np.where(keep, y - pred, 0.0)
    return np.sqrt((e ** 2).sum(axis=0) / np.maximum(keep.sum(axis=0), 1))


def _start_from_linear(W, y, dq, keep, names, channels, model):
    """Algorithm 1 without a pre-identified friction: a one-shot WLS with linear Coulomb + viscous
    columns, then the family fitted to tau - Phi_r xi_r (xi_r: its rigid-body part)."""
    from dynid.estimation import WLS

    n, n_ch, r = W.shape
    aug = np.zeros((n, n_ch, r + 2 * n_ch))
    aug[:, :, :r] = W
    for j in range(n_ch):
        aug[:, j, r + j] = np.sign(dq[:, j])
        aug[:, j, r + n_ch + j] = dq[:, j]
    b = ProblemBuilder(tuple(names) + tuple(f"fc_{c}" for c in channels) + tuple(f"fv_{c}" for c in channels), channels)
    b.add(aug, y, keep)
    lin = WLS().fit(b.build())
    resid = y - W @ lin.params[:r]
    return _fit_friction(model, dq, resid, keep, None), lin


def hierarchical_fit(W: FloatArray, y: FloatArray, dq: FloatArray, keep: np.ndarray | None, *, family: str,
                     joints: tuple[str, ...], estimator, names: tuple[str, ...], channels: tuple[str, ...],
                     build_kwargs: dict[str, Any], prior: np.ndarray | None = None, prior_source: str | None = None,
                     progress=None) -> tuple[IdentificationResult, HierarchicalFriction]:
    """Algorithm 1 of paper 003 on base-regressor rows ``W`` (n, n_ch, r) of the friction-free
    model, measured torques ``y`` (n, n_ch), joint velocities ``dq`` (n, n_ch) and the rows kept
    per joint (``keep``; None: all). ``estimator``: the rigid-body estimator (``.fit(problem)``);
    ``build_kwargs``: what :meth:`ProblemBuilder.build` needs (expressions, standard map, meta).
    Returns the rigid-body result (``solver["hierarchical"]``: friction, history, stop) and the
    friction curves."""
    model = FAMILIES[family]
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
        fits, linear = _start_from_linear(W, y, dq, keep, names, channels, model)
        start = ("fitted to tau - Phi_r xi_r, xi_r the rigid-body part of a one-shot WLS with linear Coulomb + "
                 "viscous columns")
    theta = np.array([f.params for f in fits])
    history: list[dict[str, Any]] = []
    prev_rmse = None
    result = best = None
    stop = "max_iterations"
    for k in range(1, MAX_ITER + 1):
        if progress is not None:
            progress("hierarchical iterations", k - 1, MAX_ITER)
        fr = HierarchicalFriction(family, model, joints, fits)
        tf = fr.force(dq)
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
        new_fits = _fit_friction(model, dq, y - rigid, keep, theta)
        new_theta = np.array([f.params for f in new_fits])
        dpar = _rel_change(new_theta, theta)
        drmse = np.full(rmse.shape, np.inf) if prev_rmse is None else np.abs(rmse - prev_rmse)
        history.append({"iteration": k, "rmse_per_joint": rmse.tolist(), "rmse_total": float(rmse.sum()),
                        "rmse_change_per_joint": None if prev_rmse is None else (rmse - prev_rmse).tolist(),
                        "param_change": dpar, "kept": True})
        result, best = res, HierarchicalFriction(family, model, joints, new_fits)
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
                             "L2 norm of the element-wise relative change of all friction coefficients <= 1e-3 "
                             "(both criteria); at most 50 iterations; stop and keep the previous iterate if the "
                             "total RMSE rises"},
        "friction": best.as_dict(),
        "friction_fit_rmse": {j: f.rmse for j, f in zip(joints, best.fits)},
        "history": history,
    }
    if linear is not None:
        info["start_linear_wls_rmse_per_joint"] = linear.rmse_per_channel.tolist()
    notes = [f"hierarchical iterative identification (paper 003 Sec. 3.3, Algorithm 1), friction {family!r} "
             f"({EQUATIONS[family]}); start: {start}; "
             + (f"converged after {iterations} iterations" if stop == "converged" else
                f"NOT converged: stopped after {iterations} iterations ({stop})"),
             "friction per joint (value +- std from the last refit, conditional on the rigid-body part):"]
    for j, f in zip(joints, best.fits):
        notes.append(f"  {j}: " + ", ".join(f"{n} {v:.4g}" + ("" if not np.isfinite(s) else f" +- {s:.2g}")
                                             + (" (at bound)" if b else "")
                                             for n, v, s, b in zip(f.names, f.params, f.std, f.at_bound)))
    notes.append("iteration history (training RMSE per joint, total, relative friction change):")
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
    ax[1].set_ylabel("relative change of the friction coefficients")
    ax[1].legend(fontsize=7)
    fig.suptitle(f"hierarchical identification, {info['family']} ({info['equation']}): {info['stop']} "
                 f"after {info['iterations']} iterations")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
