"""What a ``dynid identify`` run records beside its estimate (issue 38: the pipeline split by
concern), common to the in-memory and the streamed path: the result's provenance (:func:`_run_meta`),
its row selection, the inputs ``dynid predict`` rebuilds the run from (:func:`prediction_inputs`)
and the run's alarms (:func:`_alarms`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dynid._typing import FloatArray
from dynid.config import Config
from dynid.errors import InputError
from dynid.estimation import IdentificationResult
from dynid.estimation.validation import ValidationMetrics
from dynid.model.base_parameters import BaseParameters
from dynid.model.system import System
from dynid.pipeline.outcome import _versions
from dynid.pipeline.reporting import file_sha256

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
