"""``dynid payload CONFIG --out DIR``: a payload's 10 inertial parameters from a log with it mounted, given the
arm's earlier identification (issue 35 item 2; the numerics in :mod:`dynid.estimation.payload`).

The arm's ``result.json`` (``[payload] arm``) fixes the robot, the processing and the arm's model, as for
``dynid predict``: the loaded log is read and processed exactly as ``identify`` processed the arm's log (filters,
derivatives, decimation, row selection), the arm's predicted efforts are subtracted row by row, and the mount
body's 10 standard-regressor columns (the payload regressor) are compressed with the arm's base regressor beside
them (for the arm's share of the covariance). Outputs (staged: all or none): ``payload.json``, ``payload.urdf``,
``payload.xml``, ``summary.txt``.

Joint identification with the arm (experiments with and without the payload in one ``[[data]]`` identification,
``[payload]`` in ``dynid identify``'s config) is :mod:`dynid.pipeline.joint_payload`."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from dynid.config.payload import PayloadConfig
from dynid.errors import ConfigError, InputError
from dynid.estimation import ProblemBuilder
from dynid.estimation.payload import PAYLOAD_NAMES, fit_given_arm
from dynid.io.output import staged_output
from dynid.pipeline.data import build_system, check_units, preprocess, read_log, to_actuator_space
from dynid.pipeline.payload_outcome import PayloadOutcome, _mount, write_payload_files
from dynid.pipeline.predict import result_system
from dynid.pipeline.rows import Progress, _chunks, _no_progress, row_mask

__all__ = ["PayloadOutcome", "identify_payload", "write_payload", "PAYLOAD_FILES"]

PAYLOAD_FILES = ("payload.json", "payload.urdf", "payload.xml", "summary.txt")


class _Columns:
    """The columns of the rows :func:`~dynid.pipeline.rows._chunks` yields: the payload's 10 (the mount body's
    block of the standard regressor), then the arm's base columns (duck-types the ``regressor``, ``n_base``,
    ``n_standard`` of :class:`~dynid.model.base_parameters.BaseParameters` that the chunks use)."""

    def __init__(self, block, independent, n_standard: int) -> None:
        self.index = np.r_[np.asarray(block, dtype=int), np.asarray(independent, dtype=int)]
        self.n_base, self.n_standard = len(self.index), int(n_standard)

    def regressor(self, W):
        return np.asarray(W)[..., self.index]


# ------------------------------------------------------------------------------------ the arm's model
def _arm(cfg: PayloadConfig):
    """The arm's saved result and what it was identified with (as :func:`dynid.pipeline.predict.predict`)."""
    from dynid.config import _parse_identification
    from dynid.pipeline.predict import _processing_config, _robot_config, load_saved

    saved = load_saved(cfg.arm)
    inp = saved.inputs
    robot = dict(inp["robot"])
    if not robot["model"].startswith("builtin:") and not Path(robot["model"]).is_absolute():
        robot["model"] = str((saved.folder / robot["model"]).resolve())
    robot_cfg = _robot_config(robot)
    base_dir = Path(inp["config_dir"]) if inp.get("config_dir") else saved.folder
    if not base_dir.is_absolute():
        base_dir = (saved.folder / base_dir).resolve()
    icfg = _parse_identification(inp["identification"], base_dir)
    why = ("hierarchical friction curves" if icfg.hierarchical else
           "Stribeck friction" if icfg.friction_model == "stribeck" else
           "a learned residual model" if inp.get("learning") is not None else None)
    if why is not None:
        raise ConfigError(f"payload.arm: the arm result has {why}, not linear in its parameters; identify the arm "
                          "with a linear model (ols, wls, gm, physical) for dynid payload")
    if not robot_cfg.model.startswith("builtin:") and not Path(robot_cfg.model).exists():
        raise InputError(f"the robot description the arm was identified on is gone: {robot_cfg.model}")
    return saved, robot_cfg, icfg, _processing_config(inp["processing"])


def identify_payload(cfg: PayloadConfig, progress: Progress = _no_progress) -> PayloadOutcome:
    """The payload of ``cfg`` (module docstring)."""
    saved, robot_cfg, icfg, pcfg = _arm(cfg)
    inp = saved.inputs
    system, force_model, names = result_system(build_system(robot_cfg), icfg, inp, robot_cfg.model,
                                               "the arm's identification")
    body, block, parent, placement = _mount(system, cfg.body)
    check_units(cfg.data, system.actuator_kinds(), names, "data")
    raw = read_log(cfg.data, system.n_actuators, names, "data", {})
    log_a, _ = to_actuator_space(raw, system, "data")
    ds, _ = preprocess(log_a, pcfg, "data")
    if inp["coulomb_width"] is not None:
        system = system.with_coulomb_width(inp["coulomb_width"])
    base = system.base_parameters(force_model, n_samples=icfg.base_samples, seed=icfg.base_seed)
    sb = inp["base_parameters"]
    if list(base.names) != sb["names"] or not np.allclose(base.B, np.array(sb["B"]), rtol=1e-9, atol=1e-12):
        raise InputError("the arm's base parameters are not those of the robot description now (it changed since "
                         "the arm's identification); identify the arm again")
    arm = saved.result
    beta = np.asarray(arm.params, dtype=float)
    cols = _Columns(block, base.independent, base.n_standard)
    builder = ProblemBuilder(PAYLOAD_NAMES + tuple(base.names), system.channel_names(force_model))
    parallel = pcfg.decimate if pcfg.decimate_method == "parallel" else 1
    for c in _chunks(system, cols, ds, force_model, parallel_decimate=parallel, chunk_size=icfg.chunk_size,
                     progress=progress, task="payload rows", periodic=pcfg.periodic,
                     reversal_guard=pcfg.reversal_guard_s(), min_velocity=pcfg.min_velocity):
        resid = c.y - c.W[..., 10:] @ beta
        mask = row_mask(system, force_model, c.dq, pcfg.min_velocity, joint_dq=c.joint_dq,
                        min_velocity_passive=pcfg.min_velocity_passive, reversal=c.reversal)
        if mask is not None and mask.ndim == 1:
            builder.add(c.W[mask], resid[mask])
        else:
            builder.add(c.W, resid, mask)
    problem = builder.build(meta={"source": raw.meta.get("source")})
    if int(problem.n_total) <= 10:
        raise InputError(f"data: {int(problem.n_total)} equations after the arm's row selection; the payload needs "
                         "more than its 10 parameters")
    fit = fit_given_arm(problem, base.names, arm.cov_params, mass=cfg.mass, physical=cfg.physical)
    notes = ["the loaded log processed as the arm's identification processed its log (filters, derivatives, "
             "decimation, row selection); the arm's predicted efforts subtracted row by row",
             "the arm's friction and drive model are assumed unchanged by the payload (a load-dependent friction "
             "goes into the payload's estimate)"]
    if cfg.mass is not None:
        notes.append(f"known payload mass {cfg.mass:g} kg (an equality of the fit); the other 9 parameters estimated")
    arm_json = saved.folder / "result.json"
    return PayloadOutcome(cfg, fit, f"{system.model.name} ({robot_cfg.model})", body, parent, placement,
                          str(arm_json), arm.method, hashlib.sha256(arm_json.read_bytes()).hexdigest(),
                          dict(raw.meta), [int(n) for n in problem.n_obs], tuple(notes))


# ------------------------------------------------------------------------------------ outputs
def write_payload(outcome: PayloadOutcome, out_dir: str | Path) -> list[str]:
    """payload.json, payload.urdf, payload.xml and summary.txt, staged (all or none); the files written."""
    with staged_output(out_dir) as stage:
        write_payload_files(outcome, stage)
    return list(PAYLOAD_FILES)


def payload_config_of(path: str | Path) -> PayloadConfig:
    from dynid.config.payload import load_payload_config

    return load_payload_config(path)

