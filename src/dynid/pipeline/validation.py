"""Held-out scoring of ``dynid identify`` (issue 38: the pipeline split by concern): the identified
and the nominal model predict a processed held-out log (:func:`validate_with_prior`), with the other
view of a redundant mechanism, the rows a row selection keeps and the full-rate scores
(:func:`score_held_out`, which ``dynid predict`` applies to a new log too)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dynid._typing import FloatArray
from dynid.config import Config
from dynid.dataset import Dataset
from dynid.errors import InputError
from dynid.estimation import IdentificationResult
from dynid.estimation.validation import ValidationMetrics, prior_comparison
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System, as_system
from dynid.pipeline import stribeck
from dynid.pipeline.data import build_system, preprocess
from dynid.pipeline.held_out_floor import FloorAccumulator
from dynid.pipeline.outcome import FullRate, OtherView, RowSelection, SelectedRows, _other_view
from dynid.pipeline.rows import Progress, _chunks, _no_progress, row_mask

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
    return _validate(result, robot, base, ds, nominal, force_model=force_model, parallel_decimate=parallel_decimate,
                     chunk_size=chunk_size, progress=progress, friction=friction, periodic=periodic,
                     selection=selection)[:4]


def _validate(result: IdentificationResult, robot, base: BaseParameters, ds: Dataset, nominal: FloatArray | None, *,
              force_model: str | None = None, parallel_decimate: int = 1, chunk_size: int = 20000,
              progress: Progress = _no_progress, friction: stribeck.FrictionJoints | None = None, periodic=None,
              selection: RowSelection | None = None, full_rate: bool = False):
    """:func:`validate`, and in the same pass over the held-out rows the errors of the nominal
    model (base parameters ``nominal`` of the robot description's standard parameters; None:
    not computed): the prior every identified model has to beat. For a redundantly actuated
    mechanism also the other view of the same predictions (:class:`OtherView`, None otherwise).
    With ``selection`` (the training's row selection) also both models' errors on the held-out
    rows that selection keeps (:class:`SelectedRows`, None otherwise), with the held-out-fit floor on
    those rows and on every held-out row for a model linear in its parameters
    (:mod:`dynid.pipeline.held_out_floor`: the structure fitted to the held-out rows themselves).

    :func:`_validate` with ``full_rate`` (parallel decimation only) also returns, fifth, both
    models' metrics at the log's full rate, from the full-rate regressor blocks of the same pass
    (the ``tap`` of :func:`~dynid.pipeline.rows._chunks`): the scores :func:`score_held_out`
    computed in a second pass over the same rows (issue 37, item 5)."""
    system = as_system(robot)
    if friction is None and tuple(result.names) != base.names:
        raise InputError("the result's parameters are not the base parameters of this robot")
    meas, pred, prior, kept = [], [], [], []
    alt: list[tuple[FloatArray, FloatArray, FloatArray | None]] = []
    guard = None if selection is None else selection.reversal_guard
    names = system.channel_names(force_model)
    floors = None if selection is None or friction is not None else (FloorAccumulator(names, base.n_base),
                                                                      FloorAccumulator(names, base.n_base))
    full: tuple[list, list, list] | None = None
    tap = None
    if full_rate and parallel_decimate > 1 and periodic is None:
        full = ([], [], [])

        def tap(a: int, b: int, W: FloatArray, rr) -> None:  # what validate_with_prior(decimate 1) computes
            full[0].append(np.asarray(rr.y, dtype=float))
            full[1].append(_predict(result, friction, W, ds.dq[a:b], rr.Ga))
            if nominal is not None:
                full[2].append(W @ nominal)

    for c in _chunks(system, base, ds, force_model, parallel_decimate=parallel_decimate, chunk_size=chunk_size,
                     progress=progress, task="validate", periodic=periodic, reversal_guard=guard,
                     min_velocity=None if selection is None else selection.min_velocity, tap=tap):
        meas.append(c.y)
        if selection is not None:
            mask = row_mask(system, force_model, c.dq, selection.min_velocity,
                            joint_dq=c.joint_dq, min_velocity_passive=selection.min_velocity_passive,
                            reversal=c.reversal)
            kept.append(np.ones(c.y.shape, dtype=bool) if mask is None
                        else np.broadcast_to(mask if mask.ndim == 2 else mask[:, None], c.y.shape))
            if floors is not None:
                floors[0].add(c.W, c.y, kept[-1])
                floors[1].add(c.W, c.y)
        pred.append(_predict(result, friction, c.W, c.dq, c.Ga))
        if nominal is not None:
            prior.append(c.W @ nominal)
        if c.Ga is not None and c.tau is not None:
            alt.append(_other_view(c.Ga, c.tau, pred[-1], prior[-1] if nominal is not None else None, force_model))
    measured, predicted = np.concatenate(meas), np.concatenate(pred)
    k = max(1, parallel_decimate)
    t = np.asarray(ds.t)[::k][: measured.shape[0]]
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
                                                                      kept=mask),
            floor=None if floors is None else floors[0].result(), floor_all=None if floors is None else floors[1].result())
    at_full = None
    if full is not None:
        t_full = np.asarray(ds.t)[: sum(len(m) for m in full[0])]
        f_meas = np.concatenate(full[0])
        at_full = (ValidationMetrics.of(names, t_full, f_meas, np.concatenate(full[1]), src),
                   None if nominal is None else ValidationMetrics.of(names, t_full, f_meas, np.concatenate(full[2]), src))
    return metrics, nominal_metrics, other, selected, at_full


def _predict(result: IdentificationResult, friction, W: FloatArray, dq: FloatArray, Ga: FloatArray | None) -> FloatArray:
    """The identified model's outputs of base-regressor rows ``W``: linear, hierarchical or Stribeck friction."""
    if friction is None:
        return W @ result.params
    if hasattr(friction, "predict"):  # hierarchical
        return friction.predict(result, W, dq, Ga)
    return stribeck.predict(result, friction, W, dq)


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
    shared = parallel > 1 and periodic is None  # the full-rate rows are those the decimation filters
    metrics, prior, other, selected, at_full = _validate(
        result, system, base, held_out, nominal, force_model=force_model, parallel_decimate=parallel,
        chunk_size=icfg.chunk_size, progress=progress, friction=fj, periodic=periodic, selection=rows_rule,
        full_rate=shared)
    full, held_full = None, None
    if pcfg.decimate > 1 and periodic is None:
        if shared:  # parallel decimation keeps every processed sample: the held-out log at full rate is held_out
            held_full = held_out
            assert at_full is not None
            fm, fn = at_full
        else:
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
