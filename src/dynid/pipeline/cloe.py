r"""CLOE: the closed-loop output error of the *positions* (``method = "cloe"``).

What it minimises. The training experiment is replayed on the model with the estimate
:math:`\beta` under the experiment's controller, gains and reference
(``identification.experiment``, exactly as IDIM-IV and DIDIM replay it:
:mod:`dynid.pipeline.control_loop`), and CLOE chooses :math:`\beta` to minimise

.. math:: V(\beta) = \sum_j w_j \sum_i \big(q_{m,j}(t_i) - q_{s,j}(t_i; \beta)\big)^2,

the measured actuator positions of the processed training log (``train.q`` at the processed
instants :math:`t_i`, actuator side) minus the replayed actuator positions interpolated at the same
instants (the replay's positions go through the log's ``processing.lowpass`` at the simulation's
rate, so that both sides are filtered alike), actuator by actuator; the weights
:math:`w_j = 1 / s_j^2` are fixed at the start (:math:`s_j` the RMS of actuator :math:`j`'s output
error there: they only make the actuators' units commensurate, and fixed weights keep the cost one
function for the whole run). Every processed instant is used (no ``min_velocity`` row selection:
an output error on the positions has no rows to reject at reversals). This is the output-error
member of Landau's closed-loop family (CLOE: Landau & Karimi, "Recursive algorithms for
identification in closed loop: a unified approach and evaluation", Automatica 33(5), 1997), which
Gautier, Janot & Vandanjon ("A new closed-loop output error method for parameter identification of
robot dynamics", IEEE TCST 21(2), 2013) compare with DIDIM: DIDIM takes the output error of the
*forces* and approximates the Gauss-Newton Jacobian by the simulated regressor; CLOE takes that of
the positions and needs the sensitivities :math:`\partial q_s / \partial\beta`, which the replays give
only by finite differences, one replay per estimated direction.

Directions. As DIDIM does, the estimated directions are fixed once, at the start's replay (the
nominal model by default, or the WLS estimate with ``start = "wls"``): those of the column-scaled
simulated-regressor Gram :math:`\sum_j w_j W_{s,j}^T W_{s,j}` with singular values above
``directions_rtol`` (default 1e-6) of the largest
(:func:`dynid.pipeline.control_loop.output_error_directions`); :math:`\beta = \beta_0 + T_V c`, the
others held at the start's values (a note says how many). The coordinates are scaled by the
standard deviations :math:`\sigma_c` of :math:`c` from the DIDIM regression at the start's replay
(measured forces on the replayed regressor, WLS), :math:`x = c / \sigma_c`, with each force channel's
error standard deviation taken as at least ``_FORCE_FLOOR`` = 1e-3 of that channel's RMS force
(:func:`_coordinate_scale`). Why the floor: where the forces carry no error the start's regression fits
them to rounding, and so do its standard deviations. On the 1-turn shang2dof twin with white position
noise only and the truth as start (tests/test_every_method_contract.py), the force residuals were
3e-13 N m, the finite-difference step below moved the parameters by 1e-15 to 3e-14, the replayed
positions changed by 1e-15 rad (rounding) and the "Jacobian" was that rounding: rank 9 of 17
(singular values past the 9th below 6e-37 of the largest; 12 of 25 with the default
``directions_rtol``), which the covariance's pseudo-inverse turned into 8 directions known exactly.
Nothing structural: with the floor (the step then moves the parameters by 3e-5 to 9e-4 there) the
columns scale with the step and keep their direction (cosine 1.0000) from a floor of 1e-4 to 1e-3,
the Jacobian in the scaled coordinates has a condition number of 1.8, and the truth's statistic is
16.9 to 19.9 for 17 directions on three draws (bound 40.8; a fourth draw, see
tests/test_every_method_contract.py); at a floor of 1e-2 nine of the 17 columns turn (cosines -0.26
to 0.71: the Coulomb jumps below). With a force error above the floor (model error or force noise of
more than 1e-3 of the forces, the usual case) the scale is the regression's, as before.

Jacobian. Forward differences of replays along the fixed directions, step ``_FD_STEP`` = 0.5 in
:math:`x` (half a standard deviation of the force regression). Why that size: the replay is not a
smooth function of :math:`\beta` at small scales where it simulates the discontinuous Coulomb law
(``replay_coulomb_band = 0``, the default: the explicit integrator chatters about zero velocity, so
the replayed motion jumps by amounts that do not shrink with the perturbation), and a difference over
a tiny step then measures those jumps, not the slope (and a step that moves no replayed position by
more than ``_RESOLUTION`` = 1e4 ulps of the largest measured position, 2.2e-12 of it, measures only
the replay's rounding: refused with a one-line error); it must not be so large that the curvature
(and the jumps met on the way) dominates either. Measured at the start of the 1-turn shang2dof twin
(tests/test_cloe.py; the 25 columns compared with those of step 0.5): with the discontinuous law, 23
columns agree to a cosine above 0.99 for every step from 0.004 to 0.5 standard deviations, 2 do not
(cosines 0.36 to 0.54 between the steps at or below 0.1 and 0.5: a jump within half a standard
deviation), and at a step of 2 ten columns turn by more than 0.01 (the cosine of one falls to
0.06); with ``replay_coulomb_band = 0.05`` every column agrees to 1e-3 in norm and direction from
0.004 to 2 standard deviations (a smooth replay). Half a standard deviation is the largest step
that keeps the curvature's share small on that twin; with the smooth replay the step hardly
matters. The smooth replay is nevertheless not the default: CLOE is an output-error method, and a
replay law other than the data's is a model error it fits (DIDIM's reason, control_loop's
docstring). On the 1-turn twin with ``replay_coulomb_band = 0.05`` CLOE converged in 113 replays but
predicted the held-out path no better than the nominal model (mean relative RMSE 9.97 % against
9.85 %); with the data's law, 248 replays and 6.2 %.

Levenberg-Marquardt (:func:`levenberg_marquardt`, Marquardt's scaling by the diagonal of
:math:`J^T J`): a trial step that does not lower :math:`V` is rejected and :math:`\lambda` multiplied
by 10 (divided by 10 after an accepted step); a trial whose replay fails (no positive-definite mass
matrix, a diverging motion) is treated like a rejection (a shorter, more gradient-like step, as
:func:`~dynid.pipeline.control_loop._simulate_or_halve` halves it), and after ``_HALVINGS`` + 1
failures in a row the run stops with the simulator's cause. Stopping rule, after an accepted step:
no direction moved by more than ``tolerance`` of its standard deviation (from
:math:`s^2 (J^T J)^{-1}` in the weighted metric, :math:`s^2` the weighted residual variance), or the
relative decrease of :math:`V` below ``_COST_RTOL`` = 1e-6 (converged); or ``_MAX_REJECTIONS`` = 6
rejections in a row (:math:`\lambda` up by 1e6: no step along the gradient lowers the cost at the
replay's resolution; converged at a minimum); or ``max_iterations`` (not converged). Cost per
iteration: one replay for each trial step (1 when accepted at once) plus one per estimated direction
for the Jacobian at the accepted iterate (``solver["iterations"][k]["replays"]``); a 25-parameter
mechanism costs 26 replays per iteration where DIDIM costs one.

Covariance: :math:`\Sigma_x = (\sum_j J_j^T J_j / \sigma_j^2)^{-1}` (:math:`J_j` the sensitivities of
actuator :math:`j`'s positions, :math:`\sigma_j^2` its output-error variance at the estimate, on
:math:`n - r / n_a` degrees of freedom; the sandwich of :func:`output_error_covariance` where the fixed
weights are not proportional to :math:`1 / \sigma_j^2`), mapped through the directions:
:math:`\mathrm{cov}(\hat\beta) = T_V \,\mathrm{diag}(\sigma_c)\, \Sigma_x \,\mathrm{diag}(\sigma_c)\, T_V^T`
(zero along the held directions: conditional on them). A Jacobian whose column-scaled numerical
rank (numpy's ``matrix_rank`` tolerance) is below the number of estimated directions leaves some
without information: the covariance is refused with a one-line error (raise ``directions_rtol``), never
a pseudo-inverse that reports them as exact. The Jacobian is the last one evaluated, at
the iterate before the last accepted step (which moved less than ``tolerance`` of a standard
deviation when converged). It assumes white position output errors, independent from sample to
sample: the closed loop's response to the force noise and the model error are coloured, which makes
it optimistic (a note says so). Found, not understood: from a 10 % perturbed truth with white position
noise only (its assumptions), CLOE ends at estimates that fit the positions to about the noise but lie
far outside their intervals (the truth's statistic 9640 to 2.1e5 for 25 on three draws; bench/README,
Every method's contract); from the truth its intervals hold (tests/test_every_method_contract.py).

The result is a base-parameter vector like the other methods', scored on the held-out log (forces)
as DIDIM's is; its force residuals on the training log are those of the replay at the estimate.
"""

from __future__ import annotations

import collections
import dataclasses
import itertools
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from dynid.config import Config
from dynid.dataset import Dataset
from dynid.errors import ConfigError, DynidError, InputError
from dynid.estimation import WLS, IdentificationResult
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System
from dynid.pipeline.control_loop import (_HALVINGS, _experiment, _instrument_processing, _reduced_fit, _relative,
                                         _replay_rows_system, _simulated_states, output_error_directions, replay_problem)

__all__ = ["cloe_estimate", "levenberg_marquardt", "output_error_covariance", "LMResult"]

_FD_STEP = 0.5  # the finite-difference step, in standard deviations of the start's force regression (docstring)
_COST_RTOL = 1e-6  # converged when an accepted step lowers the cost by less than this fraction
_FORCE_FLOOR = 1e-3  # the least force error, of each channel's RMS force, in the coordinates' scale (docstring)
_RESOLUTION = 1e4 * np.finfo(float).eps  # a replayed position change below this share of |q| is rounding
_MAX_REJECTIONS = 6  # rejected trials in a row (lambda up by 10 each) before stopping at a minimum


@dataclasses.dataclass(frozen=True)
class LMResult:
    x: np.ndarray
    cost: float  # ||r(x)||^2
    residual: np.ndarray
    jacobian: np.ndarray  # the last one evaluated (at the iterate the last accepted step started from)
    iterations: list[dict[str, Any]]
    converged: bool
    reason: str


def levenberg_marquardt(residual: Callable[[np.ndarray], np.ndarray], jacobian: Callable[[np.ndarray, np.ndarray], np.ndarray],
                        x0, *, max_iterations: int = 10, tolerance: float = 0.5, cost_rtol: float = _COST_RTOL,
                        lam0: float = 1e-3, max_rejections: int = _MAX_REJECTIONS, failures: tuple = (),
                        max_failures: int = _HALVINGS + 1, count: Callable[[], int] | None = None,
                        r0: np.ndarray | None = None) -> LMResult:
    """Minimise ``||residual(x)||^2`` by Levenberg-Marquardt (module docstring: steps, stopping rule).

    ``jacobian(x, r)``: ``d residual / dx`` at ``x`` (``r = residual(x)``), evaluated once per accepted
    iterate (kept through rejected trials). ``failures``: exception
    types of ``residual`` at a trial point treated as a rejected step; ``max_failures`` of them in a
    row re-raise the last. ``count()``: a counter of the evaluations (recorded per iteration as
    ``replays``). ``r0``: ``residual(x0)`` if already known. The moves are in standard deviations of
    ``s^2 (J^T J)^-1``, ``s^2 = cost / (m - n)``.
    """
    count = count or (lambda: 0)
    x = np.array(x0, dtype=float)
    r = np.asarray(residual(x) if r0 is None else r0, dtype=float)
    cost = float(r @ r)
    J: np.ndarray | None = None
    lam = lam0
    history: list[dict[str, Any]] = []
    reason = f"max_iterations ({max_iterations}) reached"
    converged = False
    for k in range(1, max_iterations + 1):
        before = count()  # the replays of an iteration: its Jacobian (unless kept from a rejection) and its trials
        if J is None:
            J = np.asarray(jacobian(x, r), dtype=float)
        m, n = J.shape
        A, g = J.T @ J, J.T @ r
        D = np.maximum(np.diag(A), 1e-12 * max(float(np.max(np.diag(A))), 1e-300))
        Ainv = np.linalg.pinv(A)
        sd = np.sqrt(np.maximum(np.diag(Ainv), 0.0) * cost / max(m - n, 1))
        rejected = failed = 0
        while True:
            dx = np.linalg.solve(A + lam * np.diag(D), -g)
            try:
                r_new = np.asarray(residual(x + dx), dtype=float)
            except failures:
                failed += 1
                if failed >= max_failures:
                    raise
                lam = max(10.0 * lam, 1e-6)
                continue
            failed = 0
            c_new = float(r_new @ r_new)
            if np.isfinite(c_new) and c_new < cost:
                break
            rejected += 1
            lam = max(10.0 * lam, 1e-6)
            if rejected >= max_rejections:
                break
        if rejected >= max_rejections:
            history.append({"iteration": k, "cost": cost, "lambda": lam, "accepted": False, "max_change_in_std": 0.0,
                            "rejected": rejected, "replays": count() - before})
            converged, reason = True, f"no step lowers the cost ({rejected} rejections in a row)"
            break
        moved = float(np.max(np.abs(dx) / np.maximum(sd, 1e-300)))
        decrease = (cost - c_new) / cost if cost > 0 else 0.0
        x, r, cost = x + dx, r_new, c_new
        history.append({"iteration": k, "cost": cost, "lambda": lam, "accepted": True, "max_change_in_std": moved,
                        "rejected": rejected, "relative_decrease": decrease})
        lam = max(lam / 10.0, 1e-12)
        if moved < tolerance:
            converged, reason = True, f"no direction moved by more than {tolerance:g} of its standard deviation"
        elif decrease < cost_rtol:
            converged, reason = True, f"relative cost decrease {decrease:.3g} below {cost_rtol:g}"
        history[-1]["replays"] = count() - before
        if converged:
            break
        J_last, J = J, None
    if J is None:  # the last one evaluated (the loop ended at max_iterations after an accepted step)
        J = J_last
    return LMResult(x, cost, r, J, history, converged, reason)


def output_error_covariance(J: np.ndarray, e: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The covariance of a weighted output-error estimate (module docstring): ``J`` (n n_a, r) the
    Jacobian of the weighted residual ``(e * w).ravel()``, ``e`` (n, n_a) the output errors at the
    estimate, ``w`` (n_a,) the fixed weights. With ``sigma_j^2`` each output's error variance (on
    ``n - r / n_a`` degrees of freedom) and the output sensitivities ``S_j = J_j / w_j``, the
    sandwich ``A^-1 B A^-1``, ``A = sum_j w_j^2 S_j^T S_j``, ``B = sum_j w_j^4 sigma_j^2 S_j^T S_j``:
    ``(sum_j S_j^T S_j / sigma_j^2)^-1`` when ``w_j`` is proportional to ``1 / sigma_j``, and the
    estimator's covariance (not that of the best weighting) when the fixed weights are not. Assumes
    white errors, independent between samples and outputs. Returns ``(cov, sigma, A / s^2)``, the
    last the information matrix of the best weighting (its condition number is reported). A ``J`` of
    column-scaled numerical rank below ``r`` (numpy's ``matrix_rank`` tolerance: singular values at
    rounding level) leaves directions without information: refused (InputError), never a
    pseudo-inverse that would report them as known exactly."""
    e = np.asarray(e, dtype=float)
    n, n_a = e.shape
    r = J.shape[1]
    sigma = np.sqrt(np.sum(e**2, axis=0) / max(n - r / n_a, 1.0))
    if np.any(sigma <= 0):
        raise InputError("CLOE: zero output error on an actuator: cannot estimate its variance")
    Jw = J.reshape(n, n_a, r)
    sv = np.linalg.svd(J / np.maximum(np.linalg.norm(J, axis=0), 1e-300), compute_uv=False)
    tol = max(J.shape) * np.finfo(float).eps * sv[0]  # numpy's matrix_rank tolerance, on the column-scaled J
    if not np.all(sv > tol):
        raise InputError(f"CLOE: the position sensitivities determine only {int(np.sum(sv > tol))} of the {r} "
                         f"estimated directions (singular values of the column-scaled Jacobian down to "
                         f"{sv[-1] / sv[0]:.2g} of the largest): no covariance; raise identification.directions_rtol")
    G = np.einsum("ija,ijb->jab", Jw, Jw)  # per output: w_j^2 S_j^T S_j
    A = G.sum(axis=0)
    B = np.einsum("j,jab->ab", (w * sigma) ** 2, G)
    Ainv = np.linalg.pinv(A)
    cov = Ainv @ B @ Ainv
    info = np.einsum("j,jab->ab", 1.0 / (w * sigma) ** 2, G)
    return 0.5 * (cov + cov.T), sigma, info


def _coordinate_scale(problem, fit, TV: np.ndarray) -> np.ndarray:
    """The scale :math:`\\sigma_c` of the coordinates (module docstring, Directions): the standard
    deviations of ``c`` in the start's force regression (``fit``, WLS on ``problem`` along ``TV``)
    with each channel's error standard deviation at least ``_FORCE_FLOOR`` of that channel's RMS force,
    :math:`(\\sum_j (R_j T_V)^T R_j T_V / \\max(s_j, \\rho\\,\\mathrm{rms}_j)^2)^{-1}`."""
    p = problem.n_params
    s = np.asarray(fit.noise_std, dtype=float)
    rms = np.linalg.norm(problem.factors[:, : p + 1, p], axis=1) / np.sqrt(np.maximum(problem.n_obs, 1))
    s = np.maximum(s, _FORCE_FLOOR * rms)
    X = np.einsum("jik,kl->jil", problem.factors[:, :p, :p], TV)
    info = np.einsum("j,jia,jib->ab", 1.0 / s**2, X, X)
    return np.sqrt(np.maximum(np.diag(np.linalg.pinv(info)), 1e-300))


def _positions_like_the_log(pcfg):
    """The replay's positions through the log's ``processing.lowpass`` (velocities and accelerations
    exact, for the start's DIDIM regression); None without a low-pass."""
    if pcfg.lowpass is None:
        return None
    process = _instrument_processing(pcfg)
    return lambda ts, q, dq, ddq: (process(ts, q, dq, ddq)[0], dq, ddq)


def cloe_estimate(cfg: Config, system: System, base: BaseParameters, train: Dataset, force_model: str | None,
                  start: IdentificationResult | None, chunks, mask_of, meta: dict, progress) -> IdentificationResult:
    """CLOE (module docstring) on the processed training log ``train``; the arguments as
    :func:`dynid.pipeline.control_loop.control_loop_estimate`'s."""
    icfg = cfg.identification
    t0 = time.perf_counter()
    exp = _experiment(cfg, system)
    nominal_std = system.nominal_parameters()
    channels = system.channel_names(force_model)
    beta0 = np.array(start.params if start is not None else base.from_standard(nominal_std), dtype=float)
    band = icfg.replay_coulomb_band * float(np.max(np.abs(np.asarray(train.dq, dtype=float)))) or None
    rows_system = _replay_rows_system(system, band)
    process = _positions_like_the_log(cfg.processing)
    t = np.asarray(train.t, dtype=float)
    qm = np.asarray(train.q, dtype=float)
    replays = [0]
    cache: collections.OrderedDict = collections.OrderedDict()  # the last replays (the estimate's rows at the end)

    def replay(beta: np.ndarray):
        replays[0] += 1
        states = _simulated_states(exp, system.expand_parameters(base.to_standard(beta, nominal_std)), t, process, band)
        cache[beta.tobytes()] = states
        while len(cache) > 4:
            cache.popitem(last=False)
        return states

    try:
        states0 = replay(beta0)
    except ConfigError:
        raise
    except (DynidError, FloatingPointError, RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        raise InputError(f"identification: the experiment replayed with the start ({icfg.start}) does not simulate "
                         f"({exc}); try start = 'nominal'") from exc
    if states0[0].shape != qm.shape:
        raise InputError(f"identification: the replay gives {states0[0].shape[1]} actuator positions, the log "
                         f"{qm.shape[1]}")
    progress("CLOE iterations", 0, icfg.max_iterations)
    # the start's DIDIM regression: the fixed directions and the scale of the coordinates
    measured = ([(None, mask_of(cm)) for cm in chunks(train)] if mask_of is not None
                else itertools.repeat((None, None)))
    sim0 = train.replace(q=states0[0], dq=states0[1], ddq=states0[2])
    problem0 = replay_problem(system, base, channels, measured, chunks(sim0, states0[3], rows_system), meta)
    _, TV, rel = output_error_directions(problem0, beta0, icfg.directions_rtol)
    rank = TV.shape[1]
    fit0 = _reduced_fit(WLS(), problem0, beta0, TV, base)
    sd_c = _coordinate_scale(problem0, fit0, TV)
    e0 = qm - states0[0]
    s = np.sqrt(np.mean(e0**2, axis=0))
    w = 1.0 / np.where(s > 0, s, 1.0)  # fixed weights: the actuators' units made commensurate
    q_scale = float(np.max(np.abs(qm)))

    def beta_of(x):
        return beta0 + TV @ (sd_c * x)

    def residual(x):
        try:
            qs = replay(beta_of(x))[0]
        except ConfigError:
            raise
        except (DynidError, FloatingPointError, RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
            raise _ReplayFailed(str(exc)) from exc
        return ((qm - qs) * w).ravel()

    def jacobian(x, r):
        cols = []
        for i in range(rank):
            progress("CLOE sensitivities", i, rank)
            for h in (_FD_STEP, -_FD_STEP):  # backward where the forward replay fails
                xi = x.copy()
                xi[i] += h
                try:
                    dr = residual(xi) - r
                except _ReplayFailed as exc:
                    if h < 0:
                        raise InputError(f"identification: CLOE's sensitivity replays along direction {i + 1} do not "
                                         f"simulate ({exc})") from exc
                    continue
                moved = float(np.max(np.abs(dr.reshape(qm.shape) / w)))  # the replayed positions' largest change
                if not moved > _RESOLUTION * q_scale:
                    raise InputError(f"identification: CLOE's finite-difference replay along direction {i + 1} moves the "
                                     f"positions by at most {moved:.2g}, rounding for positions up to {q_scale:.2g}: no "
                                     "sensitivity can be measured")
                cols.append(dr / h)
                break
        progress("CLOE sensitivities", rank, rank)
        return np.column_stack(cols)

    try:
        lm = levenberg_marquardt(residual, jacobian, np.zeros(rank), max_iterations=icfg.max_iterations,
                                 tolerance=icfg.tolerance, failures=(_ReplayFailed,), count=lambda: replays[0],
                                 r0=(e0 * w).ravel())
    except _ReplayFailed as exc:
        raise InputError(f"identification: CLOE's trial steps do not simulate ({exc}); the estimate is not a robot the "
                         "simulator can run: try start = 'nominal'") from exc
    progress("CLOE iterations", icfg.max_iterations, icfg.max_iterations)
    beta = beta_of(lm.x)
    states = cache.get(beta.tobytes()) or replay(beta)
    n, n_a = qm.shape
    e = qm - states[0]
    cov_x, sigma, info = output_error_covariance(lm.jacobian, e, w)
    cov_c = sd_c[:, None] * cov_x * sd_c[None, :]
    cov = TV @ cov_c @ TV.T
    cov = 0.5 * (cov + cov.T)
    # the force residuals of the replay at the estimate (training fit in the forces, as DIDIM reports)
    sim = train.replace(q=states[0], dq=states[1], ddq=states[2])
    problem = replay_problem(system, base, channels, measured, chunks(sim, states[3], rows_system), meta)
    rss = problem.rss_per_channel(beta)
    iterations = [{"iteration": 0, "cost": float((e0 * w).ravel() @ (e0 * w).ravel()), "replays": 1},
                  *lm.iterations]
    for h in iterations:
        h["output_error_rmse_per_actuator"] = None
    iterations[-1]["output_error_rmse_per_actuator"] = np.sqrt(np.mean(e**2, axis=0)).tolist()
    iterations[0]["output_error_rmse_per_actuator"] = s.tolist()
    held = base.n_base - rank
    solver = {"algorithm": "CLOE (closed-loop output error of the positions, Levenberg-Marquardt on finite-difference "
                           "sensitivities of replays; Landau & Karimi 1997, as compared with DIDIM by Gautier, Janot & "
                           "Vandanjon 2013)",
              "experiment": _relative(icfg.experiment, cfg.source), "start": icfg.start, "iterations": iterations,
              "converged": lm.converged, "stopping": lm.reason, "tolerance_std": icfg.tolerance,
              "replays": replays[0], "wall_s": time.perf_counter() - t0, "finite_difference_step_std": _FD_STEP,
              "position_output_error_std": sigma.tolist(), "position_weights": w.tolist(),
              "estimated_directions": {"count": rank, "of": base.n_base, "threshold": icfg.directions_rtol,
                                       "smallest_kept": float(rel[rank - 1]),
                                       "largest_held": float(rel[rank]) if rank < rel.size else None},
              "directions": TV.tolist(), "direction_scale": sd_c.tolist()}
    if band is not None:
        solver["replay_coulomb_band"] = band
    notes = ["output error: the measured actuator positions minus those of the experiment replayed with the estimate "
             "under its controller, minimised by Levenberg-Marquardt (CLOE)",
             "CLOE covariance sigma_j^2 (J^T J)^-1 from the position output errors: it assumes white position output "
             "errors (independent from sample to sample); coloured errors (the loop's response to force noise, model "
             "error) make it optimistic"]
    if held:
        notes.append(f"{held} of {base.n_base} directions of the base parameters are not determined by the start's "
                     f"replayed regressor (singular value below {icfg.directions_rtol:g} of the largest): held at the "
                     "start's values; the standard errors are conditional on them")
    if not lm.converged:
        notes.append(f"not converged in {icfg.max_iterations} iterations: the last step moved a direction by "
                     f"{lm.iterations[-1]['max_change_in_std']:.3g} standard deviations")
    dof = int(max(n * n_a - rank, 1))
    return dataclasses.replace(fit0, method="CLOE", params=beta, cov_params=cov, rss_per_channel=rss,
                               n_obs=problem.n_obs, dof=dof, scale=1.0,
                               noise_std=np.sqrt(rss / np.maximum(problem.n_obs - rank / len(channels), 1.0)),
                               condition_number=float(np.linalg.cond(info)), solver=solver, provenance=dict(meta),
                               notes=tuple(notes))


class _ReplayFailed(Exception):
    """A trial replay that does not simulate (a rejected step for the Levenberg-Marquardt loop)."""
