"""``dynid identify`` on streamed logs (issue 38: the pipeline split by concern): the training and
held-out logs read, processed and compressed chunk by chunk (:mod:`dynid.pipeline.streaming`,
optionally on a Dask cluster, :mod:`dynid.pipeline.cluster_qr`), scored and recorded as the
in-memory path does."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any

import numpy as np

from dynid.config import Config
from dynid.estimation.validation import prior_comparison
from dynid.model.system import System
from dynid.pipeline.covariance import block_builder, with_covariance
from dynid.pipeline.data import check_held_out, check_joint_motion, configured_estimator
from dynid.pipeline.outcome import FullRate, IdentifyOutcome, RowSelection, SelectedRows
from dynid.pipeline.reporting import effort_units
from dynid.pipeline.rows import Chunk, Progress, _compress, row_mask
from dynid.pipeline.run_record import _alarms, _run_meta, _with_row_selection, prediction_inputs

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
