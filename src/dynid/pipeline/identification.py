"""``dynid identify``: configuration -> identified base parameters -> validation -> files.

One code path for serial and parallel robots (:mod:`dynid.model.system`): a serial arm is the
mechanism without closures. The log holds what a robot measures: actuator (joint) positions and
forces, or motor positions and currents through a drive train. Steps:

1. read the named columns (units to SI, windows; :mod:`dynid.pipeline.data`), map motor-side
   signals to the actuators through the transmission (``q_a = C^{-1}θ + q_0``, ``τ_a = C^T K i``);
2. process them: resampling, zero-phase low-pass, derivatives, trimming, decimation (or the
   period averaging and DFT filtering of paper 004 §3);
3. regression rows chunk by chunk (:meth:`System.rows`): for a serial robot pinocchio's
   joint-torque regressor with the extras; for a mechanism all joint states solved through the
   loops from the actuator states and the actuator-space regressor by virtual power (for
   redundant actuation the force model of ``identification.force_model``, default
   ``"projected"``: the measured forces enter as :math:`G_a^T\\tau_a`);
4. optionally Gautier's parallel decimation (each base-regressor column and each measured output
   low-passed by the same zero-phase filter, one sample in ``k`` kept; Gautier 1997) and the rows
   slower than ``processing.min_velocity`` left out (per actuator equation, or whole samples when
   the equations are not the actuators' own: projected equations; Gauss–Markov whitens a sample
   that keeps some actuators with the covariance of those, :class:`~dynid.estimation.problem.CrossBlock`);
5. compression into the regression problem (never the full regressor), the estimator of
   ``[identification]`` (or the Stribeck fit, or maximum likelihood with the filter cut-off,
   paper 004 Eq. 24), validation on held-out data processed identically (with a row selection
   also on the held-out rows it keeps, :class:`SelectedRows`), the output files.

The concerns live in their own modules, re-exported here: the rows and their compression
(:mod:`dynid.pipeline.rows`), several ``[[data]]`` experiments stacked as factors
(:mod:`dynid.pipeline.experiments`), the estimators that are not one compressed problem
(:mod:`dynid.pipeline.methods`), the outcome (:mod:`dynid.pipeline.outcome`) and the files
(:mod:`dynid.pipeline.outputs`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.config import Config
from dynid.dataset import Dataset
from dynid.errors import ConfigError, InputError
from dynid.estimation import IdentificationResult, RegressionProblem
from dynid.estimation.validation import ValidationMetrics, motion_overlap, prior_comparison
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System, as_system
from dynid.pipeline import stribeck
from dynid.pipeline import experiments as _experiments
from dynid.pipeline.covariance import block_builder, with_covariance
from dynid.pipeline.rows import (  # noqa: F401  (re-exported)
    Progress, _no_progress, Chunk, _chunks, CHUNK_BYTES, _parallel_chunks, row_mask, build_problem, _compress)
from dynid.pipeline.methods import (  # noqa: F401  (re-exported)
    _maximum_likelihood, ML_TIME_CANDIDATES, _acceleration_columns, _interp_rows, ML_INERTIA_POINTS_PER_CUTOFF_PERIOD, ML_INERTIA_MAX_FLOATS, _maximum_likelihood_time, _stribeck_fit, _control_loop, _coulomb_smoothing, _hierarchical_fit)
from dynid.pipeline.drive_gains import (  # noqa: F401  (re-exported)
    GAIN_REL_STD, GAIN_BLOCKS, estimate_drive_gains)
from dynid.pipeline.outcome import (  # noqa: F401  (re-exported: the names other modules import from here)
    RowSelection, SelectedRows, OtherView, _other_view, FullRate, IdentifyOutcome, _versions)
from dynid.pipeline.outputs import (  # noqa: F401
    OUTPUT_FILES, write_outputs, ONE_OF_MANY, standard_vector, export_model, export_warnings, _nominal_dict, _selected_dict, _full_rate_dict, write_files)
from dynid.pipeline.data import (build_system, check_held_out, check_joint_motion, check_units, configured_estimator, preprocess, read_log, to_actuator_space)
from dynid.pipeline.reporting import effort_units, file_sha256

__all__ = ["Chunk", "FullRate", "Progress", "ValidationMetrics", "IdentifyOutcome", "RowSelection", "SelectedRows", "build_problem",
           "prior_comparison", "row_mask", "validate", "validate_with_prior", "identify", "write_outputs",
           "write_files", "OUTPUT_FILES"]

def validate(result: IdentificationResult, robot, base: BaseParameters, ds: Dataset, *,
             force_model: str | None = None, parallel_decimate: int = 1, chunk_size: int = 20000,
             progress: Progress = _no_progress, friction: stribeck.FrictionJoints | None = None,
             periodic=None) -> ValidationMetrics:
    """Predict the held-out outputs with the identified base parameters; per-channel errors.

    The held-out data go through exactly the processing of the training data (including
    parallel decimation when used). ``robot``: a :class:`~dynid.model.system.System` or a model.
    ``friction``: the result is a Stribeck fit (:mod:`dynid.pipeline.stribeck`) with these
    friction joints.
    """
    return validate_with_prior(result, robot, base, ds, None, force_model=force_model,
                               parallel_decimate=parallel_decimate, chunk_size=chunk_size, progress=progress,
                               friction=friction, periodic=periodic)[0]


def validate_with_prior(result: IdentificationResult, robot, base: BaseParameters, ds: Dataset,
                        nominal: FloatArray | None, *, force_model: str | None = None, parallel_decimate: int = 1,
                        chunk_size: int = 20000, progress: Progress = _no_progress,
                        friction: stribeck.FrictionJoints | None = None,
                        periodic=None, selection: RowSelection | None = None,
                        ) -> tuple[ValidationMetrics, ValidationMetrics | None, OtherView | None, SelectedRows | None]:
    """:func:`validate`, and in the same pass over the held-out rows the errors of the nominal
    model (base parameters ``nominal`` of the robot description's standard parameters; None:
    not computed): the prior every identified model has to beat. For a redundantly actuated
    mechanism also the other view of the same predictions (:class:`OtherView`, None otherwise).
    With ``selection`` (the training's row selection) also both models' errors on the held-out
    rows that selection keeps (:class:`SelectedRows`, None otherwise)."""
    system = as_system(robot)
    if friction is None and tuple(result.names) != base.names:
        raise InputError("the result's parameters are not the base parameters of this robot")
    meas, pred, prior, kept = [], [], [], []
    alt: list[tuple[FloatArray, FloatArray, FloatArray | None]] = []
    guard = None if selection is None else selection.reversal_guard
    for c in _chunks(system, base, ds, force_model, parallel_decimate=parallel_decimate, chunk_size=chunk_size,
                     progress=progress, task="validate", periodic=periodic, reversal_guard=guard,
                     min_velocity=None if selection is None else selection.min_velocity):
        meas.append(c.y)
        if selection is not None:
            mask = row_mask(system, force_model, c.dq, selection.min_velocity,
                            joint_dq=c.joint_dq, min_velocity_passive=selection.min_velocity_passive,
                            reversal=c.reversal)
            kept.append(np.ones(c.y.shape, dtype=bool) if mask is None
                        else np.broadcast_to(mask if mask.ndim == 2 else mask[:, None], c.y.shape))
        pred.append(c.W @ result.params if friction is None else
                    friction.predict(result, c.W, c.dq, c.Ga) if hasattr(friction, "predict")  # hierarchical
                    else stribeck.predict(result, friction, c.W, c.dq))
        if nominal is not None:
            prior.append(c.W @ nominal)
        if c.Ga is not None and c.tau is not None:
            alt.append(_other_view(c.Ga, c.tau, pred[-1], prior[-1] if nominal is not None else None, force_model))
    measured, predicted = np.concatenate(meas), np.concatenate(pred)
    k = max(1, parallel_decimate)
    t = np.asarray(ds.t)[::k][: measured.shape[0]]
    names = system.channel_names(force_model)
    src = ds.meta.get("source")
    metrics = ValidationMetrics.of(names, t, measured, predicted, src)
    nominal_metrics = None if nominal is None else ValidationMetrics.of(names, t, measured, np.concatenate(prior), src)
    other = None
    if alt and len(alt) == len(meas):
        m_alt, p_alt = np.concatenate([a[0] for a in alt]), np.concatenate([a[1] for a in alt])
        projected = force_model == "projected"
        other_names = system.actuator_names if projected else system.channel_names("projected")
        other = OtherView(
            label=("per actuator, assuming the minimum-norm distribution tau_a = (G_a^T)^+ y of the projected "
                   "prediction y (an assumption about how the controller shares the forces; the projected "
                   "channels above need none)") if projected else
                  ("projected equations G_a^T tau_a (these need no assumption about the force distribution; the "
                   f"actuator channels above assume {force_model!r})"),
            metrics=ValidationMetrics.of(other_names, t, m_alt, p_alt, src),
            nominal=None if nominal is None else ValidationMetrics.of(
                other_names, t, m_alt, np.concatenate([a[2] for a in alt]), src))
    selected = None
    if selection is not None:
        mask = np.concatenate(kept)
        selected = SelectedRows(
            rule=selection.rule,
            metrics=ValidationMetrics.of(names, t, measured, predicted, src, kept=mask),
            nominal=None if nominal is None else ValidationMetrics.of(names, t, measured, np.concatenate(prior), src,
                                                                      kept=mask))
    return metrics, nominal_metrics, other, selected


def identify(cfg: Config, progress: Progress = _no_progress, *, readers: dict | None = None,
             plot_worker: bool = False) -> IdentifyOutcome:
    """Run the whole identification described by ``cfg`` (nothing is written).

    ``readers`` maps the files of ``cfg.data`` and ``cfg.validation`` to readers already open (the
    interface of :class:`~dynid.io.readers.TableReader`: ``columns``, ``sha256``); the array API
    (:func:`dynid.pipeline.arrays.identify_arrays`) hands its arrays in this way, through the
    same steps as a log on disk.

    ``plot_worker``: with ``output.plots``, draw the report's figures in a worker process started
    now, beside the identification, when a CPU is idle (:func:`dynid.report.worker.report_jobs`;
    ``dynid identify`` asks for it); :func:`write_outputs` collects them and stops the worker.
    Without it (the default: a library call starts no process) the figures are drawn by
    :func:`write_outputs`, in this process; the files are the same bytes either way."""
    t0 = time.perf_counter()
    jobs = None
    if cfg.output.plots:  # the report's figures: queued as their data appear, drawn beside the run or at the end
        from dynid.report.worker import InProcessJobs, report_jobs

        jobs = report_jobs() if plot_worker else InProcessJobs()
    try:
        outcome = _identify(cfg, progress, readers, jobs)
    except BaseException:
        if jobs is not None:
            jobs.close(kill=True)
        raise
    overlap = outcome.validation.overlap if outcome.train is None else motion_overlap(outcome.train, outcome.held_out)
    validation = dataclasses.replace(outcome.validation, overlap=overlap)
    prior = outcome.prior
    if outcome.nominal_validation is not None and prior is not None:  # the verdict names the kind of data
        prior = prior_comparison(validation, outcome.nominal_validation, prior["comparable"], validation.label)
    selected = outcome.selected
    if selected is not None:  # the same overlap (the same log), and the verdict on the selected rows
        sel = dataclasses.replace(selected.metrics, overlap=validation.overlap)
        sp = None if selected.nominal is None or prior is None else _selected_prior(
            sel, selected.nominal, prior["comparable"], f"row-selected {validation.label}")
        selected = dataclasses.replace(selected, metrics=sel, prior=sp)
    full = outcome.full_rate
    if full is not None and full.nominal is not None and prior is not None:
        full = dataclasses.replace(full, prior=prior_comparison(full.metrics, full.nominal, prior["comparable"],
                                                                f"full-rate {validation.label}"))
    if jobs is not None:
        jobs.submit_figure("validation.png", "dynid.report.plots:plot_validation", _validation_series(validation),
                           units=outcome.units or None)
    return dataclasses.replace(outcome, validation=validation, prior=prior, selected=selected, full_rate=full,
                               elapsed_s=time.perf_counter() - t0, jobs=jobs)


def _validation_series(v: ValidationMetrics) -> Any:
    """What :func:`~dynid.report.plots.plot_validation` draws of ``v`` (arrays only: light to send
    to the plot worker, which then needs no dynid.estimation)."""
    from types import SimpleNamespace

    return SimpleNamespace(t=v.t, measured=v.measured, predicted=v.predicted, channel_names=tuple(v.channel_names),
                           rmse=np.asarray(v.rmse), rel_rmse_pct=np.asarray(v.rel_rmse_pct), label=v.label,
                           thinned=v.thinned)  # a streamed run: its series already thinned (stream_plots)


def _submit_processing(jobs: Any, raw: Dataset, processed: Dataset) -> None:
    """Hand the processing figure (raw against processed positions) to ``jobs``, filters designed here."""
    from types import SimpleNamespace

    from dynid.report.plots import with_filter_sections

    def series(ds: Dataset) -> Any:
        return SimpleNamespace(t=ds.t, q=ds.q, names=ds.names)

    jobs.submit_figure("processing.png", "dynid.report.plots:plot_processing", series(raw), series(processed),
                       steps=with_filter_sections(processed.meta.get("processing")))


def _selected_prior(sel: ValidationMetrics, nominal: ValidationMetrics, comparable: bool, label: str) -> dict[str, Any]:
    """:func:`prior_comparison` on the selected rows; when the selection keeps no held-out row of
    a channel, no comparison, and the verdict says which channels (a held-out log that never
    moves an actuator fast enough, or never far from a reversal)."""
    empty = [c for c, k in zip(sel.channel_names, sel.rows_per_channel) if k == 0]
    if not empty:
        return prior_comparison(sel, nominal, comparable, label)
    return {"comparable": False, "beats_nominal": False, "empty_channels": empty,
            "verdict": (f"not compared on the {label} rows: the row selection keeps no held-out row of "
                        f"{', '.join(empty)} (the held-out log is never fast enough there, or never far enough from a "
                        "reversal)")}


def _check_config(cfg: Config, system: System) -> str | None:
    """Settings that cannot apply to this robot, for a physical reason; returns the force model."""
    pc, icfg = cfg.processing.periodic, cfg.identification
    if pc is not None and pc.domain == "pose" and not system.task_coordinates:
        raise ConfigError(f"processing.periodic.domain = 'pose' is for parallel robots with a platform pose; "
                          f"{system.name!r} has none (a serial arm, or a mechanism that declares no task coordinates)")
    force_model = system.force_model(icfg.force_model)
    if cfg.processing.min_velocity_passive is not None and not system.passive_friction_joints():
        raise ConfigError(f"processing.min_velocity_passive leaves out the samples where a passive joint with Coulomb "
                          f"friction is slow; {system.name!r} has no such joint "
                          f"({'a serial arm has no passive joint' if system.kind == 'serial' else 'no Coulomb term on a passive joint'})")
    if icfg.hierarchical:
        from dynid.pipeline import hierarchical

        hierarchical.check_config(cfg, system)
    elif icfg.friction_model == "stribeck":
        stribeck.check_config(cfg, system)
    if icfg.method in ("iv", "didim") and pc is not None:
        raise ConfigError(f"identification.method = {icfg.method!r} replays the experiment sample by sample; "
                          "processing.periodic replaces the log by one averaged period: use time-domain processing")
    return force_model


def _hierarchical_prior(cfg0: Config, result: IdentificationResult, force_model: str | None, held_out: Dataset,
                        held_full: Dataset | None, rows_rule, parallel: int, progress: Progress, periodic=None):
    """The nominal model of a hierarchical run as the robot description gives it, *with* its
    friction terms (the rigid-body regressor of the fit has none: scored through it, the CAD model
    would be scored without friction, an unfair baseline): (all held-out rows, the row-selected
    rows or None, the full-rate rows or None) of the description's base parameters through the
    configured robot's full regressor."""
    icfg = cfg0.identification
    system = build_system(cfg0.robot).with_structure(icfg.structure, icfg.identical_chains)
    base = system.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)
    nominal = base.from_standard(system.nominal_parameters())
    as_result = dataclasses.replace(result, names=base.names, params=nominal, cov_params=None)
    metrics, _, _, selected = validate_with_prior(as_result, system, base, held_out, None, force_model=force_model,
                                                  parallel_decimate=parallel, chunk_size=icfg.chunk_size,
                                                  progress=progress, periodic=periodic, selection=rows_rule)
    full = None
    if held_full is not None:
        full, _, _, _ = validate_with_prior(as_result, system, base, held_full, None, force_model=force_model,
                                            chunk_size=icfg.chunk_size, progress=progress)
    return metrics, None if selected is None else selected.metrics, full


def _run_meta(cfg: Config, system: System, force_model: str | None, base: BaseParameters, n_channels: int, n_eff: int,
              train_meta: Mapping[str, Any], valid_meta: Mapping[str, Any], steps: Any) -> dict[str, Any]:
    """The result's provenance common to the in-memory and the streamed path, after refusing
    fewer equations (``n_eff`` processed samples x ``n_channels``) than base parameters."""
    if n_eff * n_channels <= base.n_base:
        per = "joints" if system.kind == "serial" else "equations"
        raise InputError(f"data: {n_eff} processed samples x {n_channels} {per} are fewer than the "
                         f"{base.n_base} base parameters")
    return {
        "versions": _versions(),
        "config_file": str(cfg.source) if cfg.source else None,
        "config_sha256": file_sha256(cfg.source) if cfg.source else None,
        "config": cfg.raw,
        "robot": {"model": cfg.robot.model, **system.describe(),
                  **({"force_model": force_model or "actuator forces (non-redundant)"} if system.kind != "serial" else {})},
        "training_data": dict(train_meta),
        "validation_data": dict(valid_meta),
        "processing": steps,
        "base_parameters": {"n_base": base.n_base, "seed": base.seed, "n_samples": base.n_samples, "rank_tol": base.rank_tol},
    }


def _with_row_selection(result: IdentificationResult, pcfg, system: System, force_model: str | None) -> IdentificationResult:
    """The training's row selection in the result's provenance (``row_selection``)."""
    if pcfg.selects_rows:
        whole = not system.channels_are_actuators(force_model)
        selection = {"rows_kept_per_joint": result.n_obs.tolist()}
        if pcfg.min_velocity is not None:
            selection.update(min_velocity=list(pcfg.min_velocity),
                             rule=("whole samples with every actuator at least that fast" if whole
                                   else "per actuator equation"))
        if pcfg.min_velocity_passive is not None:
            jn = system.model.joint_names
            selection.update(min_velocity_passive=pcfg.min_velocity_passive,
                             passive_joints=[jn[j] for j in system.passive_friction_joints()],
                             passive_rule="whole samples with every passive joint with Coulomb friction at least that fast")
        if pcfg.reversal_guard is not None:
            selection.update(reversal_guard_s=pcfg.reversal_guard_s(), reversal_guard=pcfg.reversal_guard,
                             reversal_rule=("rows farther than the guard from every velocity reversal of the actuator"
                                            + (" and every sample slower than min_velocity" if pcfg.min_velocity else "")
                                            + (" (whole samples: every actuator)" if whole else " (per actuator equation)")))
        result = result.with_provenance(row_selection=selection)
    return result


def _identify(cfg: Config, progress: Progress, readers: dict | None = None, jobs: Any = None,
              gains: dict[str, Any] | None = None) -> IdentifyOutcome:
    cfg0 = cfg
    if cfg.identification.hierarchical:  # the friction-free regressor Phi_br (paper 003 Eq. 37)
        from dynid.pipeline.hierarchical import rigid_robot_config

        cfg = dataclasses.replace(cfg, robot=rigid_robot_config(cfg.robot))
    system = build_system(cfg.robot)
    original = system
    if cfg.identification.hierarchical:  # a mechanism's actuated joints lose their linear friction terms
        from dynid.pipeline.hierarchical import rigid_system

        system = rigid_system(system)
    auto, structure = None, None  # "auto": (full system, candidate chains, their source); the decision's record
    if cfg.identification.structure == "auto" and system.kind != "serial":
        from dynid.pipeline.structure import candidate_chains

        groups, source = candidate_chains(system.model, cfg.identification.identical_chains)
        if groups:
            system.with_structure("identical_chains", groups)  # the groups checked before any data is read
            auto = (groups, source)
        else:
            structure = {"mode": "auto", "chosen": "full",
                         "reason": "no identical chains: none declared by the robot description, none found in it"}
            cfg0, cfg = _explicit_structure(cfg0, "full", None), _explicit_structure(cfg, "full", None)
    else:
        system = system.with_structure(cfg.identification.structure, cfg.identification.identical_chains)
        if system.kind != "serial":
            structure = {"mode": "forced", "chosen": system.structure,
                         "reason": f"identification.structure = {cfg.identification.structure!r}",
                         **({"chains": [[list(c) for c in g] for g in system.reduction.chains]}
                            if system.reduction is not None else {})}
    _experiments.check_several(cfg, structure_decided=auto is not None)  # before the methods' own checks
    force_model = _check_config(cfg, system)
    icfg, pcfg = cfg.identification, cfg.processing
    if cfg.learning is not None:
        from dynid.learning import require_torch
        from dynid.pipeline.learning import check_learning

        check_learning(cfg, system)
        require_torch()  # before the identification, not after it
    names, kinds = system.actuator_names, system.actuator_kinds()
    check_units(cfg.data, kinds, names, "data")
    check_units(cfg.validation, kinds, names, "validation")
    readers = dict(readers or {})
    from dynid.pipeline import streaming

    several = len(cfg.training_logs) > 1
    for i, spec in enumerate(cfg.training_logs[1:], start=1):
        check_units(spec, kinds, names, f"data[{i}]")
    for i, spec in enumerate(cfg.validation_logs[1:], start=1):
        check_units(spec, kinds, names, f"validation[{i}]")
    streams, data_path = streaming.plan(cfg, system, readers)
    if cfg.identification.cluster != "off":  # the streamed path on a Dask cluster, or why not
        from dynid.pipeline.cluster_qr import check

        check(cfg, data_path["reason"] if streams is None else None)
    if streams is not None and several:
        raise ConfigError(f"data: {len(cfg.training_logs)} [[data]] experiments, but the training log is streamed "
                          f"({data_path.get('reason')}); several experiments are held in memory, one at a time")
    if streams is not None:
        if cfg.identification.structure == "auto":  # no decision on a stream (below): the full model
            cfg0, cfg = _explicit_structure(cfg0, "full", None), _explicit_structure(cfg, "full", None)
        outcome = _identify_streamed(cfg0, cfg, system, force_model, streams, data_path, progress)
        if auto is not None:  # the decision cross-validates over the log's segments, which a stream does not keep
            structure = {"mode": "auto", "chosen": "full", "chains": [[list(c) for c in g] for g in auto[0]],
                         "reason": f"identical chains {auto[1]}, but the training log is streamed ({data_path['reason']}) "
                                   "and the decision needs it in memory: full kept; identification.structure = "
                                   "'identical_chains' ties them"}
        return dataclasses.replace(outcome, structure=structure)
    raw_train = read_log(cfg.data, system.n_actuators, names, "data", readers)
    raw_valid = read_log(cfg.validation, system.n_actuators, names, "validation", readers)
    check_held_out(raw_train, raw_valid)
    train_a, notes = to_actuator_space(raw_train, system, "data")
    valid_a, _ = to_actuator_space(raw_valid, system, "validation")
    channels = system.channel_names(force_model)

    def base_parameters() -> BaseParameters:
        return system.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)

    train, steps = preprocess(train_a, pcfg, "data", unknowns=lambda: (base_parameters().n_base, len(channels)))
    if jobs is not None and icfg.method != "ml":  # (maximum likelihood processes again at its cut-off)
        _submit_processing(jobs, train_a, train)
    held_out, _ = preprocess(valid_a, pcfg, "validation")
    if system.kind != "serial" and system.model.independent_choice:  # a redundant robot's chart, over the log now
        system, cfg0, cfg = _chart_from_log(cfg0, cfg, system, train)
        channels = system.channel_names(force_model)  # the projected equations' channels follow the chart
        if original.kind != "serial":  # (hierarchical friction: the friction-carrying model, the same chart)
            original = dataclasses.replace(original, model=original.model.with_chart(independent=cfg.robot.independent))
        notes = [*notes, f"independent coordinates "
                         f"{', '.join(system.model.pin_model.names[j + 1] for j in system.model.independent.joints)}: "
                         f"{system.model.independent_choice}; [robot] independent overrides"]
    own_gains = raw_train.meta.get("drive_gains") is not None  # the log's effort.drive_gains
    if (gains is None and raw_train.meta["effort_kind"] == "current" and cfg0.robot.drive_gains is None
            and not own_gains and system.channels_are_actuators(force_model)):
        # currents without drive gains: the gains from the prior, then the identification in torque units
        progress("drive gains", 0, 1)
        est = estimate_drive_gains(system, base_parameters(), train, force_model,
                                   parallel_decimate=pcfg.decimate if pcfg.decimate_method == "parallel" else 1,
                                   chunk_size=icfg.chunk_size)
        progress("drive gains", 1, 1)
        rel = np.asarray(est["std"], float) / np.asarray(est["value"], float)
        est["used"] = bool(np.all(np.isfinite(rel)) and np.all(rel <= GAIN_REL_STD))
        if est["used"]:
            with_gains = dataclasses.replace(cfg0, robot=dataclasses.replace(cfg0.robot, drive_gains=tuple(est["value"])))
            return _identify(with_gains, progress, readers, jobs, gains=est)
        gains = est  # reported, not used
    if several and raw_train.meta["effort_kind"] == "current" and cfg0.robot.drive_gains is None and not own_gains:
        raise ConfigError("robot.drive_gains: several [[data]] experiments measure currents; give the drive gains "
                          "(they are estimated from one log only)")
    smoothing = _coulomb_smoothing(icfg.coulomb_smoothing, train_a, pcfg, system)
    if smoothing is not None:
        system = system.with_coulomb_width(smoothing["width"])
    check_joint_motion(train, system, icfg.min_joint_motion, "data")
    if auto is not None:
        system, structure, cfg0, cfg = _decide_structure(cfg0, cfg, system, train, force_model, auto, progress)
        icfg = cfg.identification
    progress("base parameters", 0, 1)
    base = base_parameters()
    progress("base parameters", 1, 1)
    parallel = pcfg.decimate if pcfg.decimate_method == "parallel" else 1
    n_eff = -(-train.n_samples // parallel)
    meta = _run_meta(cfg, system, force_model, base, len(channels), n_eff, raw_train.meta, raw_valid.meta, steps)
    periodic, fj = pcfg.periodic, None
    payload_outcome = None  # the joint arm + payload mode: the payload (dynid.pipeline.joint_payload)
    if icfg.method == "ml" and pcfg.periodic is None:
        result, pcfg, worst = _maximum_likelihood_time(cfg, system, base, train_a, force_model, progress, meta)
        if "coulomb_width" in result.solver:  # the smooth sign of the chosen cut-off, in prediction too
            smoothing = {**smoothing, "width": result.solver["coulomb_width"],
                         "source": f"auto: velocity-noise std of the training log after the low-pass at the maximum "
                                   f"likelihood cut-off {result.solver['cutoff_hz']:.3g} Hz"}
            system = system.with_coulomb_width(smoothing["width"])
        train, _ = preprocess(train_a, pcfg, "data")  # both logs as processed at the estimated f_c
        held_out, _ = preprocess(valid_a, pcfg, "validation")
        if jobs is not None:
            _submit_processing(jobs, train_a, train)
    elif icfg.method == "ml":
        result, periodic, worst = _maximum_likelihood(cfg, system, base, train_a, force_model, progress, meta)
        at_fc = dataclasses.replace(pcfg, periodic=periodic)  # both logs as processed at the estimated f_c
        train, _ = preprocess(train_a, at_fc, "data")
        held_out, _ = preprocess(valid_a, at_fc, "validation")
        if jobs is not None:
            _submit_processing(jobs, train_a, train)
    elif icfg.hierarchical:
        result, fj, worst = _hierarchical_fit(cfg, system, base, train, steps, tuple(channels), tuple(names), progress,
                                              meta, original)
    elif icfg.friction_model == "stribeck":
        result, fj, worst = _stribeck_fit(cfg, system, base, train, force_model, periodic, progress, meta)
    elif icfg.method in ("iv", "didim"):
        result, worst = _control_loop(cfg, system, base, train, force_model, parallel, meta, progress)
    elif several:
        result, worst, payload_outcome = _several(cfg, system, base, train, steps, raw_train.meta, force_model,
                                                  parallel, meta, progress, names, readers)
    else:
        blocks = block_builder(icfg.covariance, base.names, channels, n_eff)
        problem, worst = _compress(system, base, train, force_model=force_model, min_velocity=pcfg.min_velocity,
                                       parallel_decimate=parallel, chunk_size=icfg.chunk_size, progress=progress,
                                       meta=meta, cross=icfg.method == "gm", periodic=periodic,
                                       min_velocity_passive=pcfg.min_velocity_passive, blocks=blocks,
                                       reversal_guard=pcfg.reversal_guard_s())
        nominal = base.from_standard(system.nominal_parameters()) if icfg.nominal_weighting else None
        result = configured_estimator(icfg, steps, tuple(channels), tuple(names), nominal).fit(problem)
        result = with_covariance(result, blocks, icfg.covariance)
    result = _with_row_selection(result, pcfg, system, force_model)
    notes = list(notes)
    if gains is not None:
        result = result.with_provenance(drive_gains=gains)
        told = ", ".join(f"{nm} {k:.4g} +- {1.96 * s:.2g}" for nm, k, s in zip(names, gains["value"], gains["std"]))
        if gains["used"]:
            notes = [n for n in notes if "drive gains are 1" not in n and "unit drive gains" not in n]
            notes.append(f"drive gains estimated from the prior (robot.drive_gains not given; N*m/A, 95 % interval): "
                         f"{told}; the parameters, the comparison with the prior and the exported model are in torque "
                         "units")
        else:
            weak = [nm for nm, k, s in zip(names, gains["value"], gains["std"]) if not s <= GAIN_REL_STD * k]
            notes.append(f"drive gains NOT estimated: the prior does not decide those of {', '.join(weak)} (relative "
                         f"standard error above {100 * GAIN_REL_STD:g} %; all: {told} N*m/A); unit gains used, so the "
                         "parameters absorb the gains and are not comparable with the prior: give robot.drive_gains "
                         "(a known-payload experiment measures them)")
    if smoothing is not None:
        result = result.with_provenance(coulomb_smoothing=smoothing)
        notes.append(f"Coulomb terms: smooth sign erf(v / (sqrt(2) w)) with w = "
                     f"{', '.join(f'{n} {w:.3g}' for n, w in zip(names, smoothing['width']))} ({smoothing['source']}); "
                     "the same in prediction")
    if force_model == "projected":
        notes.append("redundant actuation: projected equations G_a^T tau_a (no assumption about the force distribution)")
    elif force_model is not None:
        notes.append(f"redundant actuation: actuator forces assumed distributed as {force_model!r} (an assumption about the controller)")
    if system.redundant:
        notes.append(f"largest RMS inconsistency of the redundant actuator positions: {worst:.3g}")
    if notes:
        result = result.with_notes(*notes)
    scored = score_held_out(cfg0, cfg, system, base, result, force_model, pcfg, held_out, valid_a, fj, periodic,
                            parallel, progress)
    metrics, prior, other, selected, full = scored
    if several or len(cfg.validation_logs) > 1:
        result = _per_log_validation(cfg, system, base, result, force_model, pcfg, metrics, parallel, names, readers,
                                     progress, payload_outcome)
    tr = system.transmission
    comparable = not (raw_train.meta["effort_kind"] == "current" and raw_train.meta.get("drive_gains") is None
                      and (tr is None or np.all(tr.drive_gains == 1.0)))
    learned = None
    if cfg.learning is not None:
        learned = _learn(cfg, system, base, result, train, held_out, icfg.chunk_size, progress,
                         fj if icfg.hierarchical else None)
    prediction = prediction_inputs(cfg0, pcfg, periodic, smoothing, system, base, force_model)
    alarms = _alarms(system, result, prior, comparable, ((train_a.q, train_a.tau, "data"),
                                                        (valid_a.q, valid_a.tau, "validation")))
    if structure is not None:  # what predict rebuilds: the structure chosen, never "auto" again
        ident = {k: v for k, v in prediction["identification"].items() if k != "identical_chains"}
        red = getattr(system, "reduction", None)
        prediction["identification"] = {**ident, "structure": system.structure,
                                         **({"identical_chains": [[list(c) for c in g] for g in red.chains]}
                                            if red is not None else {})}
        result = result.with_notes(f"parameter structure {structure['chosen']} ({structure['mode']}): see summary "
                                   "'Parameter structure' and result.json 'structure'")
    return IdentifyOutcome(cfg, system.model, base, result, metrics, train, held_out, tuple(notes), train_a,
                           warnings=alarms,
                           nominal_validation=prior, prior=prior_comparison(metrics, prior, comparable), system=system,
                           other_view=other, selected=selected, full_rate=full, learning=learned, payload=payload_outcome,
                           units=effort_units(system, force_model, raw_train.meta["effort_kind"]), prediction=prediction,
                           data_path={**data_path, "training_samples": train.n_samples}, structure=structure)


def _several(cfg: Config, system: System, base: BaseParameters, train: Dataset, steps, raw_meta, force_model, parallel,
             meta, progress, names, readers) -> tuple[IdentificationResult, float, Any]:
    """The ``[[data]]`` experiments, each processed and compressed on its own, their factors stacked
    (:mod:`dynid.pipeline.experiments`); the configured estimator (OLS or WLS) on the stacked factors."""
    pcfg, icfg = cfg.processing, cfg.identification
    worst = [0.0]

    joint = cfg.payload is not None  # the joint arm + payload mode (dynid.pipeline.joint_payload)
    if joint:
        from dynid.pipeline import joint_payload as _jp

        _jp.check_joint(cfg, system)
        mount = _jp.payload_columns(system, cfg.payload.body)

    def compress(ds: Dataset) -> RegressionProblem:
        if joint:
            return _jp.compress_joint(system, base, mount[1], ds, force_model=force_model, pcfg=pcfg, icfg=icfg,
                                      parallel=parallel, progress=progress, meta=meta)
        problem, w = _compress(system, base, ds, force_model=force_model, min_velocity=pcfg.min_velocity,
                               parallel_decimate=parallel, chunk_size=icfg.chunk_size, progress=progress, meta=meta,
                               cross=False, periodic=None, min_velocity_passive=pcfg.min_velocity_passive,
                               reversal_guard=pcfg.reversal_guard_s())
        worst[0] = max(worst[0], w)
        return problem

    def read(spec, label: str):
        raw = read_log(spec, system.n_actuators, names, label, readers)
        a, _ = to_actuator_space(raw, system, label)
        ds, st = preprocess(a, pcfg, label)
        check_joint_motion(ds, system, icfg.min_joint_motion, label)
        return ds, st, raw.meta

    first = _experiments.Experiment(0, cfg.training_logs[0], train, compress(train), dict(raw_meta), steps)
    exps = _experiments.build_experiments(cfg, first, compress, read)
    if joint:
        arm, outcome = _jp.fit_experiments(cfg, system, base, exps, mount, _experiments.collapse)
        return arm, worst[0], outcome
    stacked = _experiments.stack(exps)
    nominal = base.from_standard(system.nominal_parameters()) if icfg.nominal_weighting else None
    estimator = configured_estimator(icfg, steps, stacked.channel_names, tuple(names), nominal)
    return _experiments.collapse(estimator.fit(stacked), stacked, exps), worst[0], None


def _per_log_validation(cfg: Config, system: System, base: BaseParameters, result: IdentificationResult, force_model,
                        pcfg, first: ValidationMetrics, parallel, names, readers, progress,
                        payload=None) -> IdentificationResult:
    """A held-out table per ``[[validation]]`` log (each processed on its own) and the pooled one."""
    per_log = [_experiments.validation_record("validation[0]", cfg.validation_logs[0], first)]
    for i, spec in enumerate(cfg.validation_logs[1:], start=1):
        label = f"validation[{i}]"
        raw = read_log(spec, system.n_actuators, names, label, readers)
        a, _ = to_actuator_space(raw, system, label)
        ds, _ = preprocess(a, pcfg, label)
        res_i, base_i = result, base
        if spec.payload and payload is not None:  # predicted with the identified payload (joint mode)
            from dynid.pipeline.joint_payload import with_payload

            res_i, base_i = with_payload(result, base, payload, system)
            label += " (with the payload)"
        m = validate(res_i, system, base_i, ds, force_model=force_model, parallel_decimate=parallel,
                     chunk_size=cfg.identification.chunk_size, progress=progress)
        per_log.append(_experiments.validation_record(label, spec, m))
    pooled = _experiments.pooled_validation(per_log, first.channel_names)
    return result.with_provenance(validation_logs=per_log, validation_pooled=pooled)


def _chart_from_log(cfg0: Config, cfg: Config, system: System, train: Dataset,
                    max_samples: int = 200) -> tuple[System, Config, Config]:
    """The independent coordinates of a redundantly actuated mechanism that were chosen over its
    workspace, chosen again over the training log (:meth:`~dynid.model.mechanism.Mechanism.choose_independent`
    on up to ``max_samples`` evenly spread samples, all joints solved through the workspace chart);
    both configs then name them in ``[robot] independent`` (what the hierarchical prior and
    ``dynid predict`` rebuild)."""
    mech = system.model
    act = list(mech.actuated)
    cols = [act.index(j) for j in mech.independent.joints]
    pick = np.unique(np.linspace(0, train.n_samples - 1, min(max_samples, train.n_samples)).astype(int))
    q = mech.solve_positions(np.asarray(train.q)[pick][:, cols])
    chosen = mech.choose_independent(q, "samples of the training log")
    names = tuple(chosen.pin_model.names[j + 1] for j in chosen.independent.joints)

    def named(c: Config) -> Config:
        return dataclasses.replace(c, robot=dataclasses.replace(c.robot, independent=names))

    return dataclasses.replace(system, model=chosen), named(cfg0), named(cfg)


def _decide_structure(cfg0: Config, cfg: Config, system: System, train: Dataset, force_model: str | None,
                      auto: tuple, progress: Progress) -> tuple[System, dict[str, Any], Config, Config]:
    """``identification.structure = "auto"``: the full and the tied model compared on the training
    log (:func:`dynid.pipeline.structure.decide_structure`); returns the chosen system, the decision's
    record and both configs with the structure made explicit (what the rest of the run, the
    hierarchical prior and ``dynid predict`` rebuild)."""
    from dynid.pipeline.structure import N_SEGMENTS, decide_structure

    groups, source = auto
    icfg, pcfg = cfg.identification, cfg.processing
    tied = system.with_structure("identical_chains", groups)
    base_full = system.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)
    base_tied = tied.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)
    parallel = pcfg.decimate if pcfg.decimate_method == "parallel" else 1
    pose = pcfg.periodic is not None and pcfg.periodic.domain == "pose"  # one averaged period: no time segments
    k = 1 if pose else N_SEGMENTS
    edges = np.linspace(0, train.n_samples, k + 1).astype(int)
    segments = []
    for a, b in zip(edges[:-1], edges[1:]):
        part = train if k == 1 else train.rows(int(a), int(b))
        segments.append(_compress(system, base_full, part, force_model=force_model, min_velocity=pcfg.min_velocity,
                                  parallel_decimate=parallel, chunk_size=icfg.chunk_size, progress=progress,
                                  meta={}, cross=False, periodic=pcfg.periodic if pose else None,
                                  min_velocity_passive=pcfg.min_velocity_passive,
                                  reversal_guard=pcfg.reversal_guard_s(), check=False)[0])
    decision = decide_structure(segments, base_full, base_tied, tied.reduction.T, groups, source)
    chosen = tied if decision.chosen == "identical_chains" else system
    chains = groups if decision.chosen == "identical_chains" else None

    return (chosen, decision.record, _explicit_structure(cfg0, decision.chosen, chains),
            _explicit_structure(cfg, decision.chosen, chains))


def _explicit_structure(cfg: Config, structure: str, chains) -> Config:
    """``cfg`` with the structure ``"auto"`` chose (what the hierarchical prior rebuilds)."""
    ic = dataclasses.replace(cfg.identification, structure=structure, identical_chains=chains)
    return dataclasses.replace(cfg, identification=ic)


def _alarms(system: System, result: IdentificationResult, nominal: ValidationMetrics | None, comparable: bool,
            logs: tuple[tuple[FloatArray, FloatArray, str], ...]) -> tuple[Any, ...]:
    """The warnings of :mod:`dynid.pipeline.diagnostics` on this run: positions and efforts of
    each log ``(q, tau, label)`` (actuator space, SI) against the description's limits, the
    nominal model's held-out prediction against the measured efforts, the signs of the estimated
    friction. Efforts that are motor currents with unit drive gains (``comparable`` False) are in
    A: neither the effort limits nor the nominal model apply to them."""
    from dynid.pipeline.diagnostics import friction_alarms, limit_alarms, nominal_alarms

    out = []
    names, kinds = system.actuator_names, system.actuator_kinds()
    for q, tau, label in logs:
        out += limit_alarms(q, tau if comparable else None, names, kinds, system, label)
    if nominal is not None and comparable:
        out += nominal_alarms(nominal, nominal.label)
    out += friction_alarms(result, system)
    return tuple(out)


def _identify_streamed(cfg0: Config, cfg: Config, system: System, force_model: str | None, streams, data_path: dict,
                       progress: Progress) -> IdentifyOutcome:
    """:func:`_identify` on logs read, processed and compressed chunk by chunk
    (:mod:`dynid.pipeline.streaming`): the same estimate, validation and checks, without holding
    the logs (only the time columns). :func:`dynid.pipeline.streaming.plan` has checked that every
    step of this configuration can be done so."""
    from types import SimpleNamespace

    from dynid.pipeline.stream_plots import ProcessingPlot, ValidationPlot
    from dynid.pipeline.streaming import ErrorSums, StateSample, motion_overlap_streamed

    icfg, pcfg = cfg.identification, cfg.processing
    tr, va = streams
    check_held_out(tr.as_dataset_stub(), va.as_dataset_stub())
    names, channels = system.actuator_names, system.channel_names(force_model)
    proc = tr.processing(pcfg)
    steps = proc["steps"]
    progress("base parameters", 0, 1)
    base = system.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)
    progress("base parameters", 1, 1)
    n_eff = len(proc["rows"])
    meta = _run_meta(cfg, system, force_model, base, len(channels), n_eff, tr.meta, va.meta, steps)
    size = max(1, int(icfg.chunk_size) if system.max_chunk is None else min(int(icfg.chunk_size), system.max_chunk))
    constant: dict[str, Any] = {}
    notes: list[str] = []
    q_lo = np.full(system.n_actuators, np.inf)
    q_hi = np.full(system.n_actuators, -np.inf)
    tau_max = np.zeros(system.n_actuators)
    reference = StateSample(n_eff, 20000, std=True)
    plots = cfg.output.plots
    proc_plot = ProcessingPlot(tr.t, n_eff, proc["k"], system.n_actuators) if plots else None

    def training_chunks() -> Iterator[Chunk]:
        nonlocal q_lo, q_hi, tau_max
        rows = system.rows(force_model)
        for j0, p in tr.processed(system, pcfg, size, constant=constant, notes=notes,
                                  raw_tap=proc_plot.add_raw if plots else None):
            q_lo, q_hi = np.minimum(q_lo, p["q"].min(axis=0)), np.maximum(q_hi, p["q"].max(axis=0))
            tau_max = np.maximum(tau_max, np.abs(p["tau"]).max(axis=0))
            reference.add(j0, p)
            if plots:
                proc_plot.add_processed(j0, p)
            r = rows(p["q"], p["dq"], p["ddq"], p["tau"], j0)
            yield Chunk(base.regressor(r.W), r.y, p["dq"], r.inconsistency, r.joint_dq, None, r.Ga, None)
            progress("compress", j0 + p["t"].shape[0], n_eff)

    if icfg.cluster != "off":  # the chunks on a Dask cluster, their factors tree-reduced there
        from dynid.pipeline.cluster_qr import compress_on_cluster

        blocks = None  # (covariance = "model": dynid.pipeline.cluster_qr.check)
        problem, run = compress_on_cluster(cfg, system, base, force_model, tr, size, meta, progress)
        root = run.root
        q_lo, q_hi, tau_max, constant, notes = root.q_lo, root.q_hi, root.tau_max, root.constant, root.notes
        reference, data_path = run.reference, {**data_path, "cluster": run.record}
    else:
        blocks = block_builder(icfg.covariance, base.names, channels, n_eff)
        problem, worst = _compress(system, base, None, force_model=force_model, min_velocity=pcfg.min_velocity,
                                   parallel_decimate=1, chunk_size=size, progress=progress, meta=meta,
                                   cross=icfg.method == "gm", periodic=None,
                                   min_velocity_passive=pcfg.min_velocity_passive, blocks=blocks, source=training_chunks())
    tr.check_constant(constant)
    check_joint_motion(SimpleNamespace(q=np.vstack([q_lo, q_hi])), system, icfg.min_joint_motion, "data")
    nominal_w = base.from_standard(system.nominal_parameters()) if icfg.nominal_weighting else None
    result = configured_estimator(icfg, steps, tuple(channels), tuple(names), nominal_w).fit(problem)
    result = with_covariance(result, blocks, icfg.covariance)
    result = _with_row_selection(result, pcfg, system, force_model)
    notes = [n for n in notes if n != "-"]
    if notes:
        result = result.with_notes(*notes)

    nominal = base.from_standard(system.nominal_parameters())
    rows_rule = None
    if pcfg.selects_rows:
        rule = [f"min_velocity {list(pcfg.min_velocity)}"] if pcfg.min_velocity is not None else []
        if pcfg.min_velocity_passive is not None:
            rule.append(f"min_velocity_passive {pcfg.min_velocity_passive:g}")
        rows_rule = RowSelection(pcfg.min_velocity, pcfg.min_velocity_passive, None, ", ".join(rule))
    src = va.meta.get("source")

    def score(decimate: int | None, sample: StateSample | None, selection: RowSelection | None, plot: bool = False):
        nc = len(channels)
        sums = [ErrorSums(nc) for _ in range(4)]  # identified, nominal, and both on the selected rows
        rows = system.rows(force_model)
        n_val = len(va.processing(pcfg, decimate)["rows"])
        vplot = ValidationPlot(n_val, nc) if plot else None
        for j0, p in va.processed(system, pcfg, size, decimate=decimate):
            if sample is not None:
                sample.add(j0, p)
            r = rows(p["q"], p["dq"], p["ddq"], p["tau"], j0)
            W = base.regressor(r.W)
            pred, prior = W @ result.params, W @ nominal
            sums[0].add(r.y, pred)
            sums[1].add(r.y, prior)
            if vplot is not None:
                vplot.add(j0, p["t"], r.y, pred, prior)
            if selection is not None:
                mask = row_mask(system, force_model, p["dq"], selection.min_velocity, joint_dq=r.joint_dq,
                                min_velocity_passive=selection.min_velocity_passive)
                kept = (np.ones(r.y.shape, dtype=bool) if mask is None
                        else np.broadcast_to(mask if mask.ndim == 2 else mask[:, None], r.y.shape))
                sums[2].add(r.y, pred, kept)
                sums[3].add(r.y, prior, kept)
            progress("validate", j0 + p["t"].shape[0], n_val)
        selected = None if selection is None else SelectedRows(
            rule=selection.rule, metrics=sums[2].metrics(channels, src, counts=True),
            nominal=sums[3].metrics(channels, src, counts=True))
        ident, nom = sums[0].metrics(channels, src), sums[1].metrics(channels, src)
        if vplot is not None:
            ident = dataclasses.replace(ident, thinned=vplot.thinned())
            nom = dataclasses.replace(nom, thinned=vplot.thinned(nominal=True))
        return ident, nom, selected

    held = StateSample(len(va.processing(pcfg)["rows"]), 1000, std=False)
    metrics, prior, selected = score(None, held, rows_rule, plot=plots)
    metrics = dataclasses.replace(metrics, overlap=motion_overlap_streamed(reference, held))
    full = None
    if pcfg.decimate > 1:
        fm, fn, _ = score(1, None, None)
        full = FullRate(fm, fn, decimate=pcfg.decimate)
    comparable = not (tr.meta["effort_kind"] == "current" and (system.transmission is None
                                                                 or np.all(system.transmission.drive_gains == 1.0)))
    prediction = prediction_inputs(cfg0, pcfg, None, None, system, base, force_model)
    # the training log's extremes (processed: the streamed path holds no raw log)
    alarms = _alarms(system, result, prior, comparable, ((np.vstack([q_lo, q_hi]), tau_max[None, :], "data"),))
    return IdentifyOutcome(cfg, system.model, base, result, metrics, None, None, tuple(notes), None,
                           warnings=alarms,
                           nominal_validation=prior, prior=prior_comparison(metrics, prior, comparable), system=system,
                           selected=selected, full_rate=full,
                           units=effort_units(system, force_model, tr.meta["effort_kind"]), prediction=prediction,
                           data_path={**data_path, "training_samples": n_eff},
                           streamed_plots=proc_plot.signals(names, steps) if plots else None)


def score_held_out(cfg0: Config, cfg: Config, system: System, base: BaseParameters, result: IdentificationResult,
                   force_model: str | None, pcfg, held_out: Dataset, valid_a: Dataset, fj, periodic, parallel: int,
                   progress: Progress = _no_progress):
    """The identified and the nominal model on a processed held-out log (``held_out``; ``valid_a``:
    the same log in actuator space before the processing, for the full-rate scores): (metrics,
    nominal metrics, other view, selected rows, full rate). ``identify`` scores its validation log
    with it and ``dynid predict`` (:mod:`dynid.pipeline.predict`) a new log, so both apply one
    rule. ``cfg0``: the configuration as given (a hierarchical run's nominal model keeps its
    friction, :func:`_hierarchical_prior`); ``cfg``: as identified; ``pcfg``: the processing the
    model was identified with (maximum likelihood: at the estimated cut-off)."""
    icfg = cfg.identification
    nominal = base.from_standard(system.nominal_parameters())
    rows_rule = None
    if pcfg.selects_rows and not (icfg.method == "ml" and pcfg.periodic is not None):  # periodic ml: no rows selected
        rule = [f"min_velocity {list(pcfg.min_velocity)}"] if pcfg.min_velocity is not None else []
        if pcfg.min_velocity_passive is not None:
            rule.append(f"min_velocity_passive {pcfg.min_velocity_passive:g}")
        if pcfg.reversal_guard is not None:
            rule.append(f"reversal_guard {pcfg.reversal_guard_s():.3g} s")
        rows_rule = RowSelection(pcfg.min_velocity, pcfg.min_velocity_passive, pcfg.reversal_guard_s(),
                                 ", ".join(rule))
    metrics, prior, other, selected = validate_with_prior(
        result, system, base, held_out, nominal, force_model=force_model, parallel_decimate=parallel,
        chunk_size=icfg.chunk_size, progress=progress, friction=fj, periodic=periodic, selection=rows_rule)
    full, held_full = None, None
    if pcfg.decimate > 1 and periodic is None:
        held_full, _ = preprocess(valid_a, dataclasses.replace(pcfg, decimate=1), "validation")
        fm, fn, _, _ = validate_with_prior(result, system, base, held_full, nominal, force_model=force_model,
                                           chunk_size=icfg.chunk_size, progress=progress, friction=fj)
        full = FullRate(fm, fn, decimate=pcfg.decimate)
    if icfg.hierarchical:  # the CAD model with the description's friction, not the rigid part alone
        prior, sel_nominal, full_nominal = _hierarchical_prior(cfg0, result, force_model, held_out, held_full,
                                                               rows_rule, parallel, progress, periodic)
        if selected is not None:
            selected = dataclasses.replace(selected, nominal=sel_nominal)
        if full is not None:
            full = dataclasses.replace(full, nominal=full_nominal)
    return metrics, prior, other, selected, full


PREDICTION_FORMAT = 1
"""Version of the ``prediction_inputs`` section of result.json (:func:`prediction_inputs`); ``dynid
predict`` refuses a result without it or with another version."""


def prediction_inputs(cfg0: Config, pcfg, periodic, smoothing: dict[str, Any] | None, system: System,
                      base: BaseParameters, force_model: str | None) -> dict[str, Any]:
    """What ``dynid predict`` needs to score the saved model on a new log exactly as ``identify``
    scored its validation log: the robot description (resolved path) and drive train, the
    processing as identified (maximum likelihood: at the estimated cut-off), the
    ``[identification]`` table (structure, force model, base-parameter seed, hierarchical friction),
    the Coulomb smoothing widths of the fit, and the base-parameter definition to check against."""
    eff = pcfg if periodic is None or pcfg.periodic is None else dataclasses.replace(pcfg, periodic=periodic)
    robot = dataclasses.asdict(cfg0.robot)
    return {
        "format_version": PREDICTION_FORMAT,
        "config_dir": None if cfg0.source is None else str(Path(cfg0.source).parent),
        "robot": robot,
        "processing": dataclasses.asdict(eff),
        "identification": dict(cfg0.raw.get("identification", {})),
        "learning": cfg0.raw.get("learning"),
        "coulomb_width": None if smoothing is None else list(smoothing["width"]),
        "force_model": force_model,
        "actuators": list(system.actuator_names),
        "channels": list(system.channel_names(force_model)),
        "base_parameters": {"names": list(base.names), "standard_names": list(base.standard_names),
                            "B": base.B.tolist()},
    }


def _model_rows(system: System, base: BaseParameters, params: FloatArray, ds: Dataset,
                chunk_size: int) -> tuple[FloatArray, FloatArray]:
    """(measured, predicted) joint torques of a processed serial-robot Dataset at every sample."""
    meas, pred = [], []
    for c in _chunks(system, base, ds, None, chunk_size=chunk_size):
        meas.append(c.y)
        pred.append(c.W @ params)
    return np.concatenate(meas), np.concatenate(pred)


def _learn(cfg: Config, system: System, base: BaseParameters, result: IdentificationResult, train: Dataset,
           held_out: Dataset, chunk_size: int, progress: Progress, curves=None):
    """[learning]: the residual network (paper 003 Sec. 3.4) on the training log's residual.
    ``curves``: the friction curves of a hierarchical identification (paper 003 Sec. 3.3): the model
    is then the rigid-body part plus them, and the network's physical loss acts on them."""
    from dynid.pipeline.learning import linear_friction, train_and_validate

    names = tuple(system.actuator_names)
    y_tr, p_tr = _model_rows(system, base, result.params, train, chunk_size)
    y_va, p_va = _model_rows(system, base, result.params, held_out, chunk_size)
    fr = linear_friction(base.names, result.params, len(names))
    f_tr = None
    if curves is not None:
        f_tr = curves.force(train.dq)
        p_tr, p_va = p_tr + f_tr, p_va + curves.force(held_out.dq)
    return train_and_validate(cfg.learning, names, train, y_tr, p_tr, held_out, y_va, p_va, fr, progress,
                              model_friction=f_tr)
