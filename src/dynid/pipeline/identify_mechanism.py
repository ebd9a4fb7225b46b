"""``dynid identify`` for closed-loop mechanisms (parallel robots).

The log holds what a real parallel robot measures: actuator positions and actuator forces
(or currents). After the same reading and processing as serial robots (units, windows,
resampling, zero-phase low-pass, central differences, trimming, sample decimation), every
sample goes through the closed loops:

1. all joint positions by Gauss–Newton from the actuator positions, warm-started along the
   log; velocities and accelerations of all joints by least squares (exact for
   non-redundant actuation; :func:`dynid.model.loop_kinematics.actuator_states`);
2. the actuator-space regressor by virtual power (:func:`dynid.model.closed_loop.actuator_regressor`);
   for redundant actuation the force model of ``identification.force_model``
   (default ``"projected"``: the measured forces enter as :math:`G_a^T\\tau_a`, one equation
   per independent coordinate, with no assumption about the controller);
3. the base regressor, compressed chunk by chunk into the regression problem; the
   estimators, the validation on held-out data and the output files are those of serial
   robots.

Not available yet for mechanisms (refused with a one-line error, never replaced by
something else): motor-side positions through a transmission, parallel decimation,
``processing.min_velocity``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.config import Config
from dynid.dataset import Dataset
from dynid.errors import ConfigError, IdentifiabilityError, InputError
from dynid.estimation import ProblemBuilder
from dynid.model.base_parameters import BaseParameters, StandardMap
from dynid.model.closed_loop import actuator_regressor, mechanism_base_parameters
from dynid.model.loop_kinematics import actuator_states
from dynid.model.mechanism import JointCoordinates, Mechanism
from dynid.model.transmission import Transmission
from dynid.pipeline import stribeck
from dynid.model.robot import joint_kinds
from dynid.pipeline.data import check_held_out, check_units, configured_estimator, ml_covariances, preprocess, read_log

__all__ = ["identify_mechanism", "mechanism_channels"]


def mechanism_channels(mech: Mechanism, force_model: str | None) -> tuple[str, ...]:
    """Names of the regression outputs: the actuators, or the independent coordinates for
    the projected equations of a redundantly actuated mechanism."""
    if force_model == "projected":
        ind = mech.independent
        if isinstance(ind, JointCoordinates):
            return tuple(f"u_{mech.pin_model.names[j + 1]}" for j in ind.joints)
        return tuple(f"u_{'xyz'[a]}" for a in ind.axes)
    return tuple(mech.actuated_names)


def _check_pose_domain(cfg: Config, mech: Mechanism) -> None:
    pc = cfg.processing.periodic
    if pc is None or pc.domain != "pose":
        return
    if not mech.task_coordinates:
        raise ConfigError(f"processing.periodic.domain = 'pose' needs a platform pose; {mech.name!r} declares no task coordinates")
    if mech.redundant:
        raise ConfigError("processing.periodic.domain = 'pose' is not available for redundantly actuated mechanisms yet")


def _force_model(cfg: Config, mech: Mechanism) -> str | None:
    fm = cfg.identification.force_model
    if mech.redundant:
        return fm or "projected"
    if fm is not None:
        raise ConfigError(
            f"identification.force_model applies to redundantly actuated mechanisms; {mech.name!r} has "
            f"{mech.n_actuators} actuators for {mech.dof} degrees of freedom"
        )
    return None


def _refuse_unsupported(cfg: Config) -> None:
    r = cfg.robot
    if r.has_transmission:
        raise ConfigError("robot: gear ratios, couplings, drive gains and offsets are not available for closed-loop mechanisms yet")
    if "extras" in cfg.raw.get("robot", {}):
        raise ConfigError("robot.extras applies to serial robots; a mechanism's joint terms come from its description")
    p = cfg.processing
    if p.decimate > 1 and p.decimate_method == "parallel":
        raise ConfigError("processing.decimate_method = 'parallel' is not available for closed-loop mechanisms yet; use 'samples'")
    if p.min_velocity is not None:
        raise ConfigError("processing.min_velocity is not available for closed-loop mechanisms yet")


def _actuator_space(ds: Dataset, mech: Mechanism, label: str) -> tuple[Dataset, list[str]]:
    notes: list[str] = []
    if ds.meta["position_side"] == "motor" or ds.meta["effort_side"] == "motor":
        raise ConfigError(f"{label}: motor-side signals need a transmission, not available for mechanisms yet")
    tau = ds.tau
    if ds.meta["effort_kind"] == "current":
        tau = Transmission.identity(mech.n_actuators).joint_torques_from_currents(tau)
        notes.append("efforts are motor currents with unit drive gains: parameters absorb the unknown gains")
    out = ds.replace(tau=tau, names=tuple(mech.actuated_names),
                     meta={"position_side": "joint", "effort_kind": "torque", "effort_side": "joint"})
    return out, notes


def _pose_chunks(mech: Mechanism, base: BaseParameters, ds: Dataset, periodic, progress, task: str):
    """The whole averaged period at once: forward kinematics of every sample, the platform pose
    filtered and differentiated in the frequency domain, the regressor in task coordinates
    (paper 004 §3.3; :func:`dynid.model.loop_kinematics.pose_states`)."""
    from dynid.model.loop_kinematics import pose_states

    fs = 1.0 / float(np.median(np.diff(ds.t)))
    state, *_ = pose_states(mech, ds.q, fs, periodic.cutoff_hz)
    reg = actuator_regressor(mech.in_task_space(), state)
    progress(task, ds.n_samples, ds.n_samples)
    yield base.regressor(reg.W), reg.outputs(ds.tau), np.zeros(ds.n_samples)


def _chunks(mech: Mechanism, base: BaseParameters, ds: Dataset, force_model: str | None, chunk: int,
            progress, task: str, periodic=None) -> Iterator[tuple[FloatArray, FloatArray, FloatArray]]:
    """Yield ``(W_base, y, inconsistency)`` chunk by chunk."""
    if periodic is not None and periodic.domain == "pose":
        yield from _pose_chunks(mech, base, ds, periodic, progress, task)
        return
    n = ds.n_samples
    q0 = None
    data = mech.pin_model.createData()
    for a in range(0, n, chunk):
        b = min(a + chunk, n)
        state, resid = actuator_states(mech, ds.q[a:b], ds.dq[a:b], ds.ddq[a:b], q0=q0, sample_offset=a)
        q0 = state.q[-1]
        reg = actuator_regressor(mech, state, distribution=force_model, data=data)
        yield base.regressor(reg.W), reg.outputs(ds.tau[a:b]), resid
        progress(task, b, n)


def _problem(mech, base, ds, force_model, chunk, progress, meta, periodic=None, cross=False):
    builder = ProblemBuilder(base.names, mechanism_channels(mech, force_model), cross=cross)
    worst = 0.0
    for W, y, resid in _chunks(mech, base, ds, force_model, chunk, progress, "compress", periodic):
        builder.add(W, y)
        worst = max(worst, float(resid.max()))
    return builder.build(expressions=base.expressions(), standard=_standard_map(mech, base), meta=meta), worst


def _standard_map(mech: Mechanism, base: BaseParameters) -> StandardMap:
    return StandardMap(
        standard_names=mech.parameter_names,
        B=base.B,
        body_blocks=mech.body_blocks(),
        nonnegative=mech.nonnegative_parameters(),
        reference=mech.nominal_parameters(),
        nonpositive=mech.nonpositive_parameters(),
    )


def _maximum_likelihood(cfg: Config, mech: Mechanism, base: BaseParameters, train_a: Dataset, channels, chunk: int,
                        progress, meta: dict):
    """Maximum likelihood with the filter cut-off (paper 004 Eq. 24): the averaged period is
    filtered at every candidate cut-off (actuator positions, or the platform pose after one
    forward kinematics), each gives a Gauss–Markov problem and the residual of the actuator
    positions. Returns the result, the periodic processing at the chosen cut-off and the
    largest inconsistency."""
    from dynid.estimation.likelihood import CutoffFamily, MaximumLikelihood, cutoff_candidates
    from dynid.model.loop_kinematics import platform_pose, pose_states
    from dynid.signals.periodic import fourier_filter

    pc, icfg = cfg.processing.periodic, cfg.identification
    if pc is None:
        raise ConfigError("identification.method = 'ml' estimates the cut-off of the frequency-domain filter: "
                          "it needs [processing.periodic] (period averaging, paper 004 §3)")
    if pc.filter_effort:
        raise ConfigError("identification.method = 'ml' models the efforts as measured: set "
                          "processing.periodic.filter_effort = false (paper 004 §3.3)")
    if mech.redundant:
        raise ConfigError("identification.method = 'ml' is not available for redundantly actuated mechanisms yet")
    avg, steps = preprocess(train_a, cfg.processing, "data", filter_positions=False)
    meta["processing"] = steps
    cov_e, cov_d = ml_covariances(icfg, steps, tuple(channels), tuple(mech.actuated_names))
    fs = 1.0 / float(np.median(np.diff(avg.t)))
    low, high = icfg.cutoff_range_hz or (0.5 * pc.cutoff_hz, 2.0 * pc.cutoff_hz)
    cutoffs = cutoff_candidates(pc.period_s, fs, low, min(high, 0.5 * fs * (1 - 1e-9)))
    pose = platform_pose(mech, avg.q) if pc.domain == "pose" else None
    worst = [0.0]
    act = list(mech.actuated)

    def build(fc: float):
        progress("cut-off search", cutoffs.index(fc), len(cutoffs))
        if pose is not None:
            state, *_ = pose_states(mech, avg.q, fs, fc, pose=pose)
            reg = actuator_regressor(mech.in_task_space(), state)
            builder = ProblemBuilder(base.names, tuple(channels), cross=True)
            builder.add(base.regressor(reg.W), reg.outputs(avg.tau))
            q_f = state.q[:, act]
        else:
            q_f, dq, ddq = fourier_filter(avg.q, fs, fc)
            builder = ProblemBuilder(base.names, tuple(channels), cross=True)
            for W, y, resid in _chunks(mech, base, avg.replace(q=q_f, dq=dq, ddq=ddq), None, chunk, _quiet, "ml"):
                builder.add(W, y)
                worst[0] = max(worst[0], float(resid.max()))
        problem = builder.build(expressions=base.expressions(), standard=_standard_map(mech, base), meta=meta)
        return problem, avg.q - q_f

    result = MaximumLikelihood(noise_covariance=cov_e, position_covariance=cov_d).fit(
        CutoffFamily(cutoffs, build, 1.0 / pc.period_s))
    progress("cut-off search", len(cutoffs), len(cutoffs))
    return result, dataclasses.replace(pc, cutoff_hz=result.solver["cutoff_hz"]), worst[0]


def _quiet(task: str, done: int, total: int) -> None:
    return None


def identify_mechanism(cfg: Config, mech: Mechanism, progress, versions: dict[str, str]):
    """:func:`dynid.pipeline.identify.identify` for a :class:`Mechanism` (see module docstring)."""
    from dynid.pipeline.identify import IdentifyOutcome, ValidationMetrics

    _refuse_unsupported(cfg)
    _check_pose_domain(cfg, mech)
    nonlinear, fj = cfg.identification.friction_model == "stribeck", None
    if nonlinear:
        stribeck.check_config(cfg, mech)
    force_model = _force_model(cfg, mech)
    names = tuple(mech.actuated_names)
    kinds = joint_kinds(mech.pin_model, mech.actuated)
    check_units(cfg.data, kinds, names, "data")
    check_units(cfg.validation, kinds, names, "validation")
    readers: dict = {}
    raw_train = read_log(cfg.data, mech.n_actuators, names, "data", readers)
    raw_valid = read_log(cfg.validation, mech.n_actuators, names, "validation", readers)
    check_held_out(raw_train, raw_valid)
    train_a, notes = _actuator_space(raw_train, mech, "data")
    valid_a, _ = _actuator_space(raw_valid, mech, "validation")
    icfg = cfg.identification

    def unknowns() -> tuple[int, int]:
        n_base = mechanism_base_parameters(mech, distribution=force_model, n_samples=icfg.base_samples,
                                           seed=icfg.base_seed).n_base
        return n_base, len(mechanism_channels(mech, force_model))

    train, steps = preprocess(train_a, cfg.processing, "data", unknowns=unknowns)
    held_out, _ = preprocess(valid_a, cfg.processing, "validation")
    rng = np.ptp(train.q, axis=0)
    still = [f"{n} (range {r:.3g})" for n, r in zip(names, rng) if r < cfg.identification.min_joint_motion]
    if still:
        raise IdentifiabilityError(f"data: actuator never moves: {', '.join(still)}")
    progress("base parameters", 0, 1)
    base = mechanism_base_parameters(mech, distribution=force_model, n_samples=cfg.identification.base_samples,
                                     seed=cfg.identification.base_seed)
    progress("base parameters", 1, 1)
    channels = mechanism_channels(mech, force_model)
    if train.n_samples * len(channels) <= base.n_base:
        raise InputError(f"data: {train.n_samples} processed samples x {len(channels)} equations are fewer than "
                         f"the {base.n_base} base parameters")
    meta: dict[str, Any] = {
        "versions": versions,
        "config_file": str(cfg.source) if cfg.source else None,
        "config": cfg.raw,
        "robot": {"model": cfg.robot.model, "name": mech.name, "kind": "closed-loop", "dof": mech.dof,
                  "actuators": list(names), "force_model": force_model or "actuator forces (non-redundant)"},
        "training_data": dict(raw_train.meta),
        "validation_data": dict(raw_valid.meta),
        "processing": steps,
        "base_parameters": {"n_base": base.n_base, "seed": base.seed, "n_samples": base.n_samples, "rank_tol": base.rank_tol},
    }
    chunk = max(1, min(int(cfg.identification.chunk_size), 2000))
    periodic = cfg.processing.periodic
    if icfg.method == "ml":
        result, periodic, worst = _maximum_likelihood(cfg, mech, base, train_a, channels, chunk, progress, meta)
        at_fc = dataclasses.replace(cfg.processing, periodic=periodic)  # both logs as processed at the estimated f_c
        train, _ = preprocess(train_a, at_fc, "data")
        held_out, _ = preprocess(valid_a, at_fc, "validation")
    elif nonlinear:
        fj = stribeck.friction_joints(mech, base)
        rows = stribeck.subsample(train, icfg.max_samples)
        chunks = list(_chunks(mech, base, rows, force_model, chunk, progress, "Stribeck rows", periodic))
        worst = max(float(r.max()) for _, _, r in chunks)
        sp = stribeck.sample_problem(((W, y) for W, y, _ in chunks), rows, fj, base, channels,
                                     _standard_map(mech, base), meta)
        progress("Stribeck fit", 0, 1)
        result = stribeck.describe(stribeck.estimator(cfg).fit(sp), base, fj, rows.n_samples, train.n_samples)
        progress("Stribeck fit", 1, 1)
    else:
        problem, worst = _problem(mech, base, train, force_model, chunk, progress, meta, periodic,
                                  cross=icfg.method == "gm")
        nominal = base.from_standard(mech.nominal_parameters()) if icfg.nominal_weighting else None
        result = configured_estimator(icfg, steps, tuple(channels), names, nominal).fit(problem)
    notes = list(notes)
    if force_model == "projected":
        notes.append("redundant actuation: projected equations G_a^T tau_a (no assumption about the force distribution)")
    elif force_model is not None:
        notes.append(f"redundant actuation: actuator forces assumed distributed as {force_model!r} (an assumption about the controller)")
    if mech.redundant:
        notes.append(f"largest RMS inconsistency of the redundant actuator positions: {worst:.3g}")
    result = result.with_notes(*notes) if notes else result
    meas, pred = [], []
    done = 0
    for W, y, _ in _chunks(mech, base, held_out, force_model, chunk, progress, "validate", periodic):
        meas.append(y)
        if nonlinear:
            pred.append(stribeck.predict(result, fj, W, held_out.dq[done : done + W.shape[0]]))
        else:
            pred.append(W @ result.params)
        done += W.shape[0]
    measured, predicted = np.concatenate(meas), np.concatenate(pred)
    metrics = ValidationMetrics.of(channels, np.asarray(held_out.t)[: measured.shape[0]], measured, predicted,
                                   held_out.meta.get("source"))
    return IdentifyOutcome(cfg, mech, base, result, metrics, train, held_out, tuple(notes), train_a)
