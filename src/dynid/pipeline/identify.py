"""``dynid identify``: configuration -> identified base parameters -> validation -> files."""

from __future__ import annotations

import csv
import dataclasses
import platform
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from dynid import __version__
from dynid._typing import FloatArray
from dynid.config import Config
from dynid.dataset import Dataset
from dynid.errors import InputError
from dynid.estimation import ESTIMATORS, IdentificationResult, ProblemBuilder, RegressionProblem
from dynid.io.output import staged_output
from dynid.model.base_parameters import BaseParameters, robot_base_parameters
from dynid.model.regressor import regressor
from dynid.model.robot import RobotModel
from dynid.pipeline.data import build_robot, check_joint_motion, preprocess, read_log, to_joint_space, velocity_mask

__all__ = ["Progress", "ValidationMetrics", "IdentifyOutcome", "build_problem", "validate", "identify", "write_outputs", "write_files", "OUTPUT_FILES"]

Progress = Callable[[str, int, int], None]
"""``progress(task, done, total)``: called as long work advances (the CLI draws a bar)."""


def _no_progress(task: str, done: int, total: int) -> None:
    return None


def build_problem(
    robot: RobotModel,
    base: BaseParameters,
    ds: Dataset,
    *,
    mask: np.ndarray | None = None,
    chunk_size: int = 20000,
    progress: Progress = _no_progress,
    meta: dict[str, Any] | None = None,
) -> RegressionProblem:
    """Compress a processed joint-space dataset chunk by chunk (never the full regressor)."""
    if ds.dq is None or ds.ddq is None:
        raise InputError("the dataset has no velocities/accelerations; preprocess it first")
    n = ds.n_samples
    builder = ProblemBuilder(base.names, robot.joint_names)
    data = robot.create_data()
    chunk = max(1, int(chunk_size))
    buf = np.zeros((min(chunk, n), robot.dof, robot.n_standard_params))
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        out = buf[: stop - start]
        Y = regressor(robot, ds.q[start:stop], ds.dq[start:stop], ds.ddq[start:stop], data=data, out=out)
        builder.add(base.regressor(Y), ds.tau[start:stop], None if mask is None else mask[start:stop])
        progress("compress", stop, n)
    return builder.build(expressions=base.expressions(), meta=meta or {})


@dataclasses.dataclass(frozen=True, eq=False)
class ValidationMetrics:
    """Prediction errors of an identified model on held-out data."""

    channel_names: tuple[str, ...]
    n_samples: int
    rmse: FloatArray
    rms_measured: FloatArray
    max_abs_error: FloatArray
    r2: FloatArray
    t: FloatArray
    measured: FloatArray
    predicted: FloatArray
    source: dict[str, Any]

    @property
    def rel_rmse_pct(self) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100.0 * self.rmse / self.rms_measured

    def to_dict(self) -> dict[str, Any]:
        return {
            "joints": list(self.channel_names),
            "n_samples": self.n_samples,
            "rmse_per_joint": self.rmse.tolist(),
            "rel_rmse_pct_per_joint": [float(x) if np.isfinite(x) else None for x in self.rel_rmse_pct],
            "max_abs_error_per_joint": self.max_abs_error.tolist(),
            "r2_per_joint": self.r2.tolist(),
            "rms_measured_per_joint": self.rms_measured.tolist(),
            "source": self.source,
        }

    def table(self) -> str:
        rows = [("joint", "RMSE", "rel RMSE %", "max |err|", "R^2")]
        for c, r, p, m, q in zip(self.channel_names, self.rmse, self.rel_rmse_pct, self.max_abs_error, self.r2):
            rows.append((c, f"{r:.4g}", f"{p:.3g}", f"{m:.4g}", f"{q:.4f}"))
        w = [max(len(r[i]) for r in rows) for i in range(5)]
        lines = ["  ".join([r[0].ljust(w[0])] + [c.rjust(x) for c, x in zip(r[1:], w[1:])]) for r in rows]
        lines.insert(1, "-" * len(lines[0]))
        return "\n".join(lines)


def validate(
    result: IdentificationResult,
    robot: RobotModel,
    base: BaseParameters,
    ds: Dataset,
    *,
    chunk_size: int = 20000,
    progress: Progress = _no_progress,
) -> ValidationMetrics:
    """Predict the held-out torques with the identified base parameters; per-joint errors."""
    if tuple(result.names) != base.names:
        raise InputError("the result's parameters are not the base parameters of this robot")
    n = ds.n_samples
    pred = np.empty_like(ds.tau)
    data = robot.create_data()
    for start in range(0, n, chunk_size):
        stop = min(start + chunk_size, n)
        Y = regressor(robot, ds.q[start:stop], ds.dq[start:stop], ds.ddq[start:stop], data=data)
        pred[start:stop] = base.regressor(Y) @ result.params
        progress("validate", stop, n)
    err = ds.tau - pred
    rmse = np.sqrt(np.mean(err**2, axis=0))
    centred = ds.tau - ds.tau.mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = 1.0 - np.sum(err**2, axis=0) / np.sum(centred**2, axis=0)
    return ValidationMetrics(
        channel_names=robot.joint_names,
        n_samples=n,
        rmse=rmse,
        rms_measured=np.sqrt(np.mean(ds.tau**2, axis=0)),
        max_abs_error=np.max(np.abs(err), axis=0),
        r2=r2,
        t=np.asarray(ds.t),
        measured=np.asarray(ds.tau),
        predicted=pred,
        source=dict(ds.meta.get("source", {})) if isinstance(ds.meta.get("source"), dict) else {"source": str(ds.meta.get("source"))},
    )


@dataclasses.dataclass(frozen=True, eq=False)
class IdentifyOutcome:
    config: Config
    robot: RobotModel
    base: BaseParameters
    result: IdentificationResult
    validation: ValidationMetrics
    train: Dataset
    held_out: Dataset
    notes: tuple[str, ...]

    def summary_text(self) -> str:
        v = self.validation
        lines = [
            str(self.result.summary()),
            "",
            f"Validation on held-out data ({v.n_samples} samples; never used for training)",
            v.table(),
        ]
        return "\n".join(lines)


def _versions() -> dict[str, str]:
    import numpy
    import pinocchio
    import scipy

    return {
        "dynid": __version__,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "pinocchio": pinocchio.__version__,
    }


def identify(cfg: Config, progress: Progress = _no_progress) -> IdentifyOutcome:
    """Run the whole identification described by ``cfg`` (nothing is written)."""
    robot = build_robot(cfg.robot)
    names = robot.joint_names
    raw_train = read_log(cfg.data, robot.dof, names, "data")
    raw_valid = read_log(cfg.validation, robot.dof, names, "validation")
    train_j, notes = to_joint_space(raw_train, robot, "data")
    valid_j, _ = to_joint_space(raw_valid, robot, "validation")
    train, steps = preprocess(train_j, cfg.processing, "data")
    held_out, _ = preprocess(valid_j, cfg.processing, "validation")
    check_joint_motion(train, robot, cfg.identification.min_joint_motion, "data")
    progress("base parameters", 0, 1)
    base = robot_base_parameters(robot, n_samples=cfg.identification.base_samples, seed=cfg.identification.base_seed)
    progress("base parameters", 1, 1)
    if train.n_samples * robot.dof <= base.n_base:
        raise InputError(
            f"data: {train.n_samples} processed samples x {robot.dof} joints are fewer than the {base.n_base} base parameters"
        )
    mask = velocity_mask(train, cfg.processing.min_velocity)
    meta = {
        "versions": _versions(),
        "config_file": str(cfg.source) if cfg.source else None,
        "config": cfg.raw,
        "robot": {"model": cfg.robot.model, "name": robot.name, "extras": list(robot.extras),
                  "transmission": robot.transmission.describe() if robot.transmission else None},
        "training_data": dict(raw_train.meta),
        "validation_data": dict(raw_valid.meta),
        "processing": steps,
        "base_parameters": {"n_base": base.n_base, "seed": base.seed, "n_samples": base.n_samples, "rank_tol": base.rank_tol},
    }
    if mask is not None:
        meta["row_selection"] = {"min_velocity": list(cfg.processing.min_velocity or ()), "rows_kept_per_joint": mask.sum(axis=0).tolist()}
    problem = build_problem(robot, base, train, mask=mask, chunk_size=cfg.identification.chunk_size, progress=progress, meta=meta)
    estimator = ESTIMATORS[cfg.identification.method]()
    result = estimator.fit(problem)
    if notes:
        result = result.with_notes(*notes)
    metrics = validate(result, robot, base, held_out, chunk_size=cfg.identification.chunk_size, progress=progress)
    return IdentifyOutcome(cfg, robot, base, result, metrics, train, held_out, tuple(notes))


OUTPUT_FILES = ("result.json", "result.npz", "params.csv", "summary.txt", "validation.png", "report.html")


def write_outputs(outcome: IdentifyOutcome, out_dir: str | Path) -> dict[str, Path]:
    """Write result.json, result.npz, params.csv, summary.txt (+ plots, report.html).

    Files are staged and moved into ``out_dir`` only when all were written.
    """
    with staged_output(out_dir) as stage:
        write_files(outcome, stage)
    out = Path(out_dir)
    return {name: out / name for name in OUTPUT_FILES if (out / name).exists()}


def write_files(outcome: IdentifyOutcome, stage: Path) -> None:
    """Write the output files into an existing folder (see :func:`write_outputs`)."""
    res = outcome.result
    expressions = outcome.base.expressions()
    res.save(
        stage / "result",
        extra={
            "validation": outcome.validation.to_dict(),
            "training": {"n_samples": outcome.train.n_samples, "rmse_per_joint": res.rmse_per_channel.tolist()},
            "base_parameters": {
                "names": list(outcome.base.names),
                "expressions": list(expressions),
                "standard_names": list(outcome.base.standard_names),
            },
        },
    )
    with open(stage / "params.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", "value", "std", "rel_std_pct", "ci_low", "ci_high", "expression"])
        ci = res.conf_int()
        for i, n in enumerate(res.names):
            w.writerow([n, repr(float(res.params[i])), repr(float(res.bse[i])), f"{res.rel_std[i]:.6g}",
                        repr(float(ci[i, 0])), repr(float(ci[i, 1])), expressions[i]])
    (stage / "summary.txt").write_text(outcome.summary_text() + "\n")
    if outcome.config.output.plots:
        from dynid.report import plot_validation, write_html_report

        plot_validation(outcome.validation, stage / "validation.png")
        write_html_report(res, outcome.validation, stage / "report.html", plot="validation.png")
