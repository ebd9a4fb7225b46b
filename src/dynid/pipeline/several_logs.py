"""Several logs in one ``dynid identify`` run (issue 38: the pipeline split by concern): the
``[[data]]`` experiments processed and compressed one by one, their factors stacked
(:mod:`dynid.pipeline.experiments`; the joint arm + payload mode, :mod:`dynid.pipeline.joint_payload`),
and a held-out table per ``[[validation]]`` log."""

from __future__ import annotations

from typing import Any

from dynid.config import Config
from dynid.dataset import Dataset
from dynid.estimation import IdentificationResult, RegressionProblem
from dynid.estimation.validation import ValidationMetrics
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System
from dynid.pipeline import experiments as _experiments
from dynid.pipeline.data import check_joint_motion, configured_estimator, preprocess, read_log, to_actuator_space
from dynid.pipeline.rows import _compress
from dynid.pipeline.validation import validate

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
