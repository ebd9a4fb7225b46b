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
(:mod:`dynid.pipeline.outputs`), the held-out scoring (:mod:`dynid.pipeline.validation`), what a run
records beside its estimate (:mod:`dynid.pipeline.run_record`), several logs in one run
(:mod:`dynid.pipeline.several_logs`), the choices made from the training log
(:mod:`dynid.pipeline.log_choices`), the streamed path (:mod:`dynid.pipeline.identify_streamed`) and
the residual network (:mod:`dynid.pipeline.learning`).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from dynid.config import Config
from dynid.dataset import Dataset
from dynid.errors import ConfigError
from dynid.estimation.validation import ValidationMetrics, motion_overlap, prior_comparison
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System
from dynid.pipeline import stribeck
from dynid.pipeline import experiments as _experiments
from dynid.pipeline.covariance import block_builder, with_covariance
from dynid.pipeline.rows import (  # noqa: F401  (re-exported)
    Progress, _no_progress, Chunk, _chunks, CHUNK_BYTES, _parallel_chunks, row_mask, build_problem, _compress, _model_rows)
from dynid.pipeline.methods import (  # noqa: F401  (re-exported)
    _maximum_likelihood, ML_TIME_CANDIDATES, _acceleration_columns, _interp_rows, ML_INERTIA_POINTS_PER_CUTOFF_PERIOD, ML_INERTIA_MAX_FLOATS, _maximum_likelihood_time, _stribeck_fit, _control_loop, _coulomb_smoothing, _hierarchical_fit)
from dynid.pipeline.drive_gains import (  # noqa: F401  (re-exported)
    GAIN_REL_STD, GAIN_BLOCKS, estimate_drive_gains)
from dynid.pipeline.outcome import (  # noqa: F401  (re-exported: the names other modules import from here)
    RowSelection, SelectedRows, OtherView, _other_view, FullRate, IdentifyOutcome, _versions)
from dynid.pipeline.outputs import (  # noqa: F401
    OUTPUT_FILES, write_outputs, ONE_OF_MANY, standard_vector, export_model, export_warnings, _nominal_dict, _selected_dict, _full_rate_dict, write_files)
from dynid.pipeline.validation import (  # noqa: F401  (re-exported)
    validate, validate_with_prior, _selected_prior, _hierarchical_prior, score_held_out)
from dynid.pipeline.run_record import (  # noqa: F401  (re-exported)
    _run_meta, _with_row_selection, PREDICTION_FORMAT, prediction_inputs, _alarms)
from dynid.pipeline.several_logs import _several, _per_log_validation
from dynid.pipeline.log_choices import _chart_from_log, _decide_structure, _explicit_structure
from dynid.pipeline.identify_streamed import _identify_streamed
from dynid.pipeline.learning import _learn
from dynid.pipeline.data import (build_system, check_held_out, check_joint_motion, check_units, configured_estimator, preprocess, read_log, to_actuator_space)
from dynid.pipeline.reporting import effort_units

__all__ = ["Chunk", "FullRate", "Progress", "ValidationMetrics", "IdentifyOutcome", "RowSelection", "SelectedRows", "build_problem",
           "prior_comparison", "row_mask", "validate", "validate_with_prior", "identify", "write_outputs",
           "write_files", "OUTPUT_FILES"]


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
    if icfg.method in ("iv", "didim", "cloe") and pc is not None:
        raise ConfigError(f"identification.method = {icfg.method!r} replays the experiment sample by sample; "
                          "processing.periodic replaces the log by one averaged period: use time-domain processing")
    return force_model


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
    elif icfg.method in ("iv", "didim", "cloe"):
        result, worst = _control_loop(cfg, system, base, train, force_model, parallel, meta, progress)
    elif icfg.method in ("ekf", "ukf"):  # joint state-parameter Kalman filters (dynid.pipeline.kalman_estimate)
        from dynid.pipeline.kalman_estimate import kalman_estimate

        result, worst = kalman_estimate(cfg, system, base, train, force_model, progress)
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
