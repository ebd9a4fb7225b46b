"""Kalman-filter identification: ``[identification] method = "ekf"`` and ``method = "ukf"``.

The base parameters are estimated with the actuator motion by one square-root Kalman filter
over the processed training log, the extended (EKF: Gautier & Poignet 2001, "Extended Kalman
filtering and weighted least squares dynamic identification of robot", *Control Engineering
Practice* 9(12)) or the unscented one (UKF: Julier & Uhlmann 1997 and 2004; square-root form of
van der Merwe & Wan 2001, ICASSP), both in the array form of Kailath, Sayed & Hassibi 2000
(*Linear Estimation*): the filters themselves are :mod:`dynid.estimation.kalman_filters`.
Leboutet et al. 2021 ("Inertial parameter identification in robotics: a survey", *Applied
Sciences* 11(9), the survey behind BIRDy) compare these filters with the least-squares family.

The model (one for serial and parallel robots: the :class:`~dynid.model.system.System` rows,
no forward dynamics)
------------------------------------------------------------------------------------------

* State :math:`x_k = (s_k, \\beta)`: :math:`s_k` the kinematic state of each actuator coordinate
  in the white-snap model of the Kalman smoother (:mod:`dynid.signals.kalman`, ``processing.derivatives
  = "kalman"``: :math:`(q, T\\dot q, T^2\\ddot q, T^3 \\dddot q)`, scaled as there), :math:`\\beta`
  the base parameters, constant (no process noise).
* Process: :math:`s_{k+1} = F s_k + w_k` per coordinate, with :math:`F` and :math:`Q` of
  :func:`dynid.signals.kalman._model` scaled by :math:`q T^{7} = R_j / \\lambda_j`, the noise ratio
  :math:`\\lambda_j` and position noise :math:`R_j` of coordinate :math:`j` estimated by maximum
  likelihood from its own positions (:func:`dynid.signals.kalman.fit_noise_ratio`): the process and
  measurement noise are the log's own estimates.
* Measurement: :math:`z_k = (q_k, y_k)` with :math:`h(x_k) = (q(s_k), W(q_k, \\dot q_k, \\ddot q_k)\\beta)`,
  :math:`W` the system's base-regressor rows at the kinematic state (a serial arm's joint-torque
  regressor; a closed chain's actuator-space rows through its loop closures, ``System.rows``) and
  :math:`y_k` the measured forces of that sample (a redundantly actuated mechanism's outputs, the
  projected equations or an assumed force distribution, taken at the processed states). The
  force noise variance of each channel is the residual variance of a WLS fit on the same
  processed log (its rows at the processed derivatives; the result says so).
* EKF: the Jacobian of :math:`W\\beta` in :math:`(q, \\dot q, \\ddot q)` (the jerk does not enter) by
  central differences, the :math:`1 + 6 n_a` states in one batched call of the rows per step;
  in :math:`\\beta` it is :math:`W` itself. UKF: the measurement is linear in :math:`\\beta`, so the
  sigma points span the kinematic state only (:math:`2 \\cdot 4 n_a` of them, one batched call per
  step) and :math:`\\beta` is integrated exactly given them (the partially linear update of
  :mod:`dynid.estimation.kalman_filters`). The plain :math:`2L`-point transform over the whole state
  left out the product of the kinematic and parameter uncertainties and was optimistic on a fast
  motion (the truth's chi-square 67.6 to 5.1e5 for 22 parameters in four draws on the serial arm of
  tests/test_every_method_contract.py; now 21.7 to 22.9 in three, as the EKF, the fourth below).
* Start: :math:`s_0` from the smoother's start (a polynomial fit of the first samples,
  :func:`dynid.signals.kalman._start`) with its steady-state a-priori covariance;
  :math:`\\beta_0` the nominal base parameters with the diagonal prior of standard deviation
  :math:`\\max(|\\beta_{nom}|, |\\beta_{WLS}|, 10\\,\\sigma_{WLS})` (:data:`PRIOR_FACTOR` = 1; the WLS
  estimate and standard error of the same fit): a 100 % relative prior and at least 10 standard
  errors wide, so its information is at most 1 % of the data's in any parameter and it moves the
  estimate by about 1 % of a standard error or less. The result reports it (``solver["prior"]``).
* Second-order term (EKF): the measurement is bilinear in the kinematic state and the parameters
  (:math:`W(u)\\beta`); the first-order EKF leaves out the product of their uncertainties, which
  is large while the parameters are uncertain, and its covariance then misses the truth (with a
  10 times wider prior, a chi-square of 125 for 22 parameters in one simulated draw, 24 with the
  terms). The EKF here adds the Gaussian
  second-order terms of the mixed Hessian :math:`\\partial W/\\partial u` (the same central
  differences): a mean shift and an added innovation covariance
  (:func:`dynid.estimation.kalman_filters.bilinear_second_order`); the UKF's partially linear
  update integrates them (the plain unscented transform does not: above).
* Consistency (NIS test): the innovations' normalized mean square per channel over the steps after
  the start is checked against :func:`dynid.estimation.kalman_filters.nis_bound` (false alarm
  :data:`NIS_FALSE_ALARM` over all channels). A filter above it on any channel has diverged or its
  model does not hold: the result then reports **no covariance** and a note with the figures
  (``solver["nis_test"]``), rather than an interval. Both filters can still diverge from the wide
  prior on a fast motion (one draw of four on the serial arm of
  tests/test_every_method_contract.py: normalized mean squares 596 and 644 on a position channel;
  with a 10 % prior the same draw converges and covers).
* Coulomb friction: the filters' rows use the smooth sign :math:`\\mathrm{erf}(v/(\\sqrt 2 w))`
  with :math:`w` the velocity standard deviation of the position-only steady-state filter (the
  expected sign over the velocity's uncertainty; the EKF's central differences across a hard sign
  would give unbounded Jacobians). Near the reversals neither filter describes the sign's jump:
  on the simulated arm of the tests with Coulomb friction (three draws, 25 parameters) the EKF's
  covariance was optimistic in two (the truth's chi-square 55 and 243; innovations' normalized
  mean square up to 2), the UKF's held (25 to 41); with the hard sign the EKF's was far off
  (224 to 884). A limit, stated in the result's notes. With the partially linear UKF and the NIS
  test (three other draws of that arm, 2000 samples, bound 1.124): EKF 69.8, 51.9, 26.4 with
  normalized mean squares 3.9, 2.8, 1.4, so no covariance is reported on any; UKF 25.9, 15.8, 29.0
  (bound 52.6) with 1.08, 1.15, 1.12, so the second's, which covers, is withheld as well.

Which samples
-------------
The filter needs a uniformly sampled sequence: it runs over the **processed** training log
(after its low-pass, resampling, ``decimate`` by sample picking and trimming) at the processed
rate, with the processed sample period as :math:`T`, **before** any row selection
(``min_velocity``, ``reversal_guard``): a row selection leaves gaps that the white-snap process
model would have to bridge. The processed positions are the position measurements (a low-pass
makes their noise coloured; the noise ratio fit absorbs part of it), the measured forces are
taken as processed. ``decimate_method = "parallel"`` is refused (it filters the regressor rows, not
the log: there is no processed sequence of forces and states to filter).

Result
------
:class:`~dynid.estimation.results.IdentificationResult` with method ``"EKF"`` or ``"UKF"``: the
final :math:`\\beta`, the :math:`\\beta` block of the final :math:`S^T S` as its covariance (it
assumes the model's noise levels and the filter's linearization: the notes say so; none when the
innovations fail the NIS test), per-channel
training residuals of the rows at the processed derivatives (as the other methods), the force
noise used, and in ``solver`` the prior, the noise estimates, the time steps and the innovations'
normalized mean square per channel (near 1 when the filter is consistent).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.dataset import Dataset
from dynid.errors import ConfigError, IdentifiabilityError, InputError
from dynid.estimation.kalman_filters import KINDS, bilinear_second_order, nis_bound, root, run
from dynid.estimation.results import IdentificationResult
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System
from dynid.signals.kalman import ORDER, _model, _start, fit_noise_ratio, steady_state

__all__ = ["PRIOR_FACTOR", "NIS_FALSE_ALARM", "kalman_identify", "kalman_estimate"]

PRIOR_FACTOR = 1.0
"""The prior standard deviation of each base parameter, in units of the largest of its nominal value,
its WLS estimate and 10 WLS standard errors (module docstring): a 100 % prior, at least 10 standard
errors wide. A 10 times wider one was tried on the simulated arm of tests/test_kalman_estimators.py:
the first samples, linearized far from the estimate, then bias both filters (the truth's chi-square
50 to 136 for 22 parameters in three draws, against 22 to 29 with this one)."""
NIS_FALSE_ALARM = 1e-3
"""The false-alarm rate of the innovations' consistency test (:func:`dynid.estimation.kalman_filters.nis_bound`):
a filter whose normalized innovation mean square exceeds its bound on any channel reports no covariance."""
UNIFORM_RTOL = 1e-3
"""The largest relative deviation of a sample interval from the median the filter accepts."""
FD_STEP = 6e-6
"""Central-difference step of the EKF's Jacobian, relative to max(|u|, 1) for each input u (about
eps^(1/3): truncation and rounding errors balanced)."""


def _wls(W: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """OLS, then WLS with the per-channel residual variances (paper 001 Eqs. 14-16): the estimate,
    its covariance, the channels' noise std and the whitened regressor's condition number."""
    N, n_ch, p = W.shape
    if N * n_ch <= p:
        raise IdentifiabilityError(f"{N * n_ch} equations for {p} base parameters")

    def fit(w):
        A = (W * w[None, :, None]).reshape(-1, p)
        b = (y * w[None, :]).reshape(-1)
        beta, *_ = np.linalg.lstsq(A, b, rcond=None)
        r = y - np.einsum("ncp,p->nc", W, beta)
        dof = max(N - p / n_ch, 1.0)
        return beta, np.sqrt(np.sum(r * r, axis=0) / dof), A

    beta, sig, _ = fit(np.ones(n_ch))
    if not np.all(sig > 0):
        raise IdentifiabilityError("a force channel is fitted exactly by the rows: no noise level to weigh it by")
    beta, sig, A = fit(1.0 / sig)
    sv = np.linalg.svd(A, compute_uv=False)
    if sv[-1] <= sv[0] * 1e-12:
        raise IdentifiabilityError("the rows of the processed log do not determine the base parameters")
    Rf = np.linalg.qr(A, mode="r")  # A is whitened by the OLS noise levels: cov = (A^T A)^-1
    Ri = np.linalg.inv(Rf)
    return beta, Ri @ Ri.T, sig, float(sv[0] / sv[-1])


def kalman_identify(kind: str, system: System, base: BaseParameters, ds: Dataset, force_model: str | None = None, *,
                    order: int = ORDER, progress: Callable[[str, int, int], None] | None = None,
                    position_noise_std: FloatArray | None = None, second_order: bool = True,
                    smooth_coulomb: bool = True) -> tuple[IdentificationResult, float]:
    """Identify the base parameters of ``system`` from the processed log ``ds`` (uniformly sampled,
    with ``dq`` and ``ddq``) by the square-root EKF or UKF (module docstring). Returns the result
    and the largest RMS inconsistency of redundant actuator positions (0 otherwise).
    ``position_noise_std`` (n_a,): given position noise instead of its estimate; ``second_order``
    (EKF): the Gaussian second-order terms of the bilinear rows; ``smooth_coulomb``: Coulomb signs
    smoothed over the velocity's uncertainty (both module docstring; False only to study them)."""
    if kind not in KINDS:
        raise InputError(f"kind must be one of {KINDS}, got {kind!r}")
    t0 = time.perf_counter()
    if ds.dq is None or ds.ddq is None:
        raise InputError("the dataset has no velocities/accelerations; preprocess it first")
    N, n_a = ds.q.shape
    if N < 20:
        raise InputError(f"the Kalman estimators need at least 20 processed samples, got {N}")
    dt = np.diff(ds.t)
    T = float(np.median(dt))
    if not np.all(np.abs(dt - T) <= UNIFORM_RTOL * T):
        raise InputError(f"method {kind!r} needs a uniformly sampled processed log: sample intervals from "
                         f"{dt.min():.6g} "
                         f"to {dt.max():.6g} s (resample it: processing.resample)")
    rows = system.rows(force_model)
    zeros = np.zeros((1, n_a))

    # WLS on the processed rows: the force noise and the prior's scale
    r0 = rows(ds.q, ds.dq, ds.ddq, ds.tau, 0)
    Wd, y = base.regressor(r0.W), np.asarray(r0.y, dtype=float)
    worst = float(np.max(r0.inconsistency)) if r0.inconsistency.size else 0.0
    beta_w, cov_w, sig_f, cond = _wls(Wd, y)
    n_ch, p = y.shape[1], base.n_base
    # the kinematic model per coordinate (the smoother's), its noise from the positions
    F1, Q1, _ = _model(order)
    ns = order * n_a
    n = ns + p
    ratio, Rpos, vel_std, x0, S0 = np.empty(n_a), np.empty(n_a), np.empty(n_a), np.zeros(n), np.zeros((n, n))
    F, Qh = np.eye(n), np.zeros((ns, n))
    for j in range(n_a):
        given = None if position_noise_std is None else float(position_noise_std[j]) ** 2
        ratio[j], Rpos[j] = fit_noise_ratio(ds.q[:, j], given, order)
        ss = steady_state(ratio[j], order)
        scale = Rpos[j] / ratio[j]  # q T^(2 order - 1)
        b = slice(order * j, order * (j + 1))
        F[b, b] = F1
        Qh[b, b] = root(Q1 * scale)
        x0[b] = F1 @ _start(ds.q[:, j:j + 1], ss)[:, 0]  # the a-priori state of sample 0
        S0[b, b] = root(ss.P * scale)
        Pf = ss.P - np.outer(ss.K, ss.P[0])  # the filtered (a-posteriori) covariance from the positions
        vel_std[j] = np.sqrt(Pf[1, 1] * scale) / T
    # the filter's rows: a Coulomb term's sign smoothed over the velocity's uncertainty (its expected value)
    coulomb = any(nm.startswith("fc") for nm in system.parameter_names)
    frows = rows
    if smooth_coulomb and coulomb:
        try:
            frows = system.with_coulomb_width(tuple(vel_std)).rows(force_model)
        except ConfigError:  # a mechanism whose chart takes no smoothing: the sign itself
            pass

    def regress(q: FloatArray, dq: FloatArray, ddq: FloatArray, start: int = 0) -> tuple[FloatArray, Any]:
        r = frows(q, dq, ddq, np.broadcast_to(zeros, q.shape), start)
        return base.regressor(r.W), r

    beta_nom = base.from_standard(system.nominal_parameters())
    prior_std = PRIOR_FACTOR * np.maximum.reduce([np.abs(beta_nom), np.abs(beta_w), 10.0 * np.sqrt(np.diag(cov_w))])
    x0[ns:] = beta_nom
    S0[ns:, ns:] = np.diag(prior_std)
    Rh = np.diag(np.concatenate([np.sqrt(Rpos), sig_f]))
    z = np.column_stack([ds.q, y])
    pos = np.arange(n_a) * order
    scales = np.array([1.0, 1.0 / T, 1.0 / T**2])

    def kinematics(X: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        Xs = X[:, :ns].reshape(-1, n_a, order)
        return Xs[:, :, 0], Xs[:, :, 1] / T, Xs[:, :, 2] / T**2

    def measure(k: int, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        q, dq, ddq = kinematics(X)
        W, _ = regress(q, dq, ddq, k)
        Hb = np.concatenate([np.zeros((X.shape[0], n_a, p)), W], axis=1)
        return np.column_stack([q, np.einsum("bcp,bp->bc", W, X[:, ns:])]), Hb

    cols_u = np.concatenate([pos + d for d in range(3)])  # the state entries of (q, dq, ddq), in that order
    scale_u = np.repeat(scales, n_a)

    def linearize(k: int, x: FloatArray, S: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        q, dq, ddq = (v[0] for v in kinematics(x[None]))
        u = np.concatenate([q, dq, ddq])
        h = FD_STEP * np.maximum(np.abs(u), 1.0)
        U = np.repeat(u[None], 1 + 6 * n_a, axis=0)
        idx = np.arange(3 * n_a)
        U[1 + idx, idx] += h
        U[1 + 3 * n_a + idx, idx] -= h
        W, _ = regress(U[:, :n_a], U[:, n_a:2 * n_a], U[:, 2 * n_a:], k)
        f = W @ x[ns:]  # (b, n_ch)
        J = ((f[1:1 + 3 * n_a] - f[1 + 3 * n_a:]) / (2 * h)[:, None]).T  # (n_ch, 3 n_a): d f / d(q, dq, ddq)
        H = np.zeros((n_a + n_ch, n))
        H[np.arange(n_a), pos] = 1.0
        for d in range(3):  # q, dq, ddq from the scaled state entries 0, 1, 2
            H[n_a:, pos + d] = J[:, d * n_a:(d + 1) * n_a] * scales[d]
        H[n_a:, ns:] = W[0]
        hx = np.concatenate([q, f[0]])
        if not second_order:
            return hx, H, None
        G = (W[1:1 + 3 * n_a] - W[1 + 3 * n_a:]) / (2 * h)[:, None, None]  # dW/du (3 n_a, n_ch, p)
        shift, root2 = bilinear_second_order(S[:, cols_u] * scale_u, S[:, ns:], G)
        hx[n_a:] += shift
        extra = np.zeros((n_ch, n_a + n_ch))
        extra[:, n_a:] = root2
        return hx, H, extra

    def tick(done: int, total: int) -> None:
        if progress is not None:
            progress(kind, done, total)

    skip = min(N // 10, 200)
    fr = run(kind, z, x0, S0, F, Qh, Rh, linearize=linearize, measure=measure, skip=skip, progress=tick,
             linear=p if kind == "ukf" else 0)
    bound = nis_bound(N - skip, n_a + n_ch, NIS_FALSE_ALARM)
    consistent = bool(np.all(fr.nis <= bound))
    beta = fr.x[ns:]
    Sb = fr.S[:, ns:]
    cov = Sb.T @ Sb
    r = y - np.einsum("ncp,p->nc", Wd, beta)
    channels = system.channel_names(force_model)
    names = list(channels)
    solver = {
        "filter": f"square-root {kind.upper()} (array form), joint state (white-snap kinematics of order {order} per "
                  "actuator coordinate) and base parameters",
        "time_steps": int(N), "sample_period_s": T, "state_size": int(n),
        "prior": {"center": "nominal base parameters",
                  "std": prior_std.tolist(),
                  "rule": f"{PRIOR_FACTOR:g} x max(|nominal|, |WLS|, 10 WLS standard errors) per parameter"},
        "position_noise_std": np.sqrt(Rpos).tolist(),
        "position_noise_source": "given" if position_noise_std is not None else
                                 "maximum likelihood from the log's positions (dynid.signals.kalman.fit_noise_ratio)",
        "noise_ratio": ratio.tolist(),
        "force_noise_std": sig_f.tolist(),
        "force_noise_source": "residuals of a WLS fit on the same processed log (rows at the processed derivatives)",
        "innovation_nms": {**{f"q_{a}": float(v) for a, v in zip(system.actuator_names, fr.nis[:n_a])},
                           **{c: float(v) for c, v in zip(names, fr.nis[n_a:])}},
        "nis_test": {"bound": bound, "false_alarm": NIS_FALSE_ALARM, "steps": int(N - skip), "passed": consistent},
        "wls_params": beta_w.tolist(),
        "seconds": time.perf_counter() - t0,
    }
    if kind == "ukf":
        solver["unscented"] = {"alpha": 1.0, "beta": 0.0, "kappa": 0.0, "sigma_points": 2 * ns,
                               "weights": "centre 0, others 1/(2 n_u): all non-negative",
                               "linear_part": "base parameters integrated exactly given the kinematic sigma points "
                                              "(partially linear update)"}
    notes = (
        f"{kind.upper()} covariance: the parameter block of the filter's final covariance; it assumes the model's "
        "noise "
        "levels (position noise and process noise by maximum likelihood from the positions, force noise from WLS "
        "residuals on the same log) and the filter's " + ("first-order linearization" if kind == "ekf" else
                                                          "unscented transform") +
        "; solver['innovation_nms'] near 1 per channel checks them",
        f"{kind.upper()} ran over the processed training log before row selection, {N} samples at T = {T:.6g} s "
        f"(a filter needs the uniformly sampled sequence); prior: nominal base parameters, std "
        f"{PRIOR_FACTOR:g} x max(|nominal|, |WLS|, 10 WLS standard errors)",
    )
    if coulomb:
        notes += (f"{kind.upper()} with Coulomb friction: the filter's rows use the sign smoothed over the velocity's "
                  "uncertainty, and near the reversals no linearization describes its jump: the covariance is "
                  "optimistic there (see solver['innovation_nms'])",)
    if not consistent:
        worst_ch = max(solver["innovation_nms"].items(), key=lambda kv: kv[1])
        notes += (f"{kind.upper()} innovations inconsistent with the filter's covariance: normalized mean square "
                  f"{worst_ch[1]:.3g} on {worst_ch[0]} above the NIS test's bound {bound:.3g} (false alarm "
                  f"{NIS_FALSE_ALARM:g}): the filter diverged or its model does not hold, so no covariance is "
                  "reported (solver['innovation_nms'], solver['nis_test'])",)
    result = IdentificationResult(
        method=kind.upper(), names=base.names, params=beta,
        cov_params=0.5 * (cov + cov.T) if consistent else None, dof=int(N * n_ch - p),
        scale=1.0, channel_names=tuple(channels), n_obs=np.full(n_ch, N), rss_per_channel=np.sum(r * r, axis=0),
        noise_std=sig_f, condition_number=cond, expressions=base.expressions(), solver=solver, notes=notes)
    return result, worst


def kalman_estimate(cfg: Any, system: System, base: BaseParameters, train: Dataset, force_model: str | None,
                    progress: Callable[[str, int, int], None] | None = None) -> tuple[IdentificationResult, float]:
    """The pipeline's ``method = "ekf"`` / ``"ukf"`` on the processed training log (module docstring)."""
    pcfg = cfg.processing
    if pcfg.periodic is not None:
        raise ConfigError(f"identification.method = {cfg.identification.method!r} filters the log sample by sample; "
                          "processing.periodic replaces it by one averaged period: use time-domain processing")
    if pcfg.decimate > 1 and pcfg.decimate_method == "parallel":
        raise ConfigError(f"identification.method = {cfg.identification.method!r} filters the processed log sample by "
                          "sample; processing.decimate_method = 'parallel' filters the regressor rows instead: use "
                          "decimate_method = 'samples'")
    given = None
    if getattr(pcfg, "position_noise_std", None) is not None:
        given = np.broadcast_to(np.asarray(pcfg.position_noise_std, dtype=float), (system.n_actuators,))
    return kalman_identify(cfg.identification.method, system, base, train, force_model, progress=progress,
                           position_noise_std=given)
