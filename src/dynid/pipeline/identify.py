"""``dynid identify``: configuration -> identified base parameters -> validation -> files."""

from __future__ import annotations

import csv
import dataclasses
import platform
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from dynid import __version__
from dynid._files import TIMING_FILE, write_timing
from dynid._typing import FloatArray
from dynid.config import Config
from dynid.dataset import Dataset
from dynid.errors import ConfigError, InputError
from dynid.estimation import IdentificationResult, ProblemBuilder, RegressionProblem
from dynid.io.output import staged_output
from dynid.model.base_parameters import BaseParameters, StandardMap, robot_base_parameters
from dynid.model.regressor import regressor
from dynid.model.mechanism import Mechanism
from dynid.model.robot import RobotModel, joint_kinds
from dynid.pipeline import stribeck
from dynid.pipeline.data import (
    build_robot,
    check_held_out,
    check_joint_motion,
    check_units,
    configured_estimator,
    preprocess,
    read_log,
    to_joint_space,
    velocity_mask,
)
from dynid.signals import decimation_filter, decimation_segments, lowpass_sos
from dynid.stats import REPEAT_THRESHOLD, nearest_distances

__all__ = ["Progress", "ValidationMetrics", "IdentifyOutcome", "build_problem", "validate", "identify", "write_outputs", "write_files", "OUTPUT_FILES"]

Progress = Callable[[str, int, int], None]
"""``progress(task, done, total)``: called as long work advances (the CLI draws a bar)."""


def _no_progress(task: str, done: int, total: int) -> None:
    return None


def _chunks(
    robot: RobotModel,
    base: BaseParameters,
    ds: Dataset,
    parallel_decimate: int,
    chunk_size: int,
    progress: Progress,
    task: str,
) -> Iterator[tuple[FloatArray, FloatArray, FloatArray]]:
    """Yield ``(W_base, tau, dq)`` chunk by chunk, at full rate or parallel-decimated.

    Parallel decimation (Gautier 1997; FIGAROH's TX40 pipeline): each column of the
    base regressor and each effort channel are low-passed by the same zero-phase
    filter and one sample in ``k`` is kept, so torque and model see identical
    filtering even where the regressor is non-smooth (Coulomb ``sign`` columns).
    Chunks overlap by 15 filter time constants, which makes the result equal to
    whole-signal filtering to ~1e-12 without ever holding the full regressor.
    """
    if ds.dq is None or ds.ddq is None:
        raise InputError("the dataset has no velocities/accelerations; preprocess it first")
    n = ds.n_samples
    data = robot.create_data()
    if parallel_decimate <= 1:
        buf = np.empty((min(chunk_size, n), robot.dof, robot.n_standard_params))
        for start in range(0, n, chunk_size):
            stop = min(start + chunk_size, n)
            Y = regressor(robot, ds.q[start:stop], ds.dq[start:stop], ds.ddq[start:stop], data=data,
                          out=buf[: stop - start])
            yield base.regressor(Y), ds.tau[start:stop], ds.dq[start:stop]
            progress(task, stop, n)
        return
    k = parallel_decimate
    sos, margin = decimation_filter(k, ds.fs)
    if n <= 2 * k:
        raise InputError(f"{n} samples are too few to decimate by {k}")
    for a, b, keep in decimation_segments(n, k, margin, max(chunk_size, 4 * margin)):
        Y = base.regressor(regressor(robot, ds.q[a:b], ds.dq[a:b], ds.ddq[a:b], data=data))
        filt = lambda x: lowpass_sos(x, sos)[keep]  # noqa: E731
        yield filt(Y), filt(ds.tau[a:b]), filt(ds.dq[a:b])
        progress(task, b, n)


def build_problem(
    robot: RobotModel,
    base: BaseParameters,
    ds: Dataset,
    *,
    min_velocity: tuple[float, ...] | None = None,
    parallel_decimate: int = 1,
    chunk_size: int = 20000,
    progress: Progress = _no_progress,
    meta: dict[str, Any] | None = None,
    cross: bool = False,
) -> RegressionProblem:
    """Compress a processed joint-space dataset chunk by chunk (never the full regressor).

    ``min_velocity`` drops, per joint equation, the rows where that joint's (filtered)
    velocity is below the threshold [rad/s] (Coulomb friction is ill-defined there). With
    ``cross`` (a full noise covariance across joints needs every joint of every sample) it
    drops the whole samples in which any joint is that slow.
    """
    builder = ProblemBuilder(base.names, robot.joint_names, cross=cross)
    for W, tau, dq in _chunks(robot, base, ds, parallel_decimate, max(1, int(chunk_size)), progress, "compress"):
        mask = velocity_mask(dq, min_velocity)
        if cross and mask is not None:
            keep = mask.all(axis=1)
            W, tau, mask = W[keep], tau[keep], None
        builder.add(W, tau, mask)
    return builder.build(expressions=base.expressions(), standard=StandardMap.of(robot, base), meta=meta or {})


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
    overlap: dict[str, Any] | None = None  # how close the validation motion comes to the training motion

    @property
    def in_sample(self) -> bool:
        """The validation motion repeats the training motion (see :func:`motion_overlap`): its
        errors are in-sample errors, whatever window or file they come from."""
        return bool(self.overlap and self.overlap["repeats_training"])

    @property
    def label(self) -> str:
        """``"held-out"`` or ``"in-sample"`` (what the validation errors are)."""
        return "in-sample" if self.in_sample else "held-out"

    def heading(self) -> str:
        """The title of the validation table."""
        if not self.in_sample:
            return f"Validation on held-out data ({self.n_samples} samples; never used for training)"
        return (f"Validation IN-SAMPLE ({self.n_samples} samples): the validation motion repeats the training motion "
                f"(median distance to the nearest training state {self.overlap['median_distance']:.3g} training "
                f"standard deviations, below {self.overlap['threshold']:g}); these errors do not show how the model "
                "predicts new motion: validate on another trajectory")

    @classmethod
    def of(cls, channel_names, t: FloatArray, measured: FloatArray, predicted: FloatArray, source) -> ValidationMetrics:
        """Errors of ``predicted`` against ``measured`` (n, channels) per channel."""
        err = measured - predicted
        centred = measured - measured.mean(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            r2 = 1.0 - np.sum(err**2, axis=0) / np.sum(centred**2, axis=0)
        return cls(
            channel_names=tuple(channel_names),
            n_samples=int(measured.shape[0]),
            rmse=np.sqrt(np.mean(err**2, axis=0)),
            rms_measured=np.sqrt(np.mean(measured**2, axis=0)),
            max_abs_error=np.max(np.abs(err), axis=0),
            r2=r2,
            t=t,
            measured=measured,
            predicted=predicted,
            source=dict(source) if isinstance(source, dict) else {"source": str(source)},
        )

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
            "kind": self.label,
            "motion_overlap": self.overlap,
            **({"warning": self.heading()} if self.in_sample else {}),
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
    parallel_decimate: int = 1,
    chunk_size: int = 20000,
    progress: Progress = _no_progress,
    friction: stribeck.FrictionJoints | None = None,
) -> ValidationMetrics:
    """Predict the held-out torques with the identified base parameters; per-joint errors.

    The held-out data go through exactly the processing of the training data
    (including parallel decimation when used). ``friction``: the result is a Stribeck fit
    (:mod:`dynid.pipeline.stribeck`) with these friction joints.
    """
    if friction is None and tuple(result.names) != base.names:
        raise InputError("the result's parameters are not the base parameters of this robot")
    meas, pred = [], []
    for W, tau, dq in _chunks(robot, base, ds, parallel_decimate, max(1, int(chunk_size)), progress, "validate"):
        meas.append(tau)
        pred.append(W @ result.params if friction is None else stribeck.predict(result, friction, W, dq))
    measured, predicted = np.concatenate(meas), np.concatenate(pred)
    k = max(1, parallel_decimate)
    return ValidationMetrics.of(robot.joint_names, np.asarray(ds.t)[::k][: measured.shape[0]], measured, predicted,
                                ds.meta.get("source"))


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
    raw_train: Dataset | None = None  # the training log before processing (for the processing plot)
    elapsed_s: float = float("nan")  # wall-clock time of the identification (timing.json)

    def summary_text(self) -> str:
        v = self.validation
        lines = [
            str(self.result.summary()),
            "",
            v.heading(),
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
    """Run the whole identification described by ``cfg`` (nothing is written).

    Closed-loop mechanisms go through :func:`dynid.pipeline.identify_mechanism.identify_mechanism`."""
    t0 = time.perf_counter()
    outcome = _identify(cfg, progress)
    validation = dataclasses.replace(outcome.validation, overlap=motion_overlap(outcome.train, outcome.held_out))
    return dataclasses.replace(outcome, validation=validation, elapsed_s=time.perf_counter() - t0)


def motion_overlap(train: Dataset, held_out: Dataset) -> dict[str, Any]:
    """Does the validation motion repeat the training motion?

    The processed states ``(q, dq, ddq)`` of every joint (actuator) are compared: each held-out
    state's distance to the nearest training state, in training standard deviations
    (:func:`dynid.stats.nearest_distances`). A median below
    :data:`dynid.stats.REPEAT_THRESHOLD` (0.05) means the validation motion retraces the training
    motion (a tail window of a periodic excitation, a copy of the log): its errors are in-sample
    errors. A new trajectory lies about one standard deviation away.
    """
    states = lambda ds: np.hstack([ds.q, ds.dq, ds.ddq])  # noqa: E731
    d = nearest_distances(states(train), states(held_out))
    median = float(np.median(d))
    return {"median_distance": median, "p90_distance": float(np.quantile(d, 0.9)), "threshold": REPEAT_THRESHOLD,
            "repeats_training": median < REPEAT_THRESHOLD, "n_compared": int(d.size),
            "metric": "distance of held-out (q, dq, ddq) to the nearest training state, in training standard deviations"}


def _identify(cfg: Config, progress: Progress) -> IdentifyOutcome:
    robot = build_robot(cfg.robot)
    if cfg.processing.periodic is not None and cfg.processing.periodic.domain == "pose" and not isinstance(robot, Mechanism):
        raise ConfigError("processing.periodic.domain = 'pose' is for parallel robots (serial robots have no platform pose)")
    if cfg.identification.method == "ml" and not isinstance(robot, Mechanism):
        raise ConfigError("identification.method = 'ml' (cut-off estimated with the parameters, paper 004 Eq. 24) is "
                          "for parallel robots; serial robots are not supported yet")
    if isinstance(robot, Mechanism):
        from dynid.pipeline.identify_mechanism import identify_mechanism

        return identify_mechanism(cfg, robot, progress, _versions())
    nonlinear = cfg.identification.friction_model == "stribeck"
    if nonlinear:
        stribeck.check_config(cfg, robot)
    names = robot.joint_names
    kinds = joint_kinds(robot.pin_model)
    check_units(cfg.data, kinds, names, "data")
    check_units(cfg.validation, kinds, names, "validation")
    readers: dict = {}
    raw_train = read_log(cfg.data, robot.dof, names, "data", readers)
    raw_valid = read_log(cfg.validation, robot.dof, names, "validation", readers)
    check_held_out(raw_train, raw_valid)
    train_j, notes = to_joint_space(raw_train, robot, "data")
    valid_j, _ = to_joint_space(raw_valid, robot, "validation")
    icfg = cfg.identification

    def unknowns() -> tuple[int, int]:
        return robot_base_parameters(robot, n_samples=icfg.base_samples, seed=icfg.base_seed).n_base, robot.dof

    train, steps = preprocess(train_j, cfg.processing, "data", unknowns=unknowns)
    held_out, _ = preprocess(valid_j, cfg.processing, "validation")
    check_joint_motion(train, robot, cfg.identification.min_joint_motion, "data")
    progress("base parameters", 0, 1)
    base = robot_base_parameters(robot, n_samples=cfg.identification.base_samples, seed=cfg.identification.base_seed)
    progress("base parameters", 1, 1)
    pcfg = cfg.processing
    parallel = pcfg.decimate if pcfg.decimate_method == "parallel" else 1
    n_eff = -(-train.n_samples // parallel)
    if n_eff * robot.dof <= base.n_base:
        raise InputError(
            f"data: {n_eff} processed samples x {robot.dof} joints are fewer than the {base.n_base} base parameters"
        )
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
    fj = None
    if nonlinear:
        fj = stribeck.friction_joints(robot, base)
        rows = stribeck.subsample(train, icfg.max_samples)
        chunks = ((W, tau) for W, tau, _ in _chunks(robot, base, rows, 1, icfg.chunk_size, progress, "Stribeck rows"))
        sp = stribeck.sample_problem(chunks, rows, fj, base, robot.joint_names, StandardMap.of(robot, base), meta,
                                     pcfg.min_velocity)
        progress("Stribeck fit", 0, 1)
        result = stribeck.describe(stribeck.estimator(cfg).fit(sp), base, fj, rows.n_samples, train.n_samples,
                                   pcfg.min_velocity)
        progress("Stribeck fit", 1, 1)
    else:
        problem = build_problem(robot, base, train, min_velocity=pcfg.min_velocity, parallel_decimate=parallel,
                                chunk_size=icfg.chunk_size, progress=progress, meta=meta, cross=icfg.method == "gm")
        nominal = base.from_standard(robot.nominal_parameters()) if icfg.nominal_weighting else None
        estimator = configured_estimator(icfg, steps, robot.joint_names, robot.joint_names, nominal)
        result = estimator.fit(problem)
    if pcfg.min_velocity is not None:
        result = result.with_provenance(
            row_selection={"min_velocity_rad_s": list(pcfg.min_velocity), "rows_kept_per_joint": result.n_obs.tolist(),
                           "rule": ("whole samples with every joint at least that fast (full noise covariance)"
                                    if icfg.method == "gm" else "per joint equation")}
        )
    if notes:
        result = result.with_notes(*notes)
    metrics = validate(result, robot, base, held_out, parallel_decimate=parallel,
                       chunk_size=cfg.identification.chunk_size, progress=progress, friction=fj)
    return IdentifyOutcome(cfg, robot, base, result, metrics, train, held_out, tuple(notes), train_j)


OUTPUT_FILES = ("result.json", "result.npz", "params.csv", "summary.txt", "validation.png", "processing.png", "report.html",
                "model.urdf", "model.mjcf", TIMING_FILE)


def write_outputs(outcome: IdentifyOutcome, out_dir: str | Path) -> dict[str, Path]:
    """Write result.json, result.npz, params.csv, summary.txt, timing.json (+ plots, report.html).

    Files are staged and moved into ``out_dir`` only when all were written; dynid
    outputs of an earlier run that this run did not produce are removed. Returns the
    files of this run.
    """
    out = Path(out_dir)
    with staged_output(out) as stage:
        write_files(outcome, stage)
        produced = sorted(p.name for p in stage.iterdir())
    # outputs of an earlier run that this run did not write (e.g. plots now switched off)
    # would describe another identification: remove them
    for name in OUTPUT_FILES:
        if name not in produced and (out / name).is_file():
            (out / name).unlink()
    return {name: out / name for name in produced}


def export_model(outcome: IdentifyOutcome, folder: Path) -> Path | None:
    """The recovered standard parameters of a physically consistent fit as a robot description:
    ``model.urdf`` for a serial robot, ``model.mjcf`` for a closed-loop mechanism (None when the
    method recovers no standard parameters)."""
    std = outcome.result.solver.get("standard_params")
    if not std:
        return None
    from dynid.io.export import write_mjcf, write_urdf

    robot = outcome.robot
    names = robot.parameter_names
    missing = [n for n in names if n not in std]
    if missing:
        raise InputError(f"the result's standard parameters do not match the robot (missing {missing[:3]})")
    params = np.array([std[n] for n in names], dtype=float)
    if isinstance(robot, Mechanism):
        return write_mjcf(robot, params, folder / "model.mjcf", name=f"{robot.name}_identified")
    return write_urdf(robot, params, folder / "model.urdf", name=f"{robot.name}_identified")


def export_warnings(outcome: IdentifyOutcome, factor: float = 10.0) -> list[str]:
    """Lines for summary.txt when the exported standard parameters are far from the model's
    nominal ones: a body mass more than ``factor`` times above or below its nominal value. The
    base parameters fix only combinations of the standard ones; without regularization the rest
    comes from the tie-break, and a constrained fit on weak data can push it far (e.g. legs of
    hundreds of tonnes that give the same actuator forces)."""
    std = outcome.result.solver.get("standard_params")
    robot = outcome.robot
    if not std:
        return []
    nominal = robot.nominal_parameters()
    names = robot.parameter_names
    far = []
    for blk in robot.body_blocks():
        i = blk[0]
        m, m0 = float(std[names[i]]), float(nominal[i])
        if m0 > 0 and not (m0 / factor <= m <= m0 * factor):
            far.append(f"{names[i]} = {m:.4g} kg (nominal {m0:.4g} kg)")
    if not far:
        return []
    return [f"warning: the exported model's masses are far from the nominal ones: {', '.join(far)}. The data fix "
            "the base parameters only; regularization towards the nominal model (identification.regularization) "
            "gives standard parameters a simulator can trust."]


def write_files(outcome: IdentifyOutcome, stage: Path) -> None:
    """Write the output files into an existing folder (see :func:`write_outputs`)."""
    res = outcome.result
    expressions = res.expressions if res.expressions is not None else outcome.base.expressions()
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
        if res.cov_params is not None:
            ci, bse, rel = res.conf_int(), res.bse, res.rel_std
            stats = [(repr(float(bse[i])), f"{rel[i]:.6g}", repr(float(ci[i, 0])), repr(float(ci[i, 1]))) for i in range(len(res.names))]
        else:  # the method gives no covariance (see the result's notes): leave the columns empty
            stats = [("", "", "", "")] * len(res.names)
        for i, n in enumerate(res.names):
            w.writerow([n, repr(float(res.params[i])), *stats[i], expressions[i]])
    warn = export_warnings(outcome)
    (stage / "summary.txt").write_text(outcome.summary_text() + "\n" + "".join(f"\n{w}\n" for w in warn))
    export_model(outcome, stage)
    write_timing(stage, {"identify_s": outcome.elapsed_s, "solver": res.timing})
    if outcome.config.output.plots:
        from dynid.report import plot_validation, write_html_report

        plot_validation(outcome.validation, stage / "validation.png")
        if outcome.raw_train is not None:
            from dynid.report.plots import plot_processing

            plot_processing(outcome.raw_train, outcome.train, stage / "processing.png")
        write_html_report(res, outcome.validation, stage / "report.html", plot="validation.png")
