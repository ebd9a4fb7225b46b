"""The joint mode of payload identification in ``dynid identify`` (issue 35 item 2): ``[[data]]`` experiments
with ``payload = true`` (the payload mounted) and without, and a ``[payload]`` table (mount body, optional known
mass, origin, name, physical; :func:`dynid.config.payload.parse_joint_payload`).

Each experiment is processed on its own and compressed on its own with the columns [the arm's base parameters |
the mount body's 10 standard-regressor columns]; :func:`dynid.estimation.payload.joint_problem` zeroes the payload
columns of the experiments without it and stacks the factors per (experiment, channel), and
:func:`dynid.estimation.payload.fit_joint` runs Gautier's WLS (or OLS) on them, with ``payload.physical`` the
payload's pseudo-inertia :math:`\\succeq 0` (the arm's block unconstrained) and a known mass as an equality. The
arm's block (its rows and columns of the joint covariance) is ``result.json``'s result; the payload's block is
written by :func:`dynid.pipeline.payload.write_payload`'s files (``payload.json``, ``payload.urdf``,
``payload.xml``; its summary as ``payload_summary.txt``)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dynid.errors import ConfigError
from dynid.estimation import ProblemBuilder
from dynid.estimation.payload import PAYLOAD_NAMES, PayloadFit, fit_joint, joint_problem
from dynid.model.base_parameters import BaseParameters
from dynid.pipeline.rows import _chunks, row_mask

__all__ = ["check_joint", "JointColumns", "compress_joint", "fit_experiments", "payload_columns"]


def with_payload(result, base: BaseParameters, outcome, system):
    """(result, columns) predicting a held-out log with the payload mounted: the arm's base parameters then the
    identified payload's 10, on the columns [base | mount body] (for :func:`dynid.pipeline.identification.validate`)."""
    cols = JointColumns(base, outcome_block(system, outcome))
    ext = dataclasses.replace(result, names=tuple(base.names) + PAYLOAD_NAMES,
                              params=np.r_[np.asarray(result.params, float), outcome.values()], cov_params=None)
    return ext, cols


def outcome_block(system, outcome):
    return payload_columns(system, outcome.body)[1]


class JointColumns:
    """The arm's base columns then the mount body's 10 (duck-types what :func:`~dynid.pipeline.rows._chunks`
    reads of :class:`~dynid.model.base_parameters.BaseParameters`)."""

    def __init__(self, base: BaseParameters, block) -> None:
        self.index = np.r_[np.asarray(base.independent, dtype=int), np.asarray(block, dtype=int)]
        self.n_base, self.n_standard = len(self.index), int(base.n_standard)
        self.names = tuple(base.names) + PAYLOAD_NAMES

    def regressor(self, W):
        return np.asarray(W)[..., self.index]


def check_joint(cfg, system) -> None:
    """Refuse, in one line, what the joint mode does not support."""
    icfg = cfg.identification
    why = ("identification.physical_consistency (the joint fit constrains the payload block only; set "
           "payload.physical)" if icfg.physical_consistency else
           "identification.nominal_weighting" if icfg.nominal_weighting else
           "a closed-loop mechanism (the payload's mount is a serial robot's body here)" if system.kind != "serial"
           else None)
    if why is None and cfg.payload.mass is not None and not cfg.payload.physical:
        why = "payload.mass with payload.physical = false (the known mass is an equality of the constrained fit)"
    if why is None and cfg.validation_logs[0].payload:
        raise ConfigError("validation[0].payload = true: the first held-out log is scored with the arm alone (its "
                          "nominal and row-selection tables); put a log without the payload first, the loaded ones "
                          "after it (those are predicted with the payload)")
    if why is not None:
        raise ConfigError(f"payload: the joint arm + payload identification does not support {why}")


def payload_columns(system, body: str | None):
    """(joint name, body block, parent link, placement) of the mount (:func:`dynid.pipeline.payload._mount`)."""
    from dynid.pipeline.payload_outcome import _mount

    return _mount(system, body)


def compress_joint(system, base: BaseParameters, block, ds, *, force_model, pcfg, icfg, parallel, progress, meta):
    """An experiment's compressed factors with the columns [base | payload] and the measured efforts."""
    cols = JointColumns(base, block)
    builder = ProblemBuilder(tuple(base.names) + PAYLOAD_NAMES, system.channel_names(force_model))
    for c in _chunks(system, cols, ds, force_model, parallel_decimate=parallel, chunk_size=icfg.chunk_size,
                     progress=progress, periodic=None, reversal_guard=pcfg.reversal_guard_s(),
                     min_velocity=pcfg.min_velocity):
        mask = row_mask(system, force_model, c.dq, pcfg.min_velocity, joint_dq=c.joint_dq,
                        min_velocity_passive=pcfg.min_velocity_passive, reversal=c.reversal)
        if mask is not None and mask.ndim == 1:
            builder.add(c.W[mask], c.y[mask])
        else:
            builder.add(c.W, c.y, mask)
    return builder.build(meta=meta or {})


def fit_experiments(cfg, system, base: BaseParameters, exps, mount, collapse) -> tuple[Any, Any]:
    """The joint fit of the experiments (each ``problem`` with the [base | payload] columns): the arm's result
    (collapsed to the robot's channels by ``collapse(result, stacked, exps)``) and the payload's
    :class:`~dynid.pipeline.payload.PayloadOutcome`."""
    from dynid.pipeline.payload_outcome import PayloadOutcome

    pl = cfg.payload
    mounted = [bool(e.payload) for e in exps]
    stacked = joint_problem([e.problem for e in exps], mounted)
    res = fit_joint(stacked, physical=pl.physical, mass=pl.mass,
                    weighting="ols" if cfg.identification.method == "ols" else "wls", solver=cfg.identification.solver)
    out = collapse(res, stacked, exps)
    r = base.n_base
    cov = None if out.cov_params is None else np.asarray(out.cov_params)
    arm = dataclasses.replace(out, names=tuple(base.names), params=np.asarray(out.params)[:r],
                              cov_params=None if cov is None else cov[:r, :r], expressions=base.expressions(),
                              solver={k: v for k, v in out.solver.items() if k != "standard_params"},
                              method=cfg.identification.method.upper(),  # the LMI (if any) is on the payload only
                              notes=tuple(n for n in out.notes if not n.startswith("standard parameters:")))
    loaded = [e.index for e in exps if e.payload]
    arm = arm.with_notes(f"joint arm + payload fit: the arm's base parameters from every experiment, the payload's "
                         f"10 parameters (the columns of {mount[0]}'s body) from the experiments with it "
                         f"(data{loaded}); this result is the arm's block (payload.json the payload's)")
    pres = dataclasses.replace(out, names=PAYLOAD_NAMES, params=np.asarray(out.params)[r:],
                               cov_params=None if cov is None else cov[r:, r:], expressions=None,
                               notes=tuple(n for n in out.notes if not n.startswith("standard parameters:")))
    if pl.mass is not None and pres.cov_params is not None:
        c = np.array(pres.cov_params)
        c[0, :] = c[:, 0] = 0.0
        pres = dataclasses.replace(pres, cov_params=c)
    pbase = BaseParameters(PAYLOAD_NAMES, np.arange(10), np.zeros(0, dtype=int), np.zeros((10, 0)), 1e-8,
                           int(np.sum(stacked.n_obs)), 0)
    std = np.array(pres.params, dtype=float)
    if pl.mass is not None:
        std[0] = pl.mass
    fit = PayloadFit(pres, std, pbase, pl.mass, pres.cov_params, None, PAYLOAD_NAMES, ())
    n_rows = np.asarray(stacked.n_obs).reshape(len(exps), -1)[[i for i, m in enumerate(mounted) if m]].sum(axis=0)
    files = {f"data[{e.index}]": str(f) for e in exps if e.payload for f in e.spec.files()}
    notes = ["joint identification with the arm (dynid identify): the arm's base parameters shared by every "
             "[[data]] experiment, the payload's columns only in the experiments with payload = true; the payload's "
             "covariance is its block of the joint covariance",
             "the arm's friction and drive model are assumed unchanged by the payload"]
    if pl.mass is not None:
        notes.append(f"known payload mass {pl.mass:g} kg (an equality of the fit)")
    body, _, parent, placement = mount
    outcome = PayloadOutcome(pl, fit, system.name, body, parent, placement, "(joint: this identification's result.json)",
                             arm.method, "", {"source": files}, [int(n) for n in n_rows], tuple(notes))
    return arm, outcome
