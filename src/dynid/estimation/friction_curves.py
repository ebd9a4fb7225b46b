"""Friction curves fitted to constant-velocity friction points (paper 003, Sec. 3.1, Table 4).

The models (odd functions of the velocity; the points are at :math:`v > 0`, where
:math:`\\mathrm{sign}(v) = 1`), numbered as :data:`MODELS` lists them:

1. ``coulomb_viscous`` (paper 003, Eq. 2): :math:`F_c\\,\\mathrm{sign}(v) + F_v v`;
2. ``stribeck`` (Eq. 14): :math:`[F_c + (F_s - F_c)e^{-(v/v_s)^2}]\\,\\mathrm{sign}(v) + F_v v`;
3. ``power_law`` (Eq. 13, nonlinear Coulomb-viscous): :math:`F_c\\,\\mathrm{sign}(v) + F_v|v|^{\\alpha}\\mathrm{sign}(v)`;
4. ``smooth_stribeck`` (Eq. 15, the improved Stribeck model):
   :math:`[F_c + (F_s - F_c)e^{-(v/v_s)^2}]\\tfrac{2}{\\pi}\\arctan(K_v v) + F_v|v|^{\\alpha}\\mathrm{sign}(v)`;

and, on request, ``arctan_stribeck``: Eq. 15 with :math:`\\alpha = 1` (the third model of paper
003's Table 4 footnote: Stribeck with the arctangent in place of the sign only). The offset
:math:`B` of Eq. 13 is even in the velocity: it cancels in the extraction and is not fitted.

Fits (:func:`fit_curve`) are bounded weighted nonlinear least squares
(``scipy.optimize.least_squares``, trust-region reflective, with the analytic Jacobian of
:func:`curve_jacobian`) of :math:`r_k = (F(v_k; \\theta) - F_k)/\\sigma_k`, with the paper's
positivity constraints as bounds (paper 003 solves the same problem by an interior-point method):
:math:`F_c, F_s, F_v \\ge 0`,
:math:`v_s \\in [v_{min}/100, 100\\,v_{max}]`, :math:`K_v \\in [10^{-3}/v_{max}, 10^4/v_{min}]`,
:math:`\\alpha \\in [0.05, 3]` (:math:`v_{min}, v_{max}`: the smallest and largest speed of the
points). Starting values: for each point of a grid of the nonlinear parameters
(:math:`v_s, K_v, \\alpha`) the linear ones (:math:`F_c, F_s, F_v`) by non-negative least squares;
the best few grid points start the nonlinear fit, and the lowest cost wins. Standard errors:
:math:`\\mathrm{cov} = s^2 (J^T J)^{-1}` with :math:`J` the Jacobian of the weighted residuals
at the optimum (central differences) and :math:`s^2 = \\sum r_k^2/(m - p)` the reduced
chi-square, as weighted least squares does when the weights are known up to a factor (the
points' :math:`\\sigma_k` set their relative weights). A parameter at a bound has no standard
error (NaN, ``at_bound``) and the others' covariance is that with it held fixed.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence

import numpy as np
from scipy.optimize import least_squares, nnls

from dynid._typing import FloatArray
from dynid.errors import InputError
from dynid.model.friction import coulomb_viscous_force, power_law_force, smooth_stribeck_force, stribeck_force
from dynid.tolerances import scaled

__all__ = ["MODELS", "CurveFit", "curve_force", "curve_jacobian", "fit_curve", "fit_statistics", "held_out_split",
           "projected_jacobian"]

MODELS: dict[str, tuple[str, ...]] = {
    "coulomb_viscous": ("fc", "fv"),
    "stribeck": ("fc", "fs", "fv", "vs"),
    "power_law": ("fc", "fv", "alpha"),
    "smooth_stribeck": ("fc", "fs", "fv", "vs", "kv", "alpha"),
    "arctan_stribeck": ("fc", "fs", "fv", "vs", "kv"),
}
"""Model name -> its coefficients (paper 003 Table 4 numbering: the first four, in order)."""

DEFAULT_MODELS = ("coulomb_viscous", "stribeck", "power_law", "smooth_stribeck")
_LINEAR = ("fc", "fs", "fv")


def curve_force(model: str, params: dict[str, float] | Sequence[float], v: FloatArray) -> FloatArray:
    """Friction of ``model`` with ``params`` (a dict, or values in :data:`MODELS` order) at
    velocities ``v`` (m,).

    The validation-free functions of :mod:`dynid.model.friction` that its classes evaluate
    (:func:`~dynid.model.friction.smooth_stribeck_force`, ...): the same operations, the same
    result to the last bit, without constructing (and checking) a model per call, which cost
    a least-squares fit most of its time. The coefficients are not checked (a fit keeps them
    within :func:`_bounds`)."""
    p = params if isinstance(params, dict) else dict(zip(MODELS[model], params))
    v = np.asarray(v, dtype=float).reshape(-1)
    if model == "coulomb_viscous":
        return coulomb_viscous_force(v, p["fc"], p["fv"])
    if model == "stribeck":
        return stribeck_force(v, p["fc"], p["fs"], p["fv"], p["vs"], 2.0)
    if model == "power_law":
        return power_law_force(v, p["fc"], p["fv"], p["alpha"])
    if model in ("smooth_stribeck", "arctan_stribeck"):
        return smooth_stribeck_force(v, p["fc"], p["fs"], p["fv"], p["vs"], p["kv"], p.get("alpha", 1.0))
    raise InputError(f"unknown friction model {model!r}; one of {list(MODELS)}")


def curve_jacobian(model: str, params: dict[str, float] | Sequence[float], v: FloatArray) -> FloatArray:
    """Derivatives of :func:`curve_force` with respect to the coefficients, (m, p) in
    :data:`MODELS` order, at velocities ``v`` (m,): analytic, from the module docstring's
    equations (paper 003, Eq. 2, 13, 14, 15). With :math:`s = \\mathrm{sign}(v)`,
    :math:`e = e^{-(v/v_s)^2}`, :math:`a = \\tfrac{2}{\\pi}\\arctan(K_v v)` (``s`` for the models
    without the arctangent) and :math:`g = F_c + (F_s - F_c)e`:

    * :math:`\\partial F/\\partial F_c = (1 - e)a`, :math:`\\partial F/\\partial F_s = e a`
      (:math:`e = 0` without a Stribeck term);
    * :math:`\\partial F/\\partial F_v = |v|^{\\alpha}s` (:math:`v` for :math:`\\alpha = 1`);
    * :math:`\\partial F/\\partial v_s = 2 (F_s - F_c)\\, e\\, v^2 / v_s^3\\, a`;
    * :math:`\\partial F/\\partial K_v = g\\,\\tfrac{2}{\\pi} v / (1 + (K_v v)^2)`;
    * :math:`\\partial F/\\partial \\alpha = F_v |v|^{\\alpha}\\ln|v|\\, s` (0 at :math:`v = 0`).
    """
    names = MODELS[model]
    p = params if isinstance(params, dict) else dict(zip(names, params))
    v = np.asarray(v, dtype=float).reshape(-1)
    s, av = np.sign(v), np.abs(v)
    fc, fs, fv = p["fc"], p.get("fs", 0.0), p["fv"]
    a = 2.0 / np.pi * np.arctan(p["kv"] * v) if "kv" in p else s
    e = np.exp(-np.square(v / p["vs"])) if "vs" in p else np.zeros_like(v)
    pw = np.power(av, p["alpha"]) if "alpha" in p else av
    cols = {"fc": (1.0 - e) * a, "fs": e * a, "fv": pw * s}
    if "vs" in p:
        cols["vs"] = 2.0 * (fs - fc) * e * np.square(v / p["vs"]) / p["vs"] * a
    if "kv" in p:
        cols["kv"] = (fc + (fs - fc) * e) * (2.0 / np.pi) * v / (1.0 + np.square(p["kv"] * v))
    if "alpha" in p:
        cols["alpha"] = fv * pw * np.log(np.where(av > 0, av, 1.0)) * s
    return np.column_stack([cols[n] for n in names])


def projected_jacobian(model: str, x: FloatArray, v: FloatArray, P: FloatArray, w: FloatArray,
                       mask: np.ndarray) -> FloatArray:
    """Jacobian of the residual :math:`w_c (r_{kc} - \\sum_j P_{kcj} F(v_{kj}; \\theta_j))` of the
    curves of several joints reaching several channels (the hierarchical fit of a mechanism,
    :mod:`dynid.pipeline.hierarchical`), on its entries ``mask`` (n, n_c), columns
    :math:`\\theta_1, \\theta_2, \\dots` (``x``, n_j p): :math:`-w_c P_{kcj}\\,\\partial F/\\partial
    \\theta_j` (:func:`curve_jacobian`). ``v`` (n, n_j), ``P`` (n, n_c, n_j), ``w`` (n, n_c)."""
    p = len(MODELS[model])
    return np.concatenate([(-(P[:, :, j, None] * curve_jacobian(model, x[j * p:(j + 1) * p], v[:, j])[:, None, :])
                            * w[:, :, None])[mask] for j in range(v.shape[1])], axis=1)


@dataclasses.dataclass(frozen=True, eq=False)
class CurveFit:
    """One model fitted to one joint's points.

    ``names``, ``params``, ``std`` (NaN at a bound or without residual degrees of freedom),
    ``at_bound`` per coefficient; ``cov`` (p, p); ``rmse`` [N·m or N] and ``chi2_red`` of the
    fit; ``n_points``; ``success`` and ``message`` of the solver.
    """

    model: str
    names: tuple[str, ...]
    params: np.ndarray
    std: np.ndarray
    at_bound: np.ndarray
    cov: np.ndarray
    rmse: float
    chi2_red: float
    n_points: int
    success: bool
    message: str

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, self.params.tolist()))

    def force(self, v: FloatArray) -> FloatArray:
        return curve_force(self.model, self.as_dict(), v)


def _bounds(names: tuple[str, ...], v: np.ndarray, speed_range: tuple[float, float] | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    vmin, vmax = speed_range if speed_range is not None else (float(v.min()), float(v.max()))
    table = {"fc": (0.0, np.inf), "fs": (0.0, np.inf), "fv": (0.0, np.inf), "vs": (vmin / 100, 100 * vmax),
             "kv": (1e-3 / vmax, 1e4 / vmin), "alpha": (0.05, 3.0)}
    lo, hi = zip(*(table[n] for n in names))
    return np.array(lo), np.array(hi)


def _starts(model: str, v: np.ndarray, f: np.ndarray, w: np.ndarray, lo: np.ndarray, hi: np.ndarray,
            keep: int = 3, speed_range: tuple[float, float] | None = None) -> list[np.ndarray]:
    """Grid of the nonlinear coefficients, the linear ones by NNLS; the ``keep`` best, and for a model
    with a Stribeck velocity also the best of each of its grid levels (the basins of these fits
    differ mostly in ``vs``: a small hump at a low ``vs`` can mimic a steep arctan rise, so the ``keep``
    best of the linearised grid may all lie in one wrong basin; bench/README, paper 003 twin)."""
    names = MODELS[model]
    nonlinear = [n for n in names if n not in _LINEAR]
    vmin, vmax = speed_range if speed_range is not None else (float(v.min()), float(v.max()))
    grids = {"vs": np.geomspace(max(vmin / 2, lo[names.index("vs")] if "vs" in names else 0), vmax, 8),
             "kv": np.geomspace(0.1 / vmin, 100 / vmin, 7), "alpha": np.array([0.3, 0.5, 0.7, 1.0, 1.4])}
    trials = []
    for combo in itertools.product(*(grids[n] for n in nonlinear)):
        p = dict(zip(nonlinear, combo))
        a = 2 / np.pi * np.arctan(p["kv"] * v) if "kv" in p else np.ones_like(v)
        e = np.exp(-((v / p["vs"]) ** 2)) if "vs" in p else np.zeros_like(v)
        cols = {"fc": a * (1 - e), "fs": a * e, "fv": v ** p.get("alpha", 1.0)}
        lin = [n for n in names if n in _LINEAR]
        coef, res = nnls(np.column_stack([cols[n] for n in lin]) * w[:, None], f * w)
        p.update(zip(lin, coef))
        trials.append((res, np.clip([p[n] for n in names], lo, hi)))
    order = sorted(range(len(trials)), key=lambda k: trials[k][0])
    chosen = order[:keep]
    if "vs" in nonlinear:
        iv = names.index("vs")
        for level in grids["vs"]:
            k = next(k for k in order if trials[k][1][iv] == np.clip(level, lo[iv], hi[iv]))
            if k not in chosen:
                chosen.append(k)
    return [trials[k][1] for k in chosen]


def _jacobian(fun, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    cols = []
    for i in range(x.size):
        h = 1e-6 * max(abs(x[i]), 1e-3 * (hi[i] - lo[i]) if np.isfinite(hi[i]) else 1.0, 1e-12)
        up, dn = x.copy(), x.copy()
        up[i] = min(x[i] + h, hi[i]) if np.isfinite(hi[i]) else x[i] + h
        dn[i] = max(x[i] - h, lo[i])
        cols.append((fun(up) - fun(dn)) / (up[i] - dn[i]))
    return np.column_stack(cols)


def fit_statistics(resid, x: FloatArray, lo: FloatArray, hi: FloatArray):
    """At the bounded least-squares solution ``x`` of the residual function ``resid``: which
    coefficients sit at a bound (within 1e-6 of the span), the covariance
    :math:`s^2 (J_f^T J_f)^{-1}` of the free ones (NaN rows for those at a bound;
    :math:`s^2` = the reduced chi-square), their standard errors and the reduced chi-square."""
    e = resid(x)
    span = np.where(np.isfinite(hi), hi - lo, np.maximum(np.abs(x), 1.0))
    at_bound = (x - lo <= 1e-6 * span) | (hi - x <= 1e-6 * span)
    J = _jacobian(resid, x, lo, hi)
    dof = e.size - x.size
    chi2_red = float(e @ e / dof) if dof > 0 else float("nan")
    cov = np.full((x.size, x.size), np.nan)
    free = ~at_bound
    if dof > 0 and free.any():
        Jf = J[:, free]
        try:
            inv = np.linalg.inv(Jf.T @ Jf)
        except np.linalg.LinAlgError:
            inv = np.linalg.pinv(Jf.T @ Jf)
        cov[np.ix_(free, free)] = chi2_red * inv
    std = np.sqrt(np.where(np.diag(cov) >= 0, np.diag(cov), np.nan))
    return at_bound, cov, std, chi2_red


def fit_curve(model: str, v: FloatArray, f: FloatArray, sigma: FloatArray | None = None, *,
              speed_range: tuple[float, float] | None = None, start: FloatArray | None = None) -> CurveFit:
    """Fit ``model`` to points ``(v, f)`` with uncertainties ``sigma`` (see the module docstring).

    Parameters
    ----------
    model : str
        A key of :data:`MODELS`.
    v, f : arrays (m,)
        Speeds (> 0) [rad/s or m/s] and friction [N·m or N].
    sigma : array (m,), optional
        Uncertainty of each point (relative weights); default equal weights. Values below
        1e-3 of their median are raised to it (noise-free points have a spread of round-off).
    speed_range : (v_min, v_max), optional
        The speeds that set the bounds and the start grid in place of the points' smallest and
        largest (samples of a motion, :mod:`dynid.pipeline.hierarchical`, come as close to 0 as
        the sampling makes them: the grid would then sit at absurd smoothing coefficients).
    start : array (p,), optional
        One starting point (a previous fit: warm start) in place of the grid.
    """
    if model not in MODELS:
        raise InputError(f"unknown friction model {model!r}; one of {list(MODELS)}")
    v, f = np.asarray(v, dtype=float), np.asarray(f, dtype=float)
    names = MODELS[model]
    m, p = v.size, len(names)
    if m < p:
        raise InputError(f"{model}: {m} friction points for {p} coefficients ({', '.join(names)}); test more speeds")
    if np.any(v <= 0) or not np.all(np.isfinite(f)):
        raise InputError(f"{model}: speeds must be positive and friction finite")
    s = np.ones(m) if sigma is None else np.asarray(sigma, dtype=float)
    floor = max(1e-3 * float(np.median(s)), 1e-12 * max(float(np.abs(f).max()), 1.0), 1e-300)
    w = 1.0 / np.maximum(s, floor)
    lo, hi = _bounds(names, v, speed_range)

    def resid(x):
        return (curve_force(model, x, v) - f) * w

    def jac(x):
        return curve_jacobian(model, x, v) * w[:, None]

    best = None
    starts = ([np.asarray(start, dtype=float)] if start is not None
              else _starts(model, v, f, w, lo, hi, speed_range=speed_range))
    for x0 in starts:
        x0 = np.minimum(np.maximum(x0, lo), hi)  # trf moves a start on a bound strictly inside
        res = least_squares(resid, x0, bounds=(lo, hi), method="trf", x_scale="jac", xtol=scaled(1e-12), ftol=scaled(1e-12), gtol=scaled(1e-12),
                            max_nfev=2000 * p, jac=jac)
        if best is None or res.cost < best.cost:
            best = res
    x = best.x
    at_bound, cov, std, chi2_red = fit_statistics(resid, x, lo, hi)
    rmse = float(np.sqrt(np.mean((curve_force(model, x, v) - f) ** 2)))
    return CurveFit(model=model, names=names, params=x, std=std, at_bound=at_bound, cov=cov, rmse=rmse,
                    chi2_red=chi2_red, n_points=m, success=bool(best.success), message=str(best.message))


def held_out_split(speed_cmd: FloatArray, repetition: FloatArray, rule: str) -> np.ndarray:
    """Which points are held out (True) for one joint: ``"alternate_speeds"``: every other
    commanded speed level in increasing order, from the second (the lowest and the highest
    level of an odd count stay in the fit); ``"last_repetition"``: the points of the last
    repetition (needs two or more)."""
    speed_cmd, repetition = np.asarray(speed_cmd, dtype=float), np.asarray(repetition)
    if rule == "alternate_speeds":
        levels = np.unique(speed_cmd)
        held = levels[1::2]
        return np.isin(speed_cmd, held)
    if rule == "last_repetition":
        if np.unique(repetition).size < 2:
            raise InputError("held_out = 'last_repetition' needs two or more repetitions of the cycles")
        return repetition == repetition.max()
    raise InputError(f"unknown held-out rule {rule!r}")
