"""Identification through the control loop: IDIM-IV and DIDIM (``method = "iv"`` / ``"didim"``; CLOE,
the output error of the positions on the same replay, is :mod:`dynid.pipeline.cloe`).

On a robot under feedback control the measured motion answers the controller, and the
regressor built from filtered, differentiated positions carries errors that least squares
turns into bias (errors in the variables; the Coulomb reversals and the zero-order hold put
motion above any filter's cut-off, bench/README §7). Both methods replay the experiment on a
model: the robot of ``[robot]`` with the current estimate, driven by the *same* controller,
gains and reference as the experiment (``identification.experiment``: the ``dynid simulate``
configuration that describes it; its truth, friction truth, payload and sensors are not
used), and evaluate the regressor on the simulated states, which are exact and free of the
measurement noise:

* **IDIM-IV** (Janot, Vandanjon & Gautier, IEEE TCST 22(1), 2014, Sections III–IV): the
  simulated regressor is the instrument matrix :math:`Z`; the measured regressor stays in the
  normal equations, :math:`\\hat\\beta = (Z^T W)^{-1} Z^T y` with Gautier's per-channel weights
  and the IV covariance (:mod:`dynid.estimation.instrumental`). Start: the WLS estimate
  (``start = "wls"``, the paper's IDIM-LS start) or the nominal model.

  The instruments must be correlated with the measured regressor, and that regressor is built
  from *filtered* positions: the replayed motion goes through the same processing
  (``processing.lowpass`` on the positions at the simulation's rate, the same derivatives) before
  the rows are built; the exact simulated accelerations carry the closed loop's response above
  the cut-off (the zero-order hold, Coulomb switching), which the measured rows do not, and on
  the hexapod twin of ``bench/control_loop_time.py`` that alone made :math:`Z^T W` singular at
  the first replay (condition 8.5e14, now 1.6e13).

  Directions of the base parameters that the experiment barely excites are not determined by
  the instruments: along them the replayed and the measured regressors are uncorrelated and
  the IV normal equations hold noise over a vanishing singular value (the hexapod twin's 102
  base parameters: the singular values of the column-scaled :math:`Z^T W` fall continuously
  from 1 to 1e-13 of the largest; the correlation of the two regressors along the singular
  directions is at least 0.88 down to 2e-3, 0.5 at 2.5e-4, 0.1 to 0.2 below 1e-9). The
  estimate is the truncated-SVD IV solution over the directions above ``directions_rtol``
  (default 1e-3 for IV) of the largest singular value; the others keep the start's values, so from ``start = "nominal"`` they stay at
  the nominal model's (30 or 31 of 102 directions are estimated on that twin, 2 or 3 periods).
  The directions are chosen **once**, at the start's replay
  (:func:`dynid.estimation.instrumental.determined_directions`), and every later step is
  IDIM-IV on those fixed combinations (:func:`~dynid.estimation.instrumental.reduce_instrumental`:
  the instruments ``Z TU``, the regressor ``W TV``; square and well posed): the parameters the
  excitation does not determine keep their a priori values, Gautier's essential-parameter
  practice. Re-truncating at every iterate (as before) let the kept subspace turn from one
  replay to the next, and its rank flip between 30 and 31 where a singular value sat within 1 %
  of the threshold (0.99e-3 on the ``--quick`` data): the held components drifted with it and
  the estimate moved by 1 to 2 standard deviations per iteration without contracting.
  ``result.solver["instrumented_directions"]`` records the number, a note the rest; the
  standard errors are conditional on the held directions. Without the truncation the first
  IV step is noise along them and the next replay is not the experiment (the regressors'
  correlation falls to 0.01 along every direction but the first). On the 3-period hexapod
  benchmark (``bench/control_loop_time.py``) the default 1e-3 keeps 31 directions and the
  iteration does not contract: from the second iteration the steps, in standard deviations of
  the fixed combinations, are 0.1 to 0.2 (RMS) along the ten strongest and 0.3 to 0.7 along the
  ten weakest (singular values 1e-3 to 1e-2 of the largest), where the replay's jitter passes
  through the smallest singular values; ``directions_rtol = 3e-3`` (26 directions) converges in
  5 iterations, 1e-2 (18) in 2 (bench/README, closed-loop estimators, replay cost). That map is
  not smooth there: finite differences of one IV iteration at a late iterate grow as the
  difference step shrinks (spectral radius 4.3 at 0.5 sd, 15 at 0.05 sd; moves of 0.001 sd change
  the next iterate by 0.3 sd), because the replay jumps with the estimate (the computed-torque
  controller's Coulomb switch at the control instants among the causes) and the weakest kept
  directions pass the jumps on (bench/README, "IV's oscillation on the hexapod benchmark,
  diagnosed"); with the relaxation below IV converges there in 9 iterations, by the chance of a
  small step rather than by contraction.
* **DIDIM** (Gautier, Janot & Vandanjon, "A new closed-loop output error method for
  parameter identification of robot dynamics", IEEE TCST 21(2), 2013, Eqs. 14–20): the measured
  forces are regressed on the simulated regressor alone, :math:`y = W(q_s(\\beta_k))\\beta_{k+1}`
  (Gauss–Newton on the output error of the forces: the simulated force is exactly
  :math:`W(q_s)\\beta_k` because the simulation runs the inverse model's own dynamics), by WLS,
  or by the physically consistent WLS with ``physical_consistency = true`` (then every iterate
  is a physical robot and the simulation stays well posed). Start: the nominal model by default,
  as the paper does from CAD values.

  With ``physical_consistency = true`` (and no regularization) the reported estimate is the
  unconstrained step at the last iterate, with the fixed point's covariance :math:`\\Sigma`
  (below; secants of the unconstrained steps at the consistent iterates), projected onto the
  physically consistent set in the metric :math:`\\Sigma^{-1}`
  (:meth:`dynid.estimation.PhysicalLS.project`: pseudo-inertias positive semi-definite,
  friction and rotor inertias of the right sign) and reported *with* :math:`\\Sigma`. The set
  is convex and holds the truth, and a projection onto a convex set is non-expansive, so the
  confidence ellipsoid centred on the projection contains the truth whenever the unconstrained
  one does: a conservative region (the per-parameter intervals are its sections and carry no
  such guarantee). On the demo's set-up this removes the negative viscous coefficient of a
  passive joint (``fv_qb2``, truth 0.0012, to 0 with its bound active) and leaves every true
  base parameter inside its 95 % interval (25 of 25, largest |z| 1.8, the truth's
  :math:`\\chi^2` 29 for p = 25).

**Oscillating steps** (:func:`dynid.estimation.instrumental.oscillation_relaxation`): from the
second iteration on, the secant of the step along the last move, in standard deviations,
estimates the iteration's Jacobian there (:math:`\\lambda`); when, and only when, the step
reversed along that move (:math:`\\lambda < 0`: a 2-cycle at -1), the next replay takes the
step's component along the move scaled by :math:`1 / (1 - \\lambda)` (the secant root), the rest
as it is. The fixed point is unchanged (the estimate is the method's), a monotonically contracting
iteration is untouched, and ``solver["iterations"]`` records ``secant_eigenvalue`` and
``relaxation``, the notes after which iterations it acted.

Both iterate until no parameter moves by more than ``tolerance`` of its standard deviation, or
``max_iterations``; the history is in ``result.solver["iterations"]`` (for DIDIM with the output
error of each iterate, ``output_error_rmse_per_channel``: the RMS of the measured forces minus
those simulated with it, the criterion the method is built on; its fixed point neglects
:math:`\\partial q_s / \\partial\\beta` and is not a stationary point of it, so a step control
that demands a falling output error stops short of that fixed point: tried, not kept, see
bench/README, control-loop identification time). Unconstrained DIDIM estimates fixed directions
too (those of the start's replay, from the column-scaled :math:`\\sum_j w_j W_{s,j}^T W_{s,j}`,
singular values above ``directions_rtol``, default 1e-6 for DIDIM, i.e. the scaled simulated
regressor's above 1e-3 of its largest; the others at the start's values;
``solver["estimated_directions"]``). On the shang2dof twin that keeps all 25 (DIDIM as before;
IV's 1e-3 would keep 16 and leave the estimate far from the truth: 3 to 5 of 25 true base
parameters inside the 95 % intervals instead of 25). On the hexapod twin the least squares over
all 102 directions, or over those above 1e-6, gives iterates far outside the physically
consistent set (indefinite pseudo-inertias on most bodies; the feasibility program's total slack
2e3 to 1e4 from the second iterate on) and a replay fails by iteration 6 or 7; with
``directions_rtol = 1e-3`` (32 of 102) and the smooth replay below it runs, without a halving.

**The replay as a smooth function of the estimate** (``replay_coulomb_band``, default 0.05 for
IV, 0 for DIDIM). The replays can simulate the plant's Coulomb friction through a regularized
law, ``tanh(v / v_b)`` instead of ``sign(v)``
(:class:`dynid.simulation.closed_loop.ConstrainedSimulator`, ``coulomb_band``), ``v_b`` that
fraction of the largest measured actuator speed of the training log (a parallel robot's replay;
a serial robot's keeps its plant's law). With the discontinuous law the explicit integrator
chatters about zero velocity wherever a joint sticks, so the replayed motion, and the step
computed from it, depends discontinuously on the estimate: on the ``--quick`` hexapod data,
moving the iterate by 0.018 standard deviations moved the IV step's output by 1.24 (by 7e-5 for
a move of 2e-6), an iteration that cannot contract below about one standard deviation. With the
regularized law the same moves give 0.004 and 1.6e-4 (ratios 0.2 to 0.5 from 1e-4 to 1 standard
deviation), DIDIM's step is linear in the move (ratio 0.55 from 1e-6 to 1e-2), and IV converges
in 3 iterations. IV may use an approximate replay: its instruments need only be correlated with
the regressor and independent of the noise, and any such instruments keep the estimate
consistent (Janot 2014, Section III); the law equals ``sign(v)`` to 0.5 % beyond 3 ``v_b``
(Olsson, Åström, Canudas de Wit, Gäfvert & Lischinsky, Eur. J. Control 4(3), 1998, Section 2:
the classical law regularized near zero velocity for simulation). DIDIM may not, by default:
it is an output-error method, its residual the measured minus the replayed force, so a replay
law other than the data's adds an output error at every reversal that the regression then
fits; on the shang2dof twin a band of 0.05, 0.01 or 0.002 took DIDIM from 25 of 25 true base
parameters inside their intervals (5 iterations) to 6 to 12, two of three runs not converged.
With a band, DIDIM's rows of the replay take the replay's own law
(:func:`_replay_rows_system`: the smooth sign :math:`\\mathrm{erf}(v / (\\sqrt 2\\,w))` on every
joint, :math:`w = \\sqrt{2/\\pi}\\,v_b`, the slope of :math:`\\tanh(v / v_b)` at zero; the two
differ by at most 3.5 % of a Coulomb level), so that :math:`W(q_s)\\beta_k` is again the
replayed force, the premise of Gautier 2013's step. With ``sign(v_s)`` rows it was not: wherever
a replayed joint moved slower than ``v_b`` the rows' Coulomb column missed the replay's friction
by up to its whole level, and which samples did so changed with the estimate, so the output
error and the step were non-smooth in it. On the hexapod twin (``directions_rtol = 1e-3``, band
0.05) that alone kept DIDIM from converging: its moves stalled at 1.5 to 4 standard deviations
in 10 iterations, and finite-difference replays at an iterate gave sensitivities of the replayed
forces concentrated on the few decimated rows around reversals, growing as the difference step
shrank (1.2, 6.9 and 13 times the step's regressor column for moves of 1, 0.1 and 0.01 standard
deviations along one direction, nearly orthogonal to it: cosine 0.03 to 0.25), i.e. jumps, not
the slow closed-loop directions of a non-stiff loop (bench/README). With the matching rows the
``--quick`` run converges in 5 iterations (moves 23.8, 4.3, 2.0, 0.56, 0.36 standard deviations;
secant eigenvalues -0.10, 0.12, 0.46). A mechanism with asymmetric Coulomb levels (``fc+``,
``fc-``: the shang2dof twin) keeps ``sign(v)`` rows: the replay's regularization of
``c (v > 0)`` is ``c max(tanh(v / v_b), 0)``, the rows' smooth sign gives ``c (1 + erf) / 2``,
half a level apart at rest. Simulated states are
taken at the processed log's instants (linear interpolation between control instants; exact
at them), and the simulated rows go through exactly the processing of the measured rows
(parallel decimation, ``min_velocity`` selection from the measured velocities). DIDIM's rows
start the loop-closure position solve from the simulation's own joint positions, which already
satisfy it (residual below the solve's 1e-10 tolerance at the control instants: no Gauss–Newton
iteration; the rows then differ from those solved from the actuator positions at that level: the
DIDIM estimate on the hexapod twin by 1e-9 of its standard deviations). Where the log's instants
are the control instants and the mechanism's independent joints are its actuated ones (the hexapod),
DIDIM's rows take those positions as they are (:class:`~dynid.model.system.KnownJointPositions`:
no residual and Jacobian per sample to accept them) and the compiled
:func:`~dynid.model.loop_kinematics.states` for the velocity map, velocities and accelerations: the
same rows to rounding, 28 % less time per replay's rows (bench/README, issue 37 item 3, fourth
pass). IV's instrument rows
start there too: its replayed actuator positions are low-passed, so the solve still iterates,
but from within the filter's deviation of the solution instead of from the previous sample (one
Gauss–Newton step fewer; the same positions, tests/test_control_loop.py).

Processing: use parallel decimation (``processing.decimate_method = "parallel"``), as Gautier
and Janot do. On the shang2dof twin (500 Hz augmented PD, Kp = 35000) the full-rate DIDIM
iteration is unstable: the simulated accelerations at the control instants carry the closed
loop's response to the zero-order hold, which depends on the estimate, so the iteration moves
away even from the truth; low-passed and decimated, it converges from the nominal model in 3–5
iterations (15-turn circle: 24 of the 25 true base parameters inside their 95 % intervals,
held-out error below the nominal model's, where WLS on the same rows covers 10 of 25).

Uncertainty: DIDIM's Jacobian neglects how the simulated motion depends on the estimate
(Gautier 2013's assumption of a stiff loop). Where it does not, the iteration contracts slowly
(0.5 per step on the shang2dof twin with noise-free forces) and the fixed point's error is that
of one step amplified by ``(I - M)^{-1}``, ``M`` the iteration's Jacobian: the last step's
covariance is then too narrow (a 4-turn circle: 13 of 25 true base parameters outside). DIDIM
therefore reports ``(I - M)^{-1} C (I - M)^{-T}`` with ``M`` estimated by secants of the
iterates after the first (:func:`dynid.estimation.instrumental.fixed_point_covariance`;
``solver["iteration_jacobian_eigenvalues"]``). On the demo's set-up (15-turn circle, seed 2026,
parallel decimation by 5) this takes the coverage of the 95 % intervals from 16 to 21 of 25
(largest |z| 3.08 to 2.55) with the default tolerance (6 iterations). The secant estimate is
only as good as the iterates: run to a tight tolerance, the late steps (0.3 standard deviations,
no longer shrinking: Coulomb switching makes the iteration non-smooth) give a spurious
eigenvalue beyond 1, and the last step's covariance is reported with a note in
``solver["covariance"]``.

An iterate whose simulation fails (a model without a positive-definite mass matrix, or a
diverging motion) is not accepted: the step is halved up to four times, then the run stops
with an error naming the iteration and the simulator's cause (no fallback to another method).
"""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path
from typing import Any

import numpy as np

from dynid.config import Config
from dynid.dataset import Dataset
from dynid.errors import ConfigError, DynidError, InputError
from dynid.estimation import IdentificationResult, ProblemBuilder
from dynid.estimation.instrumental import (InstrumentBuilder, determined_directions, fixed_point_covariance, iv_result,
                                           iv_solve, oscillation_relaxation, reduce_instrumental)
from dynid.estimation.problem import RegressionProblem, _qr_r
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System

__all__ = ["control_loop_estimate"]

_HALVINGS = 4


@dataclasses.dataclass(frozen=True)
class _Experiment:
    cfg: Any  # SimulateConfig
    names: tuple[str, ...]  # the simulated robot's standard parameter names
    index: np.ndarray  # position of each of them in the identified robot's standard vector


def _experiment(cfg: Config, system: System) -> _Experiment:
    from dynid.config.simulate import load_simulate_config
    from dynid.model.loading import load_model

    path = cfg.identification.experiment
    exp = load_simulate_config(path)
    robot = load_model(exp.robot.model, actuated=exp.robot.actuated, independent=exp.robot.independent)
    names = tuple(robot.parameter_names)
    ident = tuple(system.model.parameter_names)  # the model's full layout (expand_parameters of a reduced one)
    missing = [n for n in names if n not in ident]
    extra = [n for n in ident if n not in names]
    if missing or extra:
        what = (f"the experiment's robot has parameters {missing[:4]} that the identified robot lacks" if missing else
                f"the identified robot has parameters {extra[:4]} that the experiment's simulator does not model "
                "(e.g. motor terms of a drive train)")
        raise ConfigError(f"identification.experiment = {path}: {what}; the experiment must simulate the robot "
                          f"being identified ({exp.robot.model} against {cfg.robot.model})")
    return _Experiment(exp, names, np.array([ident.index(n) for n in names]))


def _instrument_processing(pcfg):
    """IV: the replayed motion through the processing of the measured positions (module
    docstring): ``processing.lowpass`` on the positions (and on measured velocities), then the
    same derivatives, at the simulation's rate. Returns ``process(ts, q, dq, ddq)``."""
    from dynid.signals import central_difference, lowpass

    lp = pcfg.lowpass

    def process(ts, q, dq, ddq):
        if lp is not None:
            fs = 1.0 / float(np.median(np.diff(ts)))
            if not lp.cutoff_hz < fs / 2:
                raise ConfigError(f"processing.lowpass.cutoff_hz = {lp.cutoff_hz} Hz is not below half the experiment's "
                                  f"control rate ({fs / 2:g} Hz): the replayed motion cannot be filtered like the log")
            q = lowpass(q, lp.cutoff_hz, fs, lp.order)
            if pcfg.derivatives != "central":
                dq, ddq = lowpass(dq, lp.cutoff_hz, fs, lp.order), lowpass(ddq, lp.cutoff_hz, fs, lp.order)
        if pcfg.derivatives == "central":
            dq = central_difference(q, ts)
            ddq = central_difference(dq, ts)
        return q, dq, ddq

    return process


def _simulated_states(exp: _Experiment, standard: np.ndarray, t: np.ndarray, process=None,
                      band: float | None = None) -> tuple[np.ndarray, ...]:
    """Actuator positions, velocities, accelerations (n, n_a) of the experiment replayed with
    the standard parameters ``standard`` (identified robot's layout), at the instants ``t``;
    ``process(ts, q, dq, ddq)``, when given, processes the states at the control instants first
    (IV: :func:`_instrument_processing`). Also all the joint positions of the simulation at
    ``t`` (None if not finite): the starting points of the rows' position solve. Unprocessed
    (DIDIM) they solve it already at the control instants (no Gauss–Newton step); processed (IV)
    the solve starts from them instead of from the previous sample: the filtered actuator
    positions lie within the filter's small deviation of the simulated ones, so it takes one
    Gauss–Newton step fewer and converges to the same assembly. Unprocessed, with the log's
    instants the control instants (to 1e-9 s), the samples are the replay's own (no interpolation)
    and the joint positions come as :class:`~dynid.model.system.KnownJointPositions`."""
    from dynid.pipeline.simulate import actuator_states, run_simulation

    # standard: the model's full layout; band: the regularized Coulomb law of the replay (module docstring)
    outcome = run_simulation(exp.cfg, plant=standard[exp.index], coulomb_band=band)
    ts, q, dq, ddq = actuator_states(outcome)
    if process is not None and np.all(np.isfinite(q)) and np.all(np.isfinite(dq)) and np.all(np.isfinite(ddq)):
        q, dq, ddq = process(ts, q, dq, ddq)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(dq)) and np.all(np.isfinite(ddq))):
        raise FloatingPointError("the simulated motion is not finite")
    if t[0] < ts[0] - 1e-9 or t[-1] > ts[-1] + 1e-9:
        raise ConfigError(f"identification.experiment: the simulated experiment covers {ts[0]:g}-{ts[-1]:g} s, the "
                          f"processed log {t[0]:g}-{t[-1]:g} s (the experiment's duration must cover the log)")
    interp = lambda x: np.column_stack([np.interp(t, ts, x[:, k]) for k in range(x.shape[1])])  # noqa: E731
    joint_q = None
    motion = getattr(outcome, "motion", None)
    if motion is not None:
        qj = np.asarray(motion.q, dtype=float)
        joint_q = interp(qj) if np.all(np.isfinite(qj)) else None
    if process is None and joint_q is not None:
        # DIDIM: the log's instants are the control instants (to 1e-9 s): the replay's own samples, its
        # joint positions on the closures (projected to 1e-12 at every period), which the rows take
        # as they are (KnownJointPositions: the compiled velocity map, no position check)
        idx = np.rint((t - ts[0]) / (ts[1] - ts[0])).astype(int) if ts.size > 1 else np.zeros(t.size, dtype=int)
        idx = np.clip(idx, 0, ts.size - 1)
        if np.all(np.abs(ts[idx] - t) <= 1e-9) and np.all(np.isfinite(qj[idx])):
            from dynid.model.system import KnownJointPositions

            return q[idx], dq[idx], ddq[idx], KnownJointPositions(qj[idx])
    return interp(q), interp(dq), interp(ddq), joint_q


def _simulate_or_halve(exp, base: BaseParameters, reference: np.ndarray, beta_old, beta_new, t, k: int,
                       standard_of=None, expand=lambda pi: pi, process=None, band=None):
    """Simulate at ``beta_new``; on failure halve the step from ``beta_old`` (see module doc)."""
    step = 1.0
    last = None
    for _ in range(_HALVINGS + 1):
        beta = beta_new if beta_old is None else beta_old + step * (beta_new - beta_old)
        standard = standard_of(beta) if standard_of is not None and step == 1.0 else base.to_standard(beta, reference)
        try:
            return beta, step, _simulated_states(exp, expand(standard), t, process, band)
        except ConfigError:
            raise
        except (DynidError, FloatingPointError, RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
            last = exc
            if beta_old is None:
                break
            step *= 0.5
    raise InputError(f"identification: the experiment replayed with the estimate of iteration {k} does not simulate "
                     f"({last}); the estimate is not a robot the simulator can run: try "
                     "physical_consistency = true (method 'didim') or start = 'nominal'")


def replay_problem(system: System, base: BaseParameters, channels, measured, replay_chunks, meta: dict) -> RegressionProblem:
    """DIDIM's regression (also CLOE's at its start, :mod:`dynid.pipeline.cloe`): the equations at the
    replayed configuration (projected equations of a redundant mechanism: ``G_a(q_s)^T tau_a``), the
    measured forces, each chunk's rows selected by ``measured``'s masks (``(_, mask)`` per chunk)."""
    mb = ProblemBuilder(base.names, channels)
    for (_, mask), cs in zip(measured, replay_chunks):
        if mask is not None and mask.ndim == 1:
            mb.add(cs.W[mask], cs.y[mask])
        else:
            mb.add(cs.W, cs.y, mask)
    return mb.build(expressions=base.expressions(), standard=system.standard_map(base), meta=dict(meta))


def output_error_directions(problem: RegressionProblem, beta: np.ndarray, rtol: float):
    """The directions the replayed regressor determines (DIDIM, CLOE; module docstring): those of the
    column-scaled :math:`\\sum_j w_j W_{s,j}^T W_{s,j}` (``w_j`` from the residuals at ``beta``) with
    singular values above ``rtol`` of the largest. Returns ``(TU, TV, relative singular values)``."""
    w = 1.0 / _sigma(problem.rss_per_channel(beta), problem.n_obs, problem.n_params) ** 2
    G = np.einsum("j,jki,jkl->il", w, problem.R, problem.R)
    return determined_directions(G, G, rtol)


def _reduced_fit(estimator, problem: RegressionProblem, beta0: np.ndarray, TV: np.ndarray,
                 base: BaseParameters) -> IdentificationResult:
    """DIDIM's step on the fixed directions: the least squares of ``y - W beta0`` on ``W TV``
    (exact: each channel's factor ``[R_j TV, z_j - R_j beta0; 0, rho_j]`` re-triangularized), mapped
    back to the base parameters ``beta0 + TV c`` with the covariance ``TV C_c TV^T``."""
    p, r = problem.n_params, TV.shape[1]
    f = np.zeros((problem.n_channels, r + 1, r + 1))
    for j in range(problem.n_channels):
        M = np.zeros((p + 1, r + 1))
        M[:p, :r] = problem.R[j] @ TV
        M[:p, r] = problem.z[j] - problem.R[j] @ beta0
        M[p, r] = problem.factors[j, p, p]
        f[j] = _qr_r(M, r + 1)[: r + 1]
    reduced = RegressionProblem(tuple(f"c{i + 1}" for i in range(r)), problem.channel_names, f, problem.n_obs,
                                meta=problem.meta)
    fit = estimator.fit(reduced)
    beta = beta0 + TV @ fit.params
    cov = None if fit.cov_params is None else TV @ fit.cov_params @ TV.T
    return dataclasses.replace(fit, names=base.names, params=beta, cov_params=None if cov is None else 0.5 * (cov + cov.T),
                               rss_per_channel=problem.rss_per_channel(beta), expressions=base.expressions())


def _replay_rows_system(system: System, band: float | None) -> System | None:
    r"""DIDIM's replay rows with the replay's own Coulomb law (module docstring): the mechanism whose
    Coulomb columns are the smooth sign :math:`\mathrm{erf}(v / (\sqrt 2\,w))` on every joint with
    :math:`w = \sqrt{2/\pi}\,v_b`, the slope at zero velocity of the replay's
    :math:`\tanh(v / v_b)` (Olsson et al. 1998, Section 2; the two laws differ by at most 3.5 % of
    the Coulomb level, at :math:`|v| \approx 1.4\,v_b`). None without a band, or for a serial
    robot (its replay keeps its plant's law), or a mechanism with asymmetric Coulomb levels or
    coupled-motor terms: the replay regularizes ``c (v > 0)`` as ``c max(tanh(v / v_b), 0)``, the
    rows' smooth sign as ``c (1 + erf) / 2`` (the expected sign of a noisy velocity, what
    ``coulomb_smoothing`` needs), which differ by half a level at rest (the shang2dof twin's
    ``fc+``/``fc-``: its rows keep sign(v))."""
    from dynid.model.system import ClosedLoopSystem

    if band is None or not isinstance(system, ClosedLoopSystem):
        return None
    mech = system.model
    if any(t.kind in ("coulomb+", "coulomb-") or t.weights for t in mech.terms):
        return None
    width = float(band) * np.sqrt(2.0 / np.pi)
    return dataclasses.replace(system, model=dataclasses.replace(mech, coulomb_width=(width,) * mech.pin_model.nv))


def _relative(path, config_file) -> str:
    """The experiment's path as result.json records it: relative to the config's folder (the same
    inputs give the same bytes wherever they are)."""
    import os

    return str(path) if config_file is None else os.path.relpath(path, Path(config_file).parent)


def _sigma(rss: np.ndarray, n_obs: np.ndarray, p: int) -> np.ndarray:
    n_ch = rss.size
    dof = np.maximum(n_obs - p / n_ch, 1.0)
    s = np.sqrt(rss / dof)
    if np.any(s <= 0):
        raise InputError("zero residual on a channel: cannot weight by noise variance")
    return s


def _fixed_point(inputs, outputs, cov: np.ndarray, steps: str) -> tuple[np.ndarray, dict]:
    """The fixed point's covariance (one step's ``cov`` through the iteration's Jacobian, by
    secants of the iterates after the first, which starts far from the fixed point) and what
    result.solver records of it; ``steps`` names the steps in that record."""
    first = 1 if len(inputs) >= 3 else 0
    out, eig = fixed_point_covariance(np.array(inputs[first:]), np.array(outputs[first:]), cov)
    info = {"iteration_jacobian_eigenvalues": [complex(e).real if abs(complex(e).imag) < 1e-12 else str(e) for e in eig],
            "covariance": ("(I - M)^-1 C (I - M)^-T, M by secants of the iterates" if out is not cov else
                           f"C of the last {steps}" + (" (the estimated iteration does not contract)"
                                                        if eig.size else " (too few iterations to estimate M)"))}
    return out, info


def _projected_fixed_point(icfg, problem, free: IdentificationResult, inputs, free_outputs) -> tuple[IdentificationResult, dict]:
    """DIDIM with ``physical_consistency``: the unconstrained step at the last (consistent)
    iterate, with the fixed point's covariance (secants of the unconstrained steps at the
    consistent iterates), projected onto the physically consistent set in the metric of that
    covariance (:meth:`dynid.estimation.PhysicalLS.project`; module docstring)."""
    from dynid.estimation import PhysicalLS
    from dynid.pipeline.data import physical_options

    cov, info = _fixed_point(inputs, free_outputs, free.cov_params, "unconstrained step")
    opts = physical_options(icfg)
    smap = problem.standard
    proj = PhysicalLS(weighting="wls", constraints=opts["constraints"], solver=opts["solver"]).project(free.params, cov, smap)
    beta = proj["params"]
    moved = ("the unconstrained estimate is physically consistent: unchanged" if proj["unchanged"] else
             f"projected onto the physically consistent set (active: {', '.join(proj['active_constraints'])}); "
             f"the move is {np.sqrt(proj['distance_chi2']):.3g} in Mahalanobis units of the covariance")
    se = ("the covariance of the unconstrained fixed point, reported for the projected estimate: the projection onto a "
          "convex set is non-expansive in the covariance's metric, so the confidence ellipsoid centred on it contains "
          "the truth at least as often (conservative; the per-parameter intervals are its 1-D sections)")
    solver = {**dict(free.solver), "standard_params": dict(zip(smap.standard_names, proj["standard_params"].tolist())),
              "active_constraints": list(proj["active_constraints"]), "unchanged": proj["unchanged"],
              "projection_distance_chi2": proj["distance_chi2"], "unconstrained_params": free.params.tolist(),
              "standard_error": se, "projection_stages": proj["stages"]}
    result = dataclasses.replace(free, method="WLS+LMI (projected)", params=beta, cov_params=cov,
                                 rss_per_channel=problem.rss_per_channel(beta), solver=solver,
                                 notes=tuple(free.notes) + (moved, "standard errors: " + se))
    return result, info


def control_loop_estimate(cfg: Config, system: System, base: BaseParameters, train: Dataset, force_model: str | None,
                          start: IdentificationResult | None, chunks, mask_of, meta: dict,
                          progress) -> IdentificationResult:
    """IDIM-IV or DIDIM (module docstring) on the processed training log ``train``.

    ``start``: the WLS estimate (None when ``start = "nominal"``); ``chunks(ds)`` yields the
    :class:`~dynid.pipeline.identification.Chunk` rows of a dataset processed like the
    training rows; ``mask_of(chunk)`` the row selection of a chunk (None: every row is kept).
    """
    icfg = cfg.identification
    method = icfg.method
    exp = _experiment(cfg, system)
    nominal_std = system.nominal_parameters()
    channels = system.channel_names(force_model)
    beta = start.params if start is not None else base.from_standard(nominal_std)
    sigma = start.noise_std if start is not None else None
    estimator = None
    if method == "didim":
        from dynid.estimation import make_estimator
        from dynid.pipeline.data import physical_options

        estimator = make_estimator("wls", icfg.physical_consistency,
                                   physical=physical_options(icfg) if icfg.physical_consistency else None)
    history: list[dict[str, Any]] = []
    free_outputs: list[np.ndarray] = []  # the unconstrained steps (= outputs without physical consistency)
    inputs: list[np.ndarray] = []
    outputs: list[np.ndarray] = []
    result: IdentificationResult | None = None
    standard_of = None
    beta_prev = None
    subspace = None  # (start, TU, TV, relative singular values): the estimated directions (module docstring)
    # the replays' Coulomb band (module docstring; 0: the discontinuous law)
    band = icfg.replay_coulomb_band * float(np.max(np.abs(np.asarray(train.dq, dtype=float)))) or None
    t = np.asarray(train.t, dtype=float)
    # IV: instruments processed like the measured regressor; DIDIM: the exact simulated states
    # (its simulated forces W(q_s) beta_k are the replay's own forces; module docstring)
    process = _instrument_processing(cfg.processing) if method == "iv" else None
    # DIDIM: the replay's rows with the replay's Coulomb law, so that W(q_s) beta_k is the replayed force
    rows_system = _replay_rows_system(system, band) if method == "didim" else None
    # the measured rows do not change from one iteration to the next: computed once (forward
    # kinematics of every sample, the regressor). IV keeps them (its normal equations use them at
    # every iteration: the decimated base regressor, n/k x n_a x p doubles), DIDIM only their row
    # selection.
    if method == "iv" or mask_of is not None:
        measured = [(cm if method == "iv" else None, None if mask_of is None else mask_of(cm)) for cm in chunks(train)]
    else:  # DIDIM keeping every row: the measured rows are not needed at all
        measured = itertools.repeat((None, None))
    for k in range(1, icfg.max_iterations + 1):
        progress(f"{method.upper()} iterations", k - 1, icfg.max_iterations)
        beta_used, step, (qs, dqs, ddqs, joint_qs) = _simulate_or_halve(exp, base, nominal_std, beta_prev, beta, t, k,
                                                             standard_of, system.expand_parameters, process, band)
        sim = train.replace(q=qs, dq=dqs, ddq=ddqs)
        if method == "iv":
            builder = InstrumentBuilder(base.names, channels)
            for (cm, mask), cs in zip(measured, chunks(sim, joint_qs), strict=True):
                builder.add(cs.W, cm.W, cm.y, mask)
            problem = builder.build()
            if sigma is None:
                sigma = _sigma(problem.rss_per_channel(beta_used), problem.n_obs, base.n_base)
            if subspace is None:  # the directions the start's instruments determine, fixed for the run
                w = 1.0 / sigma**2
                subspace = (beta_used.copy(), *determined_directions(np.einsum("j,jik->ik", w, problem.ZW),
                                                                     np.einsum("j,jik->ik", w, problem.ZZ),
                                                                     icfg.directions_rtol))
            beta0, TU, TV, _ = subspace
            rank = TV.shape[1]
            reduced = reduce_instrumental(problem, TU, TV, beta0, [f"c{i + 1}" for i in range(rank)])
            for _ in range(3):  # weights from the IV residuals (Janot 2014: weighted IV)
                # the directions the instruments do not determine stay at the start's values
                c, cov_c, cond = iv_solve(reduced, sigma)
                new, cov = beta0 + TV @ c, TV @ cov_c @ TV.T
                sigma = _sigma(problem.rss_per_channel(new), problem.n_obs, rank)
            cov = 0.5 * (cov + cov.T)
            held = base.n_base - rank
            result = iv_result(problem, new, cov, sigma, cond, method="IV", provenance=dict(meta),
                               solver={"instrument_rtol": icfg.directions_rtol, "instrumented_directions": rank},
                               notes=() if not held else (
                                   f"{held} of {base.n_base} directions of the base parameters are not determined by "
                                   f"the instruments (singular value of Z^T W below {icfg.directions_rtol:g} of the largest): held "
                                   f"at the start's values; the standard errors are conditional on them",),
                               expressions=base.expressions())
        else:
            problem = replay_problem(system, base, channels, measured, chunks(sim, joint_qs, rows_system), meta)
            if icfg.physical_consistency:  # consistent iterates: every direction, under the LMIs
                result = estimator.fit(problem)
                rank = base.n_base
            else:
                if subspace is None:  # the directions the start's replay determines, fixed for the run
                    subspace = (beta_used.copy(), *output_error_directions(problem, beta_used, icfg.directions_rtol))
                beta0, _, TV, _ = subspace
                rank = TV.shape[1]
                result = _reduced_fit(estimator, problem, beta0, TV, base)
            new = result.params
            if icfg.physical_consistency:  # the unconstrained step at the same iterate (covariance, projection)
                from dynid.estimation import WLS

                free = WLS().fit(problem)
            std = result.solver.get("standard_params")
            standard_of = None
            if std:
                names = system.parameter_names
                pi = np.array([std[n] for n in names], dtype=float)
                standard_of = lambda b, _b=new, _pi=pi: _pi if np.array_equal(b, _b) else base.to_standard(b, nominal_std)  # noqa: E731
        if method == "iv" or not icfg.physical_consistency:
            free = result
        # a constrained fit at its boundary gives no covariance: measure the step by the unconstrained one's
        bse = result.bse if result.cov_params is not None else free.bse
        free_outputs.append(free.params)
        moved = float(np.max(np.abs(new - beta_used) / np.maximum(bse, 1e-300)))
        entry = {"iteration": k, "step": step, "max_change_in_std": moved,
                 "rmse_per_channel": np.sqrt(result.rss_per_channel / np.maximum(result.n_obs, 1)).tolist()}
        entry["estimated_directions"] = rank
        if method == "didim":  # the output error of the iterate itself: its simulated forces W(q_s) beta_k
            entry["output_error_rmse_per_channel"] = np.sqrt(problem.rss_per_channel(beta_used)
                                                             / np.maximum(problem.n_obs, 1)).tolist()
        history.append(entry)
        inputs.append(beta_used)
        outputs.append(new)
        beta_prev, beta = beta_used, new
        if moved < icfg.tolerance:
            break
        if len(inputs) >= 2:  # an oscillating step is relaxed (module docstring, oscillation_relaxation)
            relaxed_beta, alpha, lam = oscillation_relaxation(inputs[-2], outputs[-2], beta_used, new, bse)
            if np.isfinite(lam):
                entry["secant_eigenvalue"] = lam
            if alpha < 1.0:
                entry["relaxation"] = alpha
                beta = relaxed_beta
    progress(f"{method.upper()} iterations", icfg.max_iterations, icfg.max_iterations)
    assert result is not None
    converged = history[-1]["max_change_in_std"] < icfg.tolerance
    fixed_point: dict[str, Any] = {}
    if method == "didim" and icfg.physical_consistency and icfg.regularization == "none":
        result, fixed_point = _projected_fixed_point(icfg, problem, free, inputs, free_outputs)
    elif method == "didim" and result.cov_params is not None:
        cov, fixed_point = _fixed_point(inputs, outputs, result.cov_params, "step")
        if cov is not result.cov_params:
            result = dataclasses.replace(result, cov_params=cov)
    name = "IV" if method == "iv" else "DIDIM" + (" + " + result.method if result.method != "WLS" else "")
    solver = {**dict(result.solver), "algorithm": ("IDIM-IV (Janot, Vandanjon & Gautier 2014)" if method == "iv" else
                                                   "DIDIM (Gautier, Janot & Vandanjon 2013)"),
              "experiment": _relative(icfg.experiment, cfg.source), "start": icfg.start, "iterations": history, "converged": converged,
              "tolerance_std": icfg.tolerance, **fixed_point}
    if subspace is not None:  # the fixed directions (module docstring): how far the threshold is from the spectrum
        rel = subspace[3]
        kept = subspace[2].shape[1]
        solver["estimated_directions"] = {"count": kept, "of": base.n_base,
                                          "threshold": icfg.directions_rtol,
                                          "smallest_kept": float(rel[kept - 1]),
                                          "largest_held": float(rel[kept]) if kept < rel.size else None}
    if band is not None:
        solver["replay_coulomb_band"] = band
    if rows_system is not None:  # DIDIM's replay rows: the replay's law (erf of this width on every joint)
        solver["replay_rows_coulomb_width"] = float(rows_system.model.coulomb_width[0])
    notes = [("instruments: the regressor on the states of the experiment replayed with the current estimate under its "
              "controller; IV covariance" if method == "iv" else
              "output error: the measured forces regressed on the regressor of the experiment replayed with the current "
              "estimate under its controller")]
    if subspace is not None and subspace[2].shape[1] < base.n_base:  # as IV's and CLOE's results say it
        notes.append(f"{base.n_base - subspace[2].shape[1]} of {base.n_base} directions of the base parameters are not "
                     f"determined by the start's replayed regressor (singular value below {icfg.directions_rtol:g} of the "
                     "largest): held at the start's values; the standard errors are conditional on them")
    relaxed = [(h["iteration"], h["relaxation"]) for h in history if "relaxation" in h]
    if relaxed:  # oscillation_relaxation acted: say where
        notes.append("the iteration oscillated (the step reversed along the previous move: negative secant eigenvalue); "
                     "the next replay took the step's component along that move relaxed, after iteration "
                     + ", ".join(f"{k} by {a:.2g}" for k, a in relaxed)
                     + " (the fixed point, the reported estimate, is the method's own)")
    if not converged:
        notes.append(f"not converged in {icfg.max_iterations} iterations: the last step moved a parameter by "
                     f"{history[-1]['max_change_in_std']:.3g} standard deviations")
    return dataclasses.replace(result, method=name, solver=solver, notes=tuple(result.notes) + tuple(notes))
